"""Test-view alignment (issue 27): the interpolated test camera sits on the refined training
trajectory at its time, read from RUN/poses.json, whatever its own recorded pose says."""

from __future__ import annotations

import json

import numpy as np
import pytest

from radar4dgs.evaluate.alignment import interpolated_view, learned_corrections
from radar4dgs.model.config import TrainConfig
from radar4dgs.model.pose_refine import camera_centres, pose_error
from radar4dgs.model.run import POSES_FILE, Run
from radar4dgs.model.view import View


def straight_drive(times: np.ndarray, speed: float = 8.0) -> np.ndarray:
    """(N, 4, 4) world-to-camera of a camera 1.5 m up, looking along +x, moving at ``speed`` m/s."""
    rotation = np.array([[0.0, -1.0, 0.0], [0.0, 0.0, -1.0], [1.0, 0.0, 0.0]])  # camera x right, y down, z forward
    out = np.tile(np.eye(4), (len(times), 1, 1))
    for i, t in enumerate(times):
        out[i, :3, :3] = rotation
        out[i, :3, 3] = -rotation @ np.array([speed * t, 0.0, 1.5])
    return out


def refined_run(root, indices: list[int], world_to_camera: np.ndarray, refined: bool = True) -> Run:
    """A Run whose RUN/poses.json holds ``world_to_camera`` (N, 4, 4) as the corrected training poses."""
    frames = [{"index": i, "world_to_camera": w.tolist()} for i, w in zip(indices, world_to_camera, strict=True)]
    (root / POSES_FILE).write_text(json.dumps({"poses_refined": refined, "frames": frames}))
    return Run(root=root, scene=None, prepared=None, config=TrainConfig(), model=None)


def test_the_interpolated_test_camera_sits_on_the_refined_trajectory(tmp_path):
    """20 frames at 10 Hz, every 4th held out. The refined training cameras carry a common offset
    (the gauge: the scene was fitted there) and a little independent noise; the test camera's
    recorded pose is exact. The interpolated pose follows the trajectory, offset included."""
    times = np.arange(20) * 0.1
    train = [i for i in range(20) if i % 4 != 3]
    offset = np.array([0.05, -0.03, 0.04])
    refined = straight_drive(times[train])
    rng = np.random.default_rng(0)
    for w in refined:
        w[:3, 3] -= w[:3, :3] @ (offset + rng.normal(0, 0.01, 3))  # centre moved by offset + noise
    run = refined_run(tmp_path, train, refined)
    indices, poses = learned_corrections(run)
    assert indices == train and np.array_equal(poses, refined)
    K = np.array([[100.0, 0, 80], [0, 100.0, 45], [0, 0, 1]])
    for index in (7, 11):
        exact = straight_drive(times[[index]])[0]
        moved = interpolated_view(View(exact, K, 160, 90, float(times[index])), times[train], poses)
        shift = camera_centres(moved.world_to_camera[None])[0] - camera_centres(exact[None])[0]
        np.testing.assert_allclose(shift, offset, atol=0.012)
        assert pose_error(moved.world_to_camera, exact)[1] < 1e-6  # the orientation is the trajectory's


def test_runs_without_refined_poses_have_no_alignment(tmp_path):
    assert learned_corrections(Run(root=tmp_path, scene=None, prepared=None, config=TrainConfig(), model=None)) is None
    run = refined_run(tmp_path, [0, 1], straight_drive(np.array([0.0, 0.1])), refined=False)
    assert learned_corrections(run) is None


@pytest.mark.parametrize("count", [2, 4])
def test_few_training_frames_interpolate_linearly(tmp_path, count):
    """Under 5 training frames no smoothing spline: the centre is interpolated linearly."""
    times = np.arange(count) * 0.2
    run = refined_run(tmp_path, list(range(count)), straight_drive(times))
    _, poses = learned_corrections(run)
    view = View(np.eye(4), np.eye(3), 16, 9, 0.1)
    moved = interpolated_view(view, times, poses)
    np.testing.assert_allclose(camera_centres(moved.world_to_camera[None])[0], [0.8, 0.0, 1.5], atol=1e-12)
