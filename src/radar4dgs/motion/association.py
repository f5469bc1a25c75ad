"""Radar association: each dynamic 3D point (a dynamic Gaussian at time t_i, or in the standalone
fit a lifted dynamic pixel) takes the ego-motion-compensated radial velocity of its nearest dynamic
radar point of the same frame (K = 1, scipy cKDTree), if that point lies within a distance gate.
Unmatched points get no radar loss (their velocity is NaN).

Compensated radial velocity ``v_r_comp = v_r + d . v_s``: the point's own velocity along the line
of sight from the radar, in the world, positive when moving away (d the unit direction radar ->
point, v_s the radar's velocity, both in radar axes). It comes from ``<prepared>/radar/<frame>.npz``
(keys ``dynamic``, ``v_r_comp``, rows aligned with ``scene.load_radar(i)``; the radar front end,
``radar4dgs.radar.prepare_radar``), or for ablations and tests from the scene's ground truth
(source "oracle").

Timing: the radar point positions are those of the radar's capture time; a scene whose
``radar_timestamp`` differs from the camera's moves objects by v * (difference) between the two,
which the gate absorbs (a few cm at 10 m/s and a few ms).
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np

from radar4dgs.radar.classify import compensated_radial_velocity
from radar4dgs.radar.process import load_radar_dynamics_flags


@dataclass(frozen=True)
class RadarDynamics:
    """The dynamic radar points of one frame, in the world.

    Attributes:
        points: (R, 3) float64 world positions of the dynamic radar points.
        v_r_comp: (R,) float64 compensated radial velocity (m/s, positive = receding).
        centre: (3,) float64 the radar's position in the world at that frame (A in L_rad).
    """

    points: np.ndarray
    v_r_comp: np.ndarray
    centre: np.ndarray

    def __len__(self) -> int:
        return int(len(self.points))


def associate_nearest(points: np.ndarray, radar_points: np.ndarray, gate: float) -> tuple[np.ndarray, np.ndarray]:
    """Nearest radar point of each point (K = 1) within ``gate`` metres.

    Args:
        points: (N, 3); radar_points: (R, 3), same frame (world).
    Returns:
        index (N,) int64 into ``radar_points``, -1 when no radar point is within the gate;
        distance (N,) float64, inf when unmatched.
    """
    from scipy.spatial import cKDTree

    points = np.asarray(points, dtype=np.float64).reshape(-1, 3)
    radar_points = np.asarray(radar_points, dtype=np.float64).reshape(-1, 3)
    if len(radar_points) == 0 or len(points) == 0:
        return np.full(len(points), -1, dtype=np.int64), np.full(len(points), np.inf)
    distance, index = cKDTree(radar_points).query(points, k=1, distance_upper_bound=gate)
    # cKDTree marks "nothing within the bound" with index == len(data) and distance inf.
    index = np.where(np.isfinite(distance), index, -1).astype(np.int64)
    return index, distance


def associate_velocities(points: np.ndarray, radar: RadarDynamics, gate: float = 2.0) -> np.ndarray:
    """(N,) compensated radial velocity of each of (N, 3) ``points``' nearest dynamic radar point
    within ``gate`` (m); NaN where unmatched."""
    index, _ = associate_nearest(points, radar.points, gate)
    velocity = np.full(len(index), np.nan)
    matched = index >= 0
    velocity[matched] = radar.v_r_comp[index[matched]]
    return velocity


def _to_world(scene, index: int, xyz: np.ndarray) -> np.ndarray:
    transform = scene.radar_to_world(index)
    return xyz @ transform[:3, :3].T + transform[:3, 3]


def oracle_radar_velocity(scene, index: int) -> np.ndarray:
    """(3,) the radar's velocity in radar axes at frame ``index`` from the scene's own motion data:
    the frame's ``ego_velocity`` rotated into radar axes (the lever-arm term of a turning ego,
    omega x r, is ignored), or, without it, a central difference of the radar's world positions."""
    frame = scene.frames[index]
    radar_to_ego = scene.radar.radar_to_ego
    if frame.ego_velocity is not None:
        return radar_to_ego[:3, :3].T @ np.asarray(frame.ego_velocity, dtype=np.float64)
    lo, hi = max(index - 1, 0), min(index + 1, len(scene) - 1)
    if lo == hi:
        return np.zeros(3)
    dt = scene.frames[hi].radar_timestamp - scene.frames[lo].radar_timestamp
    velocity_world = (scene.radar_to_world(hi)[:3, 3] - scene.radar_to_world(lo)[:3, 3]) / dt
    return scene.radar_to_world(index)[:3, :3].T @ velocity_world


def oracle_radar_dynamics(scene, index: int) -> RadarDynamics:
    """Dynamic radar points of frame ``index`` from ground truth (``gt/radar_labels == 1``) with the
    compensated velocity from the scene's motion data (:func:`oracle_radar_velocity`)."""
    scan = scene.load_radar(index)
    labels = scene.load_optional("gt/radar_labels", index)
    if len(labels) != len(scan):
        raise ValueError(f"frame {scene.frames[index].name}: {len(labels)} radar labels for {len(scan)} "
                         f"radar rows")
    dynamic = labels == 1
    xyz = scan.xyz.astype(np.float64)
    comp = compensated_radial_velocity(xyz, scan.v_r, oracle_radar_velocity(scene, index))
    keep = dynamic & np.isfinite(comp)
    return RadarDynamics(_to_world(scene, index, xyz[keep]), comp[keep], scene.radar_to_world(index)[:3, 3].copy())


def prepared_radar_dynamics(scene, index: int, prepared_dir: str | Path) -> RadarDynamics:
    """Dynamic radar points of frame ``index`` from ``<prepared>/radar/<frame>.npz`` (radar front end)."""
    scan = scene.load_radar(index)
    try:
        dynamic, comp = load_radar_dynamics_flags(Path(prepared_dir) / "radar", scene.frames[index].name,
                                                  len(scan))
    except FileNotFoundError as err:
        raise FileNotFoundError(f"{err}; or set radar_source='oracle' to use the scene's "
                                f"gt/radar_labels") from err
    keep = dynamic & np.isfinite(comp)
    xyz = scan.xyz.astype(np.float64)[keep]
    return RadarDynamics(_to_world(scene, index, xyz), comp[keep], scene.radar_to_world(index)[:3, 3].copy())


def load_radar_dynamics(scene, index: int, source: str = "prepared",
                        prepared_dir: str | Path | None = None) -> RadarDynamics:
    """Dynamic radar points of frame ``index`` from ``source`` ("prepared" or "oracle")."""
    if source == "oracle":
        return oracle_radar_dynamics(scene, index)
    if source == "prepared":
        if prepared_dir is None:
            raise ValueError("radar source 'prepared' needs prepared_dir")
        return prepared_radar_dynamics(scene, index, prepared_dir)
    raise ValueError(f"unknown radar source {source!r}; choose 'prepared' or 'oracle'")
