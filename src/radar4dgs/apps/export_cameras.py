"""The camera formats of ``radar4dgs export``: a nerfstudio dataset (``transforms.json``) and a COLMAP
text model, so splatfacto or gsplat's ``simple_trainer.py`` can train on the same frames, cameras
and initial points as a radar4dgs run.

Both hold every frame of the scene (train and test) with its image copied (or linked), in the
scene's world frame (the first ego frame, z up; nothing is recentred or rescaled, so there is no
``applied_transform``), and the run's initial point cloud: the back-projected training frames the
trainer started from (:func:`radar4dgs.model.gaussians.backproject_frames`).

Conventions. The scene's ``K`` has pixel centres at integer coordinates; nerfstudio and COLMAP put
them at +0.5, so ``cx = K[0, 2] + 0.5`` and ``cy = K[1, 2] + 0.5`` in both. nerfstudio's
``transform_matrix`` is the camera-to-world matrix in OpenGL camera axes (x right, y up, z back) =
the OpenCV one times ``diag(1, -1, -1, 1)``. COLMAP's ``images.txt`` holds the world-to-camera
rotation (as a quaternion ``QW QX QY QZ``) and translation in OpenCV axes, which is the scene's
``world_to_camera`` itself.
"""

from __future__ import annotations

import os
import shutil
import struct
from pathlib import Path

import numpy as np
from scipy.spatial.transform import Rotation

from radar4dgs.io.atomic import atomic_write_bytes, atomic_write_json, atomic_write_text

# OpenCV camera axes (x right, y down, z forward) <-> OpenGL ones (x right, y up, z back).
OPENCV_TO_OPENGL = np.diag([1.0, -1.0, -1.0, 1.0])
POINTS_FILE = "sparse_pc.ply"


def opengl_camera_to_world(world_to_camera: np.ndarray) -> np.ndarray:
    """(4, 4) OpenGL-axis camera-to-world of an OpenCV world-to-camera matrix."""
    return np.linalg.inv(np.asarray(world_to_camera, dtype=np.float64)) @ OPENCV_TO_OPENGL


def opencv_world_to_camera(camera_to_world_gl: np.ndarray) -> np.ndarray:
    """The inverse of :func:`opengl_camera_to_world`."""
    return np.linalg.inv(np.asarray(camera_to_world_gl, dtype=np.float64) @ OPENCV_TO_OPENGL)


def corner_intrinsics(K: np.ndarray) -> tuple[float, float, float, float]:
    """(fx, fy, cx, cy) with pixel centres at +0.5 (nerfstudio, COLMAP) from the scene's ``K``."""
    K = np.asarray(K, dtype=np.float64)
    return float(K[0, 0]), float(K[1, 1]), float(K[0, 2] + 0.5), float(K[1, 2] + 0.5)


def initial_points(run) -> tuple[np.ndarray, np.ndarray]:
    """The run's initial point cloud: (M, 3) float64 world points and (M, 3) uint8 colours."""
    from radar4dgs.model.gaussians import backproject_frames

    points = backproject_frames(run.scene, run.prepared, run.config.init)
    colors = np.clip(np.round(points["colors"] * 255.0), 0, 255).astype(np.uint8)
    return np.asarray(points["points"], dtype=np.float64), colors


def write_points_ply(path: Path, points: np.ndarray, colors: np.ndarray) -> Path:
    """A binary little-endian point cloud PLY (``x y z`` float, ``red green blue`` uchar), as
    nerfstudio's ``ply_file_path`` (read with open3d) expects."""
    n = len(points)
    header = (f"ply\nformat binary_little_endian 1.0\nelement vertex {n}\n"
              "property float x\nproperty float y\nproperty float z\n"
              "property uchar red\nproperty uchar green\nproperty uchar blue\nend_header\n").encode("ascii")
    rows = np.zeros(n, dtype=[("x", "<f4"), ("y", "<f4"), ("z", "<f4"), ("r", "u1"), ("g", "u1"), ("b", "u1")])
    for k, name in enumerate("xyz"):
        rows[name] = points[:, k]
    for k, name in enumerate("rgb"):
        rows[name] = colors[:, k]
    return atomic_write_bytes(path, header + rows.tobytes())


def copy_images(scene, folder: Path, link: bool) -> list[str]:
    """Copy (or symlink, with ``link``) every frame's image into ``folder``; the file names."""
    folder.mkdir(parents=True, exist_ok=True)
    names = []
    for source in scene.image_files:
        target = folder / Path(source).name
        if target.exists() or target.is_symlink():
            target.unlink()
        if link:
            os.symlink(Path(source).resolve(), target)
        else:
            shutil.copyfile(source, target)
        names.append(target.name)
    return names


def write_nerfstudio(run, out: Path, link: bool = False) -> Path:
    """Write a nerfstudio dataset in ``out``: ``transforms.json``, ``images/``, ``sparse_pc.ply``.

    One intrinsics block (``camera_model`` OPENCV with zero distortion, ``fl_x fl_y cx cy w h``),
    per frame ``file_path``, ``transform_matrix`` (OpenGL camera-to-world) and ``time`` (the
    normalised scene time, for dynamic methods); ``train_filenames`` / ``test_filenames`` give the
    scene's own split (nerfstudio's dataparser uses them instead of its own fraction)."""
    from radar4dgs.io.scene import normalized_times

    scene = run.scene
    out = Path(out)
    names = copy_images(scene, out / "images", link)
    times = normalized_times(scene)
    fx, fy, cx, cy = corner_intrinsics(scene.camera.K)
    frames = [{"file_path": f"images/{name}",
               "transform_matrix": opengl_camera_to_world(scene.world_to_camera(i)).tolist(),
               "time": float(times[i])} for i, name in enumerate(names)]
    write_points_ply(out / POINTS_FILE, *initial_points(run))
    transforms = {"camera_model": "OPENCV", "fl_x": fx, "fl_y": fy, "cx": cx, "cy": cy,
                  "w": int(scene.camera.width), "h": int(scene.camera.height),
                  "k1": 0.0, "k2": 0.0, "p1": 0.0, "p2": 0.0,
                  "frames": frames, "ply_file_path": POINTS_FILE,
                  "train_filenames": [f"images/{names[i]}" for i in scene.train_indices],
                  "val_filenames": [f"images/{names[i]}" for i in scene.test_indices],
                  "test_filenames": [f"images/{names[i]}" for i in scene.test_indices]}
    return atomic_write_json(out / "transforms.json", transforms)


def colmap_pose(world_to_camera: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """COLMAP's (QW, QX, QY, QZ) and (TX, TY, TZ) of an OpenCV world-to-camera matrix."""
    w2c = np.asarray(world_to_camera, dtype=np.float64)
    x, y, z, w = Rotation.from_matrix(w2c[:3, :3]).as_quat()
    quat = np.array([w, x, y, z])
    return (quat if w >= 0 else -quat), w2c[:3, 3]


def write_colmap(run, out: Path, link: bool = False) -> Path:
    """Write a COLMAP model: ``out/images/`` and ``out/sparse/0/{cameras,images,points3D}.txt``
    (one PINHOLE camera; each image's world-to-camera pose; the initial points, without tracks),
    the layout gsplat's ``simple_trainer.py --data_dir out`` reads. The same model is also written
    in COLMAP's binary form (``.bin``): the ``pycolmap`` reader that gsplat's examples use prefers
    it, and its text reader stops at the empty observation line of an image without 2D points.
    Returns ``out/sparse/0``."""
    scene = run.scene
    out = Path(out)
    names = copy_images(scene, out / "images", link)
    sparse = out / "sparse" / "0"
    sparse.mkdir(parents=True, exist_ok=True)
    fx, fy, cx, cy = corner_intrinsics(scene.camera.K)
    atomic_write_text(sparse / "cameras.txt",
                      "# Camera list with one line of data per camera:\n"
                      "#   CAMERA_ID, MODEL, WIDTH, HEIGHT, PARAMS[]\n"
                      f"1 PINHOLE {scene.camera.width} {scene.camera.height} {fx!r} {fy!r} {cx!r} {cy!r}\n")
    lines = ["# Image list with two lines of data per image:",
             "#   IMAGE_ID, QW, QX, QY, QZ, TX, TY, TZ, CAMERA_ID, NAME",
             "#   POINTS2D[] as (X, Y, POINT3D_ID)"]
    for i, name in enumerate(names):
        quat, t = colmap_pose(scene.world_to_camera(i))
        lines.append(" ".join([str(i + 1), *(repr(float(v)) for v in quat), *(repr(float(v)) for v in t),
                               "1", name]))
        lines.append("")
    atomic_write_text(sparse / "images.txt", "\n".join(lines) + "\n")
    points, colors = initial_points(run)
    body = [f"{j + 1} {p[0]!r} {p[1]!r} {p[2]!r} {c[0]} {c[1]} {c[2]} 0.0"
            for j, (p, c) in enumerate(zip(points.tolist(), colors.tolist(), strict=True))]
    atomic_write_text(sparse / "points3D.txt",
                      "# 3D point list with one line of data per point:\n"
                      "#   POINT3D_ID, X, Y, Z, R, G, B, ERROR, TRACK[] as (IMAGE_ID, POINT2D_IDX)\n"
                      + "".join(line + "\n" for line in body))
    write_colmap_binary(sparse, (scene.camera.width, scene.camera.height, fx, fy, cx, cy),
                        [(name, *colmap_pose(scene.world_to_camera(i))) for i, name in enumerate(names)],
                        points, colors)
    return sparse


def write_colmap_binary(sparse: Path, camera: tuple, images: list, points: np.ndarray,
                        colors: np.ndarray) -> None:
    """``cameras.bin``, ``images.bin`` and ``points3D.bin`` (COLMAP's binary layout, little-endian):
    ``camera`` = (width, height, fx, fy, cx, cy) of camera 1 (PINHOLE, model id 1), ``images`` =
    [(name, quat wxyz, translation)] with ids from 1 and no 2D points, points without tracks."""
    width, height, *params = camera
    atomic_write_bytes(sparse / "cameras.bin", struct.pack("<QiiQQ4d", 1, 1, 1, width, height, *params))
    chunks = [struct.pack("<Q", len(images))]
    for i, (name, quat, t) in enumerate(images):
        chunks.append(struct.pack("<i4d3di", i + 1, *quat, *t, 1) + name.encode() + b"\x00" + struct.pack("<Q", 0))
    atomic_write_bytes(sparse / "images.bin", b"".join(chunks))
    rows = np.zeros(len(points), dtype=[("id", "<u8"), ("xyz", "<f8", 3), ("rgb", "u1", 3), ("error", "<f8"),
                                        ("track", "<u8")])
    rows["id"] = np.arange(1, len(points) + 1)
    rows["xyz"] = points
    rows["rgb"] = colors
    atomic_write_bytes(sparse / "points3D.bin", struct.pack("<Q", len(points)) + rows.tobytes())


def read_colmap_images(path: Path) -> dict[str, np.ndarray]:
    """``images.txt`` back to {NAME: (4, 4) world-to-camera} (what a COLMAP reader sees)."""
    poses = {}
    lines = [line for line in Path(path).read_text().splitlines() if not line.startswith("#")]
    for line in lines[::2]:
        words = line.split()
        qw, qx, qy, qz, tx, ty, tz = (float(v) for v in words[1:8])
        w2c = np.eye(4)
        w2c[:3, :3] = Rotation.from_quat([qx, qy, qz, qw]).as_matrix()
        w2c[:3, 3] = (tx, ty, tz)
        poses[words[9]] = w2c
    return poses
