"""The segmentation stage's configurations: the network's architecture, inference in ``prepare``
and training (``radar4dgs seg-train``). Torch-free, so the CLI parses options without torch."""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path
from typing import Literal

DynamicSource = Literal["auto", "prepared", "estimate", "oracle"]
AnchorSampling = Literal["random", "farthest", "cover"]


@dataclass
class SegModelConfig:
    """Architecture of the segmentation network (saved in every checkpoint)."""

    backbone: Literal["resnet18", "resnet34"] = "resnet18"  # torchvision ResNet block layout, truncated after layer3
    backbone_width: int = 32  # channels of layer1 (layer2 ×2, layer3 ×4); 64 = torchvision, needed for ImageNet weights
    # side (px) every patch is resized to before the network, a multiple of 16 (43 px patches at 320x180)
    input_size: int = 48
    attention_layers: int = 2  # number of (self, cross) attention pairs, LoFTR-style
    attention_heads: int = 4  # heads of the linear attention; the token width must divide by it
    decoder_width: int = 32  # channels of the U-Net decoder's first (coarsest) stage, halved per stage down to 16
    radar_hidden: int = 64  # width of the per-point radar MLP before mean pooling
    # feed the radar cross-section (dataset-specific scale: off so a synthetic-trained model transfers)
    use_rcs: bool = False

    PRESETS = {
        "tiny": {"backbone_width": 8, "input_size": 32, "attention_layers": 1, "decoder_width": 8, "radar_hidden": 16},
        "small": {},
        "paper": {"backbone_width": 64, "input_size": 128, "attention_layers": 4, "decoder_width": 64,
                  "radar_hidden": 128},
    }


@dataclass
class CompletionConfig:
    """Radar-object mask completion (``segment/complete.py``): or the network's mask with the
    depth-gated image hull of each radar object's returns (fast, close cars the patches only half cover)."""

    # On tuning seeds realistic 101 / rush 201 (small) it raised recall 0.830 -> 0.962 / 0.935 -> 0.978
    # (pixels moving > 30 px a frame: 0.36 -> 0.95 / 0.85 -> 0.99) at precision 0.963 -> 0.961 / 0.974 -> 0.968.
    # Off by default: trained on the completed masks (small, 600 iterations) the tuning seeds lost
    # novel-view PSNR* (realistic 101: 20.03 -> 19.41 dB; rush 5 Hz 214: 20.46 -> 20.11) and the
    # static layer under removed cars 16.87 -> 16.39 dB (101; benchmarks/results/masks-training.json).
    # Not broken down; likely, a fast car the masks now cover goes to the field, which cannot follow it.
    # Again on 2026-12-05 with for_flow on: recall 0.83-0.89 -> 0.98-0.99 on hard tuning seeds 231-233, PSNR*
    # +0.15 dB over training seeds 0-2 at 600 iterations (231 +1.18, 232 -0.25, 233 -0.48;
    # benchmarks/results/masks-completion-2026-12-05.json).
    enabled: bool = False  # complete the masks with the radar objects (skipped without <prepared>/radar/objects.json)
    # With enabled off, still write completed masks for the flow stage alone (<prepared>/masks/flow/):
    # the flow stage then steps the whole car the radar sees, not the part the network found, while
    # training, actors and evaluation keep the network's masks. On by default (2026-12-02), with
    # flow.radar_rigid_min_returns 30: hard tuning seeds' 2-D flow error 1.27 -> 0.73 px at 320 px (224, 226,
    # 229-233) and 2.33 -> 1.30 px at 640 px (224-227); full small, novel-view PSNR* -0.18 / +0.89 /
    # +0.99 dB on 225 / 227 / 228 (benchmarks/results/flow-rigid-completed-masks.json). Alone, at 600
    # iterations and older defaults, it had cost 214 0.7 dB (masks-training.json).
    for_flow: bool = True
    min_returns: int = 3  # objects with fewer returns in front of the camera are left to the network
    margin_m: float = 0.3  # grow the hull by this many metres at the object's median depth
    depth_tolerance_m: float = 2.5  # keep hull pixels whose depth is within this of the returns' depth range
    min_height_m: float = 0.15  # and whose point stands this high above the ego ground plane (z = 0): not road
    # Also give every object of a radar track seen in at least small_track_frames frames (a one-scan ghost
    # gets nothing) a body-sized window: body_width_m wide at its returns' depth, centred on them, holding
    # the pixels min_height_m..body_height_m above the ground within the depth band. A pedestrian's 1-4
    # returns span no hull, and the network marks 20-40 % of the pedestrians' moving pixels on the rush
    # 5 Hz seeds. Independent of `enabled`. On by default: with optim.field_lr 3e-4, bench grid, training on
    # the windows found 17 of 19 movers on hard tuning seeds 214-216 (14 without) and left calm 1 /
    # realistic 101 within 0.12 dB of novel-view PSNR and PSNR*, movers found unchanged
    # (benchmarks/results/training-small-objects-field-lr.json); the real aiMotive clip's masks are unchanged.
    small_objects: bool = True
    body_width_m: float = 1.0  # small_objects: the window's width (m at the returns' depth)
    body_height_m: float = 2.0  # small_objects: the window's top (m above the ego ground plane)
    small_track_frames: int = 3  # small_objects: only objects of tracks seen in at least this many frames

    def __post_init__(self) -> None:
        if self.body_width_m <= 0 or self.body_height_m <= self.min_height_m or self.small_track_frames < 1:
            raise ValueError(f"masks.completion needs body_width_m > 0, body_height_m > min_height_m and "
                             f"small_track_frames >= 1, got {self.body_width_m}, {self.body_height_m} "
                             f"(min_height_m {self.min_height_m}), {self.small_track_frames}")


@dataclass
class PropagationConfig:
    """Carry small mask components to neighbouring frames by template matching
    (``segment/propagate.py``): pedestrians and distant movers the radar prompts in a few frames only."""

    enabled: bool = False
    frames: int = 5  # follow a component this many frames each way at most
    min_pixels: float = 8  # components of min_pixels..max_pixels px (at 320 px width; areas scale) are carried
    max_pixels: float = 400
    search_px: float = 6  # search window half-size around the predicted place (px at 320 px width)
    distinct: float = 0.5  # keep a match whose RMS grey error is at most this x the window's median
    max_overlap: float = 0.5  # stop where more than this share of the footprint is already masked
    point_margin_px: float = 2  # carry only components with a dynamic radar point within this (px at 320 px)

    def __post_init__(self) -> None:
        if self.frames < 0 or self.search_px <= 0 or self.distinct <= 0 or self.point_margin_px < 0:
            raise ValueError(f"masks.propagation needs frames >= 0, search_px > 0, distinct > 0 and "
                             f"point_margin_px >= 0, got {self.frames}, {self.search_px}, {self.distinct}, "
                             f"{self.point_margin_px}")
        if not 0 <= self.min_pixels <= self.max_pixels:
            raise ValueError(f"masks.propagation needs 0 <= min_pixels <= max_pixels, got {self.min_pixels}, "
                             f"{self.max_pixels}")


@dataclass
class SegInferConfig:
    """How ``prepare`` turns radar and images into dynamic masks."""

    method: Literal["model", "baseline"] = "model"  # the learned network, or the non-learned radar-prompted flood fill
    # network checkpoint: seg-train's best.pt, or the name of weights shipped in the package, segnet-small
    # or segnet-small-traffic (also trained on realistic and rush traffic); None = segnet-small
    checkpoint: Path | None = None
    threshold: float = 0.5  # tau: a pixel is dynamic when its pasted probability exceeds this
    # Anchors and patch size depart from the paper (8 random anchors, 256 px patches at 1920 px):
    # a frame has 30-140 dynamic radar points, mostly on the nearest car, so 8 random anchors
    # often miss a second or distant car entirely, and a distant car (20 x 8 px at 320x180) fills
    # too little of a full-size patch for the network to find it. On synthetic small seeds 1-5
    # (pipeline radar), cover sampling with 64 anchors at 0.6 of the patch size left 5.0 % of the
    # moving pixels unmarked against 10.8 % (mask IoU 0.906 against 0.875), at 0.10 s a frame.
    num_anchors: int = 64  # most anchors per frame (fewer if fewer dynamic points, or cover stops earlier)
    # random (paper), farthest (FPS in the image), cover (no two anchors within cover_radius)
    anchor_sampling: AnchorSampling = "cover"
    cover_radius: float = 0.1  # for "cover": minimum anchor spacing, as a fraction of the patch side
    patch_scale: float = 0.6  # patch side = round(256 * W / 1920 * this) px (26 px at 320x180; paper: 1.0)
    max_points: int = 64  # radar points per patch fed to the network (nearest to the anchor kept)
    # keep, per patch, only the above-threshold regions touching the anchor (within anchor_radius)
    anchor_connected: bool = False
    # for anchor_connected: tolerance around the anchor pixel, as a fraction of the patch side
    anchor_radius: float = 0.08
    # where dynamic radar points come from: prepared radar/, estimate, oracle (gt)
    dynamic_source: DynamicSource = "auto"
    seed: int = 0  # anchor sampling seed (frame i uses seed + i, so masks are reproducible)
    save_prob: bool = True  # also write <frame>_prob.npy (float16 pasted probabilities)
    device: str = "cpu"  # torch device for the network
    completion: CompletionConfig = field(default_factory=CompletionConfig)  # radar-object mask completion
    propagation: PropagationConfig = field(default_factory=PropagationConfig)  # small components to neighbour frames

    PRESETS = {"tiny": {"num_anchors": 4}, "small": {}, "paper": {}}


@dataclass
class AugmentConfig:
    """Training augmentations (0 switches one off)."""

    drop_points: float = 0.3  # each frame drops a fraction of its radar points drawn uniformly in [0, this]
    velocity_noise: float = 0.3  # std of Gaussian noise added to the compensated radial velocity (m/s)
    # std of a per-frame shift of all projected radar points (px at 320 px width; scaled with W)
    misalign_px: float = 2.0
    point_jitter_px: float = 0.7  # std of an independent per-point shift (px at 320 px width)
    false_dynamic: float = 0.5  # chance per frame that a few static points in view are flagged dynamic
    false_dynamic_max: int = 3  # at most this many falsely flagged points per such frame
    colour_jitter: float = 0.2  # amplitude of brightness, contrast, saturation and per-channel gain changes
    hflip: float = 0.5  # chance of a horizontal flip of image, mask and radar


@dataclass
class SegTrainConfig:
    """Training of the radar–camera segmentation network."""

    model: SegModelConfig = field(default_factory=SegModelConfig)  # architecture
    augment: AugmentConfig = field(default_factory=AugmentConfig)  # augmentations
    epochs: int = 20  # passes over the training frames
    batch_size: int = 6  # frames per step (each gives up to num_anchors patches)
    lr: float = 2e-4  # Adam learning rate (paper)
    betas: tuple[float, float] = (0.9, 0.999)  # Adam betas (paper)
    dice_weight: float = 1.0  # weight of the soft Dice term next to BCE
    num_anchors: int = 8  # anchors per frame (fewer if fewer dynamic points)
    patch_scale: float = 1.0  # patch side = round(256 * W / 1920 * this)
    max_points: int = 64  # radar points per patch
    # dynamic radar points: prepared, estimate (radar front end), oracle (gt labels)
    dynamic_source: DynamicSource = "auto"
    val_every: int = 2  # validate on every this-th frame of the validation scenes
    time_limit_min: float | None = None  # stop after this many minutes (then validate and checkpoint)
    # torchvision ImageNet ResNet state_dict (.pth) to start from; needs model.backbone_width=64
    pretrained_backbone: Path | None = None
    num_threads: int = 1  # torch CPU threads (1 leaves the rest of a shared machine free)
    device: str = "cpu"  # torch device
    seed: int = 0  # initialisation, shuffling, augmentation

    PRESETS = {
        "tiny": {"model": SegModelConfig.PRESETS["tiny"], "epochs": 2, "batch_size": 2, "num_anchors": 4,
                 "max_points": 16},
        "small": {},
        "paper": {"model": SegModelConfig.PRESETS["paper"], "epochs": 50, "num_threads": 0},
    }
