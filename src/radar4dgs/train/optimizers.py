"""The optimisers of a scene model's parts and the learning-rate schedule of a run: exponential
decay of the Gaussian means' rate (in units of the scene extent), of the field's and the offset
MLP's rates; every other rate constant."""

from __future__ import annotations

import math
from typing import Any

import torch

from radar4dgs.model.appearance import FrameAppearance
from radar4dgs.model.config import TrainConfig
from radar4dgs.model.gaussians import GaussianSet
from radar4dgs.model.pose_refine import PoseCorrections
from radar4dgs.model.scene_model import SceneModel


def exponential_lr(start: float, end: float, progress: float) -> float:
    """Log-linear interpolation from ``start`` to ``end`` at ``progress`` in [0, 1]."""
    progress = min(max(progress, 0.0), 1.0)
    if start <= 0 or end <= 0:
        return start
    return math.exp(math.log(start) * (1 - progress) + math.log(end) * progress)


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
    """One optimizer per part ``model`` has: static, sky, and where present field, offsets, dynamic,
    actors (the rigid actors' motions)."""
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
    if model.actor_motion is not None:
        optimizers["actors"] = adam(model.actor_motion.param_groups(config.rigid_actors_lr))
    return optimizers


def decayed_network_lr(config: TrainConfig, start: float, progress: float) -> float:
    """The field's (and the offset MLP's) learning rate at ``progress``."""
    return start * config.optim.field_lr_final_ratio ** progress


def dynamic_progress(config: TrainConfig, step: int) -> float:
    """Where iteration ``step`` lies in the dynamic means' decay: as in the run, or with
    ``optim.dynamic_means_from_birth`` (ours only) from stage 2's first iteration (0) to the last (1).

    Why: ours creates its dynamic Gaussians at stage 2, which ``small`` starts a quarter into the
    run, so on the run's schedule they are born at a third of ``means_lr`` and have its last,
    smallest rates for most of their 1 350 iterations, each seen in only a few frames."""
    last = max(config.optim.iterations - 1, 1)
    if not (config.optim.dynamic_means_from_birth and config.method == "ours"):
        return step / last
    birth = config.stage_start(2)
    return (step - birth) / max(last - birth, 1)


def set_learning_rates(optimizers: dict[str, torch.optim.Optimizer], config: TrainConfig, extent: float,
                       step: int) -> None:
    """Set the rates of iteration ``step`` in ``optimizers`` (named as :func:`make_optimizers`'s)."""
    progress = step / max(config.optim.iterations - 1, 1)
    for name, at in (("static", progress), ("dynamic", dynamic_progress(config, step))):
        if name in optimizers:
            lrs = gaussian_lrs(config, extent, at)
            for group in optimizers[name].param_groups:
                group["lr"] = lrs[group["name"].rsplit(".", 1)[-1]]
    for name, start in (("field", config.optim.field_lr), ("offsets", config.baselines.offset_lr)):
        if name in optimizers:
            for group in optimizers[name].param_groups:
                group["lr"] = decayed_network_lr(config, start, progress)


def make_refine_optimizers(poses: PoseCorrections | None, appearance: FrameAppearance | None,
                           config: TrainConfig) -> dict[str, torch.optim.Optimizer]:
    """Adam for the pose corrections ("poses": translation and rotation groups) and the per-frame
    colour transforms ("appearance"), for those present."""
    c = config.poses
    optimizers: dict[str, torch.optim.Optimizer] = {}
    if poses is not None:
        optimizers["poses"] = adam(poses.param_groups(c.translation_lr, c.rotation_lr))
    if appearance is not None:
        optimizers["appearance"] = adam(appearance.param_groups(c.appearance_lr))
    return optimizers


def pose_lr_scale(config: TrainConfig, step: int) -> float:
    """Factor on the pose rates at iteration ``step``: 0 during the warm-up, then a log-linear decay
    from 1 to ``poses.lr_final_ratio`` at the end of the run."""
    total = max(config.optim.iterations - 1, 1)
    start = config.poses.warmup * total
    if step < start:
        return 0.0
    return exponential_lr(1.0, max(config.poses.lr_final_ratio, 1e-12), (step - start) / max(total - start, 1))


def set_refine_learning_rates(optimizers: dict[str, torch.optim.Optimizer], config: TrainConfig, step: int) -> None:
    """The pose rates of iteration ``step`` (:func:`pose_lr_scale`); the appearance rate is constant."""
    if "poses" not in optimizers:
        return
    scale = pose_lr_scale(config, step)
    for group in optimizers["poses"].param_groups:
        base = config.poses.translation_lr if group["name"] == "poses.translation" else config.poses.rotation_lr
        group["lr"] = base * scale
