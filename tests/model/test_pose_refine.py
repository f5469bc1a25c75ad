"""Pose refinement (issue 27): the SE(3) exponential against scipy and a matrix exponential, a
zero correction that changes no bit of the render, the rasterizer's gradient into the camera pose
against finite differences, and a perturbed pose recovered by optimising it against its image."""

from __future__ import annotations

import dataclasses
import math

import numpy as np
import pytest
import scipy.linalg
import torch
from scipy.spatial.transform import Rotation

from radar4dgs.evaluate.alignment import optimise_view
from radar4dgs.model.config import TrainConfig
from radar4dgs.model.gaussians import GaussianSet
from radar4dgs.model.pose_refine import (
    PoseCorrections,
    camera_centres,
    corrected_directions,
    pose_error,
    refinement_switches,
    se3_exp,
    smoothed_poses,
    smoothed_series,
    so3_exp,
    trajectory_target,
)
from radar4dgs.model.run import Run
from radar4dgs.model.scene_model import SceneModel
from radar4dgs.model.sky import SkyEnvironment, camera_ray_directions
from radar4dgs.model.view import View


def twist_matrix(xi: np.ndarray) -> np.ndarray:
    """The 4x4 se(3) matrix of a twist (rho, omega), for scipy's expm."""
    rho, w = xi[:3], xi[3:]
    out = np.zeros((4, 4))
    out[:3, :3] = [[0, -w[2], w[1]], [w[2], 0, -w[0]], [-w[1], w[0], 0]]
    out[:3, 3] = rho
    return out


@pytest.mark.parametrize("angle", [0.0, 1e-7, 1e-4, 2e-3, 0.049, 0.051, 0.3, 2.5])
def test_se3_exp_matches_scipy_rotation_and_the_matrix_exponential(angle):
    rng = np.random.default_rng(int(angle * 1e7) % 1000)
    axis = rng.normal(size=3)
    omega = axis / np.linalg.norm(axis) * angle
    xi = np.concatenate([rng.normal(size=3), omega])
    ours = se3_exp(torch.as_tensor(xi)).numpy()
    np.testing.assert_allclose(ours[:3, :3], Rotation.from_rotvec(omega).as_matrix(), atol=1e-12)
    np.testing.assert_allclose(ours, scipy.linalg.expm(twist_matrix(xi)), atol=1e-12)
    np.testing.assert_allclose(so3_exp(torch.as_tensor(omega)).numpy(), ours[:3, :3], atol=1e-15)
    # float32 is as good as float32 gets, also across the Taylor switch.
    ours32 = se3_exp(torch.as_tensor(xi, dtype=torch.float32)).numpy()
    np.testing.assert_allclose(ours32, ours, atol=3e-6)


def test_se3_exp_of_zero_is_exactly_the_identity_with_finite_gradients():
    xi = torch.zeros(2, 6, requires_grad=True)
    out = se3_exp(xi)
    assert torch.equal(out, torch.eye(4).expand(2, 4, 4))
    out.sum().backward()
    assert torch.isfinite(xi.grad).all()
    # d(exp(xi) p)/d rho = I and d/d omega = -[p]_x at zero.
    p = torch.tensor([1.0, 2.0, 3.0, 1.0], dtype=torch.float64)
    jac = torch.autograd.functional.jacobian(lambda x: (se3_exp(x) @ p)[:3], torch.zeros(6, dtype=torch.float64))
    np.testing.assert_allclose(jac[:, :3].numpy(), np.eye(3), atol=1e-12)
    np.testing.assert_allclose(jac[:, 3:].numpy(), [[0, 3, -2], [-3, 0, 1], [2, -1, 0]], atol=1e-12)


def test_pose_error():
    truth = np.eye(4)
    moved = np.eye(4)
    moved[:3, :3] = Rotation.from_rotvec([0.0, 0.0, math.radians(2.0)]).as_matrix()
    moved[:3, 3] = -moved[:3, :3] @ np.array([0.0, 0.3, 0.4])  # camera centre at (0, 0.3, 0.4)
    t, r = pose_error(moved, truth)
    assert t == pytest.approx(0.5, abs=1e-9) and r == pytest.approx(2.0, abs=1e-9)


def drive(times: np.ndarray) -> np.ndarray:
    """(N, 4, 4) world-to-camera of a car-mounted camera (OpenCV axes, looking along the path) on a
    gentle left curve at 10 m/s: heading 0.2 rad/s, 1.5 m up; a smooth path as a real drive's."""
    heading = 0.2 * times
    centres = np.stack([50 * np.sin(heading), 50 * (1 - np.cos(heading)), np.full_like(times, 1.5)], axis=1)
    out = np.tile(np.eye(4), (len(times), 1, 1))
    for i, (h, c) in enumerate(zip(heading, centres, strict=True)):
        forward, left, up = np.array([np.cos(h), np.sin(h), 0.0]), np.array([-np.sin(h), np.cos(h), 0.0]), np.eye(3)[2]
        rotation = np.stack([-left, -up, forward])  # rows: camera x (right), y (down), z (forward)
        out[i, :3, :3] = rotation
        out[i, :3, 3] = -rotation @ c
    return out


def noisy(w2c: np.ndarray, seed: int, metres: float = 0.10, degrees: float = 0.3) -> np.ndarray:
    """``w2c`` (N, 4, 4) with independent per-frame noise in camera axes (as benchmarks/poses.py)."""
    rng = np.random.default_rng(seed)
    xi = np.concatenate([rng.normal(0, metres, (len(w2c), 3)), np.radians(rng.normal(0, degrees, (len(w2c), 3)))], 1)
    return se3_exp(torch.as_tensor(xi)).numpy() @ w2c


def test_the_smoothing_spline_keeps_a_smooth_series_and_averages_out_noise():
    t = np.arange(20) * 0.1
    smooth = np.stack([3 * t, 0.5 * t ** 2 - t, np.sin(t)], axis=1)
    np.testing.assert_allclose(smoothed_series(t, smooth), smooth, atol=2e-3)
    np.testing.assert_allclose(smoothed_series(t, smooth, np.array([0.55])), [[1.65, -0.39875, np.sin(0.55)]],
                               atol=2e-3)
    rng = np.random.default_rng(0)
    errors = [np.abs(smoothed_series(t, smooth + rng.normal(0, 0.1, smooth.shape)) - smooth).mean()
              for _ in range(20)]
    assert np.mean(errors) < 0.045  # the noise's own mean |error| is 0.080
    # Fewer than 5 samples: linear interpolation, held at the ends.
    np.testing.assert_allclose(smoothed_series(np.array([0.0, 1.0]), np.array([[0.0], [2.0]]), np.array([0.25, 3.0])),
                               [[0.5], [2.0]])


def test_the_trajectory_target_recovers_a_smooth_drive_from_independent_pose_noise():
    """15 training frames at 10 Hz (every 4th of 20 held out, as the synthetic scenes), 0.10 m and
    0.3 deg of noise per axis: the target puts the cameras on a trajectory nearly 2x closer to the
    truth (mean over 10 draws: 0.156 -> 0.085 m; the noise's mean over the frames, 0.04 m, stays),
    and leaves an exact trajectory where it is."""
    t = np.array([i * 0.1 for i in range(20) if i % 4 != 3])
    truth = drive(t)
    assert np.abs(trajectory_target(t, truth)).max() < 2e-3
    before, after = [], []
    for seed in range(10):
        recorded = noisy(truth, seed)
        target = trajectory_target(t, recorded)
        assert np.all(target[:, 3:] == 0)
        moved = se3_exp(torch.as_tensor(target)).numpy() @ recorded
        before.append(np.linalg.norm(camera_centres(recorded) - camera_centres(truth), axis=1).mean())
        after.append(np.linalg.norm(camera_centres(moved) - camera_centres(truth), axis=1).mean())
        np.testing.assert_allclose(moved[:, :3, :3], recorded[:, :3, :3], atol=1e-12)  # orientation kept
    assert np.mean(before) == pytest.approx(0.16, abs=0.02)
    assert np.mean(after) < 0.6 * np.mean(before), (np.mean(before), np.mean(after))


def test_a_test_camera_on_the_smoothed_trajectory():
    """Held-out frames' poses from the training cameras: exact on an exact drive; with noisy
    training cameras, closer to the truth than linear interpolation of the two neighbours."""
    t_all = np.arange(20) * 0.1
    train, test = t_all[np.arange(20) % 4 != 3], t_all[np.arange(20) % 4 == 3]
    exact = [pose_error(got, want) for got, want in zip(smoothed_poses(train, drive(train), test), drive(test),
                                                        strict=True)]
    assert max(t for t, _ in exact[:-1]) < 2e-4 and max(r for _, r in exact) < 0.01
    # The last test frame lies 0.1 s past the last training frame: the spline goes on straight
    # (its second derivative is 0 at the ends) while the car turns, 2 m/s^2 sideways: 0.02 m off,
    # twice 1/2 a t^2 (the end slope is off too). A measured number, not a closed form.
    assert exact[-1][0] == pytest.approx(0.5 * 2.0 * 0.1 ** 2 * 2, rel=0.1)
    smoothed_err, linear_err = [], []
    for seed in range(10):
        recorded = noisy(drive(train), seed)
        got = smoothed_poses(train, recorded, test)
        centres = camera_centres(recorded)
        linear = np.stack([np.interp(test, train, centres[:, j]) for j in range(3)], 1)
        truth = camera_centres(drive(test))
        smoothed_err.append(np.linalg.norm(camera_centres(got) - truth, axis=1).mean())
        linear_err.append(np.linalg.norm(linear - truth, axis=1).mean())
        assert max(pose_error(g, w)[1] for g, w in zip(got, drive(test), strict=True)) < 0.4
    assert np.mean(smoothed_err) < 0.6 * np.mean(linear_err), (np.mean(smoothed_err), np.mean(linear_err))


def test_corrections_start_at_their_target_and_keep_its_mean():
    rng = np.random.default_rng(1)
    target = np.concatenate([rng.normal(0, 0.1, (6, 3)), np.zeros((6, 3))], 1)
    poses = PoseCorrections(6, dtype=torch.float64, target=target)
    np.testing.assert_array_equal(poses.xi.detach().numpy(), target)
    assert float(poses.prior().detach()) == 0.0 and float(poses.smoothness().detach()) == 0.0
    with torch.no_grad():
        poses.translation += torch.tensor([0.3, 0.0, -0.2], dtype=torch.float64)  # a common shift: the gauge
        poses.translation[2, 0] += 0.06
    assert float(poses.prior().detach()) > 0
    poses.remove_mean()
    deviation = poses.xi.detach().numpy() - target
    np.testing.assert_allclose(deviation.mean(0), 0.0, atol=1e-15)
    np.testing.assert_allclose(deviation[2, 0], 0.05, atol=1e-12)  # the frame's own deviation stays
    again = PoseCorrections.from_state(poses.state(), dtype=torch.float64)
    assert torch.equal(again.xi, poses.xi) and torch.equal(again.target, poses.target)
    old = PoseCorrections.from_state({k: v for k, v in poses.state().items() if k != "target"})
    assert torch.count_nonzero(old.target) == 0  # a checkpoint without a target: the recorded poses


def test_refinement_is_on_for_odometry_poses_and_appearance_for_recorded_scenes():
    assert refinement_switches("auto", "auto", {"dataset": "aimotive", "poses_from_radar": True}) == (True, True)
    assert refinement_switches("auto", "auto", {"dataset": "synthetic"}) == (False, False)
    assert refinement_switches("auto", "auto", {"dataset": "synthetic", "poses_from_odometry": True}) == (True, False)
    assert refinement_switches("on", "off", {"dataset": "aimotive", "poses_from_radar": True}) == (True, False)
    assert refinement_switches("off", "on", {}) == (False, True)
    # By default: odometry poses refined (issue 27), exposure left alone, exact poses untouched.
    defaults = TrainConfig().poses
    assert refinement_switches(defaults.refine, defaults.appearance,
                               {"dataset": "aimotive", "poses_from_radar": True}) == (True, False)
    assert refinement_switches(defaults.refine, defaults.appearance, {"dataset": "synthetic"}) == (False, False)


def look_at(eye, target=(0.0, 0.0, 0.0), up=(0.0, -1.0, 0.0)) -> np.ndarray:
    """World-to-camera (4, 4), OpenCV axes, camera at ``eye`` looking at ``target``."""
    eye, target, up = (np.asarray(v, dtype=np.float64) for v in (eye, target, up))
    z = (target - eye) / np.linalg.norm(target - eye)
    x = np.cross(z, up)
    x /= np.linalg.norm(x)
    y = np.cross(z, x)
    out = np.eye(4)
    out[:3, :3] = np.stack([x, y, z])
    out[:3, 3] = -out[:3, :3] @ eye
    return out


def textured_model(seed: int = 0, n: int = 400, dtype: torch.dtype = torch.float32) -> SceneModel:
    """n opaque, small, randomly coloured Gaussians in a 4 m box around the origin and a sky."""
    rng = np.random.default_rng(seed)
    points = rng.uniform(-2.0, 2.0, (n, 3))
    gaussians = GaussianSet.from_points(points, rng.uniform(0, 1, (n, 3)), init_opacity=0.8, dtype=dtype)
    with torch.no_grad():
        gaussians.params["log_scales"].fill_(math.log(0.12))
    sky = SkyEnvironment(8, 16, init_color=(0.3, 0.5, 0.8), dtype=dtype)
    return SceneModel(gaussians, sky).eval()


def camera(w2c: np.ndarray, width: int = 48, height: int = 32) -> View:
    K = np.array([[40.0, 0, width / 2 - 0.5], [0, 40.0, height / 2 - 0.5], [0, 0, 1]])
    return View(w2c, K, width, height, 0.5)


def test_a_zero_correction_leaves_the_render_bit_identical():
    model = textured_model()
    view = camera(look_at((0.3, -0.5, -6.0)))
    directions = camera_ray_directions(view.K, view.world_to_camera, view.height, view.width)
    plain = model.render(view, directions=directions)
    poses = PoseCorrections(3)
    recorded = torch.as_tensor(view.world_to_camera, dtype=torch.float32)
    delta = poses.delta(1)
    corrected = dataclasses.replace(view, world_to_camera=delta @ recorded)
    refined = model.render(corrected, directions=corrected_directions(directions, recorded, delta))
    for key in ("rgb", "alpha", "depth", "dynamic"):
        assert torch.equal(plain[key], refined[key]), key


def test_the_render_backpropagates_into_the_camera_pose():
    """The torch rasterizer's gradient w.r.t. the correction against central finite differences
    (float64 throughout)."""
    f64 = torch.float64
    model = textured_model(1, 150, f64)
    view = camera(look_at((0.2, -0.3, -6.0)), 24, 16)
    recorded = torch.as_tensor(view.world_to_camera, dtype=f64)
    directions = camera_ray_directions(view.K, view.world_to_camera, view.height, view.width, dtype=f64)
    weights = torch.rand(view.height, view.width, 3, generator=torch.Generator().manual_seed(0), dtype=f64)

    def loss(xi: torch.Tensor) -> torch.Tensor:
        delta = se3_exp(xi)
        moved = dataclasses.replace(view, world_to_camera=delta @ recorded)
        out = model.render(moved, directions=corrected_directions(directions, recorded, delta))
        return (out["rgb"] * weights).sum() + out["depth"].sum() * 0.01

    xi = torch.tensor([0.02, -0.01, 0.03, 0.004, -0.003, 0.002], dtype=f64, requires_grad=True)
    loss(xi).backward()
    analytic = xi.grad.numpy()
    numeric = np.zeros(6)
    with torch.no_grad():
        for j in range(6):
            e = torch.zeros(6, dtype=f64)
            e[j] = 1e-6
            numeric[j] = (float(loss(xi + e)) - float(loss(xi - e))) / 2e-6
    assert np.abs(analytic).max() > 1.0
    np.testing.assert_allclose(analytic, numeric, rtol=1e-3, atol=1e-4 * np.abs(numeric).max())


def test_optimising_a_perturbed_pose_alone_against_its_image_reduces_its_error():
    """One frame's pose perturbed by 0.10 m and 0.6 deg; 60 steps of the pose alone, scene frozen."""
    model = textured_model(2)
    truth = look_at((0.0, -0.5, -6.0))
    target = camera(truth)
    with torch.no_grad():
        image = model.render(target)["rgb"]
    offset = se3_exp(torch.tensor([0.06, -0.05, 0.06, 0.006, -0.004, 0.005], dtype=torch.float64)).numpy()
    start = camera(offset @ truth)
    before = pose_error(start.world_to_camera, truth)
    config = TrainConfig()
    run = Run(root=None, scene=None, prepared=None, config=config, model=model)
    optimised, info = optimise_view(run, start, image, steps=60, lr=5e-3)
    after = pose_error(optimised.world_to_camera, truth)
    assert before[0] == pytest.approx(0.1, abs=0.01) and before[1] > 0.4
    assert after[0] < 0.3 * before[0] and after[1] < 0.5 * before[1], (before, after)
    assert info["l1_end"] < 0.5 * info["l1_start"]
    assert all(p.requires_grad for p in model.parameters())  # the model is unfrozen afterwards
