"""The standalone fit of the deformation field to a scene's prepared data (no Gaussians yet), and
its evaluation against the scene's ground-truth scene flow.

Data (from the prepared folder only, except with the "oracle" sources):
- flow samples: the lifted pseudo scene-flow pairs ``(x_i, x_j)`` of ``<prepared>/flow`` (times
  ``t_i, t_j``), supervising ``L_flow``;
- radar samples: per frame pair (i, j), dynamic pixels of frame i lifted with frame i's depth
  (a random subset: these stand in for the dynamic Gaussians of time i), each given the
  compensated radial velocity of its nearest dynamic radar point of frame i (within a gate),
  supervising ``L_rad`` over ``dt = timestamp_j - timestamp_i``.

The field is optimised with Adam on ``L_flow + lambda L_rad`` (either term can be switched off),
with minibatches drawn from all frames at once (per-point times). Canonical points are implicit:
``warp(x, t_i, t_j) = D_tj(D_ti^-1(x))`` goes through ``x_c = D_ti^-1(x_ti)``.

Evaluation: for every adjacent pair (i, i + 1), every gt-dynamic pixel with finite gt depth is
lifted to its world point x at time t_i; its predicted flow ``D_t(i+1)(D_ti^-1(x)) - x`` is compared
with ``gt/flow`` (end-point error, metres, pooled over all pixels of all pairs).

Time coordinate: ``t = (timestamp - t_first) / (t_last - t_first)`` in [0, 1]
(:func:`radar4dgs.io.scene.normalized_times`).
"""

from __future__ import annotations

import contextlib
import time
import warnings
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Callable

import numpy as np
import torch

from radar4dgs.config import to_dict
from radar4dgs.io.image_motion import image_motion_edges, project_motion
from radar4dgs.io.scene import normalized_times
from radar4dgs.metrics.losses import flow_loss, radar_loss, velocity_loss
from radar4dgs.model.field import DeformationField, FieldConfig
from radar4dgs.motion.association import associate_velocities, load_radar_dynamics
from radar4dgs.motion.config import FlowConfig
from radar4dgs.motion.flow import frame_pairs, load_depth, load_flow_pairs, load_mask, prepare_flow
from radar4dgs.motion.lift import backproject
from radar4dgs.motion.truth import moving_surface_points
from radar4dgs.train.config import FitConfig, MotionConfig
from radar4dgs.train.object_points import (
    ObjectPoints,
    flow_near,
    frame_objects,
    oracle_object_points,
    pixels_of_objects,
    prepared_object_points,
)
from radar4dgs.train.path_prior import PathSamples, observed_path_samples, path_loss

# evaluate_sceneflow's on_pair(i, (N, 3) true moving points of frame i, (N, 3) their motion to i + 1, (N,) errors)
PairCallback = Callable[[int, np.ndarray, np.ndarray, np.ndarray], None]

# --------------------------------------------------------------------------------------------
# Data


@dataclass
class FlowSamples:
    """Pseudo scene-flow pairs: x_i (N, 3) at t_i (N,) and x_j (N, 3) at t_j (N,)."""

    x_i: np.ndarray
    x_j: np.ndarray
    t_i: np.ndarray
    t_j: np.ndarray

    def __len__(self) -> int:
        return int(len(self.x_i))


@dataclass
class RadarSamples:
    """Radar-supervised points: x (N, 3) at t_i (N,), displaced to t_j (N,) over dt (N,) seconds;
    radar centre (N, 3); associated compensated radial velocity v_r (N,)."""

    x: np.ndarray
    t_i: np.ndarray
    t_j: np.ndarray
    dt: np.ndarray
    centre: np.ndarray
    v_r: np.ndarray

    def __len__(self) -> int:
        return int(len(self.x))


def flow_samples_from_pairs(pairs: list[dict[str, np.ndarray]], times: np.ndarray) -> FlowSamples:
    """Concatenate the ``<prepared>/flow`` pairs (see :func:`radar4dgs.motion.flow.load_flow_pairs`)."""
    x_i, x_j, t_i, t_j = [], [], [], []
    for pair in pairs:
        n = len(pair["points_i"])
        x_i.append(pair["points_i"].astype(np.float64))
        x_j.append(pair["points_j"].astype(np.float64))
        t_i.append(np.full(n, times[int(pair["index_i"])]))
        t_j.append(np.full(n, times[int(pair["index_j"])]))
    if not x_i:
        empty = np.zeros((0, 3))
        return FlowSamples(empty, empty, np.zeros(0), np.zeros(0))
    return FlowSamples(np.concatenate(x_i), np.concatenate(x_j), np.concatenate(t_i), np.concatenate(t_j))


def dynamic_pixels(depth: np.ndarray, mask: np.ndarray, limit: int,
                   rng: np.random.Generator) -> tuple[np.ndarray, np.ndarray]:
    """(M,) rows and (M,) columns of at most ``limit`` (0 = all) random pixels of the (H, W) ``mask``
    with finite, positive (H, W) ``depth``."""
    valid = mask & np.isfinite(depth) & (depth > 0)
    rows, cols = np.nonzero(valid)
    if limit and len(rows) > limit:
        chosen = rng.choice(len(rows), size=limit, replace=False)
        rows, cols = rows[chosen], cols[chosen]
    return rows, cols


def dynamic_points(depth: np.ndarray, mask: np.ndarray, K: np.ndarray, world_to_cam: np.ndarray,
                   limit: int, rng: np.random.Generator) -> np.ndarray:
    """(M, 3) world points of :func:`dynamic_pixels`."""
    rows, cols = dynamic_pixels(depth, mask, limit, rng)
    pixels = np.stack([cols, rows], axis=1).astype(np.float64)
    return backproject(pixels, depth[rows, cols], K, world_to_cam)


def collect_radar_samples(scene, prepared_dir: str | Path | None, flow_config: FlowConfig, fit: FitConfig,
                          times: np.ndarray) -> tuple[RadarSamples, dict]:
    """Radar-supervised points of every frame pair (:func:`frame_pairs`), and association stats."""
    rng = np.random.default_rng(fit.seed)
    columns: dict[str, list[np.ndarray]] = {k: [] for k in ("x", "t_i", "t_j", "dt", "centre", "v_r")}
    candidates = matched_total = radar_total = 0
    for i, j in frame_pairs(scene, flow_config.skip_test_frames):
        depth = load_depth(scene, i, flow_config.depth_source, prepared_dir)
        mask = load_mask(scene, i, flow_config.mask_source, prepared_dir)
        points = dynamic_points(depth, mask, scene.camera.K, scene.world_to_camera(i),
                                fit.radar_points_per_frame, rng)
        radar = load_radar_dynamics(scene, i, fit.radar_source, prepared_dir)
        v_r = associate_velocities(points, radar, fit.radar_gate)
        candidates += len(points)
        matched_total += int(np.isfinite(v_r).sum())
        radar_total += len(radar)
        if fit.radar_returns_as_points:
            points, v_r = np.concatenate([points, radar.points]), np.concatenate([v_r, radar.v_r_comp])
        keep = np.isfinite(v_r)
        n = int(keep.sum())
        columns["x"].append(points[keep])
        columns["v_r"].append(v_r[keep])
        columns["t_i"].append(np.full(n, times[i]))
        columns["t_j"].append(np.full(n, times[j]))
        columns["dt"].append(np.full(n, scene.frames[j].timestamp - scene.frames[i].timestamp))
        columns["centre"].append(np.repeat(radar.centre[None], n, axis=0))
    joined = {k: (np.concatenate(v) if v else np.zeros((0, 3) if k in ("x", "centre") else (0,)))
              for k, v in columns.items()}
    stats = {"radar_candidates": candidates, "radar_matched": matched_total,
             "radar_dynamic_points": radar_total,
             "radar_returns_supervised": radar_total if fit.radar_returns_as_points else 0,
             "radar_matched_fraction": matched_total / candidates if candidates else None}
    return RadarSamples(**joined), stats


@dataclass
class VelocitySamples:
    """Points of radar objects: x (N, 3) at t_i (N,), displaced to t_j (N,) over dt (N,) seconds;
    their object's planar world velocity (N, 2) (m/s) and its covariance (N, 2, 2) (m^2/s^2)."""

    x: np.ndarray
    t_i: np.ndarray
    t_j: np.ndarray
    dt: np.ndarray
    velocity: np.ndarray
    covariance: np.ndarray

    def __len__(self) -> int:
        return int(len(self.x))


def add_object_pixels(scene, index: int, found: list[ObjectPoints], prepared_dir, flow_config: FlowConfig,
                      fit: FitConfig, flow_points: np.ndarray | None,
                      rng: np.random.Generator) -> tuple[list[ObjectPoints], int]:
    """``found`` with each object's dynamic pixels of frame ``index`` added to its returns
    (``fit.velocity_pixels``: all objects, or those with too few flow pairs near them, whose
    start points ``flow_points`` (F, 3) are given), and how many pixels were added."""
    wanted = [fit.velocity_pixels == "all" or flow_near(o[0], flow_points, fit.radar_gate) < fit.velocity_flow_pairs
              for o in found]
    if not any(wanted):
        return found, 0
    depth = load_depth(scene, index, flow_config.depth_source, prepared_dir)
    mask = load_mask(scene, index, flow_config.mask_source, prepared_dir)
    pixels = dynamic_points(depth, mask, scene.camera.K, scene.world_to_camera(index), fit.radar_points_per_frame,
                            rng)
    split = pixels_of_objects(pixels, found, fit.radar_gate)
    out = [(np.concatenate([points, extra]), v, S) if want else (points, v, S)
           for (points, v, S), extra, want in zip(found, split, wanted, strict=True)]
    return out, sum(len(extra) for extra, want in zip(split, wanted, strict=True) if want)


def _flow_start_points(prepared_dir, fit: FitConfig) -> dict[int, np.ndarray]:
    """Frame index -> (F, 3) start points of its flow pairs, for ``velocity_pixels="no_flow"``
    (empty when off or when there is no prepared flow: then no object has flow)."""
    if fit.velocity_pixels != "no_flow" or prepared_dir is None or not (Path(prepared_dir) / "flow").is_dir():
        return {}
    return {int(pair["index_i"]): pair["points_i"] for pair in load_flow_pairs(prepared_dir)}


def collect_velocity_samples(scene, prepared_dir: str | Path | None, flow_config: FlowConfig, fit: FitConfig,
                             times: np.ndarray) -> tuple[VelocitySamples, dict]:
    """Radar-object points of every frame pair (:func:`frame_pairs`) for ``L_vel``, and stats.

    Without ``<prepared>/radar/objects.json`` (older prepared folders) the samples are empty and
    ``stats["velocity_note"]`` says why: the term is then off, not an error.
    """
    columns: dict[str, list[np.ndarray]] = {k: [] for k in ("x", "t_i", "t_j", "dt", "velocity", "covariance")}
    stats: dict[str, Any] = {"velocity_objects": 0, "velocity_objects_rejected": 0, "velocity_pixels": 0,
                             "velocity_note": None}
    per_frame, stats["velocity_note"] = frame_objects(scene, prepared_dir, fit)
    if stats["velocity_note"]:
        warnings.warn(stats["velocity_note"], stacklevel=2)
    rng = np.random.default_rng(fit.seed)  # its own stream: the radar samples' draws stay as they were
    flow_points = _flow_start_points(prepared_dir, fit)
    for i, j in frame_pairs(scene, flow_config.skip_test_frames) if per_frame is not None else ():
        if fit.radar_source == "oracle":
            found, rejected = oracle_object_points(scene, i, fit), 0
        else:
            found, rejected = prepared_object_points(scene, i, per_frame[i], fit)
        if fit.velocity_pixels != "off" and found:
            found, added = add_object_pixels(scene, i, found, prepared_dir, flow_config, fit, flow_points.get(i), rng)
            stats["velocity_pixels"] += added
        stats["velocity_objects"] += len(found)
        stats["velocity_objects_rejected"] += rejected
        for points, velocity, covariance in found:
            n = len(points)
            columns["x"].append(points)
            columns["velocity"].append(np.repeat(velocity[None], n, axis=0))
            columns["covariance"].append(np.repeat(covariance[None], n, axis=0))
            columns["t_i"].append(np.full(n, times[i]))
            columns["t_j"].append(np.full(n, times[j]))
            columns["dt"].append(np.full(n, scene.frames[j].timestamp - scene.frames[i].timestamp))
    shapes = {"x": (0, 3), "velocity": (0, 2), "covariance": (0, 2, 2)}
    joined = {k: (np.concatenate(v) if v else np.zeros(shapes.get(k, (0,)))) for k, v in columns.items()}
    stats["velocity_samples"] = len(joined["x"])
    return VelocitySamples(**joined), stats


# --------------------------------------------------------------------------------------------
# Optimisation


def _torch_dtype(name: str) -> torch.dtype:
    return {"float32": torch.float32, "float64": torch.float64}[name]


def fit_field(flow: FlowSamples | None, radar: RadarSamples | None, field_config: FieldConfig, fit: FitConfig,
              progress: bool = False, velocity: VelocitySamples | None = None,
              path: PathSamples | None = None) -> tuple[DeformationField, list[dict]]:
    """Fit a fresh field with Adam on ``L_flow + radar_weight * L_rad + velocity_weight * L_vel``, plus
    ``acceleration_weight * L_acc`` on ``path`` (:mod:`radar4dgs.train.path_prior`) when given.

    Any sample set may be None or empty (that term is off). The normalisation is fitted to
    every sample point. Returns the field (eval mode) and a loss history (every 50 iterations).
    """
    with torch_threads(fit.threads):
        return _fit_field(flow, radar, velocity, field_config, fit, progress, path)


@contextlib.contextmanager
def torch_threads(threads: int):
    """Run the block with ``threads`` torch intra-op threads (0 = unchanged), restoring the setting
    after: torch's thread count is process-wide, so a fit must not leave it changed."""
    previous = torch.get_num_threads()
    if threads > 0:
        torch.set_num_threads(threads)
    try:
        yield
    finally:
        torch.set_num_threads(previous)


def _term_columns(flow: FlowSamples | None, radar: RadarSamples | None,
                  velocity: VelocitySamples | None) -> dict[str, tuple[np.ndarray, ...]]:
    """The arrays of each term that has samples, in the order the minibatches are drawn (flow,
    radar, velocity: a term added later must not change the draws of the earlier ones)."""
    columns = {}
    if flow is not None and len(flow) > 0:
        columns["flow"] = (flow.x_i, flow.x_j, flow.t_i, flow.t_j)
    if radar is not None and len(radar) > 0:
        columns["radar"] = (radar.x, radar.t_i, radar.t_j, radar.dt, radar.centre, radar.v_r)
    if velocity is not None and len(velocity) > 0:
        columns["velocity"] = (velocity.x, velocity.t_i, velocity.t_j, velocity.dt, velocity.velocity,
                               velocity.covariance)
    return columns


def _term_loss(name: str, deformation: DeformationField, batch: list[torch.Tensor], fit: FitConfig) -> torch.Tensor:
    if name == "flow":
        return flow_loss(deformation, *batch)
    if name == "radar":
        return radar_loss(deformation, *batch)
    return velocity_loss(deformation, *batch, position_std=fit.velocity_position_std, huber=fit.velocity_huber)


def _fit_field(flow: FlowSamples | None, radar: RadarSamples | None, velocity: VelocitySamples | None,
               field_config: FieldConfig, fit: FitConfig, progress: bool,
               path: PathSamples | None = None) -> tuple[DeformationField, list[dict]]:
    columns = _term_columns(flow, radar, velocity)
    if not columns:
        raise ValueError("nothing to fit: no flow pairs, no radar-associated points and no radar-object points")
    device, dtype = torch.device(fit.device), _torch_dtype(fit.dtype)
    generator = torch.Generator().manual_seed(fit.seed)
    torch.manual_seed(fit.seed)  # parameter initialisation of the field's hidden layers
    deformation = DeformationField(field_config).to(device=device, dtype=dtype)
    # Every sample point: x_i and x_j of the flow pairs, x of the others.
    region = [a for name, arrays in columns.items() for a in arrays[:2 if name == "flow" else 1]]
    deformation.fit_normalization(np.concatenate(region))
    tensors = {k: [torch.as_tensor(a, dtype=dtype, device=device) for a in v] for k, v in columns.items()}
    optimizer = torch.optim.Adam(deformation.parameters(), lr=fit.learning_rate)
    gamma = fit.final_learning_rate_ratio ** (1.0 / max(fit.iterations, 1))
    scheduler = torch.optim.lr_scheduler.ExponentialLR(optimizer, gamma)
    history: list[dict] = []
    steps = range(fit.iterations)
    if progress:
        from tqdm import tqdm

        steps = tqdm(steps, desc="fit-motion", unit="it")
    for step in steps:
        losses: dict[str, torch.Tensor] = {}
        for name, arrays in tensors.items():
            n = len(arrays[0])
            index = torch.randint(n, (min(fit.batch_size, n),), generator=generator).to(device)
            losses[name] = _term_loss(name, deformation, [a[index] for a in arrays], fit)
        total = losses.get("flow", 0.0) + fit.radar_weight * losses.get("radar", 0.0)
        if "velocity" in losses:
            total = total + fit.velocity_weight * losses["velocity"]
        if path is not None and fit.acceleration_weight > 0:
            index = torch.randint(len(path), (min(fit.batch_size, len(path)),), generator=generator)
            losses["acceleration"] = path_loss(deformation, path, index, generator, dtype, device)
            total = total + fit.acceleration_weight * losses["acceleration"]
        if not torch.isfinite(total):
            raise FloatingPointError(f"non-finite loss at iteration {step}: "
                                     f"{ {k: float(v) for k, v in losses.items()} }")
        optimizer.zero_grad(set_to_none=True)
        total.backward()
        optimizer.step()
        scheduler.step()
        if step % 50 == 0 or step == fit.iterations - 1:
            history.append({"iteration": step, "total": float(total.detach()),
                            **{k: float(v.detach()) for k, v in losses.items()}})
    return deformation.eval(), history


# --------------------------------------------------------------------------------------------
# Evaluation


def evaluate_sceneflow(deformation: DeformationField, scene, times: np.ndarray, chunk: int = 65536,
                       on_pair: PairCallback | None = None) -> dict:
    """End-point error of the field's scene flow on every gt-dynamic pixel of every adjacent pair.

    ``on_pair`` (:data:`PairCallback`), when given, sees each pair's points, motion and errors, so a caller can
    group them its own way (:class:`radar4dgs.evaluate.field_objects.ObjectErrors`) without a second pass.

    Returns ``epe`` (m, mean over pixels of all pairs), ``epe_by_image_motion`` (the same per bin of the pixels'
    gt image motion, ``radar4dgs.io.image_motion.image_motion_edges``), ``epe_train_pairs`` (both frames are
    training frames), ``epe_held_out_pairs`` (a test frame involved), ``zero_motion_epe`` (mean |gt flow|, the
    error of a field that does not move), ``roundtrip_max`` (m, max |D^-1(D(x)) - x| on the evaluated points),
    ``points`` and ``pairs``.
    """
    parameter = next(deformation.parameters())
    device, dtype = parameter.device, parameter.dtype
    test = set(scene.test_indices)
    errors, zero, held_out, image_motion, roundtrip = [], [], [], [], 0.0
    for i in range(len(scene) - 1):
        surface = moving_surface_points(scene, i)
        if surface is None:
            continue
        x, motion, pixels, depth = surface
        predicted = []
        with torch.no_grad():
            for start in range(0, len(x), chunk):
                xt = torch.as_tensor(x[start:start + chunk], dtype=dtype, device=device)
                canonical = deformation.inverse(xt, float(times[i]))
                moved = deformation.forward(canonical, float(times[i + 1]))
                back = deformation.inverse(deformation.forward(canonical, float(times[i])), float(times[i]))
                roundtrip = max(roundtrip, float((back - canonical).abs().max()))
                predicted.append((moved - xt).double().cpu().numpy())
        error = np.linalg.norm(np.concatenate(predicted) - motion, axis=1)
        if on_pair is not None:
            on_pair(i, x, motion, error)
        errors.append(error)
        zero.append(np.linalg.norm(motion, axis=1))
        held_out.append(np.full(len(error), i in test or (i + 1) in test))
        # The pixels' image motion from the gt arrays already loaded (NaN: behind the next camera).
        keep, moved = project_motion(scene.camera.K, np.linalg.inv(scene.world_to_camera(i)),
                                     scene.world_to_camera(i + 1), pixels, depth, motion, None, with_keep=True)
        pixel_motion = np.full(len(pixels), np.nan)
        pixel_motion[keep] = moved
        image_motion.append(pixel_motion)
    if not errors:
        return {"epe": None, "epe_train_pairs": None, "epe_held_out_pairs": None, "zero_motion_epe": None,
                "roundtrip_max": None, "points": 0, "pairs": 0, "epe_by_image_motion": []}
    e, z, h = np.concatenate(errors), np.concatenate(zero), np.concatenate(held_out)
    # A point that passes behind the next camera has no image motion (NaN): the fastest bin.
    edges = image_motion_edges(scene.camera.width)
    bins = np.digitize(np.nan_to_num(np.concatenate(image_motion), nan=1e9), edges) - 1
    by_motion = [{"low": lo, "high": None if np.isinf(hi) else hi, "points": int((bins == b).sum()),
                  "epe": float(e[bins == b].mean()) if (bins == b).any() else None}
                 for b, (lo, hi) in enumerate(zip(edges[:-1], edges[1:], strict=True))]
    return {"epe": float(e.mean()), "epe_by_image_motion": by_motion,
            "epe_train_pairs": float(e[~h].mean()) if (~h).any() else None,
            "epe_held_out_pairs": float(e[h].mean()) if h.any() else None,
            "zero_motion_epe": float(z.mean()), "roundtrip_max": roundtrip,
            "points": int(len(e)), "pairs": len(errors)}


# --------------------------------------------------------------------------------------------
# Scene level


def run_fit(scene, prepared_dir: str | Path, config: MotionConfig | None = None, use_flow: bool = True,
            use_radar: bool = True, recompute_flow: bool = False, evaluate: bool = True,
            progress: bool = False, use_velocity: bool | None = None,
            on_pair: PairCallback | None = None) -> tuple[DeformationField, dict]:
    """Fit the field to a scene's prepared data and (with gt/) evaluate it (``on_pair``: :func:`evaluate_sceneflow`'s).

    ``<prepared>/flow`` is computed with ``config.flow`` when missing (or ``recompute_flow``) and ``use_flow`` is on.
    ``use_velocity`` (None: ``config.fit.velocity``) adds ``L_vel``. Returns the field and a JSON-ready result dict
    (config, data counts, loss history, timings, and the :func:`evaluate_sceneflow` metrics under ``"sceneflow"``).
    """
    config = config or MotionConfig()
    prepared = Path(prepared_dir)
    times = normalized_times(scene)
    use_velocity = config.fit.velocity if use_velocity is None else use_velocity
    result: dict[str, Any] = {"scene": str(scene.root), "prepared": str(prepared), "use_flow": use_flow,
                              "use_radar": use_radar, "use_velocity": use_velocity, "config": to_dict(config)}
    started = time.perf_counter()
    flow_samples = radar_samples = velocity_samples = None
    if use_flow:
        if recompute_flow or not (prepared / "flow").is_dir():
            flow_started = time.perf_counter()
            prepare_flow(scene, prepared, config.flow, progress=progress)
            result["flow_prepare_seconds"] = time.perf_counter() - flow_started
        flow_samples = flow_samples_from_pairs(load_flow_pairs(prepared), times)
        result["flow_pairs"] = len(flow_samples)
    if use_radar:
        radar_samples, stats = collect_radar_samples(scene, prepared, config.flow, config.fit, times)
        result.update(stats)
    if use_velocity:
        velocity_samples, stats = collect_velocity_samples(scene, prepared, config.flow, config.fit, times)
        result.update(stats)
    path = observed_path_samples(flow_samples, radar_samples, times, config.fit.acceleration_reach) \
        if config.fit.acceleration_weight > 0 else None
    data_seconds = time.perf_counter() - started
    fit_started = time.perf_counter()
    deformation, history = fit_field(flow_samples, radar_samples, config.field, config.fit, progress,
                                     velocity=velocity_samples, path=path)
    result["fit_seconds"] = time.perf_counter() - fit_started
    result["data_seconds"] = data_seconds
    result["history"] = history
    if evaluate:
        eval_started = time.perf_counter()
        with torch_threads(config.fit.threads):
            result["sceneflow"] = evaluate_sceneflow(deformation, scene, times, on_pair=on_pair)
        result["eval_seconds"] = time.perf_counter() - eval_started
    return deformation, result


def save_field(deformation: DeformationField, path: str | Path) -> Path:
    """Save the field's state dict and its :class:`FieldConfig` (atomically) to ``path``."""
    from radar4dgs.io.atomic import atomic_save_torch

    atomic_save_torch(path, {"field_config": to_dict(deformation.config), "state_dict": deformation.state_dict()})
    return Path(path)


def write_motion_outputs(out: str | Path, deformation: DeformationField, result: dict,
                         config: MotionConfig) -> Path:
    """Write a fit's ``config.json``, ``field.pt`` and ``results.json`` into ``out`` (atomically each)."""
    from radar4dgs.config import save_config
    from radar4dgs.io.atomic import atomic_write_json

    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    save_config(config, out / "config.json")
    save_field(deformation, out / "field.pt")
    atomic_write_json(out / "results.json", result)
    return out


def load_field(path: str | Path, device: str = "cpu") -> DeformationField:
    """A field saved by :func:`save_field`."""
    from radar4dgs.config import from_dict

    payload = torch.load(Path(path), map_location=device, weights_only=True)
    deformation = DeformationField(from_dict(FieldConfig, payload["field_config"]))
    state = payload["state_dict"]
    deformation.to(device=device, dtype=state["centre"].dtype)
    deformation.load_state_dict(state)
    return deformation.eval()
