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
    corrected_directions,
    interpolate_corrections,
    pose_error,
    refinement_switches,
    se3_exp,
    so3_exp,
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


def test_pose_error_and_interpolation():
    truth = np.eye(4)
    moved = np.eye(4)
    moved[:3, :3] = Rotation.from_rotvec([0.0, 0.0, math.radians(2.0)]).as_matrix()
    moved[:3, 3] = -moved[:3, :3] @ np.array([0.0, 0.3, 0.4])  # camera centre at (0, 0.3, 0.4)
    t, r = pose_error(moved, truth)
    assert t == pytest.approx(0.5, abs=1e-9) and r == pytest.approx(2.0, abs=1e-9)
    xi = np.array([[0, 0, 0, 0, 0, 0], [1, 2, 3, 4, 5, 6.0]])
    np.testing.assert_allclose(interpolate_corrections(np.array([0.0, 1.0]), xi, np.array([0.25, 2.0])),
                               [[0.25, 0.5, 0.75, 1.0, 1.25, 1.5], [1, 2, 3, 4, 5, 6]])


def test_refinement_is_on_for_odometry_poses_and_appearance_for_recorded_scenes():
    assert refinement_switches("auto", "auto", {"dataset": "aimotive", "poses_from_radar": True}) == (True, True)
    assert refinement_switches("auto", "auto", {"dataset": "synthetic"}) == (False, False)
    assert refinement_switches("auto", "auto", {"dataset": "synthetic", "poses_from_odometry": True}) == (True, False)
    assert refinement_switches("on", "off", {"dataset": "aimotive", "poses_from_radar": True}) == (True, False)
    assert refinement_switches("off", "on", {}) == (False, True)


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
