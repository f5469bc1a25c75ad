"""Scene previews: the summary's numbers and the radar projection against hand computation."""

from __future__ import annotations

import numpy as np
import pytest

# pytest puts this folder on sys.path (rootdir-relative "prepend" imports), as for the other helpers.
from _scene_helpers import FRAMES, HEIGHT, WIDTH, write_valid_scene

from radar4dgs.io.preview import contact_sheet, doppler_colors, format_summary, radar_points_in_camera, summarize_scene
from radar4dgs.io.scene import read_scene


@pytest.fixture(scope="module")
def scene(tmp_path_factory):
    return read_scene(write_valid_scene(tmp_path_factory.mktemp("inspect") / "scene"))


def test_summary_numbers(scene):
    summary = summarize_scene(scene)
    assert summary["frames"] == FRAMES and summary["image_size"] == [WIDTH, HEIGHT]
    assert summary["radar_points_per_frame"] == {"min": 5, "median": 7.5, "max": 10, "total": 45}
    # Poses move 1 m per 0.1 s.
    assert summary["ego_speed_from_poses_mps"]["mean"] == pytest.approx(10.0)
    assert summary["ego_speed_from_ego_velocity_mps"] == pytest.approx(10.0)
    assert summary["split"] == {"test_every": 3, "train": 4, "test": 2, "test_frames": ["000002", "000005"]}
    assert summary["frame_rate_hz"] == pytest.approx(10.0)


def test_radar_point_lands_where_the_chain_says(scene):
    # Frame 2: the radar pose is 0.1 m ahead of the camera's ego pose and unrotated, the camera pose is
    # rotated by 0.02 rad; a point 10 m straight ahead of the radar, by hand:
    point_radar = np.array([[10.0, 0.0, 0.0]])
    world = 2.0 + 0.1 + 3.6 + 10.0  # ego x at radar time + radar mount + range
    camera = radar_points_in_camera(scene, 2, point_radar)[0]
    yaw = 0.02
    ego = np.array([np.cos(yaw) * (world - 2.0), -np.sin(yaw) * (world - 2.0), 0.0])  # world -> ego frame 2
    expected = np.array([-(ego[1] - 0.0), -(ego[2] - 1.5), ego[0] - 1.5])  # ego -> OpenCV camera
    np.testing.assert_allclose(camera, expected, atol=1e-9)


def test_doppler_colours_are_symmetric():
    colors = doppler_colors(np.array([-5.0, 0.0, 5.0, 50.0]), limit=5.0)
    assert colors[1].tolist() == [255, 255, 255]
    assert colors[0, 2] > colors[0, 0] and colors[2, 0] > colors[2, 2]
    np.testing.assert_array_equal(colors[2], colors[3])


def test_contact_sheet_shape(scene):
    sheet = contact_sheet(scene, num_frames=3, tile_width=64)
    assert sheet.dtype == np.uint8 and sheet.shape == (2 * 48 + 28, 128, 3)


def test_motion_statistics_need_ground_truth(scene):
    assert summarize_scene(scene)["dynamic_pixel_motion_px"] is None
    assert "motion     n/a (needs gt/dynamic_mask, gt/depth and gt/flow)" in format_summary(summarize_scene(scene))


def test_motion_statistics_of_a_synthetic_scene(motion_scene):
    from radar4dgs.io.image_motion import scene_dynamic_pixel_motion

    motion = summarize_scene(motion_scene)["dynamic_pixel_motion_px"]
    pooled = scene_dynamic_pixel_motion(motion_scene)
    assert motion["pixels"] == len(pooled) > 0
    assert motion["p50"] <= motion["p90"] <= motion["p99"] <= motion["max"]
    assert motion["p90"] == round(float(np.percentile(pooled, 90)), 2)
