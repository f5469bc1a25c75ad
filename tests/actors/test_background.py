"""Never-observed pixels (radar4dgs.actors.background) on a closed-form camera and ground plane."""

from __future__ import annotations

import numpy as np

from radar4dgs.actors.background import TrainingView, backproject, seen_in

K = np.array([[50.0, 0, 31.5], [0, 50.0, 23.5], [0, 0, 1]])
# A camera 1.5 m above the ground looking along world +x (OpenCV axes: x right, y down, z forward).
W2C = np.array([[0, -1, 0, 0], [0, 0, -1, 1.5], [1, 0, 0, 0], [0, 0, 0, 1]], dtype=float)


def ground_depth(height: int = 48, width: int = 64) -> np.ndarray:
    """(H, W) z-depth of the ground plane z = 0 seen by W2C (NaN above the horizon)."""
    rows = np.arange(height)[:, None] + np.zeros((1, width))
    slope = (rows - K[1, 2]) / K[1, 1]  # camera y / z of the ray; the ground is 1.5 m below
    return np.where(slope > 1e-6, 1.5 / np.maximum(slope, 1e-6), np.nan)


def test_backprojected_ground_pixels_lie_on_the_ground():
    depth = ground_depth()
    pixels = np.argwhere(np.isfinite(depth))
    points = backproject(depth, K, W2C, pixels)
    assert np.allclose(points[:, 2], 0.0, atol=1e-9) and (points[:, 0] > 1.5).all()


def test_a_point_is_seen_unless_outside_occluded_or_under_a_dynamic_object():
    depth = ground_depth()
    dynamic = np.zeros_like(depth)
    view = TrainingView(W2C, K, depth, dynamic)
    point = backproject(depth, K, W2C, np.array([[40, 20]]))
    assert seen_in(point, view).all()
    behind = TrainingView(W2C, K, depth * 0.5, dynamic)  # a nearer surface in front of it
    assert not seen_in(point, behind).any()
    covered = dynamic.copy()
    covered[40, 20] = 0.9  # a car over that pixel in this training frame
    assert not seen_in(point, TrainingView(W2C, K, depth, covered)).any()
    assert not seen_in(point + np.array([-10.0, 0, 0]), view).any()  # behind the camera


def test_the_default_tolerance_accepts_a_rough_static_surface_that_a_tight_one_rejects():
    # A short training's static depths are off by 10-30 %: the same surface all the same.
    depth = ground_depth()
    point = backproject(depth, K, W2C, np.array([[40, 20]]))
    rough = TrainingView(W2C, K, depth * 1.15, np.zeros_like(depth))
    assert seen_in(point, rough).all()
    assert not seen_in(point, rough, tolerance=(0.05, 0.3)).any()
