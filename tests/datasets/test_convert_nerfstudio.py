"""``radar4dgs convert nerfstudio``: the export of the shared tiny run comes back with the scene's
cameras, times, split and points; a hand-written dataset with a known camera; PLY variants; user
errors in one line."""

from __future__ import annotations

import json
from pathlib import Path

import cv2
import numpy as np
import pytest
from PIL import Image

from radar4dgs.cli import main
from radar4dgs.datasets.convert.camera_import import read_ply_points
from radar4dgs.datasets.convert.nerfstudio import convert_nerfstudio
from radar4dgs.io.scene import SceneError, normalized_times, read_scene

W, H = 64, 48


@pytest.fixture(scope="module")
def exported(tiny_trained_run, tmp_path_factory):
    """The shared tiny run exported with ``radar4dgs export --format nerfstudio``."""
    out = tmp_path_factory.mktemp("ns") / "dataset"
    assert main(["export", str(tiny_trained_run / "run"), "--format", "nerfstudio", "--out", str(out)]) == 0
    return out


def test_the_export_of_a_run_converts_back_to_the_scenes_cameras(tiny_trained_run, exported, tmp_path, capsys):
    original = read_scene(tiny_trained_run / "scene")
    assert main(["convert", "nerfstudio", str(exported), str(tmp_path / "scene"), "--quiet"]) == 0
    assert "no radar" in capsys.readouterr().out
    scene = read_scene(tmp_path / "scene")
    assert not scene.has_radar and not (tmp_path / "scene" / "radar").exists()
    assert "radar" not in json.loads((tmp_path / "scene" / "scene.json").read_text())
    assert (scene.camera.width, scene.camera.height) == (original.camera.width, original.camera.height)
    np.testing.assert_allclose(scene.camera.K, original.camera.K, atol=1e-6)
    assert len(scene) == len(original) and [f.name for f in scene.frames] == [f.name for f in original.frames]
    for i in range(len(original)):
        np.testing.assert_allclose(scene.world_to_camera(i), original.world_to_camera(i), atol=1e-6)
        assert (scene.root / "images" / scene.image_files[i].name).read_bytes() == original.image_files[i].read_bytes()
    # nerfstudio's normalised `time` comes back as the scene's normalised time; the split too.
    np.testing.assert_allclose(normalized_times(scene), normalized_times(original), atol=1e-12)
    assert scene.test_indices == original.test_indices and scene.source["split"] == "the dataset's test_filenames"
    # The initial points: what the PLY holds (float32), also as plyfile reads it.
    points, colors = scene.load_points()
    xyz, rgb = read_ply_points(exported / "sparse_pc.ply")
    np.testing.assert_allclose(points, xyz, atol=1e-5)
    np.testing.assert_allclose(colors, rgb, atol=1e-6)
    plyfile = pytest.importorskip("plyfile")
    vertex = plyfile.PlyData.read(str(exported / "sparse_pc.ply"))["vertex"]
    np.testing.assert_array_equal(points[:, 0].astype(np.float32), vertex["x"])
    np.testing.assert_array_equal(np.round(colors[:, 2] * 255), vertex["blue"])


def _image(path: Path, seed: int = 0) -> None:
    path.parent.mkdir(parents=True, exist_ok=True)
    Image.fromarray(np.random.default_rng(seed).integers(0, 255, (H, W, 3), dtype=np.uint8)).save(path)


def _gl_pose(position, yaw_deg: float = 0.0) -> list:
    """OpenGL camera-to-world: a camera at ``position`` turned by ``yaw_deg`` about world y."""
    c, s = np.cos(np.radians(yaw_deg)), np.sin(np.radians(yaw_deg))
    pose = np.eye(4)
    pose[:3, :3] = [[c, 0, s], [0, 1, 0], [-s, 0, c]]
    pose[:3, 3] = position
    return pose.tolist()


def _dataset(root: Path, **top) -> Path:
    """Three frames listed out of time order; per-frame intrinsics; a 3-point ASCII PLY."""
    for k in range(3):
        _image(root / "images" / f"f{k}.png", k)
    frames = [{"file_path": f"images/f{k}.png", "time": t, "transform_matrix": _gl_pose([k, 0.0, 0.0], 10.0 * k),
               "fl_x": 40.0, "fl_y": 41.0, "cx": 32.0, "cy": 24.0, "w": W, "h": H}
              for k, t in ((2, 1.0), (0, 0.0), (1, 0.25))]
    (root / "points.ply").write_text("ply\nformat ascii 1.0\nelement vertex 3\nproperty float x\nproperty float y\n"
                                     "property float z\nproperty uchar red\nproperty uchar green\nproperty uchar blue\n"
                                     "end_header\n0 0 -5 255 0 0\n1 2 -6 0 255 0\n-1 0 -4 0 0 255\n")
    meta = {"camera_model": "OPENCV", "frames": frames, "ply_file_path": "points.ply", **top}
    (root / "transforms.json").write_text(json.dumps(meta))
    return root


def test_a_hand_written_dataset_with_a_known_camera(tmp_path):
    scene = read_scene(convert_nerfstudio(_dataset(tmp_path / "ns"), tmp_path / "scene", progress=False))
    # Ordered by time; `time` 0, 0.25, 1 spread over (3 - 1) x 0.1 s.
    assert [f.extra["source_file"] for f in scene.frames] == ["images/f0.png", "images/f1.png", "images/f2.png"]
    np.testing.assert_allclose([f.timestamp for f in scene.frames], [0.0, 0.05, 0.2])
    np.testing.assert_allclose(scene.camera.K, [[40.0, 0, 31.5], [0, 41.0, 23.5], [0, 0, 1]])
    # OpenGL: the camera looks down its -z with y up, so the world point 5 m along -z in front of
    # the first camera (at the origin, not turned) is on the optical axis at depth 5, and a point
    # 1 m up lands above the principal point (smaller row) in the OpenCV image.
    w2c = scene.world_to_camera(0)
    cam = w2c[:3, :3] @ np.array([[0.0, 0.0, -5.0], [0.0, 1.0, -5.0]]).T + w2c[:3, 3:4]
    uv, z = scene.camera.project(cam.T)
    np.testing.assert_allclose(z, [5.0, 5.0])
    np.testing.assert_allclose(uv, [[31.5, 23.5], [31.5, 23.5 - 41.0 / 5.0]], atol=1e-9)
    # The third camera: at x = 2, turned by 20 deg; its centre and viewing direction.
    c2w = np.linalg.inv(scene.world_to_camera(2))
    np.testing.assert_allclose(c2w[:3, 3], [2.0, 0.0, 0.0], atol=1e-12)
    np.testing.assert_allclose(c2w[:3, 2], [-np.sin(np.radians(20)), 0.0, -np.cos(np.radians(20))], atol=1e-12)
    points, colors = scene.load_points()
    np.testing.assert_allclose(points, [[0, 0, -5], [1, 2, -6], [-1, 0, -4]])
    np.testing.assert_allclose(colors, np.eye(3))
    assert scene.test_every == 4 and scene.source["split"] == "default"


def test_applied_transform_is_kept_or_undone(tmp_path):
    A = [[1.0, 0.0, 0.0, 0.5], [0.0, 0.0, 1.0, 0.0], [0.0, -1.0, 0.0, 0.0]]  # nerfstudio's COLMAP turn + a shift
    src = _dataset(tmp_path / "ns", applied_transform=A, applied_scale=2.0)
    kept = read_scene(convert_nerfstudio(src, tmp_path / "kept", progress=False))
    original = read_scene(convert_nerfstudio(src, tmp_path / "original", world="original", progress=False))
    M = np.diag([2.0, 2.0, 2.0, 1.0]) @ np.vstack([A, [0, 0, 0, 1]])  # x_transforms = M x_original
    for i in range(3):
        # The same camera: a point seen by it lands at the same pixel and (unscaled) depth.
        x_original = np.array([0.3, -0.2, 1.7, 1.0])
        seen_kept = kept.world_to_camera(i) @ (M @ x_original)
        np.testing.assert_allclose(2.0 * (original.world_to_camera(i) @ x_original)[:3], seen_kept[:3], atol=1e-9)
    np.testing.assert_allclose(original.load_points()[0] @ M[:3, :3].T + M[:3, 3], kept.load_points()[0], atol=1e-5)
    assert kept.source["applied_transform"] == M.tolist()


def test_distorted_images_are_undistorted_with_opencv(tmp_path):
    root = tmp_path / "ns"
    _dataset(root)
    meta = json.loads((root / "transforms.json").read_text())
    meta["k1"], meta["p2"] = -0.2, 0.01
    (root / "transforms.json").write_text(json.dumps(meta))
    scene = read_scene(convert_nerfstudio(root, tmp_path / "scene", progress=False))
    K_raw = np.array([[40.0, 0, 31.5], [0, 41.0, 23.5], [0, 0, 1]])
    dist = np.array([-0.2, 0.0, 0.0, 0.01, 0.0])
    expected, _ = cv2.getOptimalNewCameraMatrix(K_raw, dist, (W, H), alpha=0)
    np.testing.assert_allclose(scene.camera.K, expected, atol=1e-9)
    assert scene.image_files[0].suffix == ".png" and "undistorted" in scene.source["images"]


def test_fisheye_images_are_undistorted_with_opencvs_fisheye_model(tmp_path):
    root = _dataset(tmp_path / "ns")
    meta = json.loads((root / "transforms.json").read_text())
    meta.update(camera_model="OPENCV_FISHEYE", k1=0.05, k2=-0.01, k3=0.002, k4=-0.001)
    (root / "transforms.json").write_text(json.dumps(meta))
    scene = read_scene(convert_nerfstudio(root, tmp_path / "scene", progress=False))
    K_raw = np.array([[40.0, 0, 31.5], [0, 41.0, 23.5], [0, 0, 1]])
    D = np.array([[0.05], [-0.01], [0.002], [-0.001]])
    expected = cv2.fisheye.estimateNewCameraMatrixForUndistortRectify(K_raw, D, (W, H), np.eye(3), balance=0.0)
    np.testing.assert_allclose(scene.camera.K, expected, atol=1e-9)
    assert scene.source["images"] == "undistorted (OpenCV fisheye, balance 0)"


def test_binary_ply_with_extra_properties(tmp_path):
    rows = np.zeros(2, dtype=[("x", ">f8"), ("y", ">f8"), ("z", ">f8"), ("nx", ">f4"), ("red", "u1"),
                              ("green", "u1"), ("blue", "u1"), ("alpha", "u1")])
    rows["x"], rows["z"], rows["red"], rows["blue"] = [1.5, -2.0], [3.0, 4.0], [255, 0], [51, 102]
    header = ("ply\nformat binary_big_endian 1.0\ncomment made here\nelement vertex 2\nproperty double x\n"
              "property double y\nproperty double z\nproperty float nx\nproperty uchar red\nproperty uchar green\n"
              "property uchar blue\nproperty uchar alpha\nelement face 0\nproperty list uchar int vertex_indices\n"
              "end_header\n")
    (tmp_path / "p.ply").write_bytes(header.encode() + rows.tobytes())
    xyz, rgb = read_ply_points(tmp_path / "p.ply")
    np.testing.assert_array_equal(xyz, [[1.5, 0, 3.0], [-2.0, 0, 4.0]])
    np.testing.assert_allclose(rgb, [[1.0, 0, 0.2], [0, 0, 0.4]])


def test_user_errors_are_one_line(tmp_path, capsys):
    def refused(src: Path, *options: str) -> str:
        assert main(["convert", "nerfstudio", str(src), str(tmp_path / "out"), "--quiet", *options]) == 1
        err = capsys.readouterr().err.strip()
        assert "\n" not in err and err.startswith("radar4dgs convert nerfstudio: ")
        assert not (tmp_path / "out").exists()
        return err

    (tmp_path / "empty").mkdir()
    assert refused(tmp_path / "empty").endswith("empty/transforms.json: missing file (a nerfstudio dataset has a "
                                                "transforms.json)")
    root = _dataset(tmp_path / "ns")
    meta = json.loads((root / "transforms.json").read_text())
    meta["frames"][1]["fl_x"] = 45.0
    (root / "transforms.json").write_text(json.dumps(meta))
    assert "transforms.json: the frames have 2 different cameras; the scene format has one" in refused(root)
    meta["frames"][1]["fl_x"] = 40.0
    meta.update(camera_model="EQUIRECTANGULAR")
    (root / "transforms.json").write_text(json.dumps(meta))
    assert "camera_model EQUIRECTANGULAR with distortion [0.0, 0.0, 0.0, 0.0, 0.0, 0.0] is not converted (PINHOLE, " \
           "OPENCV and OPENCV_FISHEYE are)" in refused(root)
    meta.update(camera_model="OPENCV", k4=0.1)
    (root / "transforms.json").write_text(json.dumps(meta))
    assert "camera_model OPENCV with distortion [0.0, 0.0, 0.0, 0.0, 0.0, 0.1] is not converted" in refused(root)
    meta.update(k4=0.0)
    meta["frames"][0]["time"] = 0.25
    (root / "transforms.json").write_text(json.dumps(meta))
    assert "frames[0] and frames[2] have the same time 0.25" in refused(root)
    meta["frames"][0]["time"] = 1.0
    (root / "transforms.json").write_text(json.dumps(meta))
    (root / "images" / "f1.png").unlink()
    assert refused(root).endswith("ns/images/f1.png: missing image")
    with pytest.raises(SceneError, match="missing image"):
        convert_nerfstudio(root, tmp_path / "out", progress=False)
