"""The scene-folder reader against SCENE_FORMAT.md: a folder written by another tool loads, and
every validation rule refuses a broken scene with an error naming the file and the problem."""

from __future__ import annotations

import json

import numpy as np
import pytest

# pytest puts this folder on sys.path (rootdir-relative "prepend" imports), as for the other helpers.
from _scene_helpers import HEIGHT, WIDTH, edit_json
from PIL import Image

from radar4dgs.io.scene_format import SceneError
from radar4dgs.io.scene_read import read_scene


def test_scene_written_by_another_tool_loads(tmp_path):
    """A minimal hand-written folder (JPEG images, no optional keys) follows the spec and must load."""
    root = tmp_path / "foreign"
    (root / "images").mkdir(parents=True)
    (root / "radar").mkdir()
    frames = []
    for i in range(3):
        Image.new("RGB", (8, 4), (i, 2 * i, 3)).save(root / "images" / f"f{i}.jpg")
        np.save(root / "radar" / f"f{i}.npy", np.zeros((2, 4), np.float32))
        frames.append({"name": f"f{i}", "timestamp": 100.0 + i, "ego_to_world": np.eye(4).tolist()})
    meta = {"format": "radar4dgs-scene", "version": 1,
            "camera": {"width": 8, "height": 4, "K": [[4, 0, 4], [0, 4, 2], [0, 0, 1]],
                       "cam_to_ego": np.eye(4).tolist()},
            "radar": {"radar_to_ego": np.eye(4).tolist(), "fields": ["x", "y", "z", "v_r"]},
            "frames": frames}
    (root / "scene.json").write_text(json.dumps(meta))
    scene = read_scene(root)
    assert scene.name == "foreign" and scene.test_every == 4
    assert scene.frames[1].radar_timestamp == 101.0
    np.testing.assert_array_equal(scene.frames[1].radar_ego_to_world, np.eye(4))
    assert scene.load_image(2).shape == (4, 8, 3)


# ---------------------------------------------------------------- one test per validation rule


def _break_rotation(meta):
    meta["frames"][2]["ego_to_world"][0][0] = 2.0


def _break_shape(meta):
    meta["camera"]["cam_to_ego"] = [[1, 0, 0], [0, 1, 0], [0, 0, 1]]


def _break_timestamps(meta):
    meta["frames"][3]["timestamp"] = meta["frames"][1]["timestamp"]


def _break_radar_timestamps(meta):
    meta["frames"][4]["radar_timestamp"] = 0.0


def _break_fields(meta):
    meta["radar"]["fields"] = ["x", "y", "z", "rcs", "snr"]


def _break_format(meta):
    meta["format"] = "nerfstudio"


def _break_version(meta):
    meta["version"] = 2


def _break_mirror(meta):
    meta["radar"]["radar_to_ego"] = np.diag([1.0, 1.0, -1.0, 1.0]).tolist()


def _break_duplicate_names(meta):
    meta["frames"][1]["name"] = meta["frames"][0]["name"]


def _break_nan_matrix(meta):
    meta["frames"][0]["ego_to_world"][0][3] = "nan"


def _break_text_matrix(meta):
    meta["frames"][0]["ego_to_world"][0][3] = "left"


def _break_camera_size(meta):
    meta["camera"]["width"] = WIDTH + 1


@pytest.mark.parametrize("edit, message", [
    (_break_rotation, "frames[2].ego_to_world: rotation block is not orthonormal"),
    (_break_shape, "camera.cam_to_ego has shape (3, 3), expected 4x4"),
    (_break_mirror, "radar.radar_to_ego: rotation block is not orthonormal with det +1"),
    (_break_timestamps, "timestamps do not increase: frames[2]"),
    (_break_radar_timestamps, "radar_timestamps do not increase: frames[3]"),
    (_break_fields, "radar.fields lacks required columns ['v_r']"),
    (_break_format, "'format' is 'nerfstudio'"),
    (_break_version, "'version' is 2"),
    (_break_duplicate_names, "duplicate frame names ['000000']"),
    (_break_nan_matrix, "frames[0].ego_to_world contains NaN or inf"),
    (_break_text_matrix, "frames[0].ego_to_world is not a numeric 4x4 matrix"),
    (_break_camera_size, "image is 16x12, camera says 17x12"),
])
def test_broken_metadata_is_refused(scene_copy, edit, message):
    edit_json(scene_copy, edit)
    with pytest.raises(SceneError) as info:
        read_scene(scene_copy)
    assert message in str(info.value)
    assert str(scene_copy) in str(info.value)


def test_missing_scene_json(scene_copy):
    (scene_copy / "scene.json").unlink()
    with pytest.raises(SceneError, match=r"scene\.json: missing file"):
        read_scene(scene_copy)


def test_unreadable_scene_json(scene_copy):
    (scene_copy / "scene.json").write_text("{not json")
    with pytest.raises(SceneError, match=r"scene\.json: unreadable JSON"):
        read_scene(scene_copy)


def test_missing_image(scene_copy):
    (scene_copy / "images" / "000003.png").unlink()
    with pytest.raises(SceneError, match=r"images/000003\.png: missing image"):
        read_scene(scene_copy)


def test_unreadable_image(scene_copy):
    (scene_copy / "images" / "000001.png").write_bytes(b"not a png")
    with pytest.raises(SceneError, match=r"images/000001\.png: unreadable image"):
        read_scene(scene_copy)


def test_images_of_different_sizes(scene_copy):
    Image.new("RGB", (WIDTH, HEIGHT + 2)).save(scene_copy / "images" / "000004.png")
    with pytest.raises(SceneError, match=r"images/000004\.png: image is 16x14, camera says 16x12"):
        read_scene(scene_copy)


def test_missing_radar(scene_copy):
    (scene_copy / "radar" / "000005.npy").unlink()
    with pytest.raises(SceneError, match=r"radar/000005\.npy: missing file"):
        read_scene(scene_copy)


def test_unreadable_radar(scene_copy):
    (scene_copy / "radar" / "000002.npy").write_bytes(b"garbage")
    with pytest.raises(SceneError, match=r"radar/000002\.npy: unreadable \.npy file"):
        read_scene(scene_copy)


def test_radar_column_count_disagrees_with_fields(scene_copy):
    np.save(scene_copy / "radar" / "000002.npy", np.zeros((4, 3), np.float32))
    with pytest.raises(SceneError, match=r"radar/000002\.npy: radar array has shape \(4, 3\).*names 5 columns"):
        read_scene(scene_copy)


def test_not_a_directory(tmp_path):
    with pytest.raises(SceneError, match="no such directory"):
        read_scene(tmp_path / "nowhere")
