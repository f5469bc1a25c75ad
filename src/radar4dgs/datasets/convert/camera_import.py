"""What the camera-only importers (``convert nerfstudio``, ``convert colmap``) share: the camera
conventions of those tools, a PLY point reader, the train/test split, and the writing of a
radar-less scene folder (no ``radar`` section, no ``radar/`` folder; the point cloud in
``priors/points3d.npy``, docs/data/scene-format.md).

Conventions. nerfstudio and COLMAP put pixel centres at +0.5, the scene format at integer
coordinates: ``K[0, 2] = cx - 0.5``, ``K[1, 2] = cy - 0.5``. The world stays the source's world
(nothing is rebased or rescaled), so the cameras of a scene exported with ``radar4dgs export
--format nerfstudio|colmap`` come back exactly. The ego frame is the camera's own position with
the ego axes (x forward, y left, z up): ``cam_to_ego`` is the fixed axis change ``CV_TO_EGO``
and ``ego_to_world = camera_to_world @ inv(cam_to_ego)``; there is no ground height to know.
"""

from __future__ import annotations

import re
from pathlib import Path
from typing import Any, Sequence

import cv2
import numpy as np
from PIL import Image
from tqdm import tqdm

from radar4dgs.datasets.convert.common import ImageRectifier, read_first_image
from radar4dgs.io.scene import IMAGE_SUFFIXES, Camera, Frame, SceneError, SceneWriter, split_indices
from radar4dgs.io.scene_read import rigid_matrix

# OpenCV camera axes (x right, y down, z forward) <-> OpenGL ones (x right, y up, z back).
OPENCV_TO_OPENGL = np.diag([1.0, -1.0, -1.0, 1.0])
# OpenCV camera axes -> ego axes (x forward, y left, z up), the camera at the ego origin.
CAM_TO_EGO = np.array([[0.0, 0.0, 1.0, 0.0], [-1.0, 0.0, 0.0, 0.0], [0.0, -1.0, 0.0, 0.0], [0.0, 0.0, 0.0, 1.0]])
DEFAULT_FRAME_INTERVAL = 0.1
_SAFE_NAME = re.compile(r"^[A-Za-z0-9._-]+$")


def pinhole_K(fx: float, fy: float, cx: float, cy: float) -> np.ndarray:
    """(3, 3) scene ``K`` (pixel centres at integer coordinates) of +0.5-convention intrinsics."""
    return np.array([[fx, 0.0, cx - 0.5], [0.0, fy, cy - 0.5], [0.0, 0.0, 1.0]])


def frame_of(name: str, timestamp: float, world_to_camera: np.ndarray, where: str, path: Path,
             extra: dict[str, Any] | None = None) -> Frame:
    """A :class:`Frame` whose camera has the (4, 4) OpenCV ``world_to_camera`` pose (refused when
    its rotation is not orthonormal: ``where`` and ``path`` name it)."""
    camera_to_world = rigid_matrix(np.linalg.inv(world_to_camera), where, path)
    ego_to_world = camera_to_world @ np.linalg.inv(CAM_TO_EGO)
    return Frame(name, float(timestamp), ego_to_world, float(timestamp), ego_to_world, None, dict(extra or {}))


def frame_names(files: Sequence[str]) -> list[str]:
    """Frame names: the image files' stems when they are unique and plain, else 000000, 000001, ..."""
    stems = [Path(f).stem for f in files]
    if len(set(stems)) == len(stems) and all(_SAFE_NAME.match(s) for s in stems):
        return stems
    return [f"{i:06d}" for i in range(len(files))]


def order_timestamps(count: int, interval: float) -> np.ndarray:
    """(count,) timestamps from the frames' order, ``interval`` seconds apart."""
    if not interval > 0:
        raise ValueError(f"--frame-interval must be > 0, got {interval}")
    return np.arange(count, dtype=np.float64) * interval


def test_every_of(count: int, test: Sequence[int]) -> int | None:
    """The scene format's ``test_every`` that makes exactly the frames ``test`` the test frames
    (0 when there are none), or None when no value does."""
    if not test:
        return 0
    wanted = sorted(test)
    for every in range(1, count + 2):
        if split_indices(count, every)[1] == wanted:
            return every
    return None


def read_ply_points(path: Path) -> tuple[np.ndarray, np.ndarray]:
    """The ``vertex`` element of a PLY file (ascii or binary, any extra properties): (M, 3) float64
    ``x y z`` and (M, 3) colours in [0, 1] (``red green blue``, grey when absent)."""
    try:
        raw = path.read_bytes()
    except OSError as exc:
        raise SceneError(path, f"unreadable point cloud ({exc.strerror})") from exc
    end = raw.find(b"end_header")
    if not raw.startswith(b"ply") or end < 0:
        raise SceneError(path, "not a PLY file (no 'ply' ... 'end_header' header)")
    body = raw[raw.index(b"\n", end) + 1:]
    header = raw[:end].decode("ascii", "replace").splitlines()
    fmt = next((line.split()[1] for line in header if line.startswith("format")), "")
    elements: list[tuple[str, int, list[tuple[str, str]]]] = []
    for line in header:
        words = line.split()
        if words[:1] == ["element"]:
            elements.append((words[1], int(words[2]), []))
        elif words[:1] == ["property"] and elements:
            if words[1] == "list" and elements[-1][0] == "vertex":
                raise SceneError(path, f"the vertices have a list property {words[-1]!r}; not supported")
            elements[-1][2].append((words[-1], words[1]))
    if not elements or elements[0][0] != "vertex":
        raise SceneError(path, "the first PLY element is not 'vertex'")
    _, count, props = elements[0]
    types = {"char": "i1", "int8": "i1", "uchar": "u1", "uint8": "u1", "short": "i2", "int16": "i2",
             "ushort": "u2", "uint16": "u2", "int": "i4", "int32": "i4", "uint": "u4", "uint32": "u4",
             "float": "f4", "float32": "f4", "double": "f8", "float64": "f8"}
    if fmt == "ascii":
        table = np.loadtxt(body.decode("ascii").splitlines()[:count], ndmin=2, dtype=np.float64)
        data = {name: table[:, k] for k, (name, _) in enumerate(props)}
    elif fmt in ("binary_little_endian", "binary_big_endian"):
        order = "<" if fmt == "binary_little_endian" else ">"
        dtype = np.dtype([(name, order + types[kind]) for name, kind in props])
        data = np.frombuffer(body, dtype=dtype, count=count)
    else:
        raise SceneError(path, f"unknown PLY format {fmt!r}")
    names = [name for name, _ in props]
    if not {"x", "y", "z"} <= set(names):
        raise SceneError(path, f"the vertices have no x, y, z (properties {names})")
    xyz = np.stack([np.asarray(data[k], np.float64) for k in "xyz"], axis=1)
    if {"red", "green", "blue"} <= set(names):
        kinds = dict(props)
        scale = 255.0 if types[kinds["red"]] == "u1" else (1.0 if types[kinds["red"]].startswith("f") else 65535.0)
        rgb = np.stack([np.asarray(data[k], np.float64) for k in ("red", "green", "blue")], axis=1) / scale
    else:
        rgb = np.full_like(xyz, 0.5)
    return xyz, np.clip(rgb, 0.0, 1.0)


def fisheye_rectifier(K: np.ndarray, distortion: Sequence[float], size: tuple[int, int]) -> ImageRectifier:
    """An :class:`ImageRectifier` for OpenCV's fisheye model (``distortion`` k1..k4): to the
    pinhole matrix of ``cv2.fisheye.estimateNewCameraMatrixForUndistortRectify`` with balance 0
    (every output pixel valid), the same size."""
    K = np.asarray(K, dtype=np.float64)
    D = np.zeros((4, 1))
    D[:len(distortion), 0] = distortion[:4]
    K_new = cv2.fisheye.estimateNewCameraMatrixForUndistortRectify(K, D, tuple(size), np.eye(3), balance=0.0)
    maps = cv2.fisheye.initUndistortRectifyMap(K, D, np.eye(3), K_new, tuple(size), cv2.CV_32FC1)
    return ImageRectifier(tuple(size), tuple(size), K_new, maps)


def image_reader(files: Sequence[Path], K: np.ndarray, distortion: Sequence[float] | None,
                 size: tuple[int, int], fisheye: bool = False) -> tuple[Camera, Any]:
    """The scene camera of images ``files`` with intrinsics ``K`` (scene convention) and OpenCV
    ``distortion`` (k1, k2, p1, p2[, k3, ...]; with ``fisheye`` OpenCV's fisheye k1..k4) at
    ``size`` (width, height), and a function ``index -> image`` for :meth:`SceneWriter.add_frame`:
    the file itself when it is an undistorted PNG/JPEG (copied), else the OpenCV-undistorted RGB
    array (every output pixel valid: ``getOptimalNewCameraMatrix`` alpha 0, fisheye balance 0)."""
    undistort = distortion is not None and any(float(d) != 0.0 for d in distortion)
    rectifier = None
    if undistort:
        rectifier = fisheye_rectifier(K, distortion, size) if fisheye else ImageRectifier.build(K, distortion, size)
    camera = Camera(int(size[0]), int(size[1]), rectifier.K if rectifier else np.asarray(K, np.float64),
                    CAM_TO_EGO.copy())

    def read(i: int):
        path = Path(files[i])
        if not path.is_file():
            raise SceneError(path, "missing image")
        if rectifier is None and path.suffix.lower() in IMAGE_SUFFIXES:
            try:
                with Image.open(path) as image:
                    found, mode = image.size, image.mode
            except Exception as exc:  # PIL raises many types for broken files
                raise SceneError(path, f"unreadable image ({exc})") from exc
            if found != tuple(size):
                raise SceneError(path, f"image is {found[0]}x{found[1]}, the camera says {size[0]}x{size[1]}")
            if mode in ("RGB", "L", "P", "RGBA"):
                return path
        if rectifier is None:
            rectifier_plain = ImageRectifier.build(K, None, size)
            return rectifier_plain(read_first_image(path), path)
        return rectifier(read_first_image(path), path)

    return camera, read


def write_radarless_scene(out: Path, name: str, camera: Camera, frames: Sequence[Frame], read_image: Any,
                          points: tuple[np.ndarray, np.ndarray] | None, source: dict, test_every: int | None,
                          overwrite: bool, progress: bool, desc: str) -> Path:
    """Write the radar-less scene folder ``out`` atomically: frame ``i`` is ``frames[i]`` with the
    image ``read_image(i)``; ``points`` (world (M, 3), colours (M, 3) in [0, 1]) go to
    ``priors/points3d.npy``."""
    with SceneWriter(out, overwrite=overwrite) as writer:
        for i in tqdm(range(len(frames)), desc=desc, unit="frame", disable=not progress):
            writer.add_frame(frames[i], read_image(i), None)
        if points is not None and len(points[0]):
            writer.add_points(*points)
        writer.finish(name, camera, None, source=source, test_every=test_every)
    return out


def refuse_existing(out: Path, overwrite: bool) -> None:
    """Refuse an existing output folder before any reading (``--force`` overwrites it)."""
    if Path(out).exists() and not overwrite:
        raise FileExistsError(f"{out}: already exists (pass --force to overwrite it)")
