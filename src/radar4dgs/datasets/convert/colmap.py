"""``radar4dgs convert colmap``: a COLMAP model (text ``cameras.txt``, ``images.txt``,
``points3D.txt``, or the binary ``.bin`` files COLMAP writes by default) and its images into a
radar-less scene folder (docs/data/scene-format.md, docs/data/converters.md).

The model is ``SRC`` itself when it holds ``cameras.txt`` or ``cameras.bin``, else ``SRC/sparse/0``
or ``SRC/sparse`` (the text files when both forms are there);
the images are ``--images``, else ``SRC/images`` or the ``images`` folder beside ``sparse/``.
Camera models: SIMPLE_PINHOLE and PINHOLE as they are; SIMPLE_RADIAL, RADIAL, OPENCV and
FULL_OPENCV undistorted with OpenCV (same coefficients, ``getOptimalNewCameraMatrix`` alpha 0),
OPENCV_FISHEYE, SIMPLE_RADIAL_FISHEYE and RADIAL_FISHEYE with ``cv2.fisheye`` (balance 0); any
other model (FOV, THIN_PRISM_FISHEYE) is refused. Every registered image must use the same
camera (the scene format has one). ``images.txt`` holds the world-to-camera pose in OpenCV axes, which is the scene's
``world_to_camera``. ``points3D.txt`` becomes ``priors/points3d.npy``.

Timestamps: COLMAP has none; frames are ordered by image name (as gsplat's and nerfstudio's
COLMAP readers order them), ``--frame-interval`` seconds apart.
"""

from __future__ import annotations

import struct
from dataclasses import dataclass
from pathlib import Path
from typing import Annotated, Optional

import numpy as np
import tyro
from scipy.spatial.transform import Rotation

from radar4dgs.datasets.convert.camera_import import (
    DEFAULT_FRAME_INTERVAL,
    frame_names,
    frame_of,
    image_reader,
    order_timestamps,
    pinhole_K,
    refuse_existing,
    write_radarless_scene,
)
from radar4dgs.io.scene import DEFAULT_TEST_EVERY, SceneError

# model -> (number of parameters, params -> (fx, fy, cx, cy), params -> OpenCV distortion or None)
CAMERA_MODELS = {
    "SIMPLE_PINHOLE": (3, lambda p: (p[0], p[0], p[1], p[2]), lambda p: None),
    "PINHOLE": (4, lambda p: tuple(p[:4]), lambda p: None),
    "SIMPLE_RADIAL": (4, lambda p: (p[0], p[0], p[1], p[2]), lambda p: [p[3], 0.0, 0.0, 0.0]),
    "RADIAL": (5, lambda p: (p[0], p[0], p[1], p[2]), lambda p: [p[3], p[4], 0.0, 0.0]),
    "OPENCV": (8, lambda p: tuple(p[:4]), lambda p: list(p[4:8])),
    "FULL_OPENCV": (12, lambda p: tuple(p[:4]), lambda p: list(p[4:12])),
    # OpenCV's fisheye model (cv2.fisheye): k1..k4.
    "OPENCV_FISHEYE": (8, lambda p: tuple(p[:4]), lambda p: list(p[4:8])),
    "SIMPLE_RADIAL_FISHEYE": (4, lambda p: (p[0], p[0], p[1], p[2]), lambda p: [p[3], 0.0, 0.0, 0.0]),
    "RADIAL_FISHEYE": (5, lambda p: (p[0], p[0], p[1], p[2]), lambda p: [p[3], p[4], 0.0, 0.0]),
}
FISHEYE_MODELS = ("OPENCV_FISHEYE", "SIMPLE_RADIAL_FISHEYE", "RADIAL_FISHEYE")


def _data_lines(path: Path) -> list[str]:
    """The lines of a COLMAP text file without its ``#`` comments (empty lines kept)."""
    if not path.is_file():
        raise SceneError(path, "missing file (a COLMAP text model has cameras.txt, images.txt, points3D.txt)")
    try:
        return [line for line in path.read_text(encoding="utf-8").splitlines() if not line.startswith("#")]
    except (OSError, UnicodeDecodeError) as exc:
        raise SceneError(path, f"unreadable file ({exc})") from exc


def read_cameras(path: Path) -> dict[int, tuple[str, int, int, list[float]]]:
    """``cameras.txt``: {CAMERA_ID: (MODEL, WIDTH, HEIGHT, PARAMS)}."""
    cameras = {}
    for n, line in enumerate(_data_lines(path)):
        words = line.split()
        if not words:
            continue
        try:
            cameras[int(words[0])] = (words[1], int(words[2]), int(words[3]), [float(w) for w in words[4:]])
        except (IndexError, ValueError):
            raise SceneError(path, f"line {n + 1}: expected CAMERA_ID MODEL WIDTH HEIGHT PARAMS[], got "
                                   f"{line.strip()!r}") from None
    return cameras


def read_images(path: Path) -> list[tuple[str, np.ndarray, int]]:
    """``images.txt``: [(NAME, (4, 4) world-to-camera, CAMERA_ID)], in file order. Each image is one
    line ``IMAGE_ID QW QX QY QZ TX TY TZ CAMERA_ID NAME`` followed by its 2D-points line (which may
    be empty)."""
    images, expect_image = [], True
    for n, line in enumerate(_data_lines(path)):
        if not expect_image:
            expect_image = True
            continue
        words = line.split()
        if not words:
            continue
        try:
            qw, qx, qy, qz, tx, ty, tz = (float(w) for w in words[1:8])
            camera_id, name = int(words[8]), " ".join(words[9:])
        except (IndexError, ValueError):
            raise SceneError(path, f"line {n + 1}: expected IMAGE_ID QW QX QY QZ TX TY TZ CAMERA_ID NAME, got "
                                   f"{line.strip()!r}") from None
        if not name:
            raise SceneError(path, f"line {n + 1}: an image without a NAME")
        w2c = np.eye(4)
        w2c[:3, :3] = Rotation.from_quat([qx, qy, qz, qw]).as_matrix()
        w2c[:3, 3] = (tx, ty, tz)
        images.append((name, w2c, camera_id))
        expect_image = False
    if not images:
        raise SceneError(path, "no images")
    return images


def read_points3d(path: Path) -> tuple[np.ndarray, np.ndarray]:
    """``points3D.txt``: (M, 3) float64 ``X Y Z`` and (M, 3) colours in [0, 1] (``R G B`` / 255)."""
    rows = []
    for n, line in enumerate(_data_lines(path)):
        words = line.split()
        if not words:
            continue
        try:
            rows.append([float(w) for w in words[1:7]])
        except ValueError:
            raise SceneError(path, f"line {n + 1}: expected POINT3D_ID X Y Z R G B ..., got {line.strip()!r}") \
                from None
        if len(rows[-1]) != 6:
            raise SceneError(path, f"line {n + 1}: expected POINT3D_ID X Y Z R G B ..., got {line.strip()!r}")
    table = np.asarray(rows, dtype=np.float64).reshape(-1, 6)
    return table[:, :3], np.clip(table[:, 3:] / 255.0, 0.0, 1.0)


# COLMAP's binary model ids -> (name, number of parameters), as its read_write_model.py.
BINARY_MODELS = {0: ("SIMPLE_PINHOLE", 3), 1: ("PINHOLE", 4), 2: ("SIMPLE_RADIAL", 4), 3: ("RADIAL", 5),
                 4: ("OPENCV", 8), 5: ("OPENCV_FISHEYE", 8), 6: ("FULL_OPENCV", 12), 7: ("FOV", 5),
                 8: ("SIMPLE_RADIAL_FISHEYE", 4), 9: ("RADIAL_FISHEYE", 5), 10: ("THIN_PRISM_FISHEYE", 12)}


class _Reader:
    """Little-endian values read one after another from a binary model file."""

    def __init__(self, path: Path):
        if not path.is_file():
            raise SceneError(path, "missing file (a COLMAP binary model has cameras.bin, images.bin, points3D.bin)")
        self.path, self.data, self.at = path, path.read_bytes(), 0

    def take(self, fmt: str) -> tuple:
        try:
            values = struct.unpack_from("<" + fmt, self.data, self.at)
        except struct.error:
            raise SceneError(self.path, f"truncated binary model at byte {self.at}") from None
        self.at += struct.calcsize("<" + fmt)
        return values

    def name(self) -> str:
        end = self.data.find(b"\x00", self.at)
        if end < 0:
            raise SceneError(self.path, f"truncated binary model at byte {self.at}")
        text, self.at = self.data[self.at:end].decode("utf-8", "replace"), end + 1
        return text


def read_cameras_bin(path: Path) -> dict[int, tuple[str, int, int, list[float]]]:
    """``cameras.bin``, as :func:`read_cameras`."""
    reader, cameras = _Reader(path), {}
    for _ in range(reader.take("Q")[0]):
        camera_id, model_id, width, height = reader.take("iiQQ")
        if model_id not in BINARY_MODELS:
            raise SceneError(path, f"camera {camera_id}: unknown camera model id {model_id}")
        name, count = BINARY_MODELS[model_id]
        cameras[camera_id] = (name, int(width), int(height), list(reader.take(f"{count}d")))
    return cameras


def read_images_bin(path: Path) -> list[tuple[str, np.ndarray, int]]:
    """``images.bin``, as :func:`read_images` (the 2D points are skipped)."""
    reader, images = _Reader(path), []
    for _ in range(reader.take("Q")[0]):
        _, qw, qx, qy, qz, tx, ty, tz, camera_id = reader.take("i7di")
        name = reader.name()
        points2d = reader.take("Q")[0]  # (read before `at` is: `at += take()` would lose its 8 bytes)
        reader.at += 24 * points2d  # x, y (double), POINT3D_ID (int64) per 2D point
        w2c = np.eye(4)
        w2c[:3, :3] = Rotation.from_quat([qx, qy, qz, qw]).as_matrix()
        w2c[:3, 3] = (tx, ty, tz)
        images.append((name, w2c, camera_id))
    if not images:
        raise SceneError(path, "no images")
    return images


def read_points3d_bin(path: Path) -> tuple[np.ndarray, np.ndarray]:
    """``points3D.bin``, as :func:`read_points3d` (errors and tracks skipped)."""
    reader = _Reader(path)
    count = reader.take("Q")[0]
    xyz, rgb = np.zeros((count, 3)), np.zeros((count, 3))
    for k in range(count):
        values = reader.take("Q3d3Bd")
        xyz[k], rgb[k] = values[1:4], values[4:7]
        track = reader.take("Q")[0]
        reader.at += 8 * track  # IMAGE_ID, POINT2D_IDX (int32 each) per track element
    return xyz, rgb / 255.0


def read_model(model: Path) -> tuple[dict, list, tuple[np.ndarray, np.ndarray], str]:
    """Cameras, images and points of the model folder (text when it has ``cameras.txt``, else
    binary) and which form was read."""
    if (model / "cameras.txt").is_file():
        return (read_cameras(model / "cameras.txt"), read_images(model / "images.txt"),
                read_points3d(model / "points3D.txt"), "text")
    return (read_cameras_bin(model / "cameras.bin"), read_images_bin(model / "images.bin"),
            read_points3d_bin(model / "points3D.bin"), "binary")


def locate(src: Path, images: Optional[Path]) -> tuple[Path, Path]:
    """The model folder and the images folder of ``src`` (module doc)."""
    if not src.is_dir():
        raise SceneError(src, "missing folder (a COLMAP project or model)")
    model = next((m for m in (src, src / "sparse" / "0", src / "sparse")
                  if (m / "cameras.txt").is_file() or (m / "cameras.bin").is_file()), None)
    if model is None:
        raise SceneError(src, "not a COLMAP model (no cameras.txt or cameras.bin in it, sparse/0 or sparse)")
    if images is None:
        images = next((d for d in (src / "images", model.parent.parent / "images", model / "images") if d.is_dir()),
                      src / "images")
    if not Path(images).is_dir():
        raise SceneError(images, "missing images folder (pass --images)")
    return model, Path(images)


def scene_camera(cameras: dict, used: set[int], where: Path) -> tuple[np.ndarray, tuple[int, int], list | None, str]:
    """``K``, (width, height), OpenCV distortion (None without) and the model of the one camera
    the images use; a :class:`SceneError` for several cameras or an unsupported model."""
    missing = sorted(used - set(cameras))
    if missing:
        raise SceneError(where, f"images use camera ids {missing} that cameras.txt does not hold")
    distinct = {(cameras[c][0], cameras[c][1], cameras[c][2], tuple(cameras[c][3])) for c in used}
    if len(distinct) > 1:
        raise SceneError(where, f"the images use {len(distinct)} different cameras; the scene format has one "
                                f"(convert each camera's images separately)")
    model, width, height, params = distinct.pop()
    if model not in CAMERA_MODELS:
        raise SceneError(where, f"camera model {model} is not supported ({', '.join(CAMERA_MODELS)}); undistort "
                                f"the images first (`colmap image_undistorter`)")
    count, intrinsics, distortion = CAMERA_MODELS[model]
    if len(params) != count:
        raise SceneError(where, f"camera model {model} has {count} parameters, got {len(params)}")
    dist = distortion(params)
    return pinhole_K(*intrinsics(params)), (width, height), dist if dist and any(dist) else None, model


def convert_colmap(src: str | Path, out: str | Path, images: str | Path | None = None,
                   frame_interval: float = DEFAULT_FRAME_INTERVAL, test_every: int = DEFAULT_TEST_EVERY,
                   overwrite: bool = False, progress: bool = True) -> Path:
    """Convert the COLMAP model in ``src`` into the radar-less scene folder ``out`` and return
    ``out`` (module doc)."""
    src, out = Path(src), Path(out)
    refuse_existing(out, overwrite)
    model, image_dir = locate(src, None if images is None else Path(images))
    cameras, registered, points, form = read_model(model)
    registered = sorted(registered, key=lambda item: item[0])
    cameras_file = model / ("cameras.txt" if form == "text" else "cameras.bin")
    K, size, distortion, camera_model = scene_camera(cameras, {c for _, _, c in registered}, cameras_file)
    files = [name for name, _, _ in registered]
    names = frame_names(files)
    stamps = order_timestamps(len(files), frame_interval)
    frames = [frame_of(names[k], stamps[k], w2c, f"images.txt pose of {name}", model / "images.txt",
                       {"source_file": name}) for k, (name, w2c, _) in enumerate(registered)]
    camera, read_image = image_reader([image_dir / f for f in files], K, distortion, size,
                                      camera_model in FISHEYE_MODELS)
    source = {"dataset": "colmap", "path": str(model.resolve()), "model": form, "images_path": str(image_dir.resolve()),
              "radar": "absent", "camera_model": camera_model,
              "images": ("undistorted (OpenCV fisheye, balance 0)" if camera_model in FISHEYE_MODELS else
                         "undistorted (OpenCV, getOptimalNewCameraMatrix alpha=0)") if distortion else "copied",
              "timestamps": "the images' order (sorted by name), --frame-interval seconds apart",
              "points": int(len(points[0]))}
    return write_radarless_scene(out, f"colmap-{src.name}", camera, frames, read_image, points, source, test_every,
                                 overwrite, progress, "colmap")


@dataclass
class ConvertColmapCommand:
    """Convert a COLMAP model (cameras, images, points3D) and its images into a radar-less scene folder."""

    # The COLMAP project folder (with sparse/0 and images/) or the model folder itself (text or binary).
    src: tyro.conf.Positional[Path]
    # The scene folder to write.
    out: tyro.conf.Positional[Path]
    # The images folder.
    images: Annotated[Optional[Path], tyro.conf.arg(
        help_behavior_hint="(default: SRC/images, or the images folder beside sparse/)")] = None
    # Seconds between consecutive frames (COLMAP has no timestamps).
    frame_interval: float = DEFAULT_FRAME_INTERVAL
    # Every k-th frame is a test frame; 0 = no test frames.
    test_every: int = DEFAULT_TEST_EVERY
    # Overwrite an existing output folder.
    force: bool = False
    # Hide the progress bar.
    quiet: bool = False

    def run(self) -> int:
        # A missing or malformed model raises a user error: one line (radar4dgs.cli).
        out = convert_colmap(self.src, self.out, self.images, self.frame_interval, self.test_every, self.force,
                             progress=not self.quiet)
        print(f"wrote {out} (no radar: train it with --method static)")
        return 0
