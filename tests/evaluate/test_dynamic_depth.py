"""The dynamic Gaussians' depth against the true depth: points placed at known depths along the rays
of known pixels give back exactly their relative offsets; points off the movers or behind the
camera are not counted."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from radar4dgs.evaluate.dynamic_depth import depth_errors_in_frame, pixel_depth_errors, summarize

WIDTH, HEIGHT, FOCAL = 40, 30, 50.0
K = np.array([[FOCAL, 0.0, (WIDTH - 1) / 2], [0.0, FOCAL, (HEIGHT - 1) / 2], [0.0, 0.0, 1.0]])


def ray_point(u: int, v: int, z: float) -> np.ndarray:
    """The camera-frame point at z-depth ``z`` that projects onto pixel (u, v)."""
    return np.array([(u - K[0, 2]) * z / FOCAL, (v - K[1, 2]) * z / FOCAL, z])


@settings(max_examples=25, deadline=None)
@given(offsets=st.lists(st.floats(-0.5, 2.0), min_size=1, max_size=12), shift=st.floats(-5.0, 5.0))
def test_points_on_the_movers_give_their_relative_depth_offsets(offsets, shift):
    depth = np.full((HEIGHT, WIDTH), 20.0)
    depth[5:25, 10:30] = np.linspace(6.0, 12.0, 20)[None, :]  # a slanted car
    moving = np.zeros((HEIGHT, WIDTH), dtype=bool)
    moving[5:25, 10:30] = True
    pixels = [(10 + (3 * i) % 20, 5 + (7 * i) % 20) for i in range(len(offsets))]
    on_car = [ray_point(u, v, depth[v, u] * (1 + o)) for (u, v), o in zip(pixels, offsets, strict=True)]
    elsewhere = [ray_point(2, 2, 20.0), ray_point(35, 28, 5.0), np.array([0.0, 0.0, -4.0])]  # road, road, behind
    # The camera 'shift' metres along its axis from a world origin: world_to_camera moves points back.
    world_to_camera = np.eye(4)
    world_to_camera[2, 3] = -shift
    world = np.array(on_car + elsewhere) - world_to_camera[:3, 3]
    errors = depth_errors_in_frame(world, world_to_camera, K, depth, moving)
    np.testing.assert_allclose(errors, offsets, atol=1e-9)


def test_the_summary_counts_the_share_behind_the_surface():
    summary = summarize(np.array([-0.05, 0.0, 0.05, 0.2, 0.3]))
    assert summary == {"median": 0.05, "p90_abs": summary["p90_abs"], "behind": 0.4, "gaussians": 5}
    np.testing.assert_allclose(summary["p90_abs"], np.percentile([0.05, 0.0, 0.05, 0.2, 0.3], 90))
    assert summarize(np.zeros(0))["gaussians"] == 0
    assert summarize(np.array([0.2, 0.0]), counted="pixels")["pixels"] == 2


def test_pixel_depth_errors_count_only_moving_pixels_with_both_depths():
    truth = np.full((3, 4), 10.0)
    depth = np.array([[12.0, 9.0, np.nan, 10.0], [0.0, 11.0, 10.0, np.inf], [10.0, 10.0, 10.0, 10.0]])
    truth[1, 2] = np.nan
    moving = np.zeros((3, 4), dtype=bool)
    moving[:2, :] = True  # the bottom row is road
    # kept: (0,0) +0.2, (0,1) -0.1, (0,3) 0, (1,1) +0.1; dropped: NaN, 0, inf, NaN truth, not moving.
    np.testing.assert_allclose(np.sort(pixel_depth_errors(depth, truth, moving)), [-0.1, 0.0, 0.1, 0.2])


def test_rendered_depth_scores_every_training_frame_against_the_truth(tiny_trained_run, monkeypatch):
    """A render 5 % too deep everywhere reads +0.05, counted on the true moving pixels of every training frame."""
    import torch

    import radar4dgs.evaluate.dynamic_depth as dynamic_depth
    from radar4dgs.io.scene import read_scene

    scene = read_scene(tiny_trained_run / "scene")
    monkeypatch.setattr(dynamic_depth, "frame_view", lambda scene, index, scale, times: index)
    monkeypatch.setattr(dynamic_depth, "render_view", lambda run, index: {
        "depth": torch.as_tensor(1.05 * scene.load_optional("gt/depth", index).astype(np.float64)),
        "dynamic": torch.full(scene.load_optional("gt/depth", index).shape, 0.75)})
    result = dynamic_depth.run_rendered_depth(tiny_trained_run / "run")
    moving = [int(((scene.load_optional("gt/dynamic_mask", i) > 0) & (scene.load_optional("gt/depth", i) > 0)).sum())
              for i in scene.train_indices]
    assert [row["frame"] for row in result["by_frame"]] == list(scene.train_indices)
    assert [row["pixels"] for row in result["by_frame"]] == moving
    assert result["pixels"] == sum(moving) > 0
    assert result["median"] == pytest.approx(0.05)
    assert result["behind"] == 0.0 and result["p90_abs"] == pytest.approx(0.05)
    assert all(row["median"] == pytest.approx(0.05) for row in result["by_frame"])
    assert result["dynamic_share"] == pytest.approx(0.75)


def test_rendered_depth_of_a_real_run_is_finite(tiny_trained_run):
    from radar4dgs.evaluate.dynamic_depth import run_rendered_depth

    result = run_rendered_depth(tiny_trained_run / "run")
    assert result["pixels"] > 0 and np.isfinite(result["median"]) and result["p90_abs"] >= abs(result["median"]) - 1e-12
    assert 0.0 <= result["dynamic_share"] <= 1.0
