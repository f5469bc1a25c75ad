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


def set_learning_rates(optimizers: dict[str, torch.optim.Optimizer], config: TrainConfig, extent: float,
                       step: int) -> None:
    """Set the rates of iteration ``step`` in ``optimizers`` (named as :func:`make_optimizers`'s)."""
    progress = step / max(config.optim.iterations - 1, 1)
    lrs = gaussian_lrs(config, extent, progress)
    for name in ("static", "dynamic"):
        if name in optimizers:
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


def gaussian_visibility(render: dict, keep: torch.Tensor | None) -> dict[str, torch.Tensor]:
    """``{"static": (Ns,) bool, "dynamic": (Nd,) bool}``: the Gaussians of each set that the render of
    this iteration drew (radii > 0 on both axes, and not dropped by ``keep``, over the render's
    static-then-dynamic order); a set the render left out is absent."""
    visible = (render["meta"]["radii"][0] > 0).all(dim=-1)
    if keep is not None:
        visible = visible & keep.to(visible.device)
    n_static, n_dynamic = render["n_static"], render["n_dynamic"]
    out = {"static": visible[:n_static]}
    if n_dynamic:
        out["dynamic"] = visible[n_static:n_static + n_dynamic]
    return out


@torch.no_grad()
def selective_step(optimizer: torch.optim.Optimizer, visible: torch.Tensor) -> None:
    """An Adam step of a Gaussian set's optimizer that leaves the rows of the Gaussians not drawn
    (``visible`` (N,) False) as they were: their parameters and both moments. With plain Adam a
    Gaussian keeps moving on its momentum for tens of iterations after its last gradient, and a
    dynamic Gaussian, drawn only in the few frames of its life span, spends most of the run so.
    gsplat's ``SelectiveAdam`` does this in one CUDA kernel; it is not available on the CPU, so
    here the fused step runs on every row and the hidden rows are written back."""
    hidden = ~visible
    if not bool(hidden.any()):
        optimizer.step()
        return
    saved = []
    for group in optimizer.param_groups:
        for param in group["params"]:
            if param.grad is None:
                continue
            if param.shape[0] != len(visible):
                raise ValueError(f"selective_step: parameter {group.get('name', '?')} has {param.shape[0]} rows, "
                                 f"the visibility mask {len(visible)}")
            state = optimizer.state.get(param, {})
            moments = {key: state[key][hidden].clone() for key in ("exp_avg", "exp_avg_sq") if key in state}
            saved.append((param, param[hidden].clone(), moments))
    optimizer.step()
    for param, rows, moments in saved:
        param[hidden] = rows
        for key in ("exp_avg", "exp_avg_sq"):  # moments the step created start at 0, as Adam's
            optimizer.state[param][key][hidden] = moments.get(key, 0.0)


def step_optimizers(optimizers: dict[str, torch.optim.Optimizer], names: list[str],
                    visibility: dict[str, torch.Tensor] | None) -> None:
    """Step the optimizers of ``names`` that exist; a Gaussian set named in ``visibility`` takes a
    :func:`selective_step` with its mask."""
    for name in names:
        if name not in optimizers:
            continue
        if visibility is not None and name in visibility:
            selective_step(optimizers[name], visibility[name])
        else:
            optimizers[name].step()
