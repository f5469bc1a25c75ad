"""Camera-radar time offset (issue 27): a speed profile shifted by a known offset is recovered;
a constant speed is reported unobservable."""

from __future__ import annotations

import math
import warnings

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from radar4dgs.radar.sync import estimate_time_offset, offset_cost, pose_speeds


def straight_drive(times: np.ndarray) -> np.ndarray:
    """(T, 4, 4) poses of a car on the x axis whose speed is 20 + 4 sin(1.3 t) + 2 sin(3.1 t) m/s."""
    x = 20 * times - 4 / 1.3 * np.cos(1.3 * times) - 2 / 3.1 * np.cos(3.1 * times)
    poses = np.tile(np.eye(4), (len(times), 1, 1))
    poses[:, 0, 3] = x
    return poses


def speed(t: np.ndarray) -> np.ndarray:
    return 20 + 4 * np.sin(1.3 * t) + 2 * np.sin(3.1 * t)


@pytest.mark.parametrize("offset", [0.0, 0.037, -0.081])
def test_a_known_offset_is_recovered(offset):
    camera_times = np.arange(0, 4.0, 1 / 15)  # 15 Hz, 4 s
    pose_times, pose_speed = pose_speeds(camera_times, straight_drive(camera_times))
    np.testing.assert_allclose(pose_speed, speed(pose_times), atol=0.02)  # mid-interval finite differences
    radar_times = np.arange(0.05, 3.9, 1 / 13)  # another rate
    rng = np.random.default_rng(0)
    # v_poses(t + tau) = v_radar(t): the radar sees at t the speed the poses have at t + tau.
    radar_speeds = speed(radar_times + offset) + rng.normal(0, 0.05, len(radar_times))
    result = estimate_time_offset(radar_times, radar_speeds, pose_times, pose_speed, max_offset=0.2)
    assert result["observable"]
    assert result["offset_s"] == pytest.approx(offset, abs=0.004)
    assert result["rmse"] < 0.1
    if offset:
        assert result["rmse_at_zero"] > 2 * result["rmse"]


def test_a_constant_speed_leaves_the_offset_unobservable():
    times = np.arange(0, 3.0, 0.1)
    poses = np.tile(np.eye(4), (len(times), 1, 1))
    poses[:, 0, 3] = 25 * times
    pose_times, pose_speed = pose_speeds(times, poses)
    result = estimate_time_offset(times, np.full(len(times), 25.0), pose_times, pose_speed)
    assert not result["observable"] and result["offset_s"] is None and result["rmse"] < 1e-9


@settings(max_examples=60, deadline=None)
@given(st.lists(st.floats(5.0, 7.0), min_size=6, max_size=6), st.lists(st.floats(5.0, 7.0), min_size=5, max_size=5))
def test_a_short_drive_scans_without_warnings_and_keeps_the_best_offset(radar_speeds, pose_speed):
    # Six radar samples against five pose speeds: offsets of more than 0.15 s leave under four samples
    # overlapping, so the scan's finite costs end inside it, where the refinement must not step past.
    radar_times, pose_times = np.arange(6) * 0.1, 0.05 + np.arange(5) * 0.1
    args = (radar_times, np.array(radar_speeds), pose_times, np.array(pose_speed))
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        result = estimate_time_offset(*args)
    offset = result["offset_s"] if result["offset_s"] is not None else result["best_scanned_s"]
    grid = np.arange(-0.2, 0.2 + 0.001, 0.002)
    best_scanned = min(offset_cost(o, *args) for o in grid)
    assert math.isfinite(offset_cost(offset, *args)) and offset_cost(offset, *args) <= best_scanned + 1e-12
