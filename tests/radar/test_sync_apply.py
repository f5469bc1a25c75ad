"""Applying the camera-radar time offset (issue 27): pose interpolation in closed form, the auto/off
decision, and a synthetic scene whose radar clock is skewed by a known offset, recovered and undone."""

from __future__ import annotations

import re

import numpy as np
import pytest

from radar4dgs.config import preset
from radar4dgs.datasets.synth import SynthConfig, synthesize
from radar4dgs.io import read_scene
from radar4dgs.radar.config import RadarConfig
from radar4dgs.radar.process import prepare_radar
from radar4dgs.radar.sync import interpolate_poses, offset_to_apply, prepared_synced_scene


def turning_drive(t: np.ndarray) -> np.ndarray:
    """(T, 4, 4): constant velocity (12, 3, 0) m/s while the heading turns at 0.4 rad/s."""
    poses = np.tile(np.eye(4), (len(t), 1, 1))
    c, s = np.cos(0.4 * t), np.sin(0.4 * t)
    poses[:, 0, 0], poses[:, 0, 1], poses[:, 1, 0], poses[:, 1, 1] = c, -s, s, c
    poses[:, :3, 3] = np.outer(t, [12.0, 3.0, 0.0])
    return poses


def test_interpolated_and_extrapolated_poses_are_exact_for_a_constant_rate_motion():
    times = np.array([0.0, 0.1, 0.25, 0.3])
    query = np.array([-0.07, 0.0, 0.04, 0.18, 0.3, 0.36])  # before, inside, after the stamps
    np.testing.assert_allclose(interpolate_poses(times, turning_drive(times), query), turning_drive(query),
                               atol=1e-12)


@pytest.mark.parametrize(("estimate", "mode", "from_radar", "applied"), [
    ({"offset_s": 0.08}, "auto", False, 0.08),
    ({"offset_s": -0.05}, "auto", False, -0.05),
    ({"offset_s": 0.08}, "off", False, 0.0),  # report only
    ({"offset_s": 0.004}, "auto", False, 0.0),  # within the threshold
    ({"offset_s": None, "best_scanned_s": 0.1}, "auto", False, 0.0),  # unobservable
    ({"offset_s": 0.08}, "auto", True, 0.0),  # poses integrated from this radar (aiMotive)
])
def test_auto_applies_only_an_observable_offset_above_the_threshold(estimate, mode, from_radar, applied):
    offset, action = offset_to_apply(estimate, mode, 0.01, from_radar)
    assert offset == applied
    assert action.startswith("applied" if applied else ("sync off" if mode == "off" else "not applied"))


@pytest.fixture(scope="module")
def skewed(tmp_path_factory):
    """Tiny synthetic scene, 16 frames, the ego speed swinging +-2 m/s, the radar clock 0.1 s early."""
    out = tmp_path_factory.mktemp("sync") / "scene"
    synthesize(preset(SynthConfig, "tiny", seed=1, num_frames=16, ego_speed_swing=2.0, radar_time_offset=0.1),
               out, progress=False)
    return read_scene(out)


@pytest.mark.parametrize("mode", ["auto", "off"])
def test_a_skewed_radar_clock_is_estimated_and_undone(skewed, tmp_path, mode):
    out = tmp_path / "radar"
    summary = prepare_radar(skewed, out, preset(RadarConfig, "tiny", sync=mode))
    sync = summary["time_sync"]
    assert sync["observable"] and sync["offset_s"] == pytest.approx(0.1, abs=0.005)
    synced = prepared_synced_scene(skewed, out)
    camera = np.array([f.timestamp for f in skewed.frames])
    stamps = np.array([f.radar_timestamp for f in synced.frames])
    # The truth: each scan was taken at its camera frame's time, at the camera-time ego pose.
    shift = np.array([np.linalg.norm(f.radar_ego_to_world[:3, 3] - f.ego_to_world[:3, 3]) for f in synced.frames])
    if mode == "off":
        assert sync["applied_s"] == 0.0 and synced is skewed
        np.testing.assert_allclose(stamps, camera - 0.1, atol=1e-9)
        assert shift.min() > 0.3  # the ego moves >= 3 m/s x 0.1 s between the wrong and the true pose
    else:
        assert sync["applied_s"] == sync["offset_s"] and sync["action"].startswith("applied")
        np.testing.assert_allclose(stamps, camera, atol=0.005)
        assert shift.max() < 0.005 * 25  # what 5 ms of stamp error leaves at up to 25 m/s
        # The disagreement with the poses is measured on the corrected stamps.
        assert summary["disagreement"]["rmse"] < sync["rmse_at_zero"]


def test_prepare_says_what_it_did_with_the_offset(skewed, tmp_path, capsys):
    from radar4dgs.cli import main

    assert main(["prepare", str(skewed.root), "--out", str(tmp_path / "p"), "--only", "radar", "--preset", "tiny",
                 "--quiet"]) == 0
    moved = re.search(r"\(time sync: applied: radar stamps moved by ([+-][\d.]+) ms\)", capsys.readouterr().out)
    assert moved and float(moved.group(1)) == pytest.approx(100, abs=5)
