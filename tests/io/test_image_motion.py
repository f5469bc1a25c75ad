"""Image motion of dynamic pixels from gt depth, flow and poses, against closed-form pinhole motion."""

from __future__ import annotations

import numpy as np
from hypothesis import given, settings
from hypothesis import strategies as st

from _motion_scene import CV_TO_EGO, F, K, translation, write_scene
from radar4dgs.io import read_scene
from radar4dgs.io.image_motion import (
    dynamic_pixel_motion,
    dynamic_pixel_motion_map,
    project_motion,
    scene_dynamic_pixel_motion,
)
from radar4dgs.io.scene_types import Camera, Frame, RadarSpec
from radar4dgs.io.scene_write import SceneWriter


@settings(max_examples=50, deadline=None)
@given(depth=st.floats(2.0, 80.0), dx=st.floats(-3.0, 3.0), dy=st.floats(-3.0, 3.0),
       u=st.floats(0.0, 79.0), v=st.floats(0.0, 59.0))
def test_a_point_moving_parallel_to_the_image_plane_moves_f_times_its_shift_over_depth(depth, dx, dy, u, v):
    """Static camera (camera frame = world frame): a shift (dx, dy) at depth z moves f |(dx, dy)| / z px."""
    motion = project_motion(K, np.eye(4), np.eye(4), np.array([[u, v]]), np.array([depth]),
                            np.array([[dx, dy, 0.0]]), inside=None)
    assert np.isclose(motion[0], F * np.hypot(dx, dy) / depth, rtol=1e-9, atol=1e-9)


@settings(max_examples=50, deadline=None)
@given(depth=st.floats(5.0, 80.0), forward=st.floats(0.0, 4.0), du=st.floats(-40.0, 40.0),
       dv=st.floats(-30.0, 30.0))
def test_a_camera_moving_forward_expands_the_image_about_the_principal_point(depth, forward, du, dv):
    """A static point (zero flow) at depth z and offset r px from the principal point moves
    r * forward / (z - forward) px when the camera advances along its axis."""
    next_cam = translation(0.0, 0.0, -forward)  # world -> next camera: the camera moved +forward along z
    uv = np.array([[K[0, 2] + du, K[1, 2] + dv]])
    motion = project_motion(K, np.eye(4), next_cam, uv, np.array([depth]), np.zeros((1, 3)), inside=None)
    assert np.isclose(motion[0], np.hypot(du, dv) * forward / (depth - forward), rtol=1e-9, atol=1e-9)


def test_points_behind_the_next_camera_or_outside_its_image_are_left_out():
    uv = np.array([[40.0, 30.0], [40.0, 30.0], [40.0, 30.0]])
    depth = np.array([10.0, 10.0, 10.0])
    flow = np.array([[0.0, 0.0, 0.0], [0.0, 0.0, -10.5], [5.0, 0.0, 0.0]])  # stays, behind, leaves sideways
    assert np.allclose(project_motion(K, np.eye(4), np.eye(4), uv, depth, flow, inside=None), [0.0, 50.0])
    assert np.allclose(project_motion(K, np.eye(4), np.eye(4), uv, depth, flow, inside=(80, 60)), [0.0])


def test_dynamic_pixel_motion_of_a_scene(tmp_path):
    scene = write_scene(tmp_path / "scene")
    v, u = np.nonzero(np.pad(np.ones((4, 4), bool), ((28, 28), (38, 38))))
    for i in range(2):
        z = 10.0 - i
        # world y = camera -x: the block moves +0.2 m to the camera's right, and the forward step
        # of 1 m scales every offset from the principal point by z / (z - 1).
        x_cam, y_cam = (u - K[0, 2]) / F * z + 0.2, (v - K[1, 2]) / F * z
        expected = np.hypot(F * x_cam / (z - 1) + K[0, 2] - u, F * y_cam / (z - 1) + K[1, 2] - v)
        assert np.allclose(np.sort(dynamic_pixel_motion(scene, i)), np.sort(expected), atol=1e-4)
        motion_map = dynamic_pixel_motion_map(scene, i)  # each value at its own pixel
        assert np.allclose(motion_map[v, u], expected, atol=1e-4)
        assert np.isnan(motion_map).sum() == 60 * 80 - 16
    assert np.isnan(dynamic_pixel_motion_map(scene, 2)).all()
    assert dynamic_pixel_motion(scene, 2).shape == (0,)  # the last frame has no next one
    assert scene_dynamic_pixel_motion(scene).shape == (32,)


def test_no_dynamic_pixels_no_motion(tmp_path):
    scene = write_scene(tmp_path / "scene", flow_y=0.0)
    empty = tmp_path / "empty"
    camera = Camera(80, 60, K, CV_TO_EGO)
    with SceneWriter(empty) as writer:
        for i in range(2):
            writer.add_frame(Frame(f"{i:06d}", 0.1 * i, np.eye(4), 0.1 * i, np.eye(4)), np.zeros((60, 80, 3), np.uint8),
                             np.zeros((1, 4), np.float32), gt_depth=np.ones((60, 80), np.float32),
                             gt_dynamic_mask=np.zeros((60, 80), bool), gt_flow=np.zeros((60, 80, 3), np.float32))
        writer.finish("empty", camera, RadarSpec(np.eye(4), ("x", "y", "z", "v_r")))
    assert dynamic_pixel_motion(read_scene(empty), 0).shape == (0,)
    assert len(dynamic_pixel_motion(scene, 0)) == 16
