"""The synthetic generator's skewed radar clock and swinging ego speed (issue 27): stamps and poses
against the ego's analytic trajectory; both options absent from scene.json while they are 0."""

from __future__ import annotations

import numpy as np

from radar4dgs.config import preset
from radar4dgs.datasets.synth import SynthConfig, synthesize
from radar4dgs.datasets.synth.world import EgoTrack
from radar4dgs.io import read_scene


def test_radar_stamps_and_poses_run_early_by_the_offset_and_the_speed_swings(tmp_path):
    synthesize(preset(SynthConfig, "tiny", seed=3, num_frames=12, ego_speed_swing=2.0, radar_time_offset=0.05),
               tmp_path / "s", progress=False)
    scene = read_scene(tmp_path / "s")
    synthetic = scene.extra["synthetic"]
    ego = synthetic["objects"][0]["trajectory"]
    track = EgoTrack(speed=synthetic["objects"][0]["speed"], lane_y=ego["lane_y"], amplitude=ego["amplitude"],
                     wavenumber=ego["wavenumber"], phase=ego["phase"], swing=ego["swing"],
                     swing_period=ego["swing_period"])
    to_world = np.asarray(synthetic["road_to_world"])
    for f in scene.frames:
        assert f.radar_timestamp == f.timestamp - 0.05
        np.testing.assert_allclose(f.radar_ego_to_world, to_world @ track.pose(f.timestamp - 0.05), atol=1e-9)
        np.testing.assert_allclose(f.ego_to_world, to_world @ track.pose(f.timestamp), atol=1e-9)
    # dx/dt = speed + 2 sin(2 pi t / 4): the recorded speeds follow it (the weave adds < 1 %).
    speeds = np.array([f.ego_velocity[0] for f in scene.frames])
    times = np.array([f.timestamp for f in scene.frames])
    np.testing.assert_allclose(speeds, track.speed + 2.0 * np.sin(2 * np.pi * times / 4.0), rtol=0.01)
    assert synthetic["config"]["radar_time_offset"] == 0.05


def test_default_scenes_record_neither_option(tmp_path):
    synthesize(preset(SynthConfig, "tiny", seed=3, num_frames=2), tmp_path / "s", progress=False)
    scene = read_scene(tmp_path / "s")
    record = scene.extra["synthetic"]["config"]
    assert not {"radar_time_offset", "ego_speed_swing", "ego_speed_period"} & set(record)
    assert all(f.radar_timestamp == f.timestamp for f in scene.frames)
