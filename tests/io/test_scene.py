"""The scene folder through its public entry point: a valid scene written with the writer reads
back with everything it was given (SCENE_FORMAT.md round trip)."""

from __future__ import annotations

import numpy as np
import pytest

# pytest puts this folder on sys.path (rootdir-relative "prepend" imports), as for the other helpers.
from _scene_helpers import FRAMES, HEIGHT, WIDTH, pose

from radar4dgs.io.scene import read_scene


def test_round_trip_keeps_everything(valid_scene):
    scene = read_scene(valid_scene)
    assert scene.name == "unit" and len(scene) == FRAMES and scene.test_every == 3
    assert scene.source == {"dataset": "unit-test"} and scene.extra == {"note": 1}
    assert scene.frames[2].extra == {"weather": "dry"}
    np.testing.assert_allclose(scene.frames[3].ego_to_world, pose(3.0, 0.03))
    np.testing.assert_allclose(scene.frames[3].radar_ego_to_world, pose(3.1))
    assert scene.frames[3].radar_timestamp == pytest.approx(0.31)
    assert scene.load_image(0).shape == (HEIGHT, WIDTH, 3)
    radar = scene.load_radar(4)
    assert radar.data.shape == (9, 5) and radar.xyz.shape == (9, 3)
    np.testing.assert_array_equal(radar.v_r, radar.data[:, 3])
    assert scene.optional_folders() == ["gt/depth", "gt/dynamic_mask", "gt/radar_labels"]
    assert scene.load_optional("gt/dynamic_mask", 0).dtype == bool
    assert scene.train_indices == [0, 1, 3, 4] and scene.test_indices == [2, 5]
    assert scene.duration == pytest.approx(0.5)
