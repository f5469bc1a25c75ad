"""Training the segmentation network on scenes with ``gt/dynamic_mask`` (``radar4dgs seg-train``).

One step takes ``batch_size`` frames; each frame gives up to ``num_anchors`` patches around its
(augmented) dynamic radar points, with the gt mask cut by the same boxes as the target. Loss:
BCE + soft Dice on the patch probabilities. Adam (lr 2e-4, betas 0.9/0.999) as the paper.

Radar-aware augmentations (each one imitates an error of the radar front end or the calibration):
dropped points, compensated-velocity noise, a per-frame misalignment of all projected points by a
few pixels, static points falsely flagged dynamic (so that the network learns to answer "nothing
moves here", which keeps parked cars out of the mask), colour jitter and horizontal flips.

Run folder: ``config.json`` (resolved config), ``last.pt`` (everything needed to resume, written
atomically every epoch), ``best.pt`` (model only, best validation IoU; what ``prepare`` loads
with ``--segment.checkpoint``), ``history.json`` (loss and validation IoU per epoch).
"""

from __future__ import annotations

import math
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Callable

import numpy as np
import torch
import torch.nn.functional as F

from radar4dgs.config import save_config, to_dict
from radar4dgs.io.atomic import atomic_save_torch, atomic_write_json
from radar4dgs.io.image_motion import IMAGE_MOTION_REFERENCE_WIDTH
from radar4dgs.segment.config import AugmentConfig, SegTrainConfig
from radar4dgs.segment.dataset import TrainFrame
from radar4dgs.segment.infer import SegInferConfig, frame_rng, patch_batch, segment_frame
from radar4dgs.segment.model import RadarCameraSegNet, checkpoint_payload, count_parameters, load_pretrained_backbone
from radar4dgs.segment.patches import (
    RadarFrame,
    candidate_anchors,
    extract_patches,
    in_image,
    patch_side,
    sample_anchors,
)

# --------------------------------------------------------------------------------------------
# Augmentation


def jitter_colour(image: np.ndarray, amount: float, rng: np.random.Generator) -> np.ndarray:
    """(H, W, 3) uint8 → float32 [0, 1] with random brightness, contrast, saturation and gains."""
    x = image.astype(np.float32) / 255.0
    if amount <= 0:
        return x
    grey = x.mean(axis=2, keepdims=True)
    x = grey + (x - grey) * (1 + rng.uniform(-amount, amount))  # saturation
    x = x.mean() + (x - x.mean()) * (1 + rng.uniform(-amount, amount))  # contrast
    x = x * (1 + rng.uniform(-amount, amount)) * (1 + rng.uniform(-amount / 4, amount / 4, size=3))
    return np.clip(x, 0.0, 1.0)


def augment_radar(radar: RadarFrame, width: int, height: int, config: AugmentConfig,
                  rng: np.random.Generator) -> RadarFrame:
    """Dropped points, velocity noise, misalignment and false dynamic flags (module doc)."""
    keep = (rng.random(len(radar)) >= rng.uniform(0, config.drop_points) if config.drop_points > 0
            else np.ones(len(radar), bool))
    radar = radar.subset(keep)
    scale = width / IMAGE_MOTION_REFERENCE_WIDTH
    uv = radar.uv + rng.normal(0, config.misalign_px * scale, size=2) + rng.normal(
        0, config.point_jitter_px * scale, size=radar.uv.shape)
    v = (radar.v_comp + rng.normal(0, config.velocity_noise, size=len(radar)) if config.velocity_noise > 0
         else radar.v_comp)
    dynamic = radar.dynamic.copy()
    if config.false_dynamic > 0 and rng.random() < config.false_dynamic:
        static = np.flatnonzero(~dynamic & in_image(uv, width, height))
        if len(static):
            flip = rng.choice(static, size=min(len(static), int(rng.integers(1, config.false_dynamic_max + 1))),
                              replace=False)
            dynamic[flip] = True
            # A falsely flagged point has a Doppler residual just above the front end's threshold.
            v = v.copy()
            v[flip] = rng.choice([-1.0, 1.0], size=len(flip)) * rng.uniform(0.5, 2.0, size=len(flip))
    return RadarFrame(uv.astype(np.float32), radar.cam, v.astype(np.float32), dynamic, radar.rcs)


def hflip_frame(image: np.ndarray, mask: np.ndarray, radar: RadarFrame) -> tuple[np.ndarray, np.ndarray, RadarFrame]:
    """Mirror image (H, W, 3), mask (H, W) and radar (pixel i → W − 1 − i, so u → W − 1 − u;
    camera x → −x)."""
    width = image.shape[1]
    uv = radar.uv.copy()
    uv[:, 0] = width - 1 - uv[:, 0]
    cam = radar.cam.copy()
    cam[:, 0] = -cam[:, 0]
    return image[:, ::-1].copy(), mask[:, ::-1].copy(), RadarFrame(uv, cam, radar.v_comp, radar.dynamic, radar.rcs)


def training_patches(frame: TrainFrame, config: SegTrainConfig, rng: np.random.Generator,
                     device: torch.device | str, dtype: torch.dtype):
    """Augmented network inputs and targets of one frame, or None when it has no anchor.

    Returns patches (K, 3, S, S), points (K, P, F), valid (K, P), targets (K, 1, S, S) in [0, 1].
    """
    image, mask, radar = frame.image, frame.mask, frame.radar
    height, width = mask.shape
    if config.augment.hflip > 0 and rng.random() < config.augment.hflip:
        image, mask, radar = hflip_frame(image, mask, radar)
    radar = augment_radar(radar, width, height, config.augment, rng)
    candidates = candidate_anchors(radar, width, height)
    if len(candidates) == 0:
        return None
    anchors = sample_anchors(radar.uv, candidates, config.num_anchors, rng, "random")
    tensor = torch.as_tensor(jitter_colour(image, config.augment.colour_jitter, rng),
                             device=device).permute(2, 0, 1).to(dtype)
    side = patch_side(width, config.patch_scale)
    patches, points, valid, boxes = patch_batch(tensor, radar, anchors, side, config.model.input_size,
                                                config.max_points, config.model.use_rcs)
    target = extract_patches(torch.as_tensor(mask, device=device, dtype=dtype)[None], boxes, config.model.input_size)
    return patches, points, valid, target


def segmentation_loss(logits: torch.Tensor, target: torch.Tensor, dice_weight: float) -> dict[str, torch.Tensor]:
    """BCE + ``dice_weight`` × soft Dice (per patch, averaged; a patch with an empty target adds
    to the Dice term only its predicted mass). logits, target: (K, 1, S, S). Returns named terms."""
    bce = F.binary_cross_entropy_with_logits(logits, target)
    prob = torch.sigmoid(logits).flatten(1)
    t = target.flatten(1)
    dice = 1 - (2 * (prob * t).sum(1) + 1) / (prob.sum(1) + t.sum(1) + 1)
    dice = dice.mean()
    return {"bce": bce, "dice": dice, "total": bce + dice_weight * dice}


# --------------------------------------------------------------------------------------------
# Validation and checkpoints


def validation_iou(model: RadarCameraSegNet, frames: list[TrainFrame], config: SegTrainConfig) -> float:
    """Accumulated intersection / union over ``frames`` of the masks inference would give
    (``SegInferConfig`` defaults, with this run's patch scale and point count); NaN when both are
    empty everywhere."""
    infer = SegInferConfig(patch_scale=config.patch_scale, max_points=config.max_points, seed=config.seed)
    was_training = model.training
    model.eval()
    inter = union = 0
    for i, frame in enumerate(frames):
        pred = segment_frame(model, frame.image, frame.radar, infer, frame_rng(config.seed, i)).mask(infer.threshold)
        inter += int((pred & frame.mask).sum())
        union += int((pred | frame.mask).sum())
    model.train(was_training)
    return inter / union if union else float("nan")


def _save_torch(path: Path, payload: dict) -> None:
    atomic_save_torch(path, payload)


@dataclass
class TrainState:
    """What ``last.pt`` restores: progress, history and the shuffling generator."""

    epoch: int = 0  # epochs completed
    step: int = 0
    best_iou: float = -1.0
    history: list = field(default_factory=list)
    elapsed_s: float = 0.0


def train_segmentation(train_frames: list[TrainFrame], val_frames: list[TrainFrame], config: SegTrainConfig,
                       out: Path, resume: bool = False, log: Callable[[str], None] = print,
                       metadata: dict | None = None) -> TrainState:
    """Train (or resume) into run folder ``out``; returns the final state (module doc).

    ``metadata`` (JSON-ready, e.g. the training scenes and seeds) is stored in ``best.pt``.
    """
    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    if config.num_threads > 0:
        torch.set_num_threads(config.num_threads)
    device, dtype = torch.device(config.device), torch.float32
    torch.manual_seed(config.seed)
    model = RadarCameraSegNet(config.model)
    if config.pretrained_backbone is not None:
        log(f"loaded {len(load_pretrained_backbone(model, config.pretrained_backbone))} backbone tensors "
            f"from {config.pretrained_backbone}")
    model = model.to(device=device, dtype=dtype)
    optimizer = torch.optim.Adam(model.parameters(), lr=config.lr, betas=config.betas)
    state = TrainState()
    rng = np.random.default_rng(config.seed)
    last = out / "last.pt"
    if resume and last.is_file():
        payload = torch.load(last, map_location=device, weights_only=True)
        model.load_state_dict(payload["state_dict"])
        optimizer.load_state_dict(payload["optimizer"])
        state = TrainState(**payload["train_state"])
        rng.bit_generator.state = payload["rng_state"]
        log(f"resumed from {last} after epoch {state.epoch}")
    save_config(config, out / "config.json")
    log(f"{count_parameters(model):,} parameters; {len(train_frames)} training frames, "
        f"{len(val_frames)} validation frames")

    start = time.perf_counter() - state.elapsed_s
    out_of_time = False
    while state.epoch < config.epochs and not out_of_time:
        model.train()
        order = rng.permutation(len(train_frames))
        losses = []
        for first in range(0, len(order), config.batch_size):
            items = [training_patches(train_frames[j], config, rng, device, dtype)
                     for j in order[first:first + config.batch_size]]
            items = [item for item in items if item is not None]
            if not items:
                continue
            patches, points, valid, target = (torch.cat(parts) for parts in zip(*items, strict=True))
            terms = segmentation_loss(model(patches, points, valid), target, config.dice_weight)
            if not torch.isfinite(terms["total"]):
                raise FloatingPointError(f"non-finite loss at step {state.step}: "
                                         f"{ {k: float(v) for k, v in terms.items()} }")
            optimizer.zero_grad(set_to_none=True)
            terms["total"].backward()
            optimizer.step()
            state.step += 1
            losses.append({k: v.item() for k, v in terms.items()})
            if config.time_limit_min is not None and time.perf_counter() - start > 60 * config.time_limit_min:
                out_of_time = True
                break
        state.epoch += 1
        iou = validation_iou(model, val_frames, config) if val_frames else float("nan")
        state.elapsed_s = time.perf_counter() - start
        mean = {k: float(np.mean([step_loss[k] for step_loss in losses])) for k in losses[0]} if losses else {}
        entry = {"epoch": state.epoch, "step": state.step, "loss": mean, "val_iou": None if math.isnan(iou) else iou,
                 "elapsed_s": round(state.elapsed_s, 1), "partial": out_of_time}
        state.history.append(entry)
        log(f"epoch {state.epoch:3d}  step {state.step:6d}  loss {mean.get('total', float('nan')):.4f} "
            f"(bce {mean.get('bce', float('nan')):.4f}, dice {mean.get('dice', float('nan')):.4f})  "
            f"val IoU {iou:.4f}  {state.elapsed_s:.0f} s")
        if not math.isnan(iou) and iou > state.best_iou or (not val_frames):
            state.best_iou = iou if not math.isnan(iou) else state.best_iou
            _save_torch(out / "best.pt", checkpoint_payload(model, epoch=state.epoch, val_iou=entry["val_iou"],
                                                            train_config=to_dict(config), **(metadata or {})))
        # Plain tensors, numbers, strings, lists and dicts only: torch.load(weights_only=True) reads it.
        _save_torch(last, {"state_dict": model.state_dict(), "optimizer": optimizer.state_dict(),
                           "train_state": to_dict(state), "rng_state": rng.bit_generator.state,
                           "config": to_dict(config)})
        atomic_write_json(out / "history.json", state.history)
    return state


def export_weights(checkpoint: Path, out: Path, card: Path, card_extra: dict | None = None) -> dict:
    """Write a float16 copy of a ``best.pt`` (model only) to ``out`` and a JSON card beside it:
    how the network was trained (config, seeds, epochs, validation IoU, size). Returns the card."""
    payload = torch.load(checkpoint, map_location="cpu", weights_only=True)
    from radar4dgs.segment.model import model_from_checkpoint

    model = model_from_checkpoint(payload)
    keep = {k: payload[k] for k in ("epoch", "val_iou", "train_config", "synth_seeds", "validation_seeds",
                                    "scenes") if k in payload}
    size = atomic_save_torch(out, checkpoint_payload(model, half=True, **keep))
    info = {"file": out.name, "bytes": size, "dtype": "float16",
            "parameters": count_parameters(model), "model_config": payload["model_config"],
            "training": {"epochs_completed": payload.get("epoch"), "best_val_iou": payload.get("val_iou"),
                         "synth_seeds": payload.get("synth_seeds", []),
                         "validation_seeds": payload.get("validation_seeds", []),
                         "config": payload.get("train_config")},
            **(card_extra or {})}
    atomic_write_json(card, info)
    return info
