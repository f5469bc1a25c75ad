"""A spinning lidar for `lidar/`: (N, 4) x, y, z, intensity in the ego frame."""

from __future__ import annotations

import numpy as np

from radar4dgs.datasets.synth import world as W
from radar4dgs.datasets.synth.config import LidarSimConfig
from radar4dgs.datasets.synth.radar import spherical_to_xyz
from radar4dgs.datasets.synth.raycast import NO_HIT, cast_sensor_grid, rigid
from radar4dgs.datasets.synth.shade import albedo


def simulate(world: W.World, config: LidarSimConfig, time: float, rng: np.random.Generator) -> np.ndarray:
    """One sweep at ``time`` (no motion during the sweep); intensity is the surface albedo's
    luminance (lane paint bright, asphalt dark), plus noise, clipped to 0..1."""
    n_az = max(1, int(round(360.0 / config.azimuth_step_deg)))
    azimuths = np.radians((np.arange(n_az) + 0.5) * (360.0 / n_az) - 180.0)
    elevations = np.radians(np.linspace(*config.elevation_range_deg, config.beams))
    dirs_lidar = spherical_to_xyz(np.ones((len(elevations), n_az)), azimuths[None, :], elevations[:, None])
    mount = rigid(np.eye(3), config.mount_xyz)
    prims = world.primitives_at(time)
    origin, dirs, _, hits = cast_sensor_grid(prims, world.ego.pose(time) @ mount, dirs_lidar, azimuths,
                                             np.radians(360.0 / n_az), config.max_range)
    hit = hits.prim != NO_HIT
    t, d, n, prim = hits.t[hit], dirs[hit], hits.normal[hit], hits.prim[hit]
    p = origin + d * t[:, None]
    base = albedo(world, prims.material[prim], prims.obj[prim], prim, prims.color[prim], p, n,
                  np.full(len(t), 0.05), time)
    intensity = base @ np.array([0.299, 0.587, 0.114])
    intensity = np.clip(intensity + rng.normal(0.0, config.intensity_std, len(t)), 0.0, 1.0)
    t_noisy = t + rng.normal(0.0, config.range_std, len(t))
    p_ego = (dirs_lidar[hit] * t_noisy[:, None]) + np.asarray(config.mount_xyz)
    return np.column_stack([p_ego, intensity]).astype(np.float32)
