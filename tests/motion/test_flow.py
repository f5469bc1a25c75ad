"""Optical flow, consistency, bilinear sampling and lifting to 3D, against closed forms."""

from __future__ import annotations

import cv2
import numpy as np
import pytest
import torch
from hypothesis import given, settings
from hypothesis import strategies as st

from radar4dgs.motion.flow import (backproject, bilinear_sample, build_raft, consistency_mask, dis_flow,
                                   lift_flow, load_raft, object_translation, raft_flow, reject_flow_outliers,
                                   rigid_object_flow, sample_depth)

# Tiny tensors: on the shared 2-core CI machine extra torch threads only spin.
pytestmark = pytest.mark.usefixtures("one_torch_thread")

K = np.array([[100.0, 0.0, 39.5], [0.0, 100.0, 29.5], [0.0, 0.0, 1.0]])
H, W = 60, 80


def texture(height: int, width: int, seed: int = 0) -> np.ndarray:
    rng = np.random.default_rng(seed)
    return cv2.GaussianBlur((rng.random((height, width)) * 255).astype(np.uint8), (0, 0), 1.5)


def test_dis_recovers_a_known_shift():
    big = texture(220, 360)
    a = np.ascontiguousarray(big[20:200, 20:340])
    b = np.ascontiguousarray(big[18:198, 17:337])  # content moves by (+3, +2) pixels
    for preset in ("fast", "medium"):
        flow = dis_flow(a, b, preset)
        assert flow.shape == (180, 320, 2) and flow.dtype == np.float32
        interior = flow[20:-20, 20:-20].reshape(-1, 2)
        assert np.median(interior, axis=0) == pytest.approx([3.0, 2.0], abs=0.1)
    rgb = np.repeat(a[..., None], 3, axis=2)
    assert np.allclose(dis_flow(rgb, np.repeat(b[..., None], 3, axis=2)), dis_flow(a, b))


def shifted(image: np.ndarray, du: float, dv: float) -> np.ndarray:
    """``image`` with its content moved by (du, dv) pixels (bilinear, edges replicated)."""
    matrix = np.array([[1.0, 0.0, du], [0.0, 1.0, dv]])
    return cv2.warpAffine(image, matrix, image.shape[::-1], flags=cv2.INTER_LINEAR,
                          borderMode=cv2.BORDER_REPLICATE)


@settings(max_examples=12, deadline=None)
@given(du=st.floats(-9.0, 9.0), dv=st.floats(-9.0, 9.0))
def test_object_translation_recovers_a_sub_pixel_shift(du, dv):
    a = texture(90, 160, seed=3)
    b = shifted(a, du, dv)
    rows, cols = np.mgrid[30:60, 50:110]
    pixels = np.stack([cols.ravel(), rows.ravel()], axis=1)
    shift, error = object_translation(a, b, pixels, np.zeros(2), search=12)
    assert shift == pytest.approx([du, dv], abs=0.2)
    assert error < 3.0  # grey levels; the wrong shift costs tens


def test_object_translation_refuses_a_best_shift_on_the_window_border():
    # A wide smooth blob: the error falls steadily towards the true shift, so the best shift in a
    # window too small to hold it is on the window's border.
    v, u = np.mgrid[0:90, 0:160]
    a = (20 + 210 * np.exp(-((u - 80.0) ** 2 + (v - 45.0) ** 2) / (2 * 30.0 ** 2))).astype(np.uint8)
    b = shifted(a, 10.0, 0.0)
    rows, cols = np.mgrid[30:60, 50:110]
    pixels = np.stack([cols.ravel(), rows.ravel()], axis=1)
    assert object_translation(a, b, pixels, np.zeros(2), search=6) is None
    shift, _ = object_translation(a, b, pixels, np.array([8.0, 0.0]), search=6)
    assert shift == pytest.approx([10.0, 0.0], abs=0.2)


def bar_scene(motion: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """A uniformly coloured bar (12 x 60 px, texture only at its two ends) moving ``motion`` px to
    the right over a textured static background: grey images a and b and the bar's mask in a."""
    background = texture(90, 160, seed=5)
    mask = np.zeros((90, 160), dtype=bool)
    mask[40:52, 40:100] = True

    def draw(offset: int) -> np.ndarray:
        image = background.copy()
        image[40:52, 40 + offset:100 + offset] = 200
        image[40:52, 40 + offset:43 + offset] = 30  # dark ends: the only texture
        image[40:52, 97 + offset:100 + offset] = 30
        return image

    return draw(0), draw(motion), mask


def test_rigid_object_flow_fixes_the_aperture_problem_of_a_uniform_object():
    a, b, mask = bar_scene(motion=5)
    dense = dis_flow(a, b, "medium")
    # The premise: inside the bar DIS loses most of the motion.
    assert abs(np.median(dense[mask][:, 0]) - 5.0) > 1.0
    fixed = rigid_object_flow(a, b, dense, mask)
    assert fixed[mask] == pytest.approx(np.tile([5.0, 0.0], (int(mask.sum()), 1)), abs=0.2)
    assert np.array_equal(fixed[~mask], dense[~mask])


def test_rigid_object_flow_keeps_a_dense_flow_that_explains_the_images_better():
    # An object growing by 20 % about its centre (a car coming closer): no translation explains it,
    # the exact dense flow does, so the dense flow stays.
    a = texture(90, 160, seed=6)
    centre = np.array([80.0, 45.0])
    matrix = np.hstack([1.2 * np.eye(2), ((1 - 1.2) * centre)[:, None]])
    b = cv2.warpAffine(a, matrix, (160, 90), flags=cv2.INTER_LINEAR, borderMode=cv2.BORDER_REPLICATE)
    v, u = np.mgrid[0:90, 0:160].astype(np.float32)
    exact = np.stack([0.2 * (u - centre[0]), 0.2 * (v - centre[1])], axis=-1).astype(np.float32)
    mask = (np.abs(u - centre[0]) < 25) & (np.abs(v - centre[1]) < 15)
    assert np.array_equal(rigid_object_flow(a, b, exact, mask), exact)
    # Components below min_pixels are left alone too.
    bar_a, bar_b, bar_mask = bar_scene(motion=5)
    zero = np.zeros((90, 160, 2), dtype=np.float32)
    assert np.array_equal(rigid_object_flow(bar_a, bar_b, zero, bar_mask, min_pixels=10_000), zero)


def test_bilinear_sample_is_exact_on_linear_functions_and_flags_outside():
    v, u = np.mgrid[0:H, 0:W].astype(np.float64)
    image = 2 * u + 3 * v + 1
    xy = np.array([[0.5, 0.5], [10.25, 20.75], [W - 1.0, H - 1.0], [-0.1, 3.0], [3.0, H - 0.5]])
    values, inside = bilinear_sample(image, xy)
    assert inside.tolist() == [True, True, True, False, False]
    assert values[:3] == pytest.approx(2 * xy[:3, 0] + 3 * xy[:3, 1] + 1)
    stacked, _ = bilinear_sample(np.stack([image, -image], axis=-1), xy[:2])
    assert stacked[:, 1] == pytest.approx(-stacked[:, 0])


def test_sample_depth_refuses_edges_and_sky():
    depth = np.full((H, W), 10.0)
    depth[:, 40:] = 30.0  # a depth edge between columns 39 and 40
    depth[0, 0] = np.inf  # sky
    z, valid = sample_depth(depth, np.array([[20.5, 10.0], [39.5, 10.0], [0.5, 0.5], [60.0, 30.0]]), 0.1)
    assert valid.tolist() == [True, False, False, True]
    assert z[0] == pytest.approx(10.0) and z[3] == pytest.approx(30.0)


def test_consistency_mask_constant_flows():
    forward = np.zeros((H, W, 2), np.float32)
    forward[..., 0] = 3.0
    backward = -forward
    mask = consistency_mask(forward, backward)
    assert mask[:, : W - 3].all() and not mask[:, W - 3:].any()  # the last columns leave the image
    wrong = backward.copy()
    wrong[..., 1] = 2.0  # |f_fw + f_bw|^2 = 4 > 0.01 * (9 + 13) + 0.5
    assert not consistency_mask(forward, wrong).any()
    slightly = backward + 0.5  # residual 0.5 px^2 ... (0.5^2 + 0.5^2) = 0.5 < 0.01 * (9 + 6.5) + 0.5
    assert consistency_mask(forward, slightly)[:, : W - 3].all()


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


@pytest.fixture(scope="module")
def raft_checkpoint(tmp_path_factory):
    torch.manual_seed(0)
    network = build_raft("small")
    path = tmp_path_factory.mktemp("raft") / "raft_small.pth"
    torch.save(network.state_dict(), path)
    return path, network


def test_raft_checkpoint_loads_and_matches_the_network(raft_checkpoint, tmp_path):
    path, network = raft_checkpoint
    loaded = load_raft(path, "small")
    for (name, a), b in zip(network.state_dict().items(), loaded.state_dict().values()):
        assert torch.equal(a, b), name
    a = np.repeat(texture(36, 44)[..., None], 3, axis=2)  # not a multiple of 8: exercises padding
    b = np.roll(a, 2, axis=1)
    flow = raft_flow(loaded, a, b, iterations=2)
    assert flow.shape == (36, 44, 2) and np.isfinite(flow).all()
    # wrapped checkpoints ("state_dict", DataParallel "module." prefix) load too
    wrapped = tmp_path / "wrapped.pth"
    torch.save({"state_dict": {f"module.{k}": v for k, v in network.state_dict().items()}}, wrapped)
    again = load_raft(wrapped, "small")
    assert np.allclose(raft_flow(again, a, b, iterations=2), flow, atol=1e-5)


def test_raft_errors_name_the_problem(raft_checkpoint, tmp_path):
    path, _ = raft_checkpoint
    with pytest.raises(FileNotFoundError, match="RAFT checkpoint not found"):
        load_raft(tmp_path / "missing.pth")
    with pytest.raises(ValueError, match="not a torchvision raft_large state dict"):
        load_raft(path, "large")
