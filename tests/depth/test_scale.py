"""Closed-form tests of radar scale recovery (paper plane voting and the inverse-depth affine fit)."""

from __future__ import annotations

import math

import numpy as np
import pytest
from hypothesis import given, settings, strategies as st

from _depth_helpers import K, points_on_plane, road_and_wall_depth, surface_points, tilted_plane_depth
from radar4dgs.depth import DepthConfig, DepthWarning, fill_from_neighbours, histogram_vote, metric_depth, recover_scale
from radar4dgs.depth.geometry import DirectionIndex, radar_to_camera, transform_points
from radar4dgs.depth.scale import DYNAMIC, VALID, FrameFit, RadarPairs, fit_inverse_affine, plane_votes

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


def test_plane_votes_formula():
    # Visual plane z = 2 (unscaled) seen along the optical axis; radar point at z = 6: s = 3.
    visual = np.array([[[0.0, 0.0, 2.0], [0.1, 0.0, 2.0], [0.0, 0.1, 2.0]]])
    votes, reason = plane_votes(np.array([[0.05, 0.05, 6.0]]), visual, 0.05, 0.1)
    assert reason[0] == VALID and votes[0] == pytest.approx(3.0)
    # Collinear neighbours: degenerate normal; a ray in the plane: grazing.
    collinear = np.array([[[0.0, 0.0, 2.0], [0.1, 0.0, 2.0], [0.2, 0.0, 2.0]]])
    assert np.isnan(plane_votes(np.array([[0.0, 0.0, 6.0]]), collinear, 0.05, 0.1)[0][0])
    _, reason = plane_votes(np.array([[1.0, 0.0, 0.0]]), visual, 0.05, 0.1)
    assert reason[0] != VALID


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


def test_dynamic_and_out_of_range_points_are_not_used(index):
    rng = np.random.default_rng(5)
    depth = tilted_plane_depth(NORMAL, OFFSET)
    points = points_on_plane(NORMAL, OFFSET, 50, rng)
    points[:5] *= 1.7  # moving: off the surface
    static = np.ones(50, bool)
    static[:5] = False
    behind = np.array([[0.0, 0.0, -5.0], [50.0, 0.0, 5.0]])  # behind the camera, outside the image
    fit = recover_scale(1 / depth, np.concatenate([points, behind]), K, DepthConfig(), "affine",
                        static=np.concatenate([static, [True, True]]), index=index)
    assert (fit.pairs.reason[:5] == DYNAMIC).all()
    assert (fit.pairs.reason[-2:] != VALID).all()
    assert fit.a == pytest.approx(1.0, rel=1e-6) and abs(fit.b) < 1e-6


def test_depth_edges_are_rejected(index):
    depth = np.full((90, 160), 10.0)
    depth[:, 80:] = 30.0
    v = np.arange(10, 80, 2, dtype=float)
    on_edge = np.stack([(79.5 - K[0, 2]) / K[0, 0] * np.ones_like(v), (v - K[1, 2]) / K[1, 1], np.ones_like(v)], 1) * 10
    fit = recover_scale(1 / depth, on_edge, K, DepthConfig(), "paper", index=index)
    assert fit.num_valid == 0 and not fit.ok


def test_histogram_vote_finds_the_mode():
    rng = np.random.default_rng(6)
    votes = np.concatenate([2.0 * np.exp(rng.normal(0, 0.01, 300)), rng.uniform(0.5, 10, 200)])
    assert histogram_vote(votes, 64) == pytest.approx(2.0, rel=0.01)
    assert math.isnan(histogram_vote(np.array([np.nan, -1.0]), 64))
    assert histogram_vote(np.array([3.0, 3.0, 3.0]), 64) == pytest.approx(3.0)


def test_fit_inverse_affine_falls_back_to_scale_only_without_spread():
    rng = np.random.default_rng(7)
    z = 20 + rng.normal(0, 0.01, 50)  # every point at the same depth: shift is not observable
    x = 2.0 / z
    a, b, inliers, scale_only = fit_inverse_affine(x, z, 0.08, 128, 0.03, 10, 0.05, rng)
    assert scale_only and b == 0.0 and a == pytest.approx(0.5, rel=1e-3) and inliers.all()


def _fit(ok, a=math.nan, b=math.nan):
    pairs = RadarPairs(np.zeros((0, 3)), np.zeros((0, 2)), np.zeros(0), np.zeros(0), np.zeros((0, 3), int),
                       np.zeros(0, np.int8))
    return FrameFit("affine", a, b, ok, "ok" if ok else "3 valid pairs < min_pairs 12", pairs, np.zeros(0, bool))


def test_too_few_pairs_fall_back_to_neighbours():
    fits = [_fit(False), _fit(True, 1.0, 0.1), _fit(False), _fit(True, 2.0, 0.3), _fit(False)]
    with pytest.warns(DepthWarning, match="frame 2.*frame\\(s\\) 1, 3"):
        params = fill_from_neighbours(fits, [0.0, 1.0, 2.0, 3.0, 4.0])
    assert [p.source for p in params] == ["neighbours", "fit", "neighbours", "fit", "neighbours"]
    assert (params[0].a, params[0].b) == (1.0, 0.1)  # only a later neighbour
    assert params[2].a == pytest.approx(1.5) and params[2].b == pytest.approx(0.2)  # interpolated in time
    assert params[4].from_frames == (3,)
    with pytest.raises(ValueError, match="no frame has enough"):
        fill_from_neighbours([_fit(False)], [0.0])


def test_metric_depth_guards_non_positive_inverse_depth():
    x = np.array([[1.0, 0.5, 0.0, np.nan, -1.0]])
    z, valid = metric_depth(x, 0.1, -0.02, 1.0, 100.0)
    assert valid.tolist() == [[True, True, False, False, False]]
    assert z[0, 0] == pytest.approx(12.5) and z[0, 1] == pytest.approx(1 / 0.03)
    assert (z[0, 2:] == 100.0).all() and z.dtype == np.float32


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
