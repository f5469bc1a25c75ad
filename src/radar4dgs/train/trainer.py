"""Three-stage training of the Gaussian scene (DESIGN.md stage 7).

Stage 1: static Gaussians, sky and the deformation field (the field by ``L_flow`` and ``L_rad``
only; the dynamic pixels are left out of the image losses, since no Gaussian explains them yet).
Stage 2 starts by moving the dynamic Gaussians' initial world points into the canonical space with
the field fitted so far; static Gaussians frozen, dynamic Gaussians, sky and field trained.
Stage 3: everything, plus the object loss.

Loss per iteration (one training image):
``(1 - l_r) L1 + l_r (1 - SSIM) + l_d L_invdepth + l_obj BCE(dyn, mask) [stage 3] + l_sky BCE(alpha,
not sky) + w_flow L_flow + w_rad L_rad``. Every term is checked for NaN / inf before the step.

Determinism: the camera order of an epoch and every random draw of a step come from generators
seeded by ``(seed, epoch)`` and ``(seed, step)``, so a run resumed from a checkpoint (parameters,
Adam moments, densification statistics) continues exactly as the unbroken run would.
"""

from __future__ import annotations

import math
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Callable

import numpy as np
import torch
import torch.nn.functional as F
from torch import Tensor

from radar4dgs.config import config_difference, from_dict, read_config_dict, save_config, to_dict
from radar4dgs.io.atomic import atomic_save_torch, atomic_write_json
from radar4dgs.io.scene import Scene, read_scene
from radar4dgs.metrics.image import ssim_loss_value
from radar4dgs.model.field import DeformationField
from radar4dgs.io.scene import normalized_times
from radar4dgs.train.fit_motion import torch_threads
from radar4dgs.metrics.losses import flow_loss, radar_loss
from radar4dgs.model.config import TrainConfig
from radar4dgs.train.data import (FrameTargets, MotionTargets, dynamic_masks, load_frame_targets,
                                  load_motion_targets)
from radar4dgs.train.densify import GradientStats, densify_and_prune, reset_opacities
from radar4dgs.model.gaussians import GaussianInitConfig, GaussianSet, backproject_frames, to_canonical
from radar4dgs.model.scene_model import SceneModel
from radar4dgs.model.motion_models import OffsetField
from radar4dgs.model.run import CHECKPOINT_DIR, CONFIG_FILE, HISTORY_FILE, LAST_CHECKPOINT, MODEL_FILE, RUN_FILE
from radar4dgs.model.sky import SkyEnvironment

# The named terms of the training loss, as logged in history.json.
LOSS_TERMS = ("l1", "ssim", "depth", "object", "sky", "flow", "radar")


class TrainingError(RuntimeError):
    """A training run cannot go on (non-finite loss, inconsistent run folder)."""


# --------------------------------------------------------------------------------------------
# Pure pieces


def scene_extent(scene: Scene) -> float:
    """3DGS's scene extent: 1.1 x the largest distance of a camera centre from their mean (m),
    at least 1 m (a standing camera still needs a length scale)."""
    centres = np.stack([np.linalg.inv(scene.world_to_camera(i))[:3, 3] for i in range(len(scene))])
    radius = float(np.linalg.norm(centres - centres.mean(axis=0), axis=1).max()) if len(centres) else 0.0
    return max(1.1 * radius, 1.0)


def step_generator(seed: int, step: int) -> torch.Generator:
    """The generator of every random draw of iteration ``step`` (stateless: resumable)."""
    return torch.Generator().manual_seed(int(seed) * 1_000_003 + int(step) + 1)


def frame_order(seed: int, epoch: int, n: int) -> np.ndarray:
    """(n,) permutation of the training frames for ``epoch``."""
    return np.random.default_rng([int(seed), int(epoch)]).permutation(n)


def exponential_lr(start: float, end: float, progress: float) -> float:
    """Log-linear interpolation from ``start`` to ``end`` at ``progress`` in [0, 1]."""
    progress = min(max(progress, 0.0), 1.0)
    if start <= 0 or end <= 0:
        return start
    return math.exp(math.log(start) * (1 - progress) + math.log(end) * progress)


def binary_cross_entropy(probability: Tensor, target: Tensor) -> Tensor:
    """Mean BCE of probabilities (clamped away from 0 and 1) against a bool/float target."""
    return F.binary_cross_entropy(probability.clamp(1e-4, 1 - 1e-4), target.to(probability.dtype))


def inverse_depth_l1(rendered: Tensor, alpha: Tensor, target: Tensor, valid: Tensor) -> Tensor:
    """Mean ``|1 / d_rendered - 1 / d_target|`` over ``valid`` pixels with finite positive target
    depth and some rendered opacity; 0 when there is none. All (H, W)."""
    valid = valid & torch.isfinite(target) & (target > 0) & (alpha > 0.05)
    if not bool(valid.any()):
        return rendered.sum() * 0.0
    inv_rendered = 1.0 / rendered[valid].clamp_min(0.1)
    return (inv_rendered - 1.0 / target[valid]).abs().mean()


def image_losses(render: dict[str, Any], target: FrameTargets, config: TrainConfig, stage: int,
                 ignore_dynamic: bool) -> dict[str, Tensor]:
    """The image terms (unweighted) of one iteration. With ``ignore_dynamic`` (stage 1 of the full
    method) the dynamic-mask pixels of the target take the render's own (detached) colour, so they
    give neither L1 nor SSIM gradient, and they are left out of the depth term."""
    rgb, image = render["rgb"], target.image
    if ignore_dynamic:
        image = torch.where(target.dynamic[..., None], rgb.detach(), image)
    losses = {"l1": (rgb - image).abs().mean(), "ssim": 1.0 - ssim_loss_value(rgb, image)}
    depth_valid = ~target.sky & ~target.dynamic if ignore_dynamic else ~target.sky
    losses["depth"] = inverse_depth_l1(render["depth"], render["alpha"], target.depth, depth_valid)
    losses["sky"] = binary_cross_entropy(render["alpha"], ~target.sky)
    if stage == 3:
        losses["object"] = binary_cross_entropy(render["dynamic"], target.dynamic)
    return losses


def motion_losses(deformation: DeformationField, motion: MotionTargets, batch: int,
                  generator: torch.Generator, device: torch.device, dtype: torch.dtype) -> dict[str, Tensor]:
    """``L_flow`` and ``L_rad`` on a random minibatch of the field's supervision."""
    def draw(n: int) -> Tensor:
        return torch.randint(n, (min(batch, n),), generator=generator)

    def tensor(array: np.ndarray) -> Tensor:
        return torch.as_tensor(array, dtype=dtype, device=device)

    losses = {}
    if motion.flow is not None:
        f = motion.flow
        i = draw(len(f)).numpy()
        losses["flow"] = flow_loss(deformation, tensor(f.x_i[i]), tensor(f.x_j[i]), tensor(f.t_i[i]), tensor(f.t_j[i]))
    if motion.radar is not None:
        r = motion.radar
        i = draw(len(r)).numpy()
        losses["radar"] = radar_loss(deformation, tensor(r.x[i]), tensor(r.t_i[i]), tensor(r.t_j[i]),
                                     tensor(r.dt[i]), tensor(r.centre[i]), tensor(r.v_r[i]))
    return losses


def loss_weights(config: TrainConfig) -> dict[str, float]:
    """The weight of each named loss term (the keys are :data:`LOSS_TERMS`)."""
    c = config.losses
    return {"l1": 1.0 - c.ssim_weight, "ssim": c.ssim_weight, "depth": c.depth_weight,
            "object": c.object_weight, "sky": c.sky_weight, "flow": c.flow_weight, "radar": c.radar_weight}


def total_loss(losses: dict[str, Tensor], config: TrainConfig) -> Tensor:
    """The weighted sum of the named terms (absent terms count 0)."""
    weights = loss_weights(config)
    return sum(weights[name] * value for name, value in losses.items())


def check_finite(losses: dict[str, Tensor], step: int) -> None:
    bad = {name: float(v.detach()) for name, v in losses.items() if not torch.isfinite(v)}
    if bad:
        raise TrainingError(f"non-finite loss at iteration {step}: {bad}; the last checkpoint is kept "
                            f"(resume with --resume after changing the config)")


# Where a run computes, not what it computes: a run may resume with other values.
RUNTIME_FIELDS = ("threads", "device")


def with_legacy_values(saved: dict) -> dict:
    """A saved TrainConfig dict with the fields it predates set to what a run of its time did,
    where that is not the field's default: no life span (``dynamic_lifespan`` 0) and dynamic
    pixels on the background's grid (``init.dynamic_pixel_stride`` = ``init.pixel_stride``)."""
    out = dict(saved)
    out.setdefault("dynamic_lifespan", 0.0)
    init = out.get("init")
    if isinstance(init, dict) and "dynamic_pixel_stride" not in init:
        out["init"] = {**init, "dynamic_pixel_stride": init.get("pixel_stride", GaussianInitConfig.pixel_stride)}
    return out


def run_config_difference(saved: TrainConfig | dict, config: TrainConfig) -> list[str]:
    """Where ``saved`` (a config, or its dict as saved) and ``config`` describe different runs, as
    :func:`radar4dgs.config.config_difference` lines, ignoring :data:`RUNTIME_FIELDS`. A field that
    a saved dict lacks (a run from before the field existed) counts as what such a run did
    (:func:`with_legacy_values`), else as its default."""
    if isinstance(saved, dict):
        saved = from_dict(TrainConfig, with_legacy_values(saved), partial=False)
    return config_difference(to_dict(saved), to_dict(config), ignore=RUNTIME_FIELDS)


def same_run_config(saved: TrainConfig | dict, config: TrainConfig) -> bool:
    """True when ``saved`` and ``config`` describe the same run (:func:`run_config_difference`)."""
    return not run_config_difference(saved, config)


def psnr_of(rgb: Tensor, image: Tensor) -> float:
    mse = float(((rgb.detach().clamp(0, 1) - image) ** 2).mean())
    return 10 * math.log10(1.0 / max(mse, 1e-10))


# --------------------------------------------------------------------------------------------
# Building the model


def new_field(config: TrainConfig, motion: MotionTargets | None, fallback_points: np.ndarray,
              device: torch.device, dtype: torch.dtype) -> DeformationField:
    """A fresh field (seeded), normalised to the region of its supervision (or of the dynamic
    points when there is none)."""
    torch.manual_seed(config.seed)
    deformation = DeformationField(config.field).to(device=device, dtype=dtype)
    region = []
    if motion is not None and motion.flow is not None:
        region += [motion.flow.x_i, motion.flow.x_j]
    if motion is not None and motion.radar is not None:
        region.append(motion.radar.x)
    deformation.fit_normalization(np.concatenate(region) if region else fallback_points)
    return deformation


def gaussian_kwargs(config: TrainConfig, device, dtype) -> dict[str, Any]:
    i = config.init
    return {"init_opacity": i.init_opacity, "knn_k": i.knn_k, "min_scale": i.min_scale,
            "max_scale": i.max_scale, "device": device, "dtype": dtype}


def dynamic_gaussians(points: dict[str, np.ndarray], times: np.ndarray, deformation: DeformationField,
                      config: TrainConfig, device, dtype) -> GaussianSet:
    """Dynamic Gaussians at the canonical positions of their frames' world points."""
    dyn = points["dynamic"]
    world = points["points"][dyn]
    canonical = to_canonical(world, times[points["frame"][dyn]], deformation).double().cpu().numpy() \
        if len(world) else world
    return GaussianSet.from_points(canonical, points["colors"][dyn], **gaussian_kwargs(config, device, dtype))


# --------------------------------------------------------------------------------------------
# The loop


@dataclass
class RunState:
    """Everything a checkpoint holds besides the config."""

    step: int
    model: SceneModel
    optimizers: dict[str, torch.optim.Optimizer]
    stats: dict[str, GradientStats]
    history: list[dict] = field(default_factory=list)


def gaussian_lrs(config: TrainConfig, extent: float, progress: float) -> dict[str, float]:
    """Learning rate of every Gaussian parameter (the motion ones are used only by sets that
    have them); lengths scale with the scene extent."""
    o, b = config.optim, config.baselines
    return {"means": exponential_lr(o.means_lr, o.means_lr_final, progress) * extent, "quats": o.quats_lr,
            "log_scales": o.scales_lr, "opacity_logits": o.opacity_lr, "colors": o.colors_lr,
            "velocity": b.velocity_lr * extent, "tau": b.time_lr, "log_lifespan": b.lifespan_lr,
            "control": b.control_lr * extent}


def adam(params: Any, **kwargs: Any) -> torch.optim.Adam:
    """Adam, fused where torch has the kernel: one pass over each tensor instead of a dozen; on the
    CPU about 9x faster for the sky map's six million texels. ``params`` as torch.optim.Adam's."""
    params = list(params)
    groups = params if params and isinstance(params[0], dict) else [{"params": params}]
    devices = {p.device.type for group in groups for p in group["params"]}
    return torch.optim.Adam(params, fused=devices <= {"cpu", "cuda"}, **kwargs)


def make_optimizer(gaussians: GaussianSet, config: TrainConfig, extent: float, prefix: str) -> torch.optim.Adam:
    return adam(gaussians.param_groups(gaussian_lrs(config, extent, 0.0), prefix=prefix), eps=1e-15)


def make_optimizers(model: SceneModel, config: TrainConfig, extent: float) -> dict[str, torch.optim.Optimizer]:
    """One optimizer per part ``model`` has: static, sky, and where present field, offsets, dynamic."""
    optimizers: dict[str, torch.optim.Optimizer] = {
        "static": make_optimizer(model.static, config, extent, "static."),
        "sky": adam(model.sky.parameters(), lr=config.optim.sky_lr),
    }
    if model.field is not None:
        optimizers["field"] = adam(model.field.parameters(), lr=config.optim.field_lr)
    if model.offsets is not None:
        optimizers["offsets"] = adam(model.offsets.parameters(), lr=config.baselines.offset_lr)
    if model.dynamic is not None:
        optimizers["dynamic"] = make_optimizer(model.dynamic, config, extent, "dynamic.")
    return optimizers


def with_lifespans(gaussians: GaussianSet, frame_times: np.ndarray, lifespan: float,
                   **motion: Tensor) -> GaussianSet:
    """``gaussians`` plus a life peak at the time of the frame each was seen in and the initial
    life span ``lifespan`` (normalised time; PVG, bspline, ours' dynamic set), and any other
    motion parameters."""
    n = len(gaussians)
    like = gaussians.params["means"]
    tau = torch.as_tensor(np.asarray(frame_times, dtype=np.float64)).to(like)
    log_lifespan = torch.full((n,), math.log(lifespan)).to(like)
    return gaussians.with_motion(tau=tau, log_lifespan=log_lifespan, **motion)


def offset_field(config: TrainConfig, points: np.ndarray, device, dtype) -> OffsetField:
    """A fresh (seeded) Deformable-GS offset MLP normalised to the points' bounding box."""
    torch.manual_seed(config.seed)
    if len(points):
        lo, hi = points.min(axis=0), points.max(axis=0)
        centre, scale = (lo + hi) / 2.0, max(float((hi - lo).max()) / 2.0, 1.0)
    else:
        centre, scale = np.zeros(3), 1.0
    return OffsetField(config.baselines, centre, scale).to(device=device, dtype=dtype)


def decayed_network_lr(config: TrainConfig, start: float, progress: float) -> float:
    """The field's (and the offset MLP's) learning rate at ``progress``."""
    return start * config.optim.field_lr_final_ratio ** progress


def set_learning_rates(state: RunState, config: TrainConfig, extent: float, step: int) -> None:
    progress = step / max(config.optim.iterations - 1, 1)
    lrs = gaussian_lrs(config, extent, progress)
    for name in ("static", "dynamic"):
        if name in state.optimizers:
            for group in state.optimizers[name].param_groups:
                group["lr"] = lrs[group["name"].rsplit(".", 1)[-1]]
    for name, start in (("field", config.optim.field_lr), ("offsets", config.baselines.offset_lr)):
        if name in state.optimizers:
            for group in state.optimizers[name].param_groups:
                group["lr"] = decayed_network_lr(config, start, progress)


class Trainer:
    """Trains one run folder. ``train()`` starts fresh or, with ``resume``, from the last checkpoint."""

    def __init__(self, scene_path: Path, prepared: Path, out: Path, config: TrainConfig,
                 progress: bool = True, log: Callable[[str], None] = print):
        self.scene_path, self.prepared, self.out = Path(scene_path), Path(prepared), Path(out)
        self.config = config
        self.progress = progress
        self.log = log
        self.device = torch.device(config.device)
        self.dtype = torch.float32
        self._points: dict[str, np.ndarray] | None = None

    # ---- set-up
    def _load(self) -> None:
        self.scene = read_scene(self.scene_path)
        if not (self.prepared / "depth").is_dir():
            raise FileNotFoundError(f"{self.prepared}: no prepared depth (run `radar4dgs prepare "
                                    f"{self.scene_path}` first)")
        self.times = normalized_times(self.scene)
        self.extent = scene_extent(self.scene)
        self.train_indices = self.scene.train_indices
        self.masks = dynamic_masks(self.scene, self.prepared, self.config.mask_source, self.train_indices,
                                   self.progress)
        self.targets = self._targets(self.config.resolution_scale)
        self.coarse_targets = self._targets(self.config.resolution_scale * self.config.coarse_scale) \
            if self.config.coarse_scale < 1.0 and self.config.coarse_until > 0 else self.targets
        self.motion = load_motion_targets(self.scene, self.prepared, self.config) \
            if self.config.method == "ours" else None

    def _initial_points(self) -> dict[str, np.ndarray]:
        """The back-projected training frames (deterministic given the init seed), computed once:
        the static Gaussians start from them and, at stage 2, the dynamic ones."""
        if self._points is None:
            self._points = backproject_frames(self.scene, self.prepared, self.config.init, masks=self.masks)
        return self._points

    def _targets(self, scale: float) -> list[FrameTargets]:
        return [load_frame_targets(self.scene, self.prepared, i, scale, self.times, self.device, self.dtype,
                                   dynamic=self.masks[i]) for i in self.train_indices]

    def _fresh_state(self) -> RunState:
        config, device, dtype = self.config, self.device, self.dtype
        method = config.method
        points = self._initial_points()
        # Only the methods that separate moving objects use the masks for the split.
        dyn = points["dynamic"] if method in ("ours", "bspline") else np.zeros(len(points["dynamic"]), bool)
        static = GaussianSet.from_points(points["points"][~dyn], points["colors"][~dyn],
                                         **gaussian_kwargs(config, device, dtype))
        if method == "pvg":
            static = with_lifespans(static, self.times[points["frame"][~dyn]], config.baselines.initial_lifespan,
                                    velocity=torch.zeros(len(static), 3))
        images = [(t.image.cpu().numpy() * 255).astype(np.uint8) for t in self.targets]
        sky = SkyEnvironment.from_sky_pixels(images, [t.sky.cpu().numpy() for t in self.targets],
                                             height=config.sky_height, width=config.sky_width,
                                             device=device, dtype=dtype)
        deformation, dynamic, offsets = None, None, None
        stats = {"static": GradientStats(len(static), device)}
        if method == "ours":
            deformation = new_field(config, self.motion, points["points"][dyn], device, dtype)
        elif method == "deformable":
            offsets = offset_field(config, points["points"], device, dtype)
        elif method == "bspline":
            dynamic = GaussianSet.from_points(points["points"][dyn], points["colors"][dyn],
                                              **gaussian_kwargs(config, device, dtype))
            control = torch.zeros(len(dynamic), config.baselines.control_points, 3)
            dynamic = with_lifespans(dynamic, self.times[points["frame"][dyn]], config.baselines.initial_lifespan,
                                     control=control)
            stats["dynamic"] = GradientStats(len(dynamic), device)
        model = SceneModel(static, sky, deformation, dynamic, offsets, config.baselines)
        optimizers = make_optimizers(model, config, self.extent)
        return RunState(0, model, optimizers, stats)

    def _start_dynamic(self, state: RunState) -> None:
        """Stage 2 begins: dynamic Gaussians into the canonical space of the current field."""
        points = self._initial_points()
        dynamic = dynamic_gaussians(points, self.times, state.model.field, self.config, self.device, self.dtype)
        if self.config.dynamic_lifespan > 0:
            dynamic = with_lifespans(dynamic, self.times[points["frame"][points["dynamic"]]],
                                     self.config.dynamic_lifespan)
        state.model.dynamic = dynamic
        state.optimizers["dynamic"] = make_optimizer(dynamic, self.config, self.extent, "dynamic.")
        state.stats["dynamic"] = GradientStats(len(dynamic), self.device)
        self.log(f"stage 2: {len(dynamic)} dynamic Gaussians moved to the canonical space")

    # ---- checkpoints
    def checkpoint_payload(self, state: RunState) -> dict[str, Any]:
        return {"step": state.step, "model": state.model.payload(),
                "optimizers": {k: v.state_dict() for k, v in state.optimizers.items()},
                "stats": {k: v.state_dict() for k, v in state.stats.items()},
                "history": state.history, "config": to_dict(self.config)}

    def save_checkpoint(self, state: RunState) -> Path:
        directory = self.out / CHECKPOINT_DIR
        directory.mkdir(parents=True, exist_ok=True)
        payload = self.checkpoint_payload(state)
        atomic_save_torch(directory / LAST_CHECKPOINT, payload)
        return directory / LAST_CHECKPOINT

    def load_checkpoint(self, path: Path) -> RunState:
        saved = torch.load(path, map_location="cpu", weights_only=True)
        if not same_run_config(saved.get("config") or {}, self.config):
            raise TrainingError(f"{path}: saved with a different configuration than "
                                f"{self.out / CONFIG_FILE}; resume with the run's own config")
        model = SceneModel.from_payload(saved["model"], self.device, self.dtype)
        state = RunState(int(saved["step"]), model, {}, {}, list(saved.get("history", [])))
        state.optimizers.update(make_optimizers(model, self.config, self.extent))
        for name, optimizer in state.optimizers.items():
            optimizer.load_state_dict(saved["optimizers"][name])
        for name, stats in saved["stats"].items():
            state.stats[name] = GradientStats(0, self.device)
            state.stats[name].load_state_dict(stats)
        return state

    # ---- the run
    def _write_run_files(self) -> None:
        self.out.mkdir(parents=True, exist_ok=True)
        save_config(self.config, self.out / CONFIG_FILE)
        atomic_write_json(self.out / RUN_FILE, {"scene": str(self.scene_path.resolve()),
                                                "prepared": str(self.prepared.resolve())})

    def train(self, resume: bool = False, stop_after: int | None = None) -> RunState:
        """Train; with ``resume`` continue from ``checkpoints/last.pt``. ``stop_after`` stops after
        that many iterations of this call (as if killed right after a checkpoint; tests, benchmarks)."""
        with torch_threads(self.config.threads):
            return self._train(resume, stop_after)

    def _train(self, resume: bool, stop_after: int | None) -> RunState:
        last = self.out / CHECKPOINT_DIR / LAST_CHECKPOINT
        if resume and (self.out / CONFIG_FILE).is_file():
            changed = run_config_difference(read_config_dict(TrainConfig, self.out / CONFIG_FILE), self.config)
            if changed:
                raise TrainingError(f"{self.out / CONFIG_FILE}: the run was started with another configuration "
                                    f"({'; '.join(changed[:4])}); resume with the run's options (or train into "
                                    "a new --out)")
        elif not resume and last.is_file():
            raise TrainingError(f"{self.out}: holds a run already (checkpoint {last}); pass --resume to "
                                "continue it or choose another --out")
        self._load()
        self._write_run_files()
        if resume and last.is_file():
            state = self.load_checkpoint(last)
            self.log(f"resuming {self.out} at iteration {state.step}")
        else:
            state = self._fresh_state()
        config = self.config
        total = config.optim.iterations
        end = total if stop_after is None else min(total, state.step + stop_after)
        bar = None
        if self.progress:
            from tqdm import tqdm

            bar = tqdm(total=total, initial=state.step, desc="train", unit="it", dynamic_ncols=True)
        started = time.perf_counter()
        while state.step < end:
            self._iteration(state)
            state.step += 1
            if bar is not None:
                bar.update(1)
                if state.history and "psnr" in state.history[-1]:
                    h = state.history[-1]
                    bar.set_postfix({"stage": h["stage"], "psnr": f"{h['psnr']:.2f}", "loss": f"{h['total']:.4f}",
                                     "N": state.model.num_gaussians}, refresh=False)
            every = config.checkpoint_every
            if (every > 0 and state.step % every == 0) or state.step == end:
                self.save_checkpoint(state)
        if bar is not None:
            bar.close()
        if state.step >= total:
            self.finish(state, time.perf_counter() - started)
        return state

    def finish(self, state: RunState, seconds: float) -> None:
        atomic_save_torch(self.out / MODEL_FILE, {"model": state.model.payload(), "step": state.step,
                                                  "config": to_dict(self.config)})
        atomic_write_json(self.out / HISTORY_FILE, {"history": state.history, "train_seconds_last_call": seconds,
                                                    "num_static": len(state.model.static),
                                                    "num_dynamic": 0 if state.model.dynamic is None
                                                    else len(state.model.dynamic)})

    def _iteration(self, state: RunState) -> None:
        config, step = self.config, state.step
        stage = config.stage_at(step)
        if config.method == "ours" and stage >= 2 and state.model.dynamic is None:
            self._start_dynamic(state)
        set_learning_rates(state, config, self.extent, step)
        n = len(self.targets)
        targets = self.coarse_targets if step < config.coarse_until * config.optim.iterations else self.targets
        target = targets[int(frame_order(config.seed, step // n, n)[step % n])]
        generator = step_generator(config.seed, step)
        model = state.model
        ours = config.method == "ours"
        with_dynamic = (ours and stage >= 2) or config.method == "bspline"
        keep, scale = None, 1.0
        if config.optim.dropout > 0 and step < config.optim.dropout_until * config.optim.iterations:
            keep = torch.rand(model.num_gaussians if with_dynamic else len(model.static),
                              generator=generator) >= config.optim.dropout
            keep = keep.to(self.device)
            scale = 1.0 / (1.0 - config.optim.dropout)
        render = model.render(target.view, config.raster, target.directions, keep, scale,
                              include_dynamic=with_dynamic, detach_static=ours and stage == 2)
        means2d = render["meta"]["means2d"]
        if means2d.requires_grad:
            means2d.retain_grad()
        losses = image_losses(render, target, config, stage, ignore_dynamic=ours and stage == 1)
        if ours and self.motion is not None:
            losses.update(motion_losses(model.field, self.motion, config.losses.motion_batch, generator,
                                        self.device, self.dtype))
        check_finite(losses, step)
        loss = total_loss(losses, config)
        for optimizer in state.optimizers.values():
            optimizer.zero_grad(set_to_none=True)
        loss.backward()
        trainable = ["sky", "field", "offsets"] + (["static"] if not (ours and stage == 2) else []) + \
            (["dynamic"] if with_dynamic else [])
        for name in trainable:
            if name in state.optimizers:
                state.optimizers[name].step()
        self._densify(state, render, stage, trainable, generator)
        if step % config.log_every == 0 or step == config.optim.iterations - 1:
            state.history.append({"step": step, "stage": stage, "frame": target.name, "width": target.view.width,
                                  "total": float(loss.detach()),
                                  "psnr": psnr_of(render["rgb"], target.image), "num_gaussians": model.num_gaussians,
                                  **{k: float(v.detach()) for k, v in losses.items()}})

    def _densify(self, state: RunState, render: dict, stage: int, trainable: list[str],
                 generator: torch.Generator) -> None:
        config, step = self.config, state.step
        means2d = render["meta"]["means2d"]
        if means2d.grad is None:
            return
        grad = means2d.grad[0]
        visible = (render["meta"]["radii"][0] > 0).all(dim=-1)
        width, height = render["meta"]["width"], render["meta"]["height"]
        bounds = {"static": (0, render["n_static"]),
                  "dynamic": (render["n_static"], render["n_static"] + render["n_dynamic"])}
        for name, (lo, hi) in bounds.items():
            if name in state.stats and name in trainable and hi > lo and len(state.stats[name].grad) == hi - lo:
                state.stats[name].add(grad[lo:hi], visible[lo:hi], width, height)
        d = config.densify
        total = config.optim.iterations
        if d.every <= 0 or (step + 1) % d.every != 0:
            return
        for name in ("static", "dynamic"):
            stop = max(d.stop, d.dynamic_stop) if name == "dynamic" else d.stop
            if name not in trainable or name not in state.stats or not (d.start * total <= step < stop * total):
                continue
            gaussians = getattr(state.model, name)
            counts = densify_and_prune(gaussians, state.optimizers[name], state.stats[name], self.extent, d, generator,
                                       prune_large=d.reset_every > 0 and step >= d.reset_every)
            if d.reset_every > 0 and (step + 1) % d.reset_every == 0:
                reset_opacities(gaussians, state.optimizers[name], d.reset_value)
            state.history.append({"step": step, "stage": stage, "densify": name, **counts,
                                  "num_gaussians": len(gaussians)})


def train_run(scene_path: Path, prepared: Path, out: Path, config: TrainConfig, resume: bool = False,
              progress: bool = True, stop_after: int | None = None) -> RunState:
    """Train ``scene_path`` with its ``prepared`` folder into run folder ``out``."""
    return Trainer(scene_path, prepared, out, config, progress=progress).train(resume=resume, stop_after=stop_after)
