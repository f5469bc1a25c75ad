"""The scene-folder reader and writer against SCENE_FORMAT.md: a valid scene round-trips, and every
validation rule refuses a broken scene with an error naming the file and the problem."""

from __future__ import annotations

import json
import shutil
import warnings
from pathlib import Path

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from PIL import Image

from radar4dgs.io.scene import (Camera, Frame, RadarSpec, SceneError, SceneWarning, SceneWriter, read_scene,
                                  split_indices)

WIDTH, HEIGHT, FRAMES = 16, 12, 6
FIELDS = ("x", "y", "z", "v_r", "rcs")


def _pose(x: float, yaw: float = 0.0) -> np.ndarray:
    pose = np.eye(4)
    c, s = np.cos(yaw), np.sin(yaw)
    pose[:3, :3] = [[c, -s, 0], [s, c, 0], [0, 0, 1]]
    pose[0, 3] = x
    return pose


def write_valid_scene(out: Path, rng_seed: int = 0) -> Path:
    rng = np.random.default_rng(rng_seed)
    camera = Camera(WIDTH, HEIGHT, np.array([[10.0, 0, 8], [0, 10.0, 6], [0, 0, 1]]),
                    np.array([[0, 0, 1, 1.5], [-1, 0, 0, 0], [0, -1, 0, 1.5], [0, 0, 0, 1.0]]))
    radar = RadarSpec(_pose(3.6), FIELDS)
    with SceneWriter(out) as writer:
        for i in range(FRAMES):
            frame = Frame(f"{i:06d}", 0.1 * i, _pose(1.0 * i, 0.01 * i), 0.1 * i + 0.01, _pose(1.0 * i + 0.1),
                          ego_velocity=np.array([10.0, 0, 0]), extra={"weather": "dry"})
            image = rng.integers(0, 255, (HEIGHT, WIDTH, 3), dtype=np.uint8)
            points = rng.normal(size=(5 + i, len(FIELDS))).astype(np.float32)
            writer.add_frame(frame, image, points, gt_depth=rng.uniform(1, 50, (HEIGHT, WIDTH)),
                             gt_dynamic_mask=rng.random((HEIGHT, WIDTH)) > 0.5,
                             gt_radar_labels=np.zeros(5 + i, np.int8))
        writer.finish("unit", camera, radar, source={"dataset": "unit-test"}, test_every=3, extra={"note": 1})
    return out


@pytest.fixture(scope="module")
def valid_scene(tmp_path_factory) -> Path:
    return write_valid_scene(tmp_path_factory.mktemp("scenes") / "valid")


@pytest.fixture
def scene_copy(valid_scene, tmp_path) -> Path:
    return Path(shutil.copytree(valid_scene, tmp_path / "copy"))


def _edit_json(root: Path, edit) -> None:
    meta = json.loads((root / "scene.json").read_text())
    edit(meta)
    (root / "scene.json").write_text(json.dumps(meta))


def test_round_trip_keeps_everything(valid_scene):
    scene = read_scene(valid_scene)
    assert scene.name == "unit" and len(scene) == FRAMES and scene.test_every == 3
    assert scene.source == {"dataset": "unit-test"} and scene.extra == {"note": 1}
    assert scene.frames[2].extra == {"weather": "dry"}
    np.testing.assert_allclose(scene.frames[3].ego_to_world, _pose(3.0, 0.03))
    np.testing.assert_allclose(scene.frames[3].radar_ego_to_world, _pose(3.1))
    assert scene.frames[3].radar_timestamp == pytest.approx(0.31)
    assert scene.load_image(0).shape == (HEIGHT, WIDTH, 3)
    radar = scene.load_radar(4)
    assert radar.data.shape == (9, 5) and radar.xyz.shape == (9, 3)
    np.testing.assert_array_equal(radar.v_r, radar.data[:, 3])
    assert scene.optional_folders() == ["gt/depth", "gt/dynamic_mask", "gt/radar_labels"]
    assert scene.load_optional("gt/dynamic_mask", 0).dtype == bool
    assert scene.train_indices == [0, 1, 3, 4] and scene.test_indices == [2, 5]
    assert scene.duration == pytest.approx(0.5)


def test_world_to_camera_inverts_the_chain(valid_scene):
    scene = read_scene(valid_scene)
    point_cam = np.array([0.5, -0.2, 7.0, 1.0])
    world = scene.frames[1].ego_to_world @ scene.camera.cam_to_ego @ point_cam
    np.testing.assert_allclose(scene.world_to_camera(1) @ world, point_cam, atol=1e-12)


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


def test_writer_leaves_nothing_on_error(tmp_path):
    out = tmp_path / "broken"
    with pytest.raises(ZeroDivisionError):
        with SceneWriter(out) as writer:
            writer.add_frame(Frame("a", 0.0, np.eye(4), 0.0, np.eye(4)), np.zeros((2, 2, 3), np.uint8),
                             np.zeros((0, 4)))
            1 / 0
    assert list(tmp_path.iterdir()) == []


def test_writer_refuses_to_overwrite(valid_scene):
    with pytest.raises(FileExistsError, match="already exists"):
        with SceneWriter(valid_scene):
            pass


def test_writer_without_finish_is_an_error(tmp_path):
    with pytest.raises(RuntimeError, match="without finish"):
        with SceneWriter(tmp_path / "unfinished"):
            pass
    assert list(tmp_path.iterdir()) == []


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
    _edit_json(scene_copy, edit)
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


def test_not_a_directory(tmp_path):
    with pytest.raises(SceneError, match="no such directory"):
        read_scene(tmp_path / "nowhere")


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
