"""A 4D imaging radar: ray casting on a jittered azimuth/elevation grid, material- and
range-dependent detection, exact Doppler from relative motion, then measurement noise, clutter and
multipath ghosts.

Doppler: the radar moves with ``v_radar = v_ego + omega x r_mount`` (road frame); a point with
velocity ``v_p`` seen along the unit direction ``d`` (radar to point) has
``v_r = d . (v_p - v_radar)``, positive = receding. For a static point this is ``-d . v_s``.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from radar4dgs.datasets.synth import world as W
from radar4dgs.datasets.synth.config import RadarSimConfig
from radar4dgs.datasets.synth.raycast import NO_HIT, apply, cast_sensor_grid, rigid, rot_y, rot_z

FIELDS = ("x", "y", "z", "v_r", "rcs")
STATIC, MOVING, CLUTTER = 0, 1, -1
# Base radar cross-section per material (dBsm) before the incidence term and noise.
RCS_DB = {W.GROUND: -12.0, W.SIDEWALK: -8.0, W.BUILDING: 8.0, W.POLE: 3.0, W.TRUNK: -2.0,
          W.FOLIAGE: -6.0, W.CAR_BODY: 10.0, W.CAR_CABIN: 6.0, W.WHEEL: 4.0, W.PERSON: -8.0, W.BICYCLE: -5.0}


def radar_to_ego(config: RadarSimConfig, rng: np.random.Generator) -> np.ndarray:
    """(4, 4) true mounting: bumper position with a small random yaw and pitch misalignment."""
    lo, hi = config.misalignment_deg
    yaw, pitch = (np.radians(rng.uniform(lo, hi)) * rng.choice([-1.0, 1.0]) for _ in range(2))
    return rigid(rot_z(yaw) @ rot_y(pitch), config.mount_xyz)


def grid_angles(config: RadarSimConfig) -> tuple[np.ndarray, np.ndarray]:
    """Cell-centre azimuths (A,) and elevations (E,) of the ray grid (rad), ascending."""
    def centres(fov: float, step: float) -> np.ndarray:
        n = max(1, int(round(fov / step)))
        return np.radians((np.arange(n) + 0.5) * (fov / n) - fov / 2)

    return (centres(config.azimuth_fov_deg, config.azimuth_step_deg),
            centres(config.elevation_fov_deg, config.elevation_step_deg))


def spherical_to_xyz(r: np.ndarray, az: np.ndarray, el: np.ndarray) -> np.ndarray:
    """(N, 3) points from range, azimuth (from +x towards +y) and elevation (towards +z)."""
    return np.stack([r * np.cos(el) * np.cos(az), r * np.cos(el) * np.sin(az), r * np.sin(el)], axis=-1)


def xyz_to_spherical(p: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    r = np.linalg.norm(p, axis=-1)
    return r, np.arctan2(p[..., 1], p[..., 0]), np.arcsin(np.clip(p[..., 2] / np.maximum(r, 1e-12), -1, 1))


def radar_velocity(world: W.World, time: float, mount: np.ndarray) -> np.ndarray:
    """(3,) road-frame velocity of the radar: ego velocity plus yaw rate x lever arm."""
    pose = world.ego.pose(time)
    lever = pose[:3, :3] @ mount[:3, 3]
    omega = np.array([0.0, 0.0, world.ego.yaw_rate(time)])
    return world.ego.velocity(time) + np.cross(omega, lever)


@dataclass(frozen=True)
class RadarFrame:
    """``points`` (N, 5) float32 x, y, z, v_r, rcs in the radar frame; ``labels`` (N,) int8."""

    points: np.ndarray
    labels: np.ndarray


def _reflectivity(config: RadarSimConfig, material: np.ndarray) -> np.ndarray:
    r = config.reflectivity
    table = np.zeros(len(W.MATERIAL_NAMES))
    table[[W.GROUND, W.SIDEWALK, W.BUILDING, W.POLE, W.TRUNK, W.FOLIAGE]] = (
        r.ground, r.sidewalk, r.building, r.pole, r.trunk, r.foliage)
    table[list(W.VEHICLE_MATERIALS)] = r.vehicle
    table[[W.PERSON, W.BICYCLE]] = (r.person, r.bicycle)
    return table[material]


def _measure(config: RadarSimConfig, rng: np.random.Generator, p_radar: np.ndarray, v_r: np.ndarray,
             rcs: np.ndarray) -> np.ndarray:
    """(N, 5) noisy measurements of true radar-frame points (N, 3), Doppler (N,) and rcs (N,)."""
    r, az, el = xyz_to_spherical(p_radar)
    n = len(r)
    r = np.maximum(r + rng.normal(0.0, config.range_std, n), 0.1)
    az = az + rng.normal(0.0, np.radians(config.azimuth_std_deg), n)
    el = el + rng.normal(0.0, np.radians(config.elevation_std_deg), n)
    v = v_r + rng.normal(0.0, config.v_r_std, n)
    rc = rcs + rng.normal(0.0, config.rcs_std_db, n)
    return np.column_stack([spherical_to_xyz(r, az, el), v, rc])


def simulate(world: W.World, config: RadarSimConfig, mount: np.ndarray, time: float,
             rng: np.random.Generator) -> RadarFrame:
    """One radar scan at ``time`` with the radar mounted at ``mount`` (4, 4 radar-to-ego)."""
    azimuths, elevations = grid_angles(config)
    step_az = np.radians(config.azimuth_fov_deg) / len(azimuths)
    step_el = np.radians(config.elevation_fov_deg) / len(elevations)
    az = azimuths[None, :] + rng.uniform(-0.5, 0.5, (len(elevations), len(azimuths))) * step_az
    el = elevations[:, None] + rng.uniform(-0.5, 0.5, (len(elevations), len(azimuths))) * step_el
    dirs_radar = spherical_to_xyz(np.ones_like(az), az, el)
    prims = world.primitives_at(time)
    origin, dirs, road_to_radar, hits = cast_sensor_grid(prims, world.ego.pose(time) @ mount, dirs_radar,
                                                         azimuths, step_az, config.max_range)

    hit = hits.prim != NO_HIT
    t, d, n, prim = hits.t[hit], dirs[hit], hits.normal[hit], hits.prim[hit]
    material, obj = prims.material[prim], prims.obj[prim]
    cos_inc = np.abs(np.einsum("ij,ij->i", n, d))
    p_detect = (_reflectivity(config, material) * cos_inc ** config.incidence_power
                / (1.0 + (t / config.range_half) ** 2))
    keep = rng.random(len(t)) < p_detect
    if keep.sum() > config.max_points:
        chosen = rng.choice(np.flatnonzero(keep), config.max_points, replace=False)
        keep = np.zeros_like(keep)
        keep[chosen] = True
    t, d, material, obj, cos_inc = t[keep], d[keep], material[keep], obj[keep], cos_inc[keep]
    p_road = origin + d * t[:, None]
    v_radar = radar_velocity(world, time, mount)
    v_point = world.point_velocity(obj, p_road, time)  # v + omega x r of the body at the scan time
    v_r = np.einsum("ij,ij->i", d, v_point - v_radar)
    rcs_table = np.array([RCS_DB[m] for m in range(len(W.MATERIAL_NAMES))])
    rcs = rcs_table[material] + 10 * np.log10(np.maximum(cos_inc, 0.05))
    labels = np.where(world.moving(obj, time), MOVING, STATIC)

    # Multipath ghosts: a car point reflected off the road appears at its mirror image below it.
    vehicle = np.flatnonzero(np.isin(material, W.VEHICLE_MATERIALS))
    n_ghost = min(int(rng.integers(0, config.ghost_count + 1)) if config.ghost_count > 0 else 0, len(vehicle))
    ghost = rng.choice(vehicle, n_ghost, replace=False) if n_ghost else np.zeros(0, int)
    g_road = p_road[ghost] * np.array([1.0, 1.0, -1.0])
    g_vel = v_point[ghost] * np.array([1.0, 1.0, -1.0])
    g_dir = (g_road - origin) / np.linalg.norm(g_road - origin, axis=1, keepdims=True)
    g_vr = np.einsum("ij,ij->i", g_dir, g_vel - v_radar)

    true = _measure(config, rng, apply(road_to_radar, p_road), v_r, rcs)
    ghosts = _measure(config, rng, apply(road_to_radar, g_road), g_vr, rcs[ghost] - 6.0)

    n_clutter = int(rng.poisson(config.clutter_fraction * len(t))) if config.clutter_fraction > 0 else 0
    half_az, half_el = np.radians(config.azimuth_fov_deg) / 2, np.radians(config.elevation_fov_deg) / 2
    clutter_xyz = spherical_to_xyz(rng.uniform(1.0, 0.6 * config.max_range, n_clutter),
                                   rng.uniform(-half_az, half_az, n_clutter), rng.uniform(-half_el, half_el, n_clutter))
    clutter = np.column_stack([clutter_xyz, rng.uniform(-config.clutter_v_r_max, config.clutter_v_r_max, n_clutter),
                               rng.uniform(-20.0, -5.0, n_clutter)])

    points = np.concatenate([true, ghosts, clutter]).reshape(-1, 5)
    all_labels = np.concatenate([labels, np.full(len(ghosts) + len(clutter), CLUTTER)]).astype(np.int8)
    order = rng.permutation(len(points))
    return RadarFrame(points[order].astype(np.float32), all_labels[order])
