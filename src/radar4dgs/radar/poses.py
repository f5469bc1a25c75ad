"""Ego velocity and yaw rate from the radar's own velocity, ego poses by integration, and the
reverse (the radar velocity that given poses imply), for scenes with and without poses.

Model (planar, non-holonomic, rigid body). The ego origin is the rear-axle centre, where a car
does not slide sideways: its velocity in ego axes is ``(v_x, 0, 0)`` and it turns at yaw rate
``w`` about ego z. The radar is mounted at lever arm ``t = (t_x, t_y, t_z)`` (the translation of
``radar_to_ego``) with rotation ``R`` (its rotation block). Its own velocity, which the Doppler
RANSAC measures in radar axes, is ``v_radar = R^T (v_o + w x t)``. In ego axes
``R v_radar = (v_x - w t_y, w t_x, v_z)``, so

    w   = (R v_radar)_y / t_x            (needs a lever arm |t_x| well away from 0)
    v_x = (R v_radar)_x + w t_y,   v_y = 0,   v_z = 0 (planar: poses keep z and roll/pitch at 0).

A radar ahead of the rear axle (t_x > 0) therefore sees the yaw rate as lateral velocity. The
estimate is very sensitive to the mount yaw: an error ``dpsi`` in ``R`` reads as a yaw rate of
``|v| dpsi / t_x`` (0.1 rad/s per degree at 30 m/s and t_x = 3.8 m); ``align_heading`` removes a
constant heading offset (assumes no net turning over the sequence).

Poses are integrated with the midpoint rule between timestamps: the heading at mid-interval is
``psi_i + w_mean dt / 2`` with ``w_mean = (w_i + w_i+1) / 2``; the mean body velocity, rotated by
that heading, advances the position; the first frame's ego frame is the world frame.
"""

from __future__ import annotations

import math

import numpy as np
from scipy.spatial.transform import Rotation

# Below this lever arm (m) the yaw rate is unobservable from the radar's lateral velocity.
MIN_LEVER_ARM = 0.5


def fill_gaps(timestamps: np.ndarray, values: np.ndarray) -> np.ndarray:
    """(T, C) values with non-finite rows linearly interpolated over time (held at the ends).

    All rows non-finite -> returned unchanged (all NaN).
    """
    values = np.array(values, dtype=np.float64, copy=True)
    good = np.all(np.isfinite(values), axis=1)
    if good.all() or not good.any():
        return values
    for c in range(values.shape[1]):
        values[~good, c] = np.interp(timestamps[~good], timestamps[good], values[good, c])
    return values


def heading_offset(radar_velocities: np.ndarray, radar_to_ego: np.ndarray, min_speed: float = 1.0) -> float:
    """Median heading (rad) of the radar's velocity in ego axes over frames moving faster than
    ``min_speed``, i.e. the mount yaw error when the car drives straight on average; 0 if none."""
    v = np.asarray(radar_velocities, dtype=np.float64) @ radar_to_ego[:3, :3].T
    moving = np.all(np.isfinite(v), axis=1) & (np.linalg.norm(v[:, :2], axis=1) > min_speed)
    if not moving.any():
        return 0.0
    return float(np.median(np.arctan2(v[moving, 1], v[moving, 0])))


def ego_motion_from_radar(radar_velocities: np.ndarray, radar_to_ego: np.ndarray, yaw_rate: bool = True,
                          heading_correction: float = 0.0) -> tuple[np.ndarray, np.ndarray]:
    """Ego-origin velocity and yaw rate from radar velocities (non-holonomic model, module doc).

    Args:
        radar_velocities: (T, 3) radar velocity in radar axes (m/s).
        radar_to_ego: (4, 4) mounting.
        yaw_rate: False -> yaw rate 0 and the radar's velocity is taken as the ego's (no lever arm).
        heading_correction: rad, rotation about ego z applied to the radar velocity first
            (minus :func:`heading_offset` to remove a mount yaw error).

    Returns:
        (T, 3) ego velocity in ego axes (v_y = v_z = 0 when ``yaw_rate``) and (T,) yaw rate (rad/s).
    """
    c, s = math.cos(heading_correction), math.sin(heading_correction)
    Rz = np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])
    v_mount = np.asarray(radar_velocities, dtype=np.float64) @ (Rz @ radar_to_ego[:3, :3]).T
    t = radar_to_ego[:3, 3]
    if not yaw_rate or abs(t[0]) < MIN_LEVER_ARM:
        return v_mount.copy(), np.zeros(len(v_mount))
    w = v_mount[:, 1] / t[0]
    # Planar: the vertical component is dropped too (a 1 deg mount pitch error would otherwise
    # sink the trajectory by 0.5 m/s at 30 m/s).
    v = np.stack([v_mount[:, 0] + w * t[1], np.zeros(len(w)), np.zeros(len(w))], axis=1)
    return v, w


def integrate_poses(timestamps: np.ndarray, velocities: np.ndarray, yaw_rates: np.ndarray) -> np.ndarray:
    """(T, 4, 4) ego_to_world poses, planar, by the midpoint rule; the first pose is the identity.

    Args:
        timestamps: (T,) s, increasing. velocities: (T, 3) ego velocity in ego axes (finite).
        yaw_rates: (T,) rad/s.
    """
    T = len(timestamps)
    poses = np.tile(np.eye(4), (T, 1, 1))
    psi, p = 0.0, np.zeros(3)
    for i in range(T - 1):
        dt = float(timestamps[i + 1] - timestamps[i])
        w_mean = 0.5 * (yaw_rates[i] + yaw_rates[i + 1])
        mid = psi + 0.5 * w_mean * dt
        v_mean = 0.5 * (velocities[i] + velocities[i + 1])
        c, s = math.cos(mid), math.sin(mid)
        p = p + dt * np.array([c * v_mean[0] - s * v_mean[1], s * v_mean[0] + c * v_mean[1], v_mean[2]])
        psi += w_mean * dt
        c, s = math.cos(psi), math.sin(psi)
        poses[i + 1, :3, :3] = [[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]]
        poses[i + 1, :3, 3] = p
    return poses


def poses_from_radar(timestamps: np.ndarray, radar_velocities: np.ndarray, radar_to_ego: np.ndarray,
                     yaw_rate: bool = True, align_heading: bool = False) -> tuple[np.ndarray, dict]:
    """Ego poses for a scene without any: (T, 4, 4) ego_to_world and a dict describing the model.

    ``radar_velocities`` (T, 3) may hold NaN rows (failed fits): they are interpolated in time.
    """
    v, w, info = ego_rates_from_radar(timestamps, radar_velocities, radar_to_ego, yaw_rate, align_heading)
    return integrate_poses(np.asarray(timestamps, dtype=np.float64), v, w), info


def ego_rates_from_radar(timestamps: np.ndarray, radar_velocities: np.ndarray, radar_to_ego: np.ndarray,
                         yaw_rate: bool = True, align_heading: bool = False
                         ) -> tuple[np.ndarray, np.ndarray, dict]:
    """The ego velocity (T, 3) and yaw rate (T,) that :func:`poses_from_radar` integrates, and its
    model description; for callers that need the rates themselves (box velocities, say)."""
    timestamps = np.asarray(timestamps, dtype=np.float64)
    filled = fill_gaps(timestamps, radar_velocities)
    if not np.all(np.isfinite(filled)):
        raise ValueError("no frame has a radar ego-velocity estimate; cannot integrate poses")
    correction = -heading_offset(filled, radar_to_ego) if align_heading else 0.0
    v, w = ego_motion_from_radar(filled, radar_to_ego, yaw_rate, correction)
    info = {"model": "planar non-holonomic, yaw rate from the radar lever arm" if yaw_rate
            else "radar velocity integrated without rotation",
            "integration": "midpoint rule over timestamps",
            "heading_correction_deg": math.degrees(correction),
            "filled_frames": int((~np.all(np.isfinite(radar_velocities), axis=1)).sum()),
            "mean_yaw_rate": float(np.mean(w))}
    return v, w, info


def _pose_rates(timestamps: np.ndarray, poses: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(T, 3) linear velocity and (T, 3) angular velocity, both in ego axes, by central differences
    (one-sided at the ends). Needs T >= 2."""
    T = len(timestamps)
    lo = np.clip(np.arange(T) - 1, 0, T - 1)
    hi = np.clip(np.arange(T) + 1, 0, T - 1)
    dt = (timestamps[hi] - timestamps[lo])[:, None]
    R = poses[:, :3, :3]
    v_world = (poses[hi, :3, 3] - poses[lo, :3, 3]) / dt
    v = np.einsum("tji,tj->ti", R, v_world)                 # R^T v_world
    rel = np.einsum("tji,tjk->tik", R[lo], R[hi])           # R_lo^T R_hi
    omega = Rotation.from_matrix(rel).as_rotvec() / dt       # in ego axes (body frame of lo ~ t)
    return v, omega


def expected_radar_velocity(scene) -> tuple[np.ndarray | None, str]:
    """The radar's velocity (T, 3, radar axes) that the scene's own motion data imply, and its source.

    ``v_radar = R^T (v_ego + w x t_mount)``: ``v_ego`` from the frames' ``ego_velocity`` where every
    frame has it, else from pose finite differences (``radar_ego_to_world`` at ``radar_timestamp``);
    ``w`` from the frames' ``ego_angular_velocity`` (rad/s, ego axes) where every frame has it, else
    from pose finite differences. ``(None, reason)`` when neither is usable (one frame, or
    poses that are all identical and no ego_velocity).
    """
    frames = scene.frames
    mount = scene.radar.radar_to_ego
    stamps = np.array([f.radar_timestamp for f in frames])
    poses = np.stack([f.radar_ego_to_world for f in frames])
    has_velocity = all(f.ego_velocity is not None for f in frames)
    if len(frames) < 2:
        if not has_velocity:
            return None, "one frame and no ego_velocity"
        v, omega, source = np.stack([f.ego_velocity for f in frames]), np.zeros((1, 3)), "ego_velocity"
    else:
        v_pose, omega = _pose_rates(stamps, poses)
        moved = np.abs(poses[1:] - poses[:1]).max() > 1e-9
        if has_velocity:
            v, source = np.stack([f.ego_velocity for f in frames]), "ego_velocity + pose yaw rate"
        elif moved:
            v, source = v_pose, "pose finite differences"
        else:
            return None, "poses never change and no ego_velocity"
    if all("ego_angular_velocity" in f.extra for f in frames):
        # A simulator or an IMU gives the angular velocity directly (optional per-frame key).
        omega = np.array([f.extra["ego_angular_velocity"] for f in frames], dtype=np.float64)
        source = source.replace("pose yaw rate", "ego_angular_velocity")
        if "ego_angular_velocity" not in source:
            source += " + ego_angular_velocity"
    v_mount = v + np.cross(omega, mount[:3, 3])
    return v_mount @ mount[:3, :3], source
