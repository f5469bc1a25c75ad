"""The typed scene classes: pose chains, on-demand loaders that repair or refuse per-frame files,
the alignment of per-row labels with the radar rows kept on load, and the train/test split."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from radar4dgs.io.scene_format import SceneError, SceneWarning
from radar4dgs.io.scene_read import read_scene
from radar4dgs.io.scene_types import split_indices


def test_world_to_camera_inverts_the_chain(valid_scene):
    scene = read_scene(valid_scene)
    point_cam = np.array([0.5, -0.2, 7.0, 1.0])
    world = scene.frames[1].ego_to_world @ scene.camera.cam_to_ego @ point_cam
    np.testing.assert_allclose(scene.world_to_camera(1) @ world, point_cam, atol=1e-12)


def test_nan_radar_rows_are_dropped_with_a_counting_warning(scene_copy):
    points = np.ones((6, 5), np.float32)
    points[1, 0] = np.nan
    points[4, 3] = np.inf
    points[5, 4] = np.nan  # rcs is optional: a NaN there keeps the row
    np.save(scene_copy / "radar" / "000001.npy", points)
    scene = read_scene(scene_copy)
    with pytest.warns(SceneWarning, match=r"000001\.npy: dropped 2 of 6 radar rows"):
        scan = scene.load_radar(1)
    assert len(scan) == 4 and np.isfinite(scan.xyz).all()


def test_per_row_labels_align_with_the_rows_kept_on_load(scene_copy):
    points = np.ones((5, 5), np.float32)
    points[[1, 3], 2] = np.nan
    np.save(scene_copy / "radar" / "000001.npy", points)
    with pytest.warns(SceneWarning):
        scan = read_scene(scene_copy).load_radar(1)
    labels = np.array([0, 1, -1, 1, 0], np.int8)
    np.testing.assert_array_equal(scan.align(labels, "labels.npy"), [0, -1, 0])
    with pytest.raises(SceneError, match=r"labels\.npy: 4 entries for 5 stored radar rows"):
        scan.align(labels[:4], "labels.npy")


def test_empty_radar_frame_is_allowed_and_warned(scene_copy):
    np.save(scene_copy / "radar" / "000000.npy", np.zeros((0, 5), np.float32))
    scene = read_scene(scene_copy)
    with pytest.warns(SceneWarning, match="empty radar frame"):
        assert len(scene.load_radar(0)) == 0


def test_optional_array_of_wrong_shape(scene_copy):
    np.save(scene_copy / "gt" / "depth" / "000001.npy", np.zeros((3, 3), np.float32))
    scene = read_scene(scene_copy)
    with pytest.raises(SceneError, match=r"gt/depth/000001\.npy: array has shape \(3, 3\)"):
        scene.load_optional("gt/depth", 1)


@settings(max_examples=50, deadline=None)
@given(num_frames=st.integers(0, 60), test_every=st.integers(-1, 10))
def test_split_partitions_frames(num_frames, test_every):
    train, test = split_indices(num_frames, test_every)
    assert sorted(train + test) == list(range(num_frames))
    assert not set(train) & set(test)
    if test_every > 0:
        assert test == [i for i in range(num_frames) if (i + 1) % test_every == 0]
        assert len(test) == num_frames // test_every
    else:
        assert test == []
