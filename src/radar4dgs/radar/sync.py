"""Camera-radar time offset from speed profiles (issue 27).

The radar measures its own speed by Doppler at its timestamps; the scene's poses, stamped with
the camera's clock, imply a speed too (finite differences of the radar mount's position). With a
clock offset ``tau`` between the two, the pose speed profile shifted by ``tau`` matches the
radar's:

    v_poses(t + tau) = v_radar(t)

so ``tau > 0`` means the camera's timestamps run ``tau`` seconds late relative to the radar's.
:func:`estimate_time_offset` scans offsets in ``[-max_offset, max_offset]`` for the least mean
squared speed difference over the overlapping time and refines the best one with scipy's bounded
scalar minimiser. The offset is observable only where the speed changes: a drive at constant
speed reports ``observable`` False (the speed's spread under ``min_speed_std``).
"""

from __future__ import annotations

import dataclasses
import json
import math
from pathlib import Path
from typing import Any

import numpy as np
from scipy.optimize import minimize_scalar
from scipy.spatial.transform import Rotation

# Below this spread of the radar's speed (m/s) the offset is reported as unobservable.
MIN_SPEED_STD = 0.2


def pose_speeds(times: np.ndarray, sensor_to_world: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(T - 1,) mid-interval times and speeds (m/s) of a sensor at poses ``sensor_to_world``
    (T, 4, 4) stamped ``times`` (T,): the distance between consecutive positions over the gap."""
    times = np.asarray(times, dtype=np.float64)
    positions = np.asarray(sensor_to_world, dtype=np.float64)[:, :3, 3]
    gaps = np.diff(times)
    return times[:-1] + gaps / 2, np.linalg.norm(np.diff(positions, axis=0), axis=1) / gaps


def offset_cost(offset: float, radar_times: np.ndarray, radar_speeds: np.ndarray, pose_times: np.ndarray,
                pose_speed: np.ndarray, min_overlap: int = 4) -> float:
    """Mean squared difference between the radar speeds (N,) and the pose speeds (M,) interpolated
    at ``radar_times + offset``, over the radar samples inside the pose profile's time span (inf
    when fewer than ``min_overlap`` are)."""
    shifted = radar_times + offset
    inside = (shifted >= pose_times[0]) & (shifted <= pose_times[-1]) & np.isfinite(radar_speeds)
    if inside.sum() < min_overlap:
        return math.inf
    predicted = np.interp(shifted[inside], pose_times, pose_speed)
    return float(np.mean((predicted - radar_speeds[inside]) ** 2))


def estimate_time_offset(radar_times: np.ndarray, radar_speeds: np.ndarray, pose_times: np.ndarray,
                         pose_speed: np.ndarray, max_offset: float = 0.2, step: float = 0.002,
                         min_speed_std: float = MIN_SPEED_STD) -> dict[str, Any]:
    """The offset ``tau`` (s, module docstring) that best aligns the radar's speeds (N,) at
    ``radar_times`` (N,) with the pose-implied speeds (M,) at ``pose_times`` (M,).

    Returns ``offset_s``, ``rmse`` (m/s) at it and ``rmse_at_zero``, ``observable``, the radar
    speed's spread ``speed_std`` and the scanned ``max_offset_s``; ``offset_s`` None when no offset
    leaves enough overlap or the offset is not observable (then ``best_scanned_s`` holds the scan's
    minimum).
    """
    radar_times, radar_speeds = np.asarray(radar_times, float), np.asarray(radar_speeds, float)
    pose_times, pose_speed = np.asarray(pose_times, float), np.asarray(pose_speed, float)
    grid = np.arange(-max_offset, max_offset + step / 2, step)
    costs = np.array([offset_cost(o, radar_times, radar_speeds, pose_times, pose_speed) for o in grid])
    finite = np.isfinite(costs)
    spread = float(np.nanstd(radar_speeds)) if np.isfinite(radar_speeds).any() else 0.0
    result: dict[str, Any] = {"offset_s": None, "rmse": None, "rmse_at_zero": None, "max_offset_s": max_offset,
                              "observable": False, "speed_std": spread}
    if not finite.any():
        return result
    best = int(np.nanargmin(np.where(finite, costs, np.nan)))
    # Refine between finite neighbours only: on a short drive the overlap runs out inside the scan, and
    # the bounded search would difference infinite costs (a NaN step and a RuntimeWarning).
    lo = grid[best - 1] if best > 0 and finite[best - 1] else grid[best]
    hi = grid[best + 1] if best + 1 < len(grid) and finite[best + 1] else grid[best]
    offset = float(grid[best])
    if hi > lo:
        refined = minimize_scalar(offset_cost, bounds=(lo, hi), method="bounded",
                                  args=(radar_times, radar_speeds, pose_times, pose_speed), options={"xatol": 1e-5})
        if refined.fun <= costs[best]:
            offset = float(refined.x)
    zero = offset_cost(0.0, radar_times, radar_speeds, pose_times, pose_speed)
    result.update(offset_s=offset, rmse=math.sqrt(offset_cost(offset, radar_times, radar_speeds, pose_times,
                                                              pose_speed)),
                  rmse_at_zero=math.sqrt(zero) if math.isfinite(zero) else None,
                  observable=bool(spread >= min_speed_std and 0 < best < len(grid) - 1))
    if not result["observable"]:
        # A constant speed (or a minimum at the edge of the scan) pins no offset: say so, keep the value.
        result["best_scanned_s"], result["offset_s"] = result["offset_s"], None
    return result


def scene_time_offset(scene, radar_times: np.ndarray, radar_velocities: np.ndarray,
                      max_offset: float = 0.2) -> dict[str, Any]:
    """:func:`estimate_time_offset` of a scene: the radar's Doppler speeds (the norms of
    ``radar_velocities`` (T, 3), radar frame, at ``radar_times`` (T,)) against the speed of the
    radar mount implied by the camera-time poses (``ego_to_world @ radar_to_ego``)."""
    camera_times = np.array([f.timestamp for f in scene.frames])
    mounts = np.stack([f.ego_to_world @ scene.radar.radar_to_ego for f in scene.frames])
    if len(camera_times) < 3:
        return {"offset_s": None, "note": "fewer than 3 frames"}
    pose_times, speeds = pose_speeds(camera_times, mounts)
    result = estimate_time_offset(radar_times, np.linalg.norm(radar_velocities, axis=1), pose_times, speeds,
                                  max_offset)
    result["note"] = ("the scene's poses were integrated from this radar: the offset is 0 by construction"
                      if scene.source.get("poses_from_radar") else "")
    return result


def interpolate_poses(times: np.ndarray, poses: np.ndarray, query: np.ndarray) -> np.ndarray:
    """(Q, 4, 4) poses at ``query`` (Q,) from (T, 4, 4) ``poses`` stamped ``times`` (T, increasing,
    T >= 2): on the segment of the nearest bracketing pair, translation linear and rotation along
    the pair's relative rotation vector (a constant-rate turn); past either end the first/last
    segment's motion is extrapolated (a shifted scan at the clip's edge lies just outside it)."""
    times, poses, query = np.asarray(times, float), np.asarray(poses, float), np.asarray(query, float)
    hi = np.clip(np.searchsorted(times, query), 1, len(times) - 1)
    lo = hi - 1
    s = (query - times[lo]) / (times[hi] - times[lo])
    relative = Rotation.from_matrix(np.einsum("qji,qjk->qik", poses[lo, :3, :3], poses[hi, :3, :3]))
    out = np.tile(np.eye(4), (len(query), 1, 1))
    out[:, :3, :3] = poses[lo, :3, :3] @ Rotation.from_rotvec(relative.as_rotvec() * s[:, None]).as_matrix()
    out[:, :3, 3] = poses[lo, :3, 3] + s[:, None] * (poses[hi, :3, 3] - poses[lo, :3, 3])
    return out


def offset_to_apply(time_sync: dict[str, Any], mode: str, threshold: float,
                    poses_from_radar: bool) -> tuple[float, str]:
    """The offset (s) to re-stamp the radar by under ``mode`` ("auto" | "off") and why, from an
    estimate of :func:`scene_time_offset`: "auto" applies an observable estimate whose magnitude
    exceeds ``threshold``; never when the poses come from this radar (0 by construction)."""
    offset = time_sync.get("offset_s")
    if mode == "off":
        return 0.0, "sync off: the offset is reported, not applied"
    if poses_from_radar:
        return 0.0, "not applied: the poses were integrated from this radar (offset 0 by construction)"
    if offset is None:
        return 0.0, f"not applied: the offset is not observable ({time_sync.get('note') or 'speed too constant'})"
    if abs(offset) <= threshold:
        return 0.0, f"not applied: |{offset * 1000:.1f} ms| is within the {threshold * 1000:.0f} ms threshold"
    return float(offset), f"applied: radar stamps moved by {offset * 1000:+.1f} ms"


def synced_scene(scene, offset: float):
    """``scene`` with every radar scan re-stamped ``radar_timestamp + offset`` (camera clock) and its
    ``radar_ego_to_world`` the ego pose at that time, interpolated from the camera-time poses
    (:func:`interpolate_poses`); ``scene`` itself when ``offset`` is 0. Consumers that relate a scan
    to its camera frame (depth, masks, object points) then move its static points by the ego motion
    and its objects by their velocity over the corrected ``timestamp - radar_timestamp``."""
    if not offset or len(scene.frames) < 2:
        return scene
    camera_times = np.array([f.timestamp for f in scene.frames])
    stamps = np.array([f.radar_timestamp for f in scene.frames]) + offset
    poses = interpolate_poses(camera_times, np.stack([f.ego_to_world for f in scene.frames]), stamps)
    frames = tuple(dataclasses.replace(f, radar_timestamp=float(t), radar_ego_to_world=p)
                   for f, t, p in zip(scene.frames, stamps, poses, strict=True))
    return dataclasses.replace(scene, frames=frames)


def prepared_synced_scene(scene, prepared_radar):
    """``scene`` re-stamped by the offset the radar stage applied (``<prepared_radar>/summary.json``
    ``time_sync.applied_s``; ``scene`` as is when the summary has none)."""
    path = Path(prepared_radar) / "summary.json"
    if not path.is_file():
        return scene
    applied = (json.loads(path.read_text(encoding="utf-8")).get("time_sync") or {}).get("applied_s") or 0.0
    return synced_scene(scene, float(applied))
