"""Stage 2: the radar front end: ego-motion from Doppler (RANSAC), dynamic points, poses.

Public API::

    from radar4dgs.radar import estimate_ego_motion, classify_dynamic, RadarConfig
    ego = estimate_ego_motion(xyz, v_r, seed=0)          # EgoMotion(velocity, inliers, covariance, ok, reason)
    is_dynamic, v_r_comp = classify_dynamic(xyz, v_r, ego)
"""

from radar4dgs.radar.classify import classify_dynamic, compensated_radial_velocity, dynamic_threshold
from radar4dgs.radar.config import RadarConfig
from radar4dgs.radar.ego_motion import EgoMotion, estimate_ego_motion
from radar4dgs.radar.poses import (
                                   ego_motion_from_radar,
                                   ego_rates_from_radar,
                                   expected_radar_velocity,
                                   integrate_poses,
                                   poses_from_radar,
)
from radar4dgs.radar.process import load_radar_outputs, prepare_radar

__all__ = ["EgoMotion", "RadarConfig", "classify_dynamic", "compensated_radial_velocity", "dynamic_threshold", "ego_motion_from_radar", "ego_rates_from_radar",
           "estimate_ego_motion", "expected_radar_velocity", "integrate_poses", "load_radar_outputs",
           "poses_from_radar", "prepare_radar"]
