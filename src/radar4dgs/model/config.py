"""The trainer's configuration (DESIGN.md stage 7): one dataclass per concern, named presets.

:class:`TrainConfig` nests the Gaussian initialisation, the deformation field, the losses, the
optimiser, densification, the rasterizer and pose refinement (:mod:`radar4dgs.model.pose_config`).
Stage boundaries are fractions of the total so that every preset keeps the paper's proportions
(30k iterations, stage 2 at 15k, stage 3 at 20k).
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass
from typing import Any, ClassVar, Literal, Mapping

from radar4dgs.model.pose_config import PoseRefineConfig
from radar4dgs.render.config import RasterConfig


@dataclass
class FieldConfig:
    """Sizes of the invertible deformation field."""

    # Affine coupling layers; layer l changes coordinate l mod 3, so a multiple of 3 changes each
    # coordinate equally often.
    num_layers: int = 6
    # Width of each coupling layer's MLP.
    hidden: int = 64
    # Hidden layers of each coupling layer's MLP (each `hidden` wide, ReLU).
    hidden_layers: int = 2
    # Fourier frequencies of the time code: [t, sin(2^k pi t), cos(2^k pi t)], k < this. Few is
    # better: held-out (test) frames are reached by interpolating in t, and higher frequencies
    # interpolate badly. Fitting ground-truth flow pairs of a 50-frame synthetic scene, the EPE on
    # pairs touching held-out frames was 0.22 m with 4 frequencies and 0.034 m with 1.
    time_frequencies: int = 1
    # Fourier frequencies applied to the two conditioning coordinates (normalised to ~[-1, 1]).
    # More frequencies separate nearby objects that move differently, but they raise the
    # Lipschitz constant of each coupling, and the inverse amplifies float32 rounding by about that
    # constant per layer: with random weights the float32 round-trip error is ~1e-6 at 2
    # frequencies, ~3e-5 at 3, ~1e-2 at 5 (benchmarks/motion.py). 2 keeps it below 1e-5.
    space_frequencies: int = 2
    # Bound m of the log-scale, s = m * tanh(raw / m): each layer scales its coordinate by at most
    # exp(m). Driving motion is mostly translation, so a small bound costs nothing and keeps the
    # inverse well conditioned.
    max_log_scale: float = 0.5
    # Margin added to the bounding box of the dynamic points when fitting the normalisation
    # (fraction of the half-extent), so points a little outside the box stay inside [-1, 1].
    normalization_margin: float = 0.1
    # Smallest half-extent (m) of the normalisation box per axis, so a flat dynamic region (all
    # points at one height) is not blown up along that axis.
    normalization_min_scale: float = 1.0

    PRESETS: ClassVar[Mapping[str, Mapping[str, Any]]] = {
        "tiny": {"num_layers": 3, "hidden": 32, "time_frequencies": 2},
        "small": {},
        "paper": {"num_layers": 9, "hidden": 128, "time_frequencies": 6},
    }


@dataclass
class GaussianInitConfig:
    """How the Gaussians are initialised from the prepared depth (or the scene's LiDAR)."""

    # "depth": back-project the radar-scaled monocular depth of every training frame (ours);
    # "lidar": the scene's lidar/ points of the training frames (the paper's sensor ablation),
    # coloured and split by projecting them into their frame's image and mask.
    source: Literal["depth", "lidar"] = "depth"
    # Candidate pixels are taken on a grid with this step (1 = every pixel) before subsampling.
    pixel_stride: int = 2
    # Dynamic-mask pixels are taken on this (finer) grid: moving objects cover a small part of
    # a driving image (~0.4 % of the synthetic small frames), and at the background's step they
    # get a few dozen Gaussians per frame, too few to draw a car.
    dynamic_pixel_stride: int = 1
    # At most this many points are kept per training frame (uniform random subset of the
    # candidates); 0 or less keeps every candidate.
    points_per_frame: int = 20_000
    # Cap on the total number of static Gaussians (uniform random subset over all frames).
    max_static: int = 200_000
    # Cap on the total number of dynamic Gaussians. points_per_frame is drawn first, from the static and dynamic
    # candidates together, so at 640x360 the small preset's 15 000 a frame leave about 48 000 dynamic candidates on a
    # strict hard scene and a higher cap needs points_per_frame raised too (training logs when it held the cap).
    # 60 000 with 30 000 a frame there: PSNR* +0.23 dB (grid, ten runs), short of a default's +0.3.
    max_dynamic: int = 50_000
    # Pixels whose depth confidence (``depth/<frame>_confidence.npy``) is below this are dropped;
    # 0 keeps every non-sky pixel (confidence is 0 where the depth stage had no radar support,
    # which is still a usable initial position).
    min_confidence: float = 0.0
    # Pixels deeper than this (metres) are dropped: far background is left to the sky map.
    max_depth: float = 200.0
    # Initial opacity of every Gaussian, in (0, 1).
    init_opacity: float = 0.1
    # Initial scale = mean distance to this many nearest neighbours (isotropic).
    knn_k: int = 3
    # Initial scales are clamped to [min_scale, max_scale] metres (duplicates give 0 distance).
    min_scale: float = 1e-3
    max_scale: float = 3.0
    # Seed of the subsampling generator (np.random.default_rng).
    seed: int = 0

    PRESETS: ClassVar[dict[str, dict]] = {
        # 160x90 synthetic frames: every second pixel is ~3.6k candidates, keep them all.
        "tiny": {"pixel_stride": 2, "points_per_frame": 4_000, "max_static": 20_000, "max_dynamic": 5_000},
        "small": {"pixel_stride": 2, "points_per_frame": 15_000, "max_static": 150_000, "max_dynamic": 30_000},
        # 1920x1080 x 50 frames: ~2M candidates per frame at stride 1; keep a dense but bounded set.
        "paper": {"pixel_stride": 2, "points_per_frame": 40_000, "max_static": 1_000_000,
                  "max_dynamic": 200_000},
    }

    def __post_init__(self) -> None:
        if self.pixel_stride < 1 or self.dynamic_pixel_stride < 1:
            raise ValueError(f"pixel_stride and dynamic_pixel_stride must be >= 1, got {self.pixel_stride}, "
                             f"{self.dynamic_pixel_stride}")
        if not 0.0 < self.init_opacity < 1.0:
            raise ValueError(f"init_opacity must lie in (0, 1), got {self.init_opacity}")
        if self.knn_k < 1:
            raise ValueError(f"knn_k must be >= 1, got {self.knn_k}")
        if not 0.0 < self.min_scale <= self.max_scale:
            raise ValueError(f"need 0 < min_scale <= max_scale, got {self.min_scale}, {self.max_scale}")
        if self.max_static < 0 or self.max_dynamic < 0:
            raise ValueError("max_static and max_dynamic must be >= 0")


@dataclass
class BaselineConfig:
    """Sizes and learning rates of the baselines' motion models. The life-peak and life-span
    learning rates (``time_lr``, ``lifespan_lr``) also train ours' dynamic life spans
    (``TrainConfig.dynamic_lifespan``); nothing else here is used by ours or static."""

    # PVG: cycle length l as a fraction of the sequence (the paper compares with l = 0.2).
    pvg_period: float = 0.2
    # PVG and bspline: initial life span beta (normalised time): a Gaussian starts visible over
    # about +-2 beta around the frame that saw it.
    initial_lifespan: float = 0.2
    # PVG velocity (m per normalised time unit, scaled by the scene extent) and life-peak learning
    # rates; the life span's is on log(beta). The last two serve PVG, bspline and ours' dynamic set.
    velocity_lr: float = 1e-2
    time_lr: float = 1e-3
    lifespan_lr: float = 1e-2
    # bspline: control points per trajectory over [0, 1] and their rate (m, scaled by the extent).
    control_points: int = 8
    control_lr: float = 1e-3
    # deformable: MLP width, hidden layers, Fourier frequencies of x (normalised) and t, and
    # learning rate (decayed by the field's final ratio, as the VGPT field).
    offset_hidden: int = 64
    offset_layers: int = 3
    offset_space_frequencies: int = 6
    offset_time_frequencies: int = 4
    offset_lr: float = 1e-3

    def __post_init__(self) -> None:
        if not 0.0 < self.pvg_period:
            raise ValueError(f"pvg_period must be > 0, got {self.pvg_period}")
        if not 0.0 < self.initial_lifespan:
            raise ValueError(f"initial_lifespan must be > 0, got {self.initial_lifespan}")
        if self.control_points < 4:
            raise ValueError(f"a cubic B-spline needs >= 4 control points, got {self.control_points}")


# "ours": static + dynamic Gaussians moved by the VGPT field; "static": every Gaussian static, no
# field (the same trainer with dynamics switched off); "deformable", "pvg", "bspline": the
# baselines' motion models (model.motion_models). Ablations of "ours" are config changes, named in
# train.variants.
Method = Literal["ours", "static", "deformable", "pvg", "bspline"]
# Where the dynamic masks come from: the prepared ones (the segmentation network), the non-learned
# radar flood-fill baseline (computed once into prepared/masks_baseline), or ground truth (oracle).
MaskSource = Literal["predicted", "baseline", "gt"]


@dataclass
class LossConfig:
    """Weights of the training loss (DESIGN.md stage 7) and of the field's supervision."""

    # lambda_r: weight of (1 - SSIM) against the L1 term, which gets (1 - lambda_r).
    ssim_weight: float = 0.2
    # Ours: extra weight of the L1 term on the dynamic-mask pixels, each counting 1 + this (the others 1); 0 = off.
    # A car covers about 2 % of a frame. At 3, hard tuning seeds 234-236 x two training seeds at full small:
    # novel-view PSNR* +0.91 dB, PSNR -0.07; at 10: +1.51 / -0.27 (docs: Training, weighting the moving pixels).
    dynamic_l1_weight: float = 3.0
    # Pixels by which that weight's mask is widened (a max filter at the training resolution; negative: narrowed);
    # 0 = the mask as prepared. At weight 10, +6 and -2 px each lost 0.8-1.7 dB PSNR* on hard tuning pairs.
    dynamic_l1_dilation: int = 0
    # lambda_d: inverse-depth L1 against the radar-scaled prepared depth (non-sky pixels).
    depth_weight: float = 0.1
    # Weight of |log d - log d_prepared| on the dynamic-mask pixels where the image trains them; 0 = off.
    # Scale-free: lambda_d's pull in depth on a car 20 % too deep is 16x weaker at 20 m than at 5 m.
    dynamic_depth_weight: float = 0.0
    # lambda_obj: BCE of the rendered dynamic mask vs the prepared mask (stage 3); 0.25 / 1.0 lost 0.2 / 0.7 dB PSNR*.
    object_weight: float = 0.05
    # lambda_sky: BCE of the rendered opacity against the sky mask (opacity 0 on sky).
    sky_weight: float = 0.05
    # Weight of metrics.losses.static_over_movers: static Gaussians drawn over a mover from more than
    # over_movers_margin (relative) in front of its prepared depth lose opacity; 0 = off.
    over_movers_weight: float = 0.0
    over_movers_margin: float = 0.05
    flow_weight: float = 1.0  # weight of L_flow (m^2) on the field
    radar_weight: float = 0.5  # weight of L_rad (m) on the field (as the standalone fit's radar_weight)
    # Weight of L_vel (objects' full velocity, FitConfig.velocity_weight); 0 = off. At 0.1 the field moves every
    # object nearer the truth (crossing cars too), yet novel-view PSNR* fell on all five strict tuning seeds (mean
    # -1.17 dB; -0.59 on hard seed 214 before): docs/research/training.md, the velocity term.
    velocity_weight: float = 0.0
    motion_batch: int = 1024  # flow pairs and radar points drawn per iteration for L_flow, L_rad, L_vel
    # Weight of L_acc (m^2, train.path_prior): the field's paths of observed moving points bent within
    # acceleration_reach frame steps of the time they were seen; 0 = off. At 1, hard tuning seeds 229 / 230 at
    # full small (three training seeds each): the trained field's scene-flow error 0.170 / 0.055 -> 0.141 /
    # 0.043 m, novel-view PSNR* -0.10 dB (docs: Training, the field's path between frames).
    acceleration_weight: float = 0.0
    acceleration_reach: float = 2.0
    # Association gate (m) of a dynamic point to its nearest dynamic radar point. 1 m, not the fit's 2 m:
    # at 2 m mask spill beside a mover took its Doppler (benchmarks/radar_targets.py, hard tuning seeds).
    radar_gate: float = 1.0
    radar_points_per_frame: int = 2000  # dynamic pixels per frame lifted as radar-supervised points
    # Also supervise the field at the dynamic radar returns (FitConfig.radar_returns_as_points, on
    # there). Off: on synthetic small seed 1 it took novel-view PSNR* from 22.63 to 20.17 dB; returns
    # flagged dynamic by mistake move the field where dynamic Gaussians are.
    radar_returns_as_points: bool = False


@dataclass
class OptimConfig:
    """Iterations, stage boundaries, learning rates and dropout."""

    # Total iterations (one training image each).
    iterations: int = 1800
    # Stage 2 (static frozen; dynamic Gaussians and field) starts at this fraction (paper 15k/30k).
    stage2_start: float = 0.5
    # Stage 3 (everything, plus the object loss) starts at this fraction (paper 20k/30k).
    stage3_start: float = 2.0 / 3.0
    # Learning rate of the Gaussian means, in units of the scene extent (3DGS: 1.6e-4), decayed
    # exponentially to means_lr_final over the run.
    means_lr: float = 1.6e-4
    means_lr_final: float = 1.6e-6
    # Ours: the dynamic means' decay runs from their birth at stage 2 to the end instead of over the
    # whole run, so they start at means_lr, not at its value stage2_start into the run.
    dynamic_means_from_birth: bool = False
    # Learning rates of the other Gaussian parameters (colour and opacity are logits).
    quats_lr: float = 1e-3
    scales_lr: float = 5e-3
    opacity_lr: float = 5e-2
    colors_lr: float = 1e-2
    # Deformation field (Adam), decayed by field_lr_final_ratio over the run. 1e-3 moved fast cars' dynamic
    # Gaussians 1.7-1.9 m off in stage 2's first 12 iterations (hard seed 214), losing some; 3e-4 keeps them.
    field_lr: float = 3e-4
    field_lr_final_ratio: float = 0.1
    # Ours: before stage 1, fit the field alone to its supervision (L_flow, L_rad and L_vel with
    # the losses' weights, the standalone fit's learning rate and schedule) for this many
    # iterations; 0 = off. Stage 1 trains the field for only stage2_start x iterations at field_lr
    # (150 at the bench grid's 600), and stage 2 places the dynamic Gaussians with that field: on the
    # hard tuning seeds its scene-flow error was 0.10-0.61 m there, 0.06-0.18 m after a full fit.
    # small pre-fits 1000 (bench grid: PSNR* +0.52 dB on the rush 5 Hz report seeds, calm seeds 1 / 2
    # +0.58 / -0.19 dB); tiny (a smoke test) and paper (whose stage 1 is long) keep it off.
    field_prefit_iterations: int = 0
    sky_lr: float = 1e-2  # sky environment map (colour logits)
    # Gaussian dropout: each iteration this fraction of the Gaussians gets opacity 0 and the rest
    # are scaled by 1 / (1 - p) (clamped to 1), so the expected opacity is unchanged; used until
    # dropout_until of the run, so the model settles on the opacities it is evaluated with.
    dropout: float = 0.1
    dropout_until: float = 0.9


@dataclass
class DensifyConfig:
    """3DGS adaptive density control (gsplat's DefaultStrategy rules, written here: gsplat is
    CUDA-only in this project)."""

    # Densify and prune every this many iterations, from start to stop (fractions of the run).
    every: int = 100
    start: float = 0.05
    stop: float = 0.5
    # The dynamic Gaussians keep densifying until this fraction of the run (when later than stop).
    # "ours" creates them at stage 2, which starts where the static window ends (the paper's 15k of
    # 30k), so with the default 0 they never densify.
    dynamic_stop: float = 0.0
    # Grow Gaussians whose mean screen-space position gradient (NDC units, as 3DGS) exceeds this.
    grad_threshold: float = 2e-4
    # The dynamic set's threshold (0 = grad_threshold): a mover's Gaussians are seen in a few frames of their life
    # span each, so their averaged gradients run lower than the static set's. 5e-5 with dynamic_stop 0.8 at 640 px:
    # PSNR* +0.19 dB over nine grid runs of the strict tuning seeds, short of a default's +0.3; at the full small
    # preset (to the 100 000 cap) +0.02 on 404 and -1.67 on 409.
    dynamic_grad_threshold: float = 0.0
    # Clone when the largest scale is below this fraction of the scene extent, else split in two.
    clone_max_scale: float = 0.01
    # The dynamic set's line (0 = clone_max_scale): a mover's Gaussians (~0.1 m) lie below 1 % of a street's extent,
    # so they are only ever cloned in place, never split finer.
    dynamic_clone_max_scale: float = 0.0
    # Prune Gaussians with opacity below this, or larger than prune_scale x the scene extent.
    prune_opacity: float = 0.005
    prune_scale: float = 0.1
    # Reset opacities to reset_value every this many iterations (0 = never).
    reset_every: int = 0
    reset_value: float = 0.01
    # Never let a set grow beyond this many Gaussians (the CPU rasterizer's time grows with it).
    max_gaussians: int = 200_000

    def __post_init__(self) -> None:
        if self.grad_threshold < 0 or self.dynamic_grad_threshold < 0:
            raise ValueError(f"grad_threshold and dynamic_grad_threshold must be >= 0, got {self.grad_threshold}, "
                             f"{self.dynamic_grad_threshold}")
        if self.dynamic_clone_max_scale < 0:
            raise ValueError(f"dynamic_clone_max_scale must be >= 0, got {self.dynamic_clone_max_scale}")

    def for_set(self, name: str) -> DensifyConfig:
        """The rules for Gaussian set ``name`` ("static" or "dynamic"): the dynamic set's own stop, gradient
        threshold and clone line where they are set."""
        if name != "dynamic":
            return self
        return dataclasses.replace(self, stop=max(self.stop, self.dynamic_stop),
                                   grad_threshold=self.dynamic_grad_threshold or self.grad_threshold,
                                   clone_max_scale=self.dynamic_clone_max_scale or self.clone_max_scale)


@dataclass
class TrainConfig:
    """Everything `radar4dgs train` needs besides the scene and its prepared folder."""

    # "ours" (static + dynamic Gaussians and the VGPT field), "static" (dynamics off), or a
    # baseline's motion model: "deformable", "pvg", "bspline".
    method: Method = "ours"
    # Dynamic masks used for the static/dynamic split, the image losses and the object loss.
    mask_source: MaskSource = "predicted"
    # Ours: initial life span (normalised time) of each dynamic Gaussian around the frame it was seen in,
    # learned afterwards (PVG's temporal visibility); 0 = visible at every time, as the paper. A car's copy
    # then draws it only near its own frame, so the field's error over long gaps blurs nothing. 0.05 is about
    # 2.5 frames of 50 either side (small seed 1, novel-view PSNR* 22.74 / 23.27 / 23.51 / 23.39 dB at 0.2 /
    # 0.1 / 0.05 / 0.025).
    dynamic_lifespan: float = 0.05
    # Ours: rendered between training frames, each copy is fully visible within this fraction of the distance to
    # the nearest training frame (SceneModel.window_fraction). 0.5 on hard tuning seeds 229 / 230: PSNR* +0.20 /
    # +0.56 dB over 0.25 at -0.03 / -0.05 dB of PSNR; at 0.75 and 1 the copies smear onto the road.
    held_out_window: float = 0.5
    # Ours: a dynamic mean is a point of the field's canonical space, drawn at t at D_t(x) ("canonical", the
    # paper), or its position at its life peak tau, drawn at D_t(D_tau^-1(x)) ("own-time"): the motion terms
    # fix only relative motion, so with "canonical" the image terms slide the dynamic set along the rays.
    dynamic_positions: Literal["canonical", "own-time"] = "canonical"
    # Ours: training renders draw a dynamic Gaussian ahead of the static ones up to this fraction of its depth nearer
    # (scene_model.dynamic_drawn_in_front: road Gaussians hid the cars' lower part); 0.1: PSNR* +0.34 dB (hard tuning).
    dynamic_in_front: float = 0.1
    # Ours: the finished model's dynamic_in_front (every render after training: evaluation, render, videos, edits);
    # trained at 0.1, drawn at 0.2: held-out PSNR* +0.64 dB more on the hard tuning seeds, PSNR +0.02 (no retraining).
    render_in_front: float = 0.2
    # Ours: dynamic Gaussians the field moves faster than this (px per frame at 320 px width) start with a
    # life span shortened in proportion, down to one frame (model_init.speed_scaled_lifespans); 0 = off.
    dynamic_lifespan_reference_px: float = 0.0
    # Ours: at this fraction of the iterations (0 = never) the dynamic Gaussians are grouped into
    # actors (radar4dgs.actors.discover, default ActorConfig) and each actor's Gaussians leave the field for a
    # rigid motion of its own: a yaw and a translation per training frame, linear in between (model.actor_motion),
    # started from the field's motion and learned at rigid_actors_lr (Adam; radians and metres). One smooth field
    # cannot give a fast car and its slow neighbours opposite motions; a rigid body per actor can.
    rigid_actors_at: float = 0.0
    # 0.0005: novel-view PSNR* +0.11 dB over 0.002 on ten strict tuning grid runs, 0.01: -0.91 (rigid-actors-lr.json).
    rigid_actors_lr: float = 0.0005
    # Weight of the rigid actors' smoothness term (ActorMotion.acceleration: squared change of velocity from one
    # key interval to the next, m and rad): per-frame poses fitted to their own images alone drift off the path.
    rigid_actors_smoothness: float = 0.0
    # Weight of the rigid actors' heading term (ActorMotion.heading_mismatch: each actor turns as its path turns,
    # rad²). Off: at 100 it halved a cut-in car's yaw error and moved PSNR* +0.04 dB over ten strict tuning runs.
    rigid_actors_heading: float = 0.0
    # Only actors whose centroid moves at least this far in the image from one frame to the next (90th
    # percentile over their consecutive visible frames; a fraction of the image width) move rigidly; the field
    # keeps the others. A lead car followed at the ego's speed hardly moves in the image, and the field holds it
    # better than per-frame poses (calm seeds 1-3, actors at most 5 px a frame at 320 px: -0.22 / -0.66 / -0.09
    # dB of novel-view PSNR* with every actor rigid; at 0.025 none of them moves rigidly). 0 = every actor.
    rigid_actors_min_motion: float = 0.0
    # Before the first and after the last training frame an actor's Gaussians were born in, its initial path goes on
    # at the velocity of its first or last two such frames, not the field's motion (which moves a copy anywhere
    # outside its life span). On: novel-view PSNR* +0.21 dB over ten strict tuning grid runs, +0.18 on calm 1-3 /
    # realistic 101-102, +0.19 / +0.86 at full small on 404 / 409 (benchmarks/results/rigid-actors-extrapolate.json).
    rigid_actors_extrapolate: bool = True
    # At the switch, each actor's path moves along the line of sight to fit the velocities of the radar objects it
    # holds (train.rigid_actors.radar_corrected_shift): the images place a far car across the line of sight, not
    # along it, and far crossing cars' actors were metres off there (their paths turning 50 degrees on straight roads).
    # Off: +0.02 dB of PSNR* over ten strict tuning grid runs (benchmarks/results/rigid-actor-priors.json).
    rigid_actors_radar_path: bool = False
    # At the switch, dynamic Gaussians the discovery left to the field join an actor whose fitted body covers them in
    # their own frame within this fraction of the image width (train.rigid_actors.attach_free); 0 = off. 0.0125 in
    # small: PSNR* +0.11 dB over ten strict tuning grid runs, +0.19 on calm 1-3 / realistic 101-102.
    rigid_actors_attach: float = 0.0
    # At the switch each actor's path keeps its reference frame's height (train.rigid_actors.fit_rigid_track, flat):
    # the field's paths drift up to metres in height, and a copy carried to the next frame drifts with them. True in
    # small: novel-view PSNR* +0.52 dB over ten strict tuning grid runs (benchmarks/results/rigid-actors-flat.json).
    rigid_actors_flat: bool = False
    # Ours, stage 3: static Gaussians learn only outside the dynamic masks (alternate iterations ignore those
    # pixels / freeze the static set), so they cannot bake in a car the dynamic ones under-explain. Off: it cost
    # 0.5-0.6 dB of novel-view PSNR on realistic traffic (docs/pipeline/training.md).
    static_outside_masks: bool = False
    seed: int = 0  # of the initial subsampling, camera order, dropout and motion minibatches
    resolution_scale: float = 1.0  # render and supervise at this fraction of the scene resolution (1 = full)
    # Coarse-to-fine: iterations before coarse_until (fraction of the run) render at
    # coarse_scale x resolution_scale. The early iterations mostly fix colours and opacities and do
    # not need the full image; on the CPU the saving is modest, since projecting and sorting the
    # Gaussians does not shrink with the image.
    coarse_scale: float = 1.0
    coarse_until: float = 0.0
    # Save a checkpoint every this many iterations (and at the end); 0 = only at the end.
    checkpoint_every: int = 500
    # Log the loss terms every this many iterations.
    log_every: int = 25
    # Torch device ("auto": CUDA when torch sees a GPU, else the CPU; or "cpu", "cuda", "cuda:1", ...)
    # and intra-op threads (0 = torch's default).
    device: str = "auto"
    threads: int = 0
    # Training frames whose targets (image, depth, sky and dynamic masks, ray directions: about 30
    # bytes a pixel, on the device) stay in memory, the most recently used; the others are read
    # from disk when drawn (about 5 ms a frame at 160x90 on a CPU). 0 keeps every frame, so
    # memory grows with the drive. Changes no result (a runtime field, as threads).
    frame_cache: int = 64
    # Initialisation from the prepared depth.
    init: GaussianInitConfig = dataclasses.field(default_factory=GaussianInitConfig)
    # The invertible deformation field.
    field: FieldConfig = dataclasses.field(default_factory=FieldConfig)
    losses: LossConfig = dataclasses.field(default_factory=LossConfig)
    optim: OptimConfig = dataclasses.field(default_factory=OptimConfig)
    densify: DensifyConfig = dataclasses.field(default_factory=DensifyConfig)
    raster: RasterConfig = dataclasses.field(default_factory=RasterConfig)
    # The baselines' motion models (deformable, pvg, bspline), and the life-span learning rates.
    baselines: BaselineConfig = dataclasses.field(default_factory=BaselineConfig)
    # Camera pose refinement and exposure compensation (on by default for odometry poses).
    poses: PoseRefineConfig = dataclasses.field(default_factory=PoseRefineConfig)
    # Sky map size (texels, equirectangular). A texel should be about a pixel: 2048 texels round
    # the horizon are 0.18 deg each, a pixel of the 320-wide, 70-deg synthetic camera 0.22. The
    # sky is a tenth of a driving image; a 128-texel map (2.8 deg a texel) blurred its clouds and
    # held sky pixels at 24 dB (synthetic seed 1, sky fitted alone: 24.3 dB at 64x128, 35.0 at
    # 512x1024, 46.8 at 1024x2048; novel views within 2 dB of those).
    sky_height: int = 1024
    sky_width: int = 2048

    PRESETS: ClassVar[Mapping[str, Mapping[str, Any]]] = {
        # Seconds on a CPU: a smoke test of the whole loop, not a reconstruction.
        "tiny": {"init": {**GaussianInitConfig.PRESETS["tiny"], "max_static": 8_000, "max_dynamic": 2_000},
                 "field": dict(FieldConfig.PRESETS["tiny"]),
                 "optim": {"iterations": 200}, "checkpoint_every": 100, "log_every": 10,
                 "densify": {"every": 50, "max_gaussians": 12_000},
                 "losses": {"motion_batch": 512, "radar_points_per_frame": 500},
                 "sky_height": 256, "sky_width": 512, "poses": dict(PoseRefineConfig.PRESETS["tiny"])},
        # 320x180 on 2 CPU cores in about 15 minutes (the demo's budget is 20 in all): fewer
        # iterations than a GPU run, the first third at half resolution. Stage 2 starts at a
        # quarter of the run, not half: 1 800 iterations leave the dynamic Gaussians too few
        # views otherwise, while the field's own fit (stage 1) needs only a few hundred
        # (600-iteration runs of synthetic seed 1: novel-view PSNR* 18.1 dB with the paper's
        # 1/2 and 2/3, 19.1 with 1/4 and 0.4, same background PSNR).
        "small": {"init": {**GaussianInitConfig.PRESETS["small"], "max_static": 50_000},
                  "field": dict(FieldConfig.PRESETS["small"]),
                  "optim": {"iterations": 1800, "stage2_start": 0.25, "stage3_start": 0.4,
                            "field_prefit_iterations": 1000},
                  "coarse_scale": 0.5, "coarse_until": 0.35,
                  # Rigid actors from 30 % of the run: novel-view PSNR* +0.93 dB over ten grid runs of the strict
                  # hard tuning seeds at 640 px (every run gains), +0.28 on calm 1-3 and realistic 101-102 at 320
                  # px, +0.94 / +0.70 at this preset on 404 / 409 (benchmarks/results/rigid-actors-640px-strict.json).
                  "rigid_actors_at": 0.3, "rigid_actors_smoothness": 1.0, "rigid_actors_attach": 0.0125,
                  "rigid_actors_flat": True,
                  "densify": {"max_gaussians": 100_000}, "poses": dict(PoseRefineConfig.PRESETS["small"])},
        # 1920x1080 frames are ~60 MB each on the device: 16 of them, not 64.
        "paper": {"init": dict(GaussianInitConfig.PRESETS["paper"]), "field": dict(FieldConfig.PRESETS["paper"]),
                  "frame_cache": 16,
                  "optim": {"iterations": 30_000}, "checkpoint_every": 5000, "log_every": 100,
                  "densify": {"every": 100, "reset_every": 3000, "max_gaussians": 3_000_000},
                  "losses": {"motion_batch": 8192, "radar_points_per_frame": 10_000},
                  "sky_height": 2048, "sky_width": 4096, "poses": dict(PoseRefineConfig.PRESETS["paper"])},
    }

    def __post_init__(self) -> None:
        o = self.optim
        if o.iterations < 1:
            raise ValueError(f"optim.iterations must be >= 1, got {o.iterations}")
        if not 0.0 <= o.stage2_start <= o.stage3_start <= 1.0:
            raise ValueError("need 0 <= optim.stage2_start <= optim.stage3_start <= 1, got "
                             f"{o.stage2_start}, {o.stage3_start}")
        if self.dynamic_lifespan < 0 or not 0.0 <= self.held_out_window <= 1.0:
            raise ValueError(f"need dynamic_lifespan >= 0 and held_out_window in [0, 1], got "
                             f"{self.dynamic_lifespan} and {self.held_out_window}")
        if self.dynamic_positions == "own-time" and self.dynamic_lifespan <= 0:
            raise ValueError("dynamic_positions='own-time' needs a life peak per Gaussian: dynamic_lifespan > 0")
        if not (0.0 <= self.dynamic_in_front < 1.0 and 0.0 <= self.render_in_front < 1.0):
            raise ValueError("dynamic_in_front and render_in_front must be in [0, 1), got "
                             f"{self.dynamic_in_front} and {self.render_in_front}")
        if self.frame_cache < 0:
            raise ValueError(f"frame_cache must be >= 0 (0 = every frame), got {self.frame_cache}")
        for name in ("rigid_actors_smoothness", "rigid_actors_heading"):
            if getattr(self, name) < 0:
                raise ValueError(f"{name} must be >= 0, got {getattr(self, name)}")
        if self.rigid_actors_min_motion < 0:
            raise ValueError(f"rigid_actors_min_motion must be >= 0, got {self.rigid_actors_min_motion}")
        if not 0.0 <= self.rigid_actors_at < 1.0:
            raise ValueError(f"rigid_actors_at must lie in [0, 1) (0 = never), got {self.rigid_actors_at}")
        if self.dynamic_lifespan_reference_px < 0:
            raise ValueError(f"dynamic_lifespan_reference_px must be >= 0, got {self.dynamic_lifespan_reference_px}")
        if not 0.0 <= o.dropout < 1.0:
            raise ValueError(f"optim.dropout must lie in [0, 1), got {o.dropout}")
        for name in ("resolution_scale", "coarse_scale"):
            if not 0.0 < getattr(self, name) <= 1.0:
                raise ValueError(f"{name} must lie in (0, 1], got {getattr(self, name)}")

    def stage_start(self, stage: int) -> int:
        """The first iteration of "ours"' stage 2 or 3 (from ``optim.stage2_start`` / ``stage3_start``)."""
        return round({2: self.optim.stage2_start, 3: self.optim.stage3_start}[stage] * self.optim.iterations)

    def stage_at(self, step: int) -> int:
        """The training stage (1, 2 or 3) of iteration ``step`` (0-based); only "ours" has stages:
        the other methods stay in stage 1 with every part trained from the start."""
        if self.method != "ours":
            return 1
        return 3 if step >= self.stage_start(3) else 2 if step >= self.stage_start(2) else 1
