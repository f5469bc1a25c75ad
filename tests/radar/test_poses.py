import numpy as np
import pytest
from _radar_helpers import RADAR_TO_EGO

from radar4dgs.radar.poses import ego_motion_from_radar, fill_gaps, heading_offset, integrate_poses, poses_from_radar


def _radar_velocity(v_ego, w, mount):
    return mount[:3, :3].T @ (v_ego + np.cross([0, 0, w], mount[:3, 3]))


def test_lever_arm_model_inverts():
    yaw = np.radians(2.0)
    mount = RADAR_TO_EGO.copy()
    mount[:3, 3] = [3.8, 0.2, 0.4]
    mount[:2, :2] = [[np.cos(yaw), -np.sin(yaw)], [np.sin(yaw), np.cos(yaw)]]
    v_ego, w = np.array([20.0, 0.0, 0.0]), 0.15
    v_radar = _radar_velocity(v_ego, w, mount)
    v, rate = ego_motion_from_radar(v_radar[None], mount)
    np.testing.assert_allclose(v[0], v_ego, atol=1e-12)
    assert rate[0] == pytest.approx(w)
    # No lever arm (radar at the ego origin): the yaw rate cannot be observed.
    centred = mount.copy()
    centred[:3, 3] = 0
    _, rate = ego_motion_from_radar(v_radar[None], centred)
    assert rate[0] == 0.0


def test_midpoint_integration_of_an_arc():
    speed, w = 10.0, 0.2
    t = np.linspace(0, 3, 31)
    poses = integrate_poses(t, np.tile([speed, 0, 0], (31, 1)), np.full(31, w))
    psi = w * t[-1]
    np.testing.assert_allclose(poses[-1, :2, 3], [speed / w * np.sin(psi), speed / w * (1 - np.cos(psi))],
                               atol=1e-3)
    np.testing.assert_allclose(poses[-1, :2, :2], [[np.cos(psi), -np.sin(psi)], [np.sin(psi), np.cos(psi)]])
    np.testing.assert_allclose(poses[0], np.eye(4))


def test_poses_from_radar_fills_failed_frames_and_aligns_heading():
    t = np.arange(10) * 0.1
    mount = RADAR_TO_EGO.copy()
    v_radar = np.tile(_radar_velocity(np.array([15.0, 0, 0]), 0.0, mount), (10, 1))
    # A 1 degree heading error in the measured velocity: read literally, a turn of 15*0.0175/3.5 rad/s.
    c, s = np.cos(np.radians(1)), np.sin(np.radians(1))
    biased = v_radar @ np.array([[c, -s, 0], [s, c, 0], [0, 0, 1]]).T
    biased[4] = np.nan
    poses, info = poses_from_radar(t, biased, mount, align_heading=False)
    assert info["filled_frames"] == 1
    assert abs(info["mean_yaw_rate"]) > 0.05
    poses, info = poses_from_radar(t, biased, mount, align_heading=True)
    assert info["heading_correction_deg"] == pytest.approx(-1.0, abs=1e-6)
    np.testing.assert_allclose(poses[-1, :3, 3], [15 * 0.9, 0, 0], atol=1e-9)
    assert heading_offset(np.full((3, 3), np.nan), mount) == 0.0
    with pytest.raises(ValueError, match="no frame"):
        poses_from_radar(t, np.full((10, 3), np.nan), mount)


def test_fill_gaps():
    t = np.array([0.0, 1.0, 2.0, 3.0])
    v = np.array([[0.0], [np.nan], [2.0], [np.nan]])
    np.testing.assert_allclose(fill_gaps(t, v)[:, 0], [0, 1, 2, 2])
