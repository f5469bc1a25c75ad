"""nerfstudio camera paths (``camera_path.json``, as nerfstudio's and gsplat's viewers save them) as
:class:`~radar4dgs.model.view.View` lists for ``radar4dgs render --trajectory nerfstudio:FILE``.

The file's ``camera_path`` list has one entry per rendered frame: ``camera_to_world`` (16 numbers,
a row-major 4x4 flattened, OpenGL camera axes: x right, y up, z back; a nested 4x4 is accepted
too), ``fov`` (the vertical field of view, degrees), ``aspect`` (width / height) and optionally
``render_time`` (nerfstudio's normalised time in [0, 1], which is the scene's normalised time;
0, the first frame, where absent). The image size is the file's ``render_width`` x
``render_height`` (``render_height * aspect`` when the width is absent), or the scene camera's
size when the file has neither; either is multiplied by ``--scale``. Pixels are square
(``fx = fy = 0.5 * height / tan(fov / 2)``) and the principal point is the image centre, as
nerfstudio renders them. The poses are in the scene's world frame (the frame of the run's
exports: ``radar4dgs export --format gsplat`` / ``nerfstudio``).
"""

from __future__ import annotations

import json
import math
import os
from pathlib import Path

import numpy as np

from radar4dgs.model.view import View, resized_size

PREFIX = "nerfstudio:"
# Rotation tolerance: the viewers write float32 matrices.
_ORTHONORMAL_TOL = 1e-3
_OPENCV_TO_OPENGL = np.diag([1.0, -1.0, -1.0, 1.0])


def is_nerfstudio(spec: str) -> bool:
    """Whether a ``--trajectory`` spec names a nerfstudio camera path."""
    return isinstance(spec, str) and spec.strip().lower().startswith(PREFIX)


def _matrix(value, where: str) -> np.ndarray:
    try:
        m = np.asarray(value, dtype=np.float64).reshape(4, 4)
    except (TypeError, ValueError):
        raise ValueError(f"{where}: 'camera_to_world' must be 16 numbers (a row-major 4x4)") from None
    if not np.isfinite(m).all():
        raise ValueError(f"{where}: 'camera_to_world' contains NaN or inf")
    R = m[:3, :3]
    if np.abs(m[3] - (0, 0, 0, 1)).max() > _ORTHONORMAL_TOL or np.abs(R @ R.T - np.eye(3)).max() > _ORTHONORMAL_TOL \
            or np.linalg.det(R) <= 0:
        raise ValueError(f"{where}: 'camera_to_world' is not a rigid transform (rotation and translation, "
                         "last row 0 0 0 1)")
    m[3] = (0, 0, 0, 1)
    return m


def _number(entry: dict, key: str, where: str, low: float, high: float, default: float | None = None) -> float:
    value = entry.get(key, default)
    if value is None or isinstance(value, bool) or not isinstance(value, (int, float)) \
            or not math.isfinite(value) or not low <= value <= high:
        raise ValueError(f"{where}: {key!r} must be a number in [{low:g}, {high:g}], got {value!r}")
    return float(value)


def read_camera_path(path: str | os.PathLike) -> dict:
    """Read and check a nerfstudio ``camera_path.json``: returns ``width`` / ``height`` (the file's
    render size, None where absent) and ``cameras``: a list of {``world_to_camera`` (4, 4) OpenCV,
    ``fov`` degrees, ``aspect``, ``time``}. Raises ValueError naming the file and the camera."""
    path = Path(path)
    try:
        data = json.loads(path.read_text(encoding="utf-8"))
    except (OSError, UnicodeDecodeError, json.JSONDecodeError) as exc:
        raise ValueError(f"{path}: cannot read the nerfstudio camera path: {exc}") from None
    if not isinstance(data, dict) or not isinstance(data.get("camera_path"), list) or not data["camera_path"]:
        raise ValueError(f"{path}: not a nerfstudio camera path (no non-empty 'camera_path' list)")
    cameras = []
    for i, entry in enumerate(data["camera_path"]):
        where = f"{path}: camera {i}"
        if not isinstance(entry, dict) or "camera_to_world" not in entry:
            raise ValueError(f"{where}: expected an object with 'camera_to_world'")
        c2w_gl = _matrix(entry["camera_to_world"], where)
        cameras.append({"world_to_camera": np.linalg.inv(c2w_gl @ _OPENCV_TO_OPENGL),
                        "fov": _number(entry, "fov", where, 1e-3, 179.0),
                        "aspect": _number(entry, "aspect", where, 1e-3, 1e3, default=data.get("aspect", 16 / 9)),
                        "time": _number(entry, "render_time", where, 0.0, 1.0, default=0.0)})
    sizes = {}
    for key in ("render_width", "render_height"):
        value = data.get(key)
        if value is not None and (isinstance(value, bool) or not isinstance(value, (int, float)) or value < 1):
            raise ValueError(f"{path}: {key!r} must be a positive number of pixels, got {value!r}")
        sizes[key] = None if value is None else int(round(value))
    return {"width": sizes["render_width"], "height": sizes["render_height"], "cameras": cameras}


def nerfstudio_intrinsics(fov_deg: float, width: int, height: int) -> np.ndarray:
    """(3, 3) K in the scene's convention (pixel centres at integer coordinates) of a camera with
    vertical field of view ``fov_deg``, square pixels and the principal point at the image centre."""
    f = 0.5 * height / math.tan(math.radians(fov_deg) / 2.0)
    return np.array([[f, 0.0, width / 2.0 - 0.5], [0.0, f, height / 2.0 - 0.5], [0.0, 0.0, 1.0]])


def camera_path_views(path: str | os.PathLike, camera, scale: float = 1.0) -> list[View]:
    """The :class:`View` of every camera of the nerfstudio path ``path``; ``camera`` (the scene's)
    gives the size where the file has none."""
    parsed = read_camera_path(path)
    views = []
    for cam in parsed["cameras"]:
        if parsed["height"] is not None:
            base_h = parsed["height"]
            base_w = parsed["width"] if parsed["width"] is not None else max(1, round(base_h * cam["aspect"]))
        else:
            base_w, base_h = camera.width, camera.height
        width, height = resized_size(base_w, base_h, scale)
        views.append(View(cam["world_to_camera"], nerfstudio_intrinsics(cam["fov"], width, height), width, height,
                          cam["time"]))
    return views


def write_camera_path(path: str | os.PathLike, world_to_cameras, fovs, times, width: int, height: int) -> Path:
    """Write a nerfstudio camera path (one camera per pose: OpenCV ``world_to_cameras`` (N, 4, 4),
    vertical ``fovs`` in degrees, normalised ``times``) with render size ``width`` x ``height``."""
    from radar4dgs.io.atomic import atomic_write_json

    entries = []
    for w2c, fov, t in zip(world_to_cameras, fovs, times, strict=True):
        c2w_gl = np.linalg.inv(np.asarray(w2c, dtype=np.float64)) @ _OPENCV_TO_OPENGL
        entries.append({"camera_to_world": c2w_gl.reshape(-1).tolist(), "fov": float(fov),
                        "aspect": width / height, "render_time": float(t)})
    return atomic_write_json(path, {"camera_type": "perspective", "render_width": int(width),
                                    "render_height": int(height), "fps": 10, "seconds": len(entries) / 10,
                                    "camera_path": entries})
