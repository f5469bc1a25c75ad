"""Reading and validating a scene folder: :func:`read_scene` parses ``scene.json`` section by
section (format, camera, radar, frames, split and source), refusing a broken scene with a
:class:`~radar4dgs.io.scene_format.SceneError` that names the file and the problem, then checks
that every frame's image and radar file exists with the declared size and column count."""

from __future__ import annotations

import math
from pathlib import Path
from typing import Any, Mapping, Sequence

import numpy as np
from PIL import Image

from radar4dgs.io.scene_files import _check_radar_shape, _load_npy
from radar4dgs.io.scene_format import (
    DEFAULT_TEST_EVERY,
    FORMAT_NAME,
    FORMAT_VERSION,
    IMAGE_SUFFIXES,
    ORTHONORMAL_TOLERANCE,
    REQUIRED_RADAR_FIELDS,
    SceneError,
    read_json_file,
)
from radar4dgs.io.scene_types import Camera, Frame, MissingRadar, RadarSpec, Scene

# --------------------------------------------------------------------------------------------
# Checked values


def _matrix(value: Any, shape: tuple[int, int], where: str, path: Path) -> np.ndarray:
    try:
        matrix = np.asarray(value, dtype=np.float64)
    except (TypeError, ValueError):
        raise SceneError(path, f"{where} is not a numeric {shape[0]}x{shape[1]} matrix") from None
    if matrix.shape != shape:
        raise SceneError(path, f"{where} has shape {matrix.shape}, expected {shape[0]}x{shape[1]}")
    if not np.isfinite(matrix).all():
        raise SceneError(path, f"{where} contains NaN or inf")
    return matrix


def rigid_matrix(value: Any, where: str, path: Path) -> np.ndarray:
    matrix = _matrix(value, (4, 4), where, path)
    rotation = matrix[:3, :3]
    error = np.abs(rotation.T @ rotation - np.eye(3)).max()
    if error > ORTHONORMAL_TOLERANCE or np.linalg.det(rotation) < 0:
        raise SceneError(path, f"{where}: rotation block is not orthonormal with det +1 "
                         f"(max |R^T R - I| = {error:.2e})")
    if not np.allclose(matrix[3], [0.0, 0.0, 0.0, 1.0], atol=1e-9):
        raise SceneError(path, f"{where}: last row is {matrix[3].tolist()}, expected [0, 0, 0, 1]")
    return matrix


def _require(mapping: Mapping[str, Any], key: str, where: str, path: Path) -> Any:
    if not isinstance(mapping, Mapping) or key not in mapping:
        raise SceneError(path, f"missing key {where}{key!r}")
    return mapping[key]


def _number(value: Any, where: str, path: Path) -> float:
    if isinstance(value, bool) or not isinstance(value, (int, float)) or not math.isfinite(value):
        raise SceneError(path, f"{where} must be a finite number, got {value!r}")
    return float(value)


_FRAME_KEYS = {"name", "timestamp", "ego_to_world", "radar_timestamp", "radar_ego_to_world", "ego_velocity"}
_SCENE_KEYS = {"format", "version", "name", "source", "camera", "radar", "frames", "test_every"}


def _parse_frame(entry: Any, index: int, path: Path) -> Frame:
    where = f"frames[{index}]."
    if not isinstance(entry, Mapping):
        raise SceneError(path, f"frames[{index}] is not an object")
    name = _require(entry, "name", where, path)
    if not isinstance(name, str) or not name or "/" in name or "\\" in name:
        raise SceneError(path, f"{where}name must be a non-empty file stem, got {name!r}")
    timestamp = _number(_require(entry, "timestamp", where, path), f"{where}timestamp", path)
    ego_to_world = rigid_matrix(_require(entry, "ego_to_world", where, path), f"{where}ego_to_world", path)
    radar_timestamp = _number(entry.get("radar_timestamp", timestamp), f"{where}radar_timestamp", path)
    radar_pose = entry.get("radar_ego_to_world")
    radar_ego_to_world = ego_to_world if radar_pose is None else rigid_matrix(
        radar_pose, f"{where}radar_ego_to_world", path)
    velocity = entry.get("ego_velocity")
    if velocity is not None:
        velocity = np.asarray(velocity, dtype=np.float64)
        if velocity.shape != (3,) or not np.isfinite(velocity).all():
            raise SceneError(path, f"{where}ego_velocity must be 3 finite floats")
    extra = {k: v for k, v in entry.items() if k not in _FRAME_KEYS}
    return Frame(name, timestamp, ego_to_world, radar_timestamp, radar_ego_to_world, velocity, extra)


def _find_image(root: Path, name: str) -> Path:
    for suffix in IMAGE_SUFFIXES:
        candidate = root / "images" / f"{name}{suffix}"
        if candidate.is_file():
            return candidate
    raise SceneError(root / "images" / f"{name}.png", "missing image (looked for .png, .jpg and .jpeg)")



# --------------------------------------------------------------------------------------------
# scene.json, section by section


def _load_meta(root: Path) -> tuple[Path, Mapping[str, Any]]:
    """The path of ``scene.json`` and its top-level object, after the format name and version."""
    if not root.is_dir():
        raise SceneError(root, "not a scene folder (no such directory)")
    meta_path = root / "scene.json"
    if not meta_path.is_file():
        raise SceneError(meta_path, "missing file")
    meta = read_json_file(meta_path)
    if not isinstance(meta, Mapping):
        raise SceneError(meta_path, "top level must be a JSON object")
    if meta.get("format") != FORMAT_NAME:
        raise SceneError(meta_path, f"'format' is {meta.get('format')!r}, expected {FORMAT_NAME!r}")
    if meta.get("version") != FORMAT_VERSION:
        raise SceneError(meta_path, f"'version' is {meta.get('version')!r}; this reader knows version "
                         f"{FORMAT_VERSION}")
    return meta_path, meta


def _parse_camera(meta: Mapping[str, Any], meta_path: Path) -> Camera:
    """The ``camera`` section: positive integer size, pinhole K, rigid cam_to_ego."""
    cam = _require(meta, "camera", "", meta_path)
    width, height = _require(cam, "width", "camera.", meta_path), _require(cam, "height", "camera.", meta_path)
    if not all(isinstance(v, int) and not isinstance(v, bool) and v > 0 for v in (width, height)):
        raise SceneError(meta_path, f"camera.width/height must be positive integers, got {width!r}, {height!r}")
    K = _matrix(_require(cam, "K", "camera.", meta_path), (3, 3), "camera.K", meta_path)
    if K[0, 0] <= 0 or K[1, 1] <= 0 or not np.allclose(K[2], [0, 0, 1]):
        raise SceneError(meta_path, "camera.K must have positive focal lengths and last row [0, 0, 1]")
    return Camera(width, height, K, rigid_matrix(_require(cam, "cam_to_ego", "camera.", meta_path),
                                           "camera.cam_to_ego", meta_path))


def _parse_radar(meta: Mapping[str, Any], meta_path: Path) -> RadarSpec | MissingRadar:
    """The ``radar`` section: unique column names including the required ones, rigid radar_to_ego;
    a :class:`MissingRadar` when the section is absent or null (a radar-less scene,
    docs/data/scene-format.md)."""
    rad = meta.get("radar")
    if rad is None:
        return MissingRadar(meta_path.parent)
    fields = _require(rad, "fields", "radar.", meta_path)
    if not isinstance(fields, list) or not all(isinstance(f, str) for f in fields):
        raise SceneError(meta_path, "radar.fields must be a list of column names")
    missing = [f for f in REQUIRED_RADAR_FIELDS if f not in fields]
    if missing:
        raise SceneError(meta_path, f"radar.fields lacks required columns {missing}")
    if len(set(fields)) != len(fields):
        raise SceneError(meta_path, f"radar.fields has duplicate names {fields}")
    return RadarSpec(rigid_matrix(_require(rad, "radar_to_ego", "radar.", meta_path), "radar.radar_to_ego",
                            meta_path), tuple(fields))


def _check_increasing(frames: Sequence[Frame], meta_path: Path) -> None:
    """Refuse camera or radar timestamps that do not strictly increase, naming the first pair."""
    for attribute in ("timestamp", "radar_timestamp"):
        stamps = np.array([getattr(f, attribute) for f in frames])
        bad = np.nonzero(np.diff(stamps) <= 0)[0]
        if len(bad):
            i = int(bad[0])
            raise SceneError(meta_path, f"{attribute}s do not increase: frames[{i}] ({frames[i].name}) at "
                             f"{stamps[i]:.6f} s, frames[{i + 1}] ({frames[i + 1].name}) at {stamps[i + 1]:.6f} s")


def _parse_frames(meta: Mapping[str, Any], meta_path: Path) -> tuple[Frame, ...]:
    """The ``frames`` list: a non-empty list of valid frames with unique names, in time order."""
    entries = _require(meta, "frames", "", meta_path)
    if not isinstance(entries, list) or not entries:
        raise SceneError(meta_path, "'frames' must be a non-empty list")
    frames = tuple(_parse_frame(entry, i, meta_path) for i, entry in enumerate(entries))
    names = [f.name for f in frames]
    if len(set(names)) != len(names):
        duplicated = sorted({n for n in names if names.count(n) > 1})
        raise SceneError(meta_path, f"duplicate frame names {duplicated}")
    _check_increasing(frames, meta_path)
    return frames


def _parse_test_every(meta: Mapping[str, Any], meta_path: Path) -> int:
    """The optional integer ``test_every`` (default ``DEFAULT_TEST_EVERY``)."""
    test_every = meta.get("test_every", DEFAULT_TEST_EVERY)
    if isinstance(test_every, bool) or not isinstance(test_every, int):
        raise SceneError(meta_path, f"test_every must be an integer, got {test_every!r}")
    return test_every


def _parse_source(meta: Mapping[str, Any], meta_path: Path) -> Mapping[str, Any]:
    """The optional ``source`` object (default empty)."""
    source = meta.get("source", {})
    if not isinstance(source, Mapping):
        raise SceneError(meta_path, "'source' must be an object")
    return source


# --------------------------------------------------------------------------------------------
# Per-frame files


def _check_images(image_files: Sequence[Path], width: int, height: int) -> None:
    """Every image opens (header only) with the camera's size and an 8-bit RGB-like mode."""
    for image_path in image_files:
        try:
            with Image.open(image_path) as image:
                size = image.size
                mode = image.mode
        except Exception as exc:
            raise SceneError(image_path, f"unreadable image ({exc})") from exc
        if size != (width, height):
            raise SceneError(image_path, f"image is {size[0]}x{size[1]}, camera says {width}x{height}")
        if mode not in ("RGB", "L", "P", "RGBA"):
            raise SceneError(image_path, f"image mode {mode} is not 8-bit RGB")


def _check_radar_files(root: Path, frames: Sequence[Frame], fields: Sequence[str]) -> None:
    """Every frame's radar array exists and has the named column count (header only, memory-mapped)."""
    for frame in frames:
        radar_path = root / "radar" / f"{frame.name}.npy"
        _check_radar_shape(radar_path, _load_npy(radar_path, mmap_mode="r"), fields)


def read_scene(path: str | Path, check_files: bool = True) -> Scene:
    """Load and validate a scene folder.

    Checks every rule of ``SCENE_FORMAT.md`` that does not need the pixel or radar values: the JSON
    structure, 4x4 rigid matrices, increasing timestamps, that every image exists with the camera's
    size (header only) and that every radar array has the named column count. NaN/inf radar rows
    are dropped (with a warning) when a scan is loaded.

    Raises:
        SceneError: naming the offending file and the problem.
    """
    root = Path(path)
    meta_path, meta = _load_meta(root)
    camera = _parse_camera(meta, meta_path)
    radar = _parse_radar(meta, meta_path)
    frames = _parse_frames(meta, meta_path)
    test_every = _parse_test_every(meta, meta_path)
    source = _parse_source(meta, meta_path)

    image_files = tuple(_find_image(root, f.name) for f in frames)
    if check_files:
        _check_images(image_files, camera.width, camera.height)
        if isinstance(radar, RadarSpec):
            _check_radar_files(root, frames, radar.fields)

    extra = {k: v for k, v in meta.items() if k not in _SCENE_KEYS}
    return Scene(root, str(meta.get("name", root.name)), camera, radar, frames, dict(source), test_every,
                 image_files, extra)
