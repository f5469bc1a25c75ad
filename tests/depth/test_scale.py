"""Closed-form tests of radar scale recovery (paper plane voting and the inverse-depth affine fit)."""

from __future__ import annotations

import numpy as np
import pytest
from _depth_helpers import K, points_on_plane, road_and_wall_depth, surface_points, tilted_plane_depth
from hypothesis import given, settings
from hypothesis import strategies as st

from radar4dgs.depth import DepthConfig, metric_depth, recover_scale
from radar4dgs.depth.geometry import DirectionIndex, radar_to_camera, transform_points

NORMAL, OFFSET = (0.2, 0.5, 1.0), 10.0


@pytest.fixture(scope="module")
def index():
    return DirectionIndex(K, 160, 90)


def test_paper_recovers_scale_exactly_without_noise(index):
    rng = np.random.default_rng(0)
    depth = tilted_plane_depth(NORMAL, OFFSET)
    scale = 7.3
    x = (scale / depth).astype(np.float64)  # the prior is depth / scale, handed over as 1 / depth
    points = points_on_plane(NORMAL, OFFSET, 200, rng)
    fit = recover_scale(x, points, K, DepthConfig(), "paper", index=index)
    assert fit.ok and fit.b == 0.0
    assert fit.depth_scale == pytest.approx(scale, rel=1e-9)
    votes = fit.votes[np.isfinite(fit.votes)]
    assert len(votes) >= 150 and np.allclose(votes, scale, rtol=1e-9)


def test_paper_within_two_percent_with_radar_noise(index):
    rng = np.random.default_rng(1)
    depth = tilted_plane_depth(NORMAL, OFFSET)
    x = 0.25 / depth
    points = points_on_plane(NORMAL, OFFSET, 300, rng) + rng.normal(0, 0.08, (300, 3))
    fit = recover_scale(x, points, K, DepthConfig(), "paper", index=index)
    assert fit.ok
    assert abs(fit.depth_scale / 0.25 - 1) < 0.02


def test_affine_recovers_scale_and_shift(index):
    rng = np.random.default_rng(2)
    depth = tilted_plane_depth(NORMAL, OFFSET)
    A, B = 3.0, 0.2
    x = A / depth + B
    points = points_on_plane(NORMAL, OFFSET, 200, rng)
    fit = recover_scale(x, points, K, DepthConfig(), "affine", index=index)
    assert fit.ok and not fit.scale_only
    assert fit.a == pytest.approx(1 / A, rel=1e-6)
    assert fit.b == pytest.approx(-B / A, rel=1e-5)
    z, valid = metric_depth(x, fit.a, fit.b, 1.0, 250.0)
    assert valid.all() and np.allclose(z, depth, rtol=1e-5)


def _road_scene(rng, noise=0.0):
    depth = road_and_wall_depth()
    points = surface_points(depth, 200, rng)
    points += rng.normal(0, noise, points.shape)
    # Ghosts: mirror images below the road (camera y grows downwards; the road is at y = 1.5).
    src = points[rng.choice(len(points), 40)]
    ghosts = src.copy()
    ghosts[:, 1] = 2 * 1.5 - src[:, 1] + rng.uniform(0.5, 2.0, 40)
    # Clutter: 20 % of all points, anywhere in the field of view at any range.
    n_clutter = (len(points) + len(ghosts)) // 4
    r = rng.uniform(3, 80, n_clutter)
    rays = np.stack([rng.uniform(-0.7, 0.7, n_clutter), rng.uniform(-0.4, 0.4, n_clutter), np.ones(n_clutter)], 1)
    clutter = rays / np.linalg.norm(rays, axis=1, keepdims=True) * r[:, None]
    all_points = np.concatenate([points, ghosts, clutter])
    labels = np.concatenate([np.zeros(len(points)), np.ones(len(ghosts)), 2 * np.ones(n_clutter)])
    return depth, all_points, labels


@pytest.mark.parametrize("noise", [0.0, 0.05])
def test_affine_robust_to_ghosts_and_clutter(index, noise):
    rng = np.random.default_rng(3)
    depth, points, labels = _road_scene(rng, noise)
    A, B = 4.0, 0.3
    x = A / depth + B  # sky: B
    fit = recover_scale(x, points, K, DepthConfig(), "affine", index=index)
    assert fit.ok
    tol = 1e-3 if noise == 0 else 0.02  # clutter that happens to lie on a surface may stay
    assert fit.a == pytest.approx(1 / A, rel=tol)
    assert fit.b == pytest.approx(-B / A, rel=5 * tol)
    # Ghosts land on road pixels much nearer than themselves: none may survive as an inlier.
    assert not fit.inliers[labels == 1].any()
    assert (labels[fit.inliers] == 2).mean() < 0.1
    z, valid = metric_depth(x, fit.a, fit.b, 1.0, 250.0)
    surface = np.isfinite(depth)
    assert np.median(np.abs(z[surface] / depth[surface] - 1)) < max(10 * tol, 1e-5)


def test_paper_robust_to_ghosts_and_clutter(index):
    rng = np.random.default_rng(4)
    depth, points, labels = _road_scene(rng, noise=0.05)
    with np.errstate(divide="ignore"):
        x = 2.5 / depth  # depth / 2.5 as inverse depth; sky 0
    fit = recover_scale(x, points, K, DepthConfig(), "paper", index=index)
    assert fit.ok and abs(fit.depth_scale / 2.5 - 1) < 0.02


def test_radar_to_camera_compensates_ego_motion():
    cam_to_ego = np.array([[0.0, 0.0, 1.0, 1.5], [-1.0, 0.0, 0.0, 0.0], [0.0, -1.0, 0.0, 1.5], [0, 0, 0, 1.0]])
    radar_to_ego = np.eye(4)
    radar_to_ego[:3, 3] = (3.0, 0.0, 0.5)
    ego_cam, ego_radar = np.eye(4), np.eye(4)
    ego_radar[0, 3] = 0.5  # the radar fired 0.5 m further along
    world_point = np.array([[20.0, 1.0, 1.0]])
    in_radar = transform_points(np.linalg.inv(ego_radar @ radar_to_ego), world_point)
    in_cam = transform_points(np.linalg.inv(ego_cam @ cam_to_ego), world_point)
    T = radar_to_camera(cam_to_ego, radar_to_ego, ego_cam, ego_radar)
    assert np.allclose(transform_points(T, in_radar), in_cam)


@settings(max_examples=25, deadline=None)
@given(scale=st.floats(0.01, 100.0), shift=st.floats(0.0, 1.0), nx=st.floats(-0.3, 0.3), ny=st.floats(0.3, 0.6),
       offset=st.floats(3.0, 40.0), seed=st.integers(0, 2**16))
def test_random_scales_and_shifts(scale, shift, nx, ny, offset, seed):
    index = DirectionIndex(K, 160, 90)
    rng = np.random.default_rng(seed)
    normal = (nx, ny, 1.0)
    depth = tilted_plane_depth(normal, offset)
    points = points_on_plane(normal, offset, 80, rng)
    config = DepthConfig(max_depth=1e4)
    # paper: a depth / scale prior gives the scale back exactly.
    fit = recover_scale(scale / depth, points, K, config, "paper", index=index)
    assert fit.ok and fit.depth_scale == pytest.approx(scale, rel=1e-6)
    # affine: x = scale / z + shift * scale / z_min (the shift on the prior's own scale).
    x = scale / depth + shift * scale / depth.min()
    fit = recover_scale(x, points, K, config, "affine", index=index)
    assert fit.ok
    z, _ = metric_depth(x, fit.a, fit.b, 0.1, 1e4)
    assert np.allclose(z, depth, rtol=1e-4)

