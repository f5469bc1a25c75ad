"""Depth sampling, lifting 2D flow to 3D and outlier rejection, against closed forms."""

from __future__ import annotations

import numpy as np
import pytest

from radar4dgs.motion.lift import backproject, lift_flow, reject_flow_outliers, sample_depth

K = np.array([[100.0, 0.0, 39.5], [0.0, 100.0, 29.5], [0.0, 0.0, 1.0]])
H, W = 60, 80


def test_sample_depth_refuses_edges_and_sky():
    depth = np.full((H, W), 10.0)
    depth[:, 40:] = 30.0  # a depth edge between columns 39 and 40
    depth[0, 0] = np.inf  # sky
    z, valid = sample_depth(depth, np.array([[20.5, 10.0], [39.5, 10.0], [0.5, 0.5], [60.0, 30.0]]), 0.1)
    assert valid.tolist() == [True, False, False, True]
    assert z[0] == pytest.approx(10.0) and z[3] == pytest.approx(30.0)


def plane_scene(motion=(1.0, 0.0, 0.0), camera_step=(0.0, 0.0, 0.5), z=10.0):
    """A fronto-parallel plane at depth z moving by ``motion`` (world = camera i frame) while the
    camera moves forward by ``camera_step``; exact flow and depths by formula."""
    world_to_cam_i = np.eye(4)
    world_to_cam_j = np.eye(4)
    world_to_cam_j[:3, 3] = -np.asarray(camera_step)
    v, u = np.mgrid[0:H, 0:W].astype(np.float64)
    X, Y = (u - K[0, 2]) / K[0, 0] * z, (v - K[1, 2]) / K[1, 1] * z
    Xj, Yj, Zj = X + motion[0] - camera_step[0], Y + motion[1] - camera_step[1], z + motion[2] - camera_step[2]
    flow = np.stack([K[0, 0] * Xj / Zj + K[0, 2] - u, K[1, 1] * Yj / Zj + K[1, 2] - v], axis=-1)
    depth_i = np.full((H, W), z)
    depth_j = np.full((H, W), Zj)
    return flow.astype(np.float32), depth_i, depth_j, world_to_cam_i, world_to_cam_j


def test_lift_flow_recovers_a_known_translation_with_a_moving_camera():
    motion = np.array([1.0, -0.2, 0.3])
    flow, depth_i, depth_j, w2c_i, w2c_j = plane_scene(motion)
    valid = np.ones((H, W), bool)
    valid[:5] = False
    points_i, points_j, pixels = lift_flow(flow, depth_i, depth_j, K, w2c_i, w2c_j, valid)
    assert len(points_i) > 0.5 * H * W
    assert (pixels[:, 1] >= 5).all()
    assert np.allclose(points_j - points_i, motion, atol=1e-4)
    # points_i are the back-projections of the kept pixels
    assert np.allclose(points_i, backproject(pixels, np.full(len(pixels), 10.0), K, w2c_i))
    # a target mask that excludes the right half of frame j drops matches landing there
    target = np.ones((H, W), bool)
    target[:, W // 2:] = False
    _, _, kept = lift_flow(flow, depth_i, depth_j, K, w2c_i, w2c_j, valid, target_mask=target)
    assert (kept[:, 0] + flow[kept[:, 1].astype(int), kept[:, 0].astype(int), 0] <= W // 2 - 1).all()


@pytest.mark.parametrize("scale_j", [0.99, 1.0, 1.01])
def test_one_scale_for_both_ends_keeps_a_biased_prior_out_of_the_motion(scale_j):
    # The prior draws the plane 2 % too deep in both frames; frame i's object scale corrects it exactly,
    # frame j's own scale is off by +-1 % (sparse returns). Each end on its own frame's scale moves the
    # plane 0.098 m (1 % of its 9.8 m in frame j) too far or too near; frame j's map times frame i's
    # scale gives the motion.
    motion = np.array([1.0, -0.2, 0.3])
    flow, depth_i, depth_j, w2c_i, w2c_j = plane_scene(motion)
    base_i, base_j = 1.02 * depth_i, 1.02 * depth_j
    scaled_j = base_j / 1.02 * scale_j
    valid = np.ones((H, W), bool)
    own_i, own_j, _ = lift_flow(flow, depth_i, scaled_j, K, w2c_i, w2c_j, valid)
    assert np.abs((own_j - own_i - motion)[:, 2]).mean() == pytest.approx(abs(scale_j - 1) * 9.8, rel=1e-3)
    one_i, one_j, _ = lift_flow(flow, depth_i, base_j, K, w2c_i, w2c_j, valid, target_scale=depth_i / base_i)
    assert np.allclose(one_j - one_i, motion, atol=1e-4)


def test_lift_flow_drops_invalid_depth_and_shape_errors():
    flow, depth_i, depth_j, w2c_i, w2c_j = plane_scene()
    depth_i[:, :10] = np.inf
    points_i, _, pixels = lift_flow(flow, depth_i, depth_j, K, w2c_i, w2c_j, np.ones((H, W), bool))
    assert (pixels[:, 0] >= 10).all() and np.isfinite(points_i).all()
    with pytest.raises(ValueError, match="shapes disagree"):
        lift_flow(flow[:-1], depth_i, depth_j, K, w2c_i, w2c_j, np.ones((H, W), bool))


def test_reject_flow_outliers_per_component():
    mask = np.zeros((H, W), bool)
    mask[10:20, 10:20] = True  # object A
    mask[40:50, 50:60] = True  # object B
    rows, cols = np.nonzero(mask)
    pixels = np.stack([cols, rows], 1).astype(np.float64)
    points_i = np.zeros((len(pixels), 3))
    points_j = np.where(pixels[:, :1] < 30, [1.0, 0.0, 0.0], [0.0, 2.0, 0.0])  # A moves x, B moves y
    points_j = points_j + np.random.default_rng(0).normal(0, 0.01, points_j.shape)
    points_j[0] += [5.0, 0.0, 0.0]  # one gross outlier in A
    keep = reject_flow_outliers(points_i, points_j, pixels, mask)
    assert not keep[0] and keep[1:].mean() > 0.97


def test_two_touching_objects_keep_their_own_motion_with_local_medians():
    # One mask component holding two objects side by side (a car beside another, touching in the
    # image), 2 m apart in depth: 60 % move 1.5 m forward, 40 % 1.5 m forward and 0.5 m sideways.
    mask = np.zeros((H, W), bool)
    mask[10:30, 10:35] = True
    rows, cols = np.nonzero(mask)
    pixels = np.stack([cols, rows], 1).astype(np.float64)
    second = cols >= 25
    rng = np.random.default_rng(1)
    points_i = np.stack([cols * 0.1, rows * 0.1, np.where(second, 22.0, 20.0)], 1)
    flow = np.where(second[:, None], [0.5, 0.0, 1.5], [0.0, 0.0, 1.5]) + rng.normal(0, 0.01, (len(cols), 3))
    flow[3] += [0.0, 0.0, 4.0]  # a gross outlier on the first object
    points_j = points_i + flow
    whole = reject_flow_outliers(points_i, points_j, pixels, mask)
    local = reject_flow_outliers(points_i, points_j, pixels, mask, neighbours=16)
    assert whole[second].mean() < 0.05  # against one median the second object is all "outliers"
    assert local[second].mean() > 0.95 and local[~second].sum() == (~second).sum() - 1 and not local[3]


def test_a_given_target_depth_replaces_the_sample_only_where_they_agree():
    motion = np.array([1.0, -0.2, 0.3])
    flow, depth_i, depth_j, w2c_i, w2c_j = plane_scene(motion)
    valid = np.ones((H, W), bool)
    noisy_j = depth_j * 1.03  # 3 % too far: 0.29 m of false motion along the line of sight
    given = np.full((H, W), np.nan)
    given[:, : W // 2] = 9.8  # the exact depth at j (10 + 0.3 - 0.5) for the left half of frame i's pixels
    given[:10] = 9.8 * 1.5  # beyond the tolerance: the sample stays
    points_i, points_j, pixels = lift_flow(flow, depth_i, noisy_j, K, w2c_i, w2c_j, valid, target_depth=given,
                                           target_depth_tolerance=0.2)
    error = np.abs((points_j - points_i - motion)[:, 2])
    exact = (pixels[:, 0] < W // 2) & (pixels[:, 1] >= 10)
    assert error[exact].max() < 1e-6
    assert error[~exact] == pytest.approx(0.03 * 9.8, rel=1e-3)
