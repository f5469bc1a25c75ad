"""The parts a run's scene model starts from: the scene's length scale, a fresh deformation field,
the dynamic Gaussians in its canonical space, life spans, and the Deformable-GS offset MLP."""

from __future__ import annotations

from typing import Any

import numpy as np
import torch
from torch import Tensor

from radar4dgs.io.scene import Scene
from radar4dgs.model.config import TrainConfig
from radar4dgs.model.field import DeformationField
from radar4dgs.model.gaussians import GaussianSet, to_canonical
from radar4dgs.model.motion_models import OffsetField
from radar4dgs.train.config import FitConfig
from radar4dgs.train.data import MotionTargets
from radar4dgs.train.fit_motion import fit_field


def scene_extent(scene: Scene) -> float:
    """3DGS's scene extent: 1.1 x the largest distance of a camera centre from their mean (m),
    at least 1 m (a standing camera still needs a length scale)."""
    centres = np.stack([np.linalg.inv(scene.world_to_camera(i))[:3, 3] for i in range(len(scene))])
    radius = float(np.linalg.norm(centres - centres.mean(axis=0), axis=1).max()) if len(centres) else 0.0
    return max(1.1 * radius, 1.0)


def new_field(config: TrainConfig, motion: MotionTargets | None, fallback_points: np.ndarray,
              device: torch.device, dtype: torch.dtype, progress: bool = False) -> DeformationField:
    """A fresh field (seeded), normalised to the region of its supervision (or of the dynamic
    points when there is none); with ``optim.field_prefit_iterations`` > 0 and supervision, fitted
    to it first (:func:`prefit_field`)."""
    fitted = prefit_field(config, motion, device, dtype, progress) if motion is not None else None
    if fitted is not None:
        return fitted
    torch.manual_seed(config.seed)
    deformation = DeformationField(config.field).to(device=device, dtype=dtype)
    region = []
    if motion is not None and motion.flow is not None:
        region += [motion.flow.x_i, motion.flow.x_j]
    if motion is not None and motion.radar is not None:
        region.append(motion.radar.x)
    deformation.fit_normalization(np.concatenate(region) if region else fallback_points)
    return deformation


def prefit_field(config: TrainConfig, motion: MotionTargets, device: torch.device, dtype: torch.dtype,
                 progress: bool = False) -> DeformationField | None:
    """A field fitted alone to ``motion`` for ``optim.field_prefit_iterations`` iterations (the
    standalone fit, :func:`radar4dgs.train.fit_motion.fit_field`, with the run's seed and motion
    batch), in training mode; None when that is 0 or no term the run weights has samples.

    Only the terms the run trains the field with take part (the ablations turn a term off by its
    weight), weighted relative to ``L_flow`` as in training."""
    losses = config.losses
    flow = motion.flow if losses.flow_weight > 0 else None
    radar = motion.radar if losses.radar_weight > 0 else None
    velocity = motion.velocity if losses.velocity_weight > 0 else None
    if config.optim.field_prefit_iterations <= 0 or (flow is None and radar is None and velocity is None):
        return None
    scale = losses.flow_weight if flow is not None else 1.0  # fit_field weighs L_flow by 1
    fit = FitConfig(iterations=config.optim.field_prefit_iterations, batch_size=losses.motion_batch,
                    radar_weight=losses.radar_weight / scale, velocity_weight=losses.velocity_weight / scale,
                    acceleration_weight=losses.acceleration_weight / scale,
                    velocity_position_std=motion.velocity_position_std, velocity_huber=motion.velocity_huber,
                    seed=config.seed, threads=0, device=str(device),
                    dtype="float64" if dtype == torch.float64 else "float32")
    deformation, _ = fit_field(flow, radar, config.field, fit, progress, velocity=velocity, path=motion.path)
    return deformation.train()


def gaussian_kwargs(config: TrainConfig, device, dtype) -> dict[str, Any]:
    i = config.init
    return {"init_opacity": i.init_opacity, "knn_k": i.knn_k, "min_scale": i.min_scale,
            "max_scale": i.max_scale, "device": device, "dtype": dtype}


def dynamic_gaussians(points: dict[str, np.ndarray], times: np.ndarray, deformation: DeformationField,
                      config: TrainConfig, device, dtype) -> GaussianSet:
    """Dynamic Gaussians at the canonical positions of their frames' world points (at the world points
    themselves with ``config.dynamic_positions`` "own-time")."""
    dyn = points["dynamic"]
    world = points["points"][dyn]
    means = world
    if len(world) and config.dynamic_positions == "canonical":
        means = to_canonical(world, times[points["frame"][dyn]], deformation).double().cpu().numpy()
    return GaussianSet.from_points(means, points["colors"][dyn], **gaussian_kwargs(config, device, dtype))


def with_lifespans(gaussians: GaussianSet, frame_times: np.ndarray, lifespan: float | np.ndarray,
                   **motion: Tensor) -> GaussianSet:
    """``gaussians`` plus a life peak at the time of the frame each was seen in and the initial
    life span ``lifespan`` (normalised time, one for all or (N,) per Gaussian; PVG, bspline, ours'
    dynamic set), and any other motion parameters."""
    n = len(gaussians)
    like = gaussians.params["means"]
    tau = torch.as_tensor(np.asarray(frame_times, dtype=np.float64)).to(like)
    log_lifespan = torch.as_tensor(np.log(np.broadcast_to(np.asarray(lifespan, dtype=np.float64), (n,)))).to(like)
    return gaussians.with_motion(tau=tau, log_lifespan=log_lifespan, **motion)


@torch.no_grad()
def image_speeds(world: np.ndarray, frames: np.ndarray, times: np.ndarray, deformation: DeformationField,
                 scene: Scene) -> np.ndarray:
    """(M,) how far (px per frame) the field moves each of the (M, 3) ``world`` points, seen in
    frame ``frames`` (M,), over one frame interval, in that frame's camera (the object's own motion,
    without the ego's)."""
    step = float(np.min(np.diff(times))) if len(times) > 1 else 1.0
    ref = next(deformation.parameters())
    speeds = np.zeros(len(world))
    for frame in np.unique(frames):
        rows = frames == frame
        t = float(times[frame])
        to = t + step if t + step <= 1.0 else t - step
        x = torch.as_tensor(world[rows], dtype=ref.dtype, device=ref.device)
        moved = deformation.warp(x, t, to).double().cpu().numpy()
        uv, z = scene.camera.project(_in_camera(scene, int(frame), world[rows]))
        uv_moved, z_moved = scene.camera.project(_in_camera(scene, int(frame), moved))
        ok = (z > 0.1) & (z_moved > 0.1)
        speeds[np.flatnonzero(rows)[ok]] = np.linalg.norm(uv_moved[ok] - uv[ok], axis=1)
    return speeds


def _in_camera(scene: Scene, frame: int, points: np.ndarray) -> np.ndarray:
    w2c = scene.world_to_camera(frame)
    return points @ w2c[:3, :3].T + w2c[:3, 3]


def speed_scaled_lifespans(speeds: np.ndarray, base: float, reference_px: float, frame_step: float) -> np.ndarray:
    """(M,) life spans: ``base`` for points slower than ``reference_px`` per frame, shortened in
    proportion to their speed beyond it, never below one frame (``frame_step``, normalised time).

    Why: a dynamic Gaussian is one frame's copy of its object, drawn at other times through the
    field; the field's error grows with the object's speed, so a fast object's copies, drawn over
    the default span of a few frames, overlay as a smear along its path. One frame is the floor so
    a held-out time between two training frames still sees both neighbours' copies.
    """
    scale = np.minimum(1.0, reference_px / np.maximum(speeds, 1e-9))
    return np.clip(base * scale, min(frame_step, base), base)


def offset_field(config: TrainConfig, points: np.ndarray, device, dtype) -> OffsetField:
    """A fresh (seeded) Deformable-GS offset MLP normalised to the points' bounding box."""
    torch.manual_seed(config.seed)
    if len(points):
        lo, hi = points.min(axis=0), points.max(axis=0)
        centre, scale = (lo + hi) / 2.0, max(float((hi - lo).max()) / 2.0, 1.0)
    else:
        centre, scale = np.zeros(3), 1.0
    return OffsetField(config.baselines, centre, scale).to(device=device, dtype=dtype)
