"""Test-view alignment (issue 27): the interpolated test camera sits on the refined training
trajectory at its time, read from RUN/poses.json, whatever its own recorded pose says; the
exposure alignment takes out a global colour transform and nothing fitted on the pixel itself."""

from __future__ import annotations

import json

import numpy as np
import pytest
import torch
from hypothesis import given, settings
from hypothesis import strategies as st

from radar4dgs.evaluate.alignment import exposure_aligned, interpolated_view, learned_corrections
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


def textured(height: int = 12, width: int = 16, seed: int = 0) -> torch.Tensor:
    return torch.as_tensor(np.random.default_rng(seed).uniform(0.1, 0.9, (height, width, 3)))


@settings(max_examples=25, deadline=None)
@given(gain=st.floats(0.5, 1.2), bias=st.floats(-0.05, 0.05), width=st.integers(6, 17))
def test_a_global_exposure_change_is_taken_out_exactly(gain, bias, width):
    gt = textured(width=width)
    mixing = torch.tensor([[gain, 0.02, 0.0], [0.0, gain, 0.01], [0.03, 0.0, gain]], dtype=gt.dtype)
    render = gt @ mixing.T + bias  # a white-balance and exposure error, inside [0, 1]
    assert torch.allclose(exposure_aligned(render, gt), gt, atol=1e-9)


def test_each_half_is_corrected_by_the_other_halfs_transform():
    gt = textured()
    render = gt.clone()
    render[:, :8] *= 0.5  # left half half as bright, right half exact
    aligned = exposure_aligned(render, gt)
    # The left half gets the identity fitted on the right; the right gets the left's doubling.
    assert torch.allclose(aligned[:, :8], 0.5 * gt[:, :8], atol=1e-9)
    assert torch.allclose(aligned[:, 8:], (2 * gt[:, 8:]).clamp(0, 1), atol=1e-9)


def test_an_unrelated_render_is_not_fitted_to_the_truth():
    gt, render = textured(seed=1), textured(seed=2)
    aligned = exposure_aligned(render, gt)
    # Cross-fitted on independent noise, the best transform is about the other half's mean colour.
    error = float(((aligned - gt) ** 2).mean())
    assert error > 0.8 * float(((gt - gt.mean(dim=(0, 1))) ** 2).mean())


def test_a_flat_render_and_a_one_column_image():
    gt = textured()
    aligned = exposure_aligned(torch.full_like(gt, 0.5), gt)
    assert torch.isfinite(aligned).all()
    with pytest.raises(ValueError, match="at least 2 columns"):
        exposure_aligned(gt[:, :1], gt[:, :1])
