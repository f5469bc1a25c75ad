"""Scene-level radar processing: per-frame ego-motion, optional temporal smoothing, dynamic flags,
compensated Doppler, and a summary that compares the radar with the scene's own motion data.

Outputs (``out_dir`` is ``<prepared>/radar``):
    ``<frame>.npz``: ``ego_velocity`` (3,) float64 radar axes (smoothed when enabled), ``covariance``
    (3, 3), ``ok`` (bool, the frame's own fit), ``inliers`` (N,) bool, ``dynamic`` (N,) bool,
    ``v_r_comp`` (N,) float32; rows aligned with ``scene.load_radar(i)`` (NaN rows dropped).
    ``summary.json``: per-frame speed, ok, reason, and the disagreement with the scene's motion data;
    ``time_sync``: the camera-radar clock offset estimate (:mod:`radar4dgs.radar.sync`), the offset
    ``applied_s`` (``RadarConfig.sync``) and the ``action`` taken. Objects, tracking and the
    disagreement use the re-stamped scans; later stages get them with ``prepared_synced_scene``.
    ``objects.json``: the dynamic points grouped into tracked objects with a planar velocity each
    (schema in :mod:`radar4dgs.radar.objects`; read it with ``load_radar_objects``).
    ``objects_split.json``: the same with every cluster's outliers fitted again
    (``RadarObjectConfig.split_outliers``; with that option on, the same as ``objects.json``); the flow
    stage predicts its rejected pixels' motion from it where ``objects.json`` has no object for them.
"""

from __future__ import annotations

import math
from pathlib import Path
from typing import Any, Callable, Iterable

import numpy as np

from radar4dgs.config import to_dict
from radar4dgs.io.atomic import atomic_save_npz, atomic_write_json
from radar4dgs.radar.classify import classify_dynamic
from radar4dgs.radar.config import RadarConfig
from radar4dgs.radar.ego_motion import EgoMotion, estimate_ego_motion
from radar4dgs.radar.objects import OBJECTS_FILE, SPLIT_OBJECTS_FILE, detect_objects, track_objects
from radar4dgs.radar.poses import expected_radar_velocity, fill_gaps
from radar4dgs.radar.sync import offset_to_apply, scene_time_offset, synced_scene

NPZ_KEYS = ("ego_velocity", "covariance", "ok", "inliers", "dynamic", "v_r_comp")


def fit_frames(scans: Iterable[tuple[np.ndarray, np.ndarray]], config: RadarConfig,
               progress: Callable[[Iterable], Iterable] = lambda x: x,
               radar_to_ego: np.ndarray | None = None) -> list[EgoMotion]:
    """Per-scan ego-motion; frame i uses seed ``config.seed + i`` and, with ``temporal_prior``, the
    previous frame's velocity (when that fit was ok) as an extra hypothesis and as the reference of
    the ``prior_gate`` check (only the previous frame's: after a failed frame the next one starts
    afresh, so one wrong fit cannot lock out the following ones). ``scans`` yields ((N, 3) xyz, (N,) v_r).
    With ``radar_to_ego`` the ground-vehicle prior (``vertical_prior_std``) is applied."""
    vertical = None if radar_to_ego is None else np.asarray(radar_to_ego)[:3, :3].T @ np.array([0.0, 0.0, 1.0])
    fits: list[EgoMotion] = []
    prior = None
    for i, (xyz, v_r) in enumerate(progress(scans)):
        fit = estimate_ego_motion(xyz, v_r, config, prior=prior if config.temporal_prior else None,
                                  vertical_axis=vertical, seed=config.seed + i)
        prior = fit.velocity if fit.ok else None
        fits.append(fit)
    return fits


def smooth_velocities(timestamps: np.ndarray, fits: list[EgoMotion], config: RadarConfig) -> np.ndarray:
    """(T, 3) velocities after temporal smoothing over ``smoothing_window`` frames (ok fits only;
    failed frames are interpolated from neighbours; with no ok fit at all, the raw estimates)."""
    raw = np.stack([f.velocity if f.ok else np.full(3, np.nan) for f in fits])
    if not np.isfinite(raw).any():
        return np.stack([f.velocity for f in fits])
    filled = fill_gaps(np.asarray(timestamps, dtype=np.float64), raw)
    if config.smoothing == "none":
        return np.where(np.isfinite(raw), raw, filled)
    half = max(config.smoothing_window, 1) // 2
    out = np.empty_like(filled)
    for i in range(len(fits)):
        window = [j for j in range(max(0, i - half), min(len(fits), i + half + 1)) if fits[j].ok]
        if not window:
            out[i] = filled[i]
        elif config.smoothing == "median":
            out[i] = np.median(raw[window], axis=0)
        else:
            # Inverse-covariance weighted mean: a noisy frame pulls less.
            info = [np.linalg.pinv(fits[j].covariance) for j in window]
            out[i] = np.linalg.pinv(sum(info)) @ sum(m @ raw[j] for m, j in zip(info, window, strict=True))
    return out


def _finite_or_none(x: float) -> float | None:
    return float(x) if x is not None and math.isfinite(x) else None


def prepare_radar(scene, out_dir: str | Path, config: RadarConfig | None = None,
                  progress: Callable[[Iterable], Iterable] = lambda x: x) -> dict:
    """Run the radar front end on every frame of ``scene`` and write ``out_dir`` (module doc).

    Returns the summary dict (also written as ``summary.json``).
    """
    import dataclasses

    config = config or RadarConfig()
    out_dir = Path(out_dir)
    out_dir.mkdir(parents=True, exist_ok=True)
    scans = [scene.load_radar(i) for i in range(len(scene))]
    points = [(s.xyz.astype(np.float64), s.v_r.astype(np.float64)) for s in scans]
    fits = fit_frames(points, config, progress, scene.radar.radar_to_ego)
    stamps = np.array([f.radar_timestamp for f in scene.frames])
    velocities = smooth_velocities(stamps, fits, config)
    # Camera-radar clock offset: Doppler speeds against the speed the camera-time poses imply. The
    # Doppler fits do not depend on the stamps; everything placed in the world or in time below does.
    time_sync = scene_time_offset(scene, stamps, velocities, config.sync_max_offset)
    applied, time_sync["action"] = offset_to_apply(time_sync, config.sync, config.sync_threshold,
                                                   bool(scene.source.get("poses_from_radar")))
    time_sync["applied_s"] = applied
    scene = synced_scene(scene, applied)
    stamps = np.array([f.radar_timestamp for f in scene.frames])

    frames, detections, split_detections = [], [], []
    # The split objects are a second, finer reading of the same scans: only the flow stage's fill reads them.
    split_config = None if config.objects.split_outliers else dataclasses.replace(config.objects, split_outliers=True)
    for i, (fit, (xyz, v_r)) in enumerate(zip(fits, points, strict=True)):
        used = dataclasses.replace(fit, velocity=velocities[i])
        if not np.all(np.isfinite(used.covariance)) and np.all(np.isfinite(used.velocity)):
            # Filled-in frame: no own covariance; borrow a loose one so thresholds stay finite.
            used = dataclasses.replace(used, covariance=np.eye(3) * (10 * config.noise_std) ** 2)
        dynamic, comp = classify_dynamic(xyz, v_r, used, config)
        atomic_save_npz(out_dir / f"{scene.frames[i].name}.npz", dict(
            ego_velocity=used.velocity.astype(np.float64), covariance=used.covariance.astype(np.float64),
            ok=np.bool_(fit.ok), inliers=fit.inliers, dynamic=dynamic, v_r_comp=comp.astype(np.float32)),
            compressed=False)
        for wanted, found in ((config.objects, detections), (split_config, split_detections)):
            if wanted is not None:
                found.append(detect_objects(xyz, comp, dynamic, scene.radar_to_world(i), wanted,
                                            seed=config.seed + i, radar_velocity=used.velocity,
                                            angle_std=(config.azimuth_std, config.elevation_std)))
        frames.append({"name": scene.frames[i].name, "ok": bool(fit.ok), "reason": fit.reason,
                       "points": int(len(xyz)), "inliers": int(fit.inliers.sum()),
                       "dynamic": int(dynamic.sum()), "speed": _finite_or_none(used.speed),
                       "velocity": [_finite_or_none(x) for x in used.velocity],
                       "residual_std": _finite_or_none(fit.residual_std), "dof": fit.dof,
                       "iterations": fit.iterations})

    summary: dict[str, Any] = {"frames": frames, "num_ok": int(sum(f.ok for f in fits)),
                               "num_frames": len(fits), "config": to_dict(config)}
    summary["disagreement"] = compare_with_scene(scene, velocities)
    summary["time_sync"] = time_sync
    for i, entry in enumerate(frames):
        errs = summary["disagreement"].get("per_frame")
        entry["disagreement"] = None if errs is None else errs[i]
    atomic_write_json(out_dir / "summary.json", summary)
    names = [f.name for f in scene.frames]
    objects = track_objects(names, stamps, detections, config.objects)
    atomic_write_json(out_dir / OBJECTS_FILE, objects)
    split = (objects if split_config is None
             else track_objects(names, stamps, split_detections, split_config))
    atomic_write_json(out_dir / SPLIT_OBJECTS_FILE, split)
    return summary


def compare_with_scene(scene, velocities: np.ndarray) -> dict:
    """Disagreement (m/s) between (T, 3) radar velocities and what the scene's ego_velocity / poses
    imply (:func:`expected_radar_velocity`): per-frame norm of the difference, RMSE and max."""
    expected, source = expected_radar_velocity(scene)
    if expected is None:
        return {"source": None, "note": source, "per_frame": None, "rmse": None, "max": None}
    err = np.linalg.norm(velocities - expected, axis=1)
    good = np.isfinite(err)
    note = ""
    if scene.source.get("poses_from_radar"):
        note = "the scene's poses were themselves integrated from this radar: not an independent check"
    return {"source": source, "note": note,
            "per_frame": [_finite_or_none(e) for e in err],
            "rmse": _finite_or_none(float(np.sqrt(np.mean(err[good] ** 2)))) if good.any() else None,
            "max": _finite_or_none(float(err[good].max())) if good.any() else None}


def load_radar_outputs(prepared_radar: str | Path, name: str, keys: tuple[str, ...] = NPZ_KEYS
                       ) -> dict[str, np.ndarray]:
    """The arrays ``keys`` (default all, ``NPZ_KEYS``) of one frame's ``<name>.npz``."""
    path = Path(prepared_radar) / f"{name}.npz"
    if not path.is_file():
        raise FileNotFoundError(f"{path}: missing file (run `radar4dgs prepare` first)")
    with np.load(path, allow_pickle=False) as data:
        missing = [k for k in keys if k not in data.files]
        if missing:
            raise ValueError(f"{path}: missing arrays {missing} (written by an older or other tool; "
                             f"rerun `radar4dgs prepare --only radar --force`)")
        return {k: data[k] for k in keys}


def load_radar_dynamics_flags(prepared_radar: str | Path, name: str, num_points: int
                              ) -> tuple[np.ndarray, np.ndarray]:
    """One frame's (N,) bool ``dynamic`` flags and (N,) float64 compensated radial velocity
    ``v_r_comp`` (m/s) from ``<prepared_radar>/<name>.npz``, checked against the scan's N points."""
    out = load_radar_outputs(prepared_radar, name, ("dynamic", "v_r_comp"))
    dynamic, comp = out["dynamic"].astype(bool), out["v_r_comp"].astype(np.float64)
    if len(dynamic) != num_points or len(comp) != num_points:
        raise ValueError(f"{Path(prepared_radar) / f'{name}.npz'}: {len(dynamic)} rows, but the scan has "
                         f"{num_points} points (rerun `radar4dgs prepare --only radar --force`)")
    return dynamic, comp
