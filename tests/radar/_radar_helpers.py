"""Hand-made radar scans and a tiny scene folder with closed-form ground truth."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from radar4dgs.io.scene import Camera, Frame, RadarSpec, SceneWriter


def directions(rng: np.random.Generator, n: int, az: float = 1.0, el: float = 0.25) -> np.ndarray:
    """(n, 3) unit directions, azimuth in +-az, elevation in +-el (rad)."""
    a = rng.uniform(-az, az, n)
    e = rng.uniform(-el, el, n)
    return np.stack([np.cos(e) * np.cos(a), np.cos(e) * np.sin(a), np.sin(e)], axis=1)


def static_scan(rng, n, v_s, noise=0.05, **kw):
    """(n, 3) xyz and (n,) v_r = -d . v_s + noise."""
    d = directions(rng, n, **kw)
    r = rng.uniform(3.0, 80.0, n)
    return d * r[:, None], -d @ np.asarray(v_s, float) + rng.normal(0.0, noise, n)


def mixed_scan(rng, n, v_s, dynamic_fraction=0.3, noise=0.05, **kw):
    """Static scan where a random subset moves: v_r += d . v_point with |v_point| in [2, 15] m/s."""
    xyz, v_r = static_scan(rng, n, v_s, noise, **kw)
    moving = rng.random(n) < dynamic_fraction
    d = xyz / np.linalg.norm(xyz, axis=1, keepdims=True)
    v_point = rng.normal(size=(n, 3))
    v_point *= rng.uniform(2.0, 15.0, (n, 1)) / np.linalg.norm(v_point, axis=1, keepdims=True)
    radial = np.einsum("ij,ij->i", d, v_point)
    # Keep the moving points measurable along the line of sight (>= 1 m/s), as the metric does.
    radial = np.where(np.abs(radial) < 1.0, np.sign(radial + 1e-9) * 1.0, radial)
    v_r = np.where(moving, v_r + radial, v_r)
    return xyz, v_r, moving


RADAR_TO_EGO = np.array([[1.0, 0, 0, 3.5], [0, 1.0, 0, 0.0], [0, 0, 1.0, 0.5], [0, 0, 0, 1.0]])


def write_tiny_scene(out: Path, frames: int = 6, speed: float = 10.0, yaw_rate: float = 0.0, seed: int = 0,
                     labels: bool = True, ego_velocity: bool = True, n: int = 200, poses: bool = True) -> Path:
    """A scene driving at ``speed`` along a constant-curvature path; radar scans built in closed form
    from the radar velocity ``R^T (v_ego + w x t)``; 25 % of the points move (label 1)."""
    rng = np.random.default_rng(seed)
    dt = 0.1
    omega = np.array([0.0, 0.0, yaw_rate])
    v_ego = np.array([speed, 0.0, 0.0])
    v_radar = RADAR_TO_EGO[:3, :3].T @ (v_ego + np.cross(omega, RADAR_TO_EGO[:3, 3]))
    K = np.array([[40.0, 0, 16], [0, 40.0, 8], [0, 0, 1]])
    cam_to_ego = np.array([[0, 0, 1, 1.5], [-1, 0, 0, 0], [0, -1, 0, 1.4], [0, 0, 0, 1.0]], float)
    with SceneWriter(out) as writer:
        for i in range(frames):
            t = i * dt
            psi = yaw_rate * t
            pose = np.eye(4)
            if poses:
                if abs(yaw_rate) > 1e-12:
                    pose[:2, 3] = [speed / yaw_rate * np.sin(psi), speed / yaw_rate * (1 - np.cos(psi))]
                else:
                    pose[0, 3] = speed * t
                pose[:2, :2] = [[np.cos(psi), -np.sin(psi)], [np.sin(psi), np.cos(psi)]]
            xyz, v_r, moving = mixed_scan(rng, n, v_radar, dynamic_fraction=0.25, noise=0.05)
            data = np.column_stack([xyz, v_r, rng.uniform(0, 10, n)]).astype(np.float32)
            frame = Frame(f"{i:06d}", t, pose, t, pose, v_ego if ego_velocity else None)
            extra = {"gt_radar_labels": moving.astype(np.int8)} if labels else {}
            writer.add_frame(frame, np.zeros((16, 32, 3), np.uint8), data, **extra)
        writer.finish("tiny-radar", Camera(32, 16, K, cam_to_ego),
                      RadarSpec(RADAR_TO_EGO, ("x", "y", "z", "v_r", "rcs")), source={"dataset": "test"})
    return out
