"""``radar4dgs convert colmap``: the export of the shared tiny run comes back with the scene's
cameras and points; a hand-written model with a known camera; OpenCV undistortion; user errors
in one line."""

from __future__ import annotations

import struct
from pathlib import Path

import cv2
import numpy as np
import pytest
from PIL import Image
from scipy.spatial.transform import Rotation

from radar4dgs.cli import main
from radar4dgs.datasets.convert.colmap import convert_colmap
from radar4dgs.io.scene import read_scene

W, H = 64, 48


def test_the_export_of_a_run_converts_back_to_the_scenes_cameras(tiny_trained_run, tmp_path, capsys):
    original = read_scene(tiny_trained_run / "scene")
    exported = tmp_path / "colmap"
    assert main(["export", str(tiny_trained_run / "run"), "--format", "colmap", "--out", str(exported)]) == 0
    assert main(["convert", "colmap", str(exported), str(tmp_path / "scene"), "--quiet"]) == 0
    assert "no radar" in capsys.readouterr().out
    scene = read_scene(tmp_path / "scene")
    assert not scene.has_radar and scene.source["camera_model"] == "PINHOLE"
    np.testing.assert_allclose(scene.camera.K, original.camera.K, atol=1e-6)
    assert [f.name for f in scene.frames] == [f.name for f in original.frames]
    for i in range(len(original)):
        np.testing.assert_allclose(scene.world_to_camera(i), original.world_to_camera(i), atol=1e-6)
    # points3D.txt: the exported points (written with repr) and their colours.
    rows = [line.split() for line in (exported / "sparse" / "0" / "points3D.txt").read_text().splitlines()
            if not line.startswith("#")]
    points, colors = scene.load_points()
    np.testing.assert_allclose(points, np.array([r[1:4] for r in rows], float), atol=1e-4)  # stored float32
    np.testing.assert_allclose(colors * 255, np.array([r[4:7] for r in rows], float), atol=1e-4)
    # COLMAP has no times: the frames' order, 0.1 s apart.
    np.testing.assert_allclose([f.timestamp for f in scene.frames], np.arange(len(scene)) * 0.1)


def test_the_binary_model_reads_as_the_text_one(tiny_trained_run, tmp_path):
    exported = tmp_path / "colmap"
    assert main(["export", str(tiny_trained_run / "run"), "--format", "colmap", "--out", str(exported)]) == 0
    text = read_scene(convert_colmap(exported, tmp_path / "text", progress=False))
    for name in ("cameras", "images", "points3D"):
        (exported / "sparse" / "0" / f"{name}.txt").unlink()
    binary = read_scene(convert_colmap(exported, tmp_path / "binary", progress=False))
    assert (text.source["model"], binary.source["model"]) == ("text", "binary")
    np.testing.assert_array_equal(binary.camera.K, text.camera.K)
    for i in range(len(text)):
        np.testing.assert_allclose(binary.world_to_camera(i), text.world_to_camera(i), atol=1e-12)
    np.testing.assert_array_equal(binary.load_points()[0], text.load_points()[0])
    np.testing.assert_array_equal(binary.load_points()[1], text.load_points()[1])


def test_a_hand_written_binary_model_skips_2d_points_and_tracks(tmp_path):
    root = _model(tmp_path / "p", f"SIMPLE_PINHOLE {W} {H} 50.0 32.0 24.0")
    model = root / "sparse" / "0"
    for name in ("cameras", "images", "points3D"):
        (model / f"{name}.txt").unlink()
    (model / "cameras.bin").write_bytes(struct.pack("<QiiQQ3d", 1, 7, 0, W, H, 50.0, 32.0, 24.0))
    chunks = [struct.pack("<Q", len(POSES))]
    for k, (name, (q, t)) in enumerate(POSES.items()):
        chunks += [struct.pack("<i7di", k + 1, *q, *t, 7), name.encode() + b"\x00", struct.pack("<Q", 2),
                   struct.pack("<ddqddq", 10.0, 20.0, 1, 12.5, 3.0, -1)]
    (model / "images.bin").write_bytes(b"".join(chunks))
    chunks = [struct.pack("<Q", len(POINTS))]
    for j, p in enumerate(POINTS):
        chunks += [struct.pack("<Q3d3Bd", j + 1, *p[:3], *p[3:], 0.5), struct.pack("<Q", 2),
                   struct.pack("<iiii", 1, 0, 2, 1)]
    (model / "points3D.bin").write_bytes(b"".join(chunks))
    scene = read_scene(convert_colmap(root, tmp_path / "scene", progress=False))
    np.testing.assert_allclose(scene.camera.K, [[50.0, 0, 31.5], [0, 50.0, 23.5], [0, 0, 1]])
    assert [f.name for f in scene.frames] == ["a", "b"]
    for i, name in enumerate(["a.png", "b.png"]):
        np.testing.assert_allclose(scene.world_to_camera(i), _w2c(*POSES[name]), atol=1e-12)
    np.testing.assert_allclose(scene.load_points()[0], [p[:3] for p in POINTS])
    np.testing.assert_allclose(scene.load_points()[1], [[1.0, 0, 0], [0, 128 / 255, 1.0]], atol=1e-7)


def _w2c(qvec, tvec) -> np.ndarray:
    pose = np.eye(4)
    pose[:3, :3] = Rotation.from_quat([qvec[1], qvec[2], qvec[3], qvec[0]]).as_matrix()
    pose[:3, 3] = tvec
    return pose


# Two images listed out of name order; the second turned 90 deg about the camera's y axis.
POSES = {"b.png": ([np.cos(np.pi / 4), 0.0, np.sin(np.pi / 4), 0.0], [0.0, 0.0, 2.0]),
         "a.png": ([1.0, 0.0, 0.0, 0.0], [0.5, -0.25, 0.0])}
POINTS = [[0.0, 0.0, 10.0, 255, 0, 0], [1.0, -1.0, 8.0, 0, 128, 255]]


def _model(root: Path, camera: str, layout: str = "project") -> Path:
    """A COLMAP text model with ``camera`` (one cameras.txt line after the id) in ``root``."""
    model = root / "sparse" / "0" if layout == "project" else root
    model.mkdir(parents=True)
    images = root / "images"
    for k, name in enumerate(sorted(POSES)):
        images.mkdir(exist_ok=True)
        Image.fromarray(np.random.default_rng(k).integers(0, 255, (H, W, 3), dtype=np.uint8)).save(images / name)
    (model / "cameras.txt").write_text(f"# Camera list\n7 {camera}\n")
    lines = ["# Image list with two lines of data per image:"]
    for k, (name, (q, t)) in enumerate(POSES.items()):
        lines += [f"{k + 1} {' '.join(map(str, q))} {' '.join(map(str, t))} 7 {name}", "10.0 20.0 1 12.5 3.0 -1"]
    (model / "images.txt").write_text("\n".join(lines) + "\n")
    (model / "points3D.txt").write_text("# 3D point list\n" + "".join(
        f"{j + 1} {' '.join(map(str, p))} 0.5 1 0\n" for j, p in enumerate(POINTS)))
    return root


def test_a_hand_written_model_with_a_known_camera(tmp_path):
    scene = read_scene(convert_colmap(_model(tmp_path / "p", f"SIMPLE_PINHOLE {W} {H} 50.0 32.0 24.0"),
                                      tmp_path / "scene", test_every=0, progress=False))
    assert [f.name for f in scene.frames] == ["a", "b"] and scene.test_indices == []
    # COLMAP's principal point is in +0.5 pixel-centre coordinates.
    np.testing.assert_allclose(scene.camera.K, [[50.0, 0, 31.5], [0, 50.0, 23.5], [0, 0, 1]])
    for i, name in enumerate(["a.png", "b.png"]):
        np.testing.assert_allclose(scene.world_to_camera(i), _w2c(*POSES[name]), atol=1e-12)
    # Point 1 is 10 m straight ahead of camera a (shifted by t): it projects where COLMAP says.
    cam = (scene.world_to_camera(0) @ np.array([0.0, 0.0, 10.0, 1.0]))[:3]
    uv, z = scene.camera.project(cam[None])
    np.testing.assert_allclose(uv[0] + 0.5, [32.0 + 50.0 * 0.5 / 10.0, 24.0 - 50.0 * 0.25 / 10.0])
    # Camera b's centre in the world is -R^T t.
    np.testing.assert_allclose(np.linalg.inv(scene.world_to_camera(1))[:3, 3],
                               -_w2c(*POSES["b.png"])[:3, :3].T @ [0.0, 0.0, 2.0], atol=1e-12)
    points, colors = scene.load_points()
    np.testing.assert_allclose(points, [p[:3] for p in POINTS])
    np.testing.assert_allclose(colors, [[1.0, 0, 0], [0, 128 / 255, 1.0]], atol=1e-7)
    assert scene.image_files[0].read_bytes() == (tmp_path / "p" / "images" / "a.png").read_bytes()


def test_the_model_folder_itself_and_an_images_option(tmp_path):
    root = _model(tmp_path / "m", f"PINHOLE {W} {H} 50.0 51.0 32.0 24.0", layout="model")
    scene = read_scene(convert_colmap(root, tmp_path / "scene", images=root / "images", progress=False))
    np.testing.assert_allclose(scene.camera.K, [[50.0, 0, 31.5], [0, 51.0, 23.5], [0, 0, 1]])


def test_opencv_distortion_is_undistorted_where_a_point_lands(tmp_path):
    k1, k2, p1, p2 = -0.25, 0.05, 0.002, -0.001
    root = _model(tmp_path / "p", f"OPENCV {W} {H} 50.0 50.0 32.0 24.0 {k1} {k2} {p1} {p2}")
    # A white dot where the distorting camera a sees a world point; black elsewhere.
    K_raw = np.array([[50.0, 0, 31.5], [0, 50.0, 23.5], [0, 0, 1]])
    dist = np.array([k1, k2, p1, p2])
    point_cam = np.array([[-1.8, 1.1, 6.0]])
    raw_uv = cv2.projectPoints(point_cam, np.zeros(3), np.zeros(3), K_raw, dist)[0][0, 0]
    image = np.zeros((H, W, 3), np.uint8)
    cv2.circle(image, (int(round(raw_uv[0])), int(round(raw_uv[1]))), 1, (255, 255, 255), -1)
    Image.fromarray(image).save(root / "images" / "a.png")
    scene = read_scene(convert_colmap(root, tmp_path / "scene", progress=False))
    expected_K, _ = cv2.getOptimalNewCameraMatrix(K_raw, dist, (W, H), alpha=0)
    np.testing.assert_allclose(scene.camera.K, expected_K, atol=1e-9)
    out = scene.load_image(0).astype(float)[..., 0]
    found = np.array([(out * np.arange(W)).sum(), (out.T * np.arange(H)).sum()]) / out.sum()
    uv, _ = scene.camera.project(point_cam)
    assert np.linalg.norm(found - uv[0]) < 0.75


def test_fisheye_is_undistorted_where_a_point_lands(tmp_path):
    k1, k2, k3, k4 = 0.08, -0.02, 0.004, -0.001
    root = _model(tmp_path / "p", f"OPENCV_FISHEYE {W} {H} 30.0 30.0 32.0 24.0 {k1} {k2} {k3} {k4}")
    K_raw = np.array([[30.0, 0, 31.5], [0, 30.0, 23.5], [0, 0, 1]])
    D = np.array([[k1], [k2], [k3], [k4]])
    point_cam = np.array([[[-1.5, 0.9, 4.0]]])
    raw_uv = cv2.fisheye.projectPoints(point_cam, np.zeros(3), np.zeros(3), K_raw, D)[0][0, 0]
    image = np.zeros((H, W, 3), np.uint8)
    cv2.circle(image, (int(round(raw_uv[0])), int(round(raw_uv[1]))), 1, (255, 255, 255), -1)
    Image.fromarray(image).save(root / "images" / "a.png")
    scene = read_scene(convert_colmap(root, tmp_path / "scene", progress=False))
    assert scene.source["images"] == "undistorted (OpenCV fisheye, balance 0)"
    out = scene.load_image(0).astype(float)[..., 0]
    found = np.array([(out * np.arange(W)).sum(), (out.T * np.arange(H)).sum()]) / out.sum()
    uv, _ = scene.camera.project(point_cam[0])
    assert np.linalg.norm(found - uv[0]) < 0.75


def test_user_errors_are_one_line(tmp_path, capsys):
    def refused(src: Path) -> str:
        assert main(["convert", "colmap", str(src), str(tmp_path / "out"), "--quiet"]) == 1
        err = capsys.readouterr().err.strip()
        assert "\n" not in err and err.startswith("radar4dgs convert colmap: ")
        assert not (tmp_path / "out").exists()
        return err

    assert refused(tmp_path / "nowhere").endswith("nowhere: missing folder (a COLMAP project or model)")
    fov = _model(tmp_path / "f", f"FOV {W} {H} 50 50 32 24 0.1")
    assert refused(fov).endswith("sparse/0/cameras.txt: camera model FOV is not supported (SIMPLE_PINHOLE, PINHOLE, "
                                 "SIMPLE_RADIAL, RADIAL, OPENCV, FULL_OPENCV, OPENCV_FISHEYE, SIMPLE_RADIAL_FISHEYE, "
                                 "RADIAL_FISHEYE); undistort the images first (`colmap image_undistorter`)")
    short = _model(tmp_path / "s", f"PINHOLE {W} {H} 50 50 32")
    assert refused(short).endswith("cameras.txt: camera model PINHOLE has 4 parameters, got 3")
    (tmp_path / "n" / "sparse" / "0").mkdir(parents=True)
    assert refused(tmp_path / "n").endswith("n: not a COLMAP model (no cameras.txt or cameras.bin in it, sparse/0 or "
                                            "sparse)")
    binary = tmp_path / "b" / "sparse" / "0"
    binary.mkdir(parents=True)
    (tmp_path / "b" / "images").mkdir()
    (binary / "cameras.bin").write_bytes(struct.pack("<QiiQQ", 1, 1, 11, W, H))
    assert refused(tmp_path / "b").endswith("cameras.bin: camera 1: unknown camera model id 11")
    (binary / "cameras.bin").write_bytes(struct.pack("<QiiQQ3d", 1, 1, 1, W, H, 50.0, 50.0, 32.0))
    assert refused(tmp_path / "b").endswith("cameras.bin: truncated binary model at byte 32")
    broken = _model(tmp_path / "x", f"PINHOLE {W} {H} 50 50 32 24")
    (broken / "sparse" / "0" / "images.txt").write_text("1 1 0 0 0 0 0 zero 7 a.png\n\n")
    assert "images.txt: line 1: expected IMAGE_ID QW QX QY QZ TX TY TZ CAMERA_ID NAME" in refused(broken)
    with pytest.raises(FileExistsError, match="already exists"):
        convert_colmap(broken, tmp_path, progress=False)
