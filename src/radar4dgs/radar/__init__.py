"""Stage 2: the radar front end: ego-motion from Doppler (RANSAC), dynamic points, poses.

Public API::

    from radar4dgs.radar import estimate_ego_motion, classify_dynamic, RadarConfig
    ego = estimate_ego_motion(xyz, v_r, seed=0)          # EgoMotion(velocity, inliers, covariance, ok, reason)
    is_dynamic, v_r_comp = classify_dynamic(xyz, v_r, ego)
    objects = load_radar_objects(prepared_dir)           # per frame: tracked objects, planar velocity

Importing this package does not import scipy: the names below load their module on first use,
so that the CLI's configurations (:class:`RadarConfig`) stay cheap to import.
"""

from __future__ import annotations

import importlib
from typing import Any

from radar4dgs.radar.config import RadarConfig

_LAZY = {
    "classify_dynamic": "classify", "compensated_radial_velocity": "classify", "dynamic_threshold": "classify",
    "EgoMotion": "ego_motion", "estimate_ego_motion": "ego_motion", "ego_motion_from_radar": "poses",
    "ego_rates_from_radar": "poses", "expected_radar_velocity": "poses", "integrate_poses": "poses",
    "poses_from_radar": "poses", "load_radar_outputs": "process", "prepare_radar": "process",
    "load_radar_objects": "objects", "RadarObject": "objects",
}

__all__ = ["RadarConfig", *_LAZY]


def __getattr__(name: str) -> Any:
    if name in _LAZY:
        return getattr(importlib.import_module(f"radar4dgs.radar.{_LAZY[name]}"), name)
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
