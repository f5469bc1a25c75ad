"""The scene folder, version 1 (``SCENE_FORMAT.md``), as typed classes, a validating reader and an
atomic writer.

Every data source is converted into this layout once; every later stage reads only this layout.
The reader refuses a broken scene with a :class:`SceneError` that names the file and the problem.
"""

from __future__ import annotations

import json
import math
import warnings
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Iterable, Mapping, Sequence

import numpy as np
from PIL import Image

from radar4dgs.io.atomic import atomic_directory, atomic_save_npy, atomic_write_json

FORMAT_NAME = "radar4dgs-scene"
FORMAT_VERSION = 1
REQUIRED_RADAR_FIELDS = ("x", "y", "z", "v_r")
IMAGE_SUFFIXES = (".png", ".jpg", ".jpeg")
DEFAULT_TEST_EVERY = 4
# Optional per-frame folders: name -> (file suffix, what it holds). Kept here so the reader, the
# writer and `inspect` agree on one list.
OPTIONAL_FOLDERS: dict[str, str] = {
    "lidar": ".npy",
    "priors/mono_depth": ".npy",
    "priors/sky_mask": ".png",
    "gt/depth": ".npy",
    "gt/dynamic_mask": ".png",
    "gt/sky_mask": ".png",
    "gt/flow": ".npy",
    "gt/radar_labels": ".npy",
}
# A rotation block is accepted as orthonormal when ||R^T R - I||_max stays below this; converters
# write float64 matrices, but float32 round trips in other tools lose about 1e-7.
ORTHONORMAL_TOLERANCE = 1e-4


class SceneError(ValueError):
    """A scene folder breaks the format; the message names the file and the problem."""

    def __init__(self, path: Path | str, problem: str):
        self.path = Path(path)
        self.problem = problem
        super().__init__(f"{path}: {problem}")


class SceneWarning(UserWarning):
    """Something in a scene was repaired on load (dropped rows, an empty radar frame)."""


# --------------------------------------------------------------------------------------------
# Typed classes


@dataclass(frozen=True)
class Camera:
    """A pinhole camera with undistorted images.

    Attributes:
        width, height: image size in pixels.
        K: (3, 3) float64 intrinsics for the stored images.
        cam_to_ego: (4, 4) float64, OpenCV camera axes (x right, y down, z forward) to ego axes.
    """

    width: int
    height: int
    K: np.ndarray
    cam_to_ego: np.ndarray

    def project(self, points_cam: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Project (N, 3) camera-frame points; returns (N, 2) pixel coordinates and (N,) z-depth."""
        z = points_cam[:, 2]
        with np.errstate(divide="ignore", invalid="ignore"):
            uv = (points_cam @ self.K.T)[:, :2] / z[:, None]
        return uv, z


@dataclass(frozen=True)
class RadarSpec:
    """The radar's mounting and the columns of its per-frame arrays."""

    radar_to_ego: np.ndarray
    fields: tuple[str, ...]

    def column(self, name: str) -> int:
        try:
            return self.fields.index(name)
        except ValueError:
            raise KeyError(f"radar has no column {name!r}; columns are {list(self.fields)}") from None


@dataclass(frozen=True)
class Frame:
    """One time step: a camera image and the radar scan closest to it.

    Attributes:
        name: file stem shared by every per-frame file.
        timestamp: camera capture time (s).
        ego_to_world: (4, 4) ego pose at ``timestamp``.
        radar_timestamp: radar capture time (s); equals ``timestamp`` when the scene omits it.
        radar_ego_to_world: (4, 4) ego pose at ``radar_timestamp``.
        ego_velocity: (3,) m/s in the ego frame, or None.
        extra: any other keys of the frame's JSON object, kept so a round trip loses nothing.
    """

    name: str
    timestamp: float
    ego_to_world: np.ndarray
    radar_timestamp: float
    radar_ego_to_world: np.ndarray
    ego_velocity: np.ndarray | None = None
    extra: Mapping[str, Any] = field(default_factory=dict)


@dataclass(frozen=True)
class RadarScan:
    """One radar frame: ``data`` (N, F) float32 in the radar frame, columns named by ``fields``.

    ``rows`` (N,) are the indices of these points among the ``stored`` rows of the file (rows with
    NaN are dropped on load), so per-row files such as ``gt/radar_labels`` can be aligned.
    """

    data: np.ndarray
    fields: tuple[str, ...]
    rows: np.ndarray | None = None
    stored: int | None = None

    def align(self, per_stored_row: np.ndarray, path: Path | str) -> np.ndarray:
        """The entries of an array with one entry per stored row (``gt/radar_labels``) that belong
        to this scan's points; a :class:`SceneError` naming ``path`` when the counts disagree."""
        stored = len(self) if self.stored is None else self.stored
        if len(per_stored_row) != stored:
            raise SceneError(path, f"{len(per_stored_row)} entries for {stored} stored radar rows")
        return per_stored_row if self.rows is None else per_stored_row[self.rows]

    def __len__(self) -> int:
        return int(self.data.shape[0])

    def column(self, name: str) -> np.ndarray:
        """(N,) values of one named column."""
        if name not in self.fields:
            raise KeyError(f"radar has no column {name!r}; columns are {list(self.fields)}")
        return self.data[:, self.fields.index(name)]

    @property
    def xyz(self) -> np.ndarray:
        """(N, 3) positions in the radar frame (m)."""
        return np.stack([self.column("x"), self.column("y"), self.column("z")], axis=1)

    @property
    def v_r(self) -> np.ndarray:
        """(N,) raw Doppler radial velocity (m/s), positive = receding."""
        return self.column("v_r")


def normalized_times(scene) -> np.ndarray:
    """(N,) float64 ``t = (timestamp - t_first) / (t_last - t_first)``; all zeros for one frame."""
    stamps = np.array([f.timestamp for f in scene.frames], dtype=np.float64)
    span = stamps[-1] - stamps[0] if len(stamps) > 1 else 0.0
    return (stamps - stamps[0]) / span if span > 0 else np.zeros_like(stamps)


def split_indices(num_frames: int, test_every: int = DEFAULT_TEST_EVERY) -> tuple[list[int], list[int]]:
    """Train and test frame indices: frame i is a test frame when ``(i + 1) % test_every == 0``.

    ``test_every <= 0`` means no test frames.
    """
    if test_every <= 0:
        return list(range(num_frames)), []
    test = [i for i in range(num_frames) if (i + 1) % test_every == 0]
    test_set = set(test)
    return [i for i in range(num_frames) if i not in test_set], test


@dataclass(frozen=True)
class Scene:
    """A loaded scene folder. Per-frame arrays are read on demand with the ``load_*`` methods."""

    root: Path
    name: str
    camera: Camera
    radar: RadarSpec
    frames: tuple[Frame, ...]
    source: Mapping[str, Any] = field(default_factory=dict)
    test_every: int = DEFAULT_TEST_EVERY
    image_files: tuple[Path, ...] = ()
    extra: Mapping[str, Any] = field(default_factory=dict)

    def __len__(self) -> int:
        return len(self.frames)

    # ---- split
    @property
    def train_indices(self) -> list[int]:
        return split_indices(len(self.frames), self.test_every)[0]

    @property
    def test_indices(self) -> list[int]:
        return split_indices(len(self.frames), self.test_every)[1]

    @property
    def duration(self) -> float:
        return float(self.frames[-1].timestamp - self.frames[0].timestamp) if self.frames else 0.0

    # ---- optional folders
    def has(self, folder: str) -> bool:
        """True when the optional ``folder`` (a key of ``OPTIONAL_FOLDERS``) holds every frame's file."""
        suffix = OPTIONAL_FOLDERS[folder]
        return all((self.root / folder / f"{f.name}{suffix}").is_file() for f in self.frames)

    def optional_folders(self) -> list[str]:
        return [name for name in OPTIONAL_FOLDERS if self.has(name)]

    def _frame(self, index: int) -> Frame:
        return self.frames[index]

    # ---- loaders
    def load_image(self, index: int) -> np.ndarray:
        """(H, W, 3) uint8 RGB image of frame ``index``."""
        path = self.image_files[index]
        try:
            with Image.open(path) as image:
                array = np.asarray(image.convert("RGB"))
        except Exception as exc:  # PIL raises many types for broken files
            raise SceneError(path, f"unreadable image ({exc})") from exc
        if array.shape[:2] != (self.camera.height, self.camera.width):
            raise SceneError(path, f"image is {array.shape[1]}x{array.shape[0]}, camera says "
                             f"{self.camera.width}x{self.camera.height}")
        return array

    def load_radar(self, index: int) -> RadarScan:
        """The radar scan of frame ``index``; rows with NaN/inf in x, y, z or v_r are dropped with a
        :class:`SceneWarning` that counts them; an empty scan is allowed and warned."""
        path = self.root / "radar" / f"{self._frame(index).name}.npy"
        data = _load_npy(path)
        _check_radar_shape(path, data, self.radar.fields)
        data = data.astype(np.float32, copy=False)
        required = [self.radar.fields.index(name) for name in REQUIRED_RADAR_FIELDS]
        finite = np.isfinite(data[:, required]).all(axis=1)
        stored = len(data)
        if not finite.all():
            warnings.warn(f"{path}: dropped {int((~finite).sum())} of {stored} radar rows with NaN or "
                          f"inf in x, y, z or v_r", SceneWarning, stacklevel=2)
            data = data[finite]
        if len(data) == 0:
            warnings.warn(f"{path}: empty radar frame", SceneWarning, stacklevel=2)
        return RadarScan(np.ascontiguousarray(data), self.radar.fields, np.flatnonzero(finite), stored)

    def load_optional(self, folder: str, index: int) -> np.ndarray:
        """Array of optional ``folder`` for frame ``index``; masks come back as bool (H, W)."""
        if folder not in OPTIONAL_FOLDERS:
            raise KeyError(f"unknown optional folder {folder!r}; known: {list(OPTIONAL_FOLDERS)}")
        path = self.root / folder / f"{self._frame(index).name}{OPTIONAL_FOLDERS[folder]}"
        if not path.is_file():
            raise SceneError(path, f"missing file (the scene has no complete {folder}/ folder)")
        if path.suffix == ".png":
            return read_mask_png(path, (self.camera.height, self.camera.width))
        array = _load_npy(path)
        _check_optional_array(path, folder, array, self.camera)
        return array

    def world_to_camera(self, index: int) -> np.ndarray:
        """(4, 4) world-to-camera (OpenCV axes) transform of frame ``index``."""
        cam_to_world = self._frame(index).ego_to_world @ self.camera.cam_to_ego
        return np.linalg.inv(cam_to_world)

    def radar_to_world(self, index: int) -> np.ndarray:
        """(4, 4) radar-to-world transform at the radar's capture time of frame ``index``."""
        return self._frame(index).radar_ego_to_world @ self.radar.radar_to_ego

    def radar_to_camera(self, index: int) -> np.ndarray:
        """(4, 4) radar frame to the camera (OpenCV axes) of frame ``index``.

        Goes through the world, so a radar captured at another time than the camera (its own
        ``radar_ego_to_world``) lands where it should.
        """
        return self.world_to_camera(index) @ self.radar_to_world(index)


# --------------------------------------------------------------------------------------------
# Reading


def read_mask_png(path: str | Path, shape: tuple[int, int] | None = None) -> np.ndarray:
    """(H, W) bool mask of a 0/255 PNG (values above 127 are set); a :class:`SceneError` naming the
    file when it cannot be read or is not ``shape`` (H, W)."""
    try:
        with Image.open(path) as image:
            mask = np.asarray(image.convert("L")) > 127
    except Exception as exc:  # PIL raises many types for broken files
        raise SceneError(path, f"unreadable mask ({exc})") from exc
    if shape is not None and mask.shape != tuple(shape):
        raise SceneError(path, f"mask is {mask.shape[1]}x{mask.shape[0]}, expected {shape[1]}x{shape[0]}")
    return mask


def _load_npy(path: Path, mmap_mode: str | None = None) -> np.ndarray:
    """The array in ``path``; ``mmap_mode="r"`` reads only the header until data is touched."""
    if not path.is_file():
        raise SceneError(path, "missing file")
    try:
        return np.load(path, mmap_mode=mmap_mode, allow_pickle=False)
    except Exception as exc:
        raise SceneError(path, f"unreadable .npy file ({exc})") from exc


def _check_radar_shape(path: Path, data: np.ndarray, fields: Sequence[str]) -> None:
    if data.ndim != 2 or data.shape[1] != len(fields):
        raise SceneError(path, f"radar array has shape {data.shape}, but scene.json names "
                         f"{len(fields)} columns {list(fields)}; expected (N, {len(fields)})")


def _check_optional_array(path: Path, folder: str, array: np.ndarray, camera: Camera) -> None:
    hw = (camera.height, camera.width)
    expected = {"priors/mono_depth": hw, "gt/depth": hw, "gt/flow": hw + (3,)}.get(folder)
    if expected is not None and array.shape != expected:
        raise SceneError(path, f"array has shape {array.shape}, expected {expected}")
    if folder == "lidar" and (array.ndim != 2 or array.shape[1] != 4):
        raise SceneError(path, f"lidar array has shape {array.shape}, expected (N, 4)")
    if folder == "gt/radar_labels" and array.ndim != 1:
        raise SceneError(path, f"radar labels have shape {array.shape}, expected (N,)")


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


def _rigid(value: Any, where: str, path: Path) -> np.ndarray:
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
    ego_to_world = _rigid(_require(entry, "ego_to_world", where, path), f"{where}ego_to_world", path)
    radar_timestamp = _number(entry.get("radar_timestamp", timestamp), f"{where}radar_timestamp", path)
    radar_pose = entry.get("radar_ego_to_world")
    radar_ego_to_world = ego_to_world if radar_pose is None else _rigid(
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
    if not root.is_dir():
        raise SceneError(root, "not a scene folder (no such directory)")
    meta_path = root / "scene.json"
    if not meta_path.is_file():
        raise SceneError(meta_path, "missing file")
    try:
        meta = json.loads(meta_path.read_text(encoding="utf-8"))
    except (OSError, UnicodeDecodeError, json.JSONDecodeError) as exc:
        raise SceneError(meta_path, f"unreadable JSON ({exc})") from exc
    if not isinstance(meta, Mapping):
        raise SceneError(meta_path, "top level must be a JSON object")
    if meta.get("format") != FORMAT_NAME:
        raise SceneError(meta_path, f"'format' is {meta.get('format')!r}, expected {FORMAT_NAME!r}")
    if meta.get("version") != FORMAT_VERSION:
        raise SceneError(meta_path, f"'version' is {meta.get('version')!r}; this reader knows version "
                         f"{FORMAT_VERSION}")

    cam = _require(meta, "camera", "", meta_path)
    width, height = _require(cam, "width", "camera.", meta_path), _require(cam, "height", "camera.", meta_path)
    if not all(isinstance(v, int) and not isinstance(v, bool) and v > 0 for v in (width, height)):
        raise SceneError(meta_path, f"camera.width/height must be positive integers, got {width!r}, {height!r}")
    K = _matrix(_require(cam, "K", "camera.", meta_path), (3, 3), "camera.K", meta_path)
    if K[0, 0] <= 0 or K[1, 1] <= 0 or not np.allclose(K[2], [0, 0, 1]):
        raise SceneError(meta_path, "camera.K must have positive focal lengths and last row [0, 0, 1]")
    camera = Camera(width, height, K, _rigid(_require(cam, "cam_to_ego", "camera.", meta_path),
                                             "camera.cam_to_ego", meta_path))

    rad = _require(meta, "radar", "", meta_path)
    fields = _require(rad, "fields", "radar.", meta_path)
    if not isinstance(fields, list) or not all(isinstance(f, str) for f in fields):
        raise SceneError(meta_path, "radar.fields must be a list of column names")
    missing = [f for f in REQUIRED_RADAR_FIELDS if f not in fields]
    if missing:
        raise SceneError(meta_path, f"radar.fields lacks required columns {missing}")
    if len(set(fields)) != len(fields):
        raise SceneError(meta_path, f"radar.fields has duplicate names {fields}")
    radar = RadarSpec(_rigid(_require(rad, "radar_to_ego", "radar.", meta_path), "radar.radar_to_ego",
                             meta_path), tuple(fields))

    entries = _require(meta, "frames", "", meta_path)
    if not isinstance(entries, list) or not entries:
        raise SceneError(meta_path, "'frames' must be a non-empty list")
    frames = tuple(_parse_frame(entry, i, meta_path) for i, entry in enumerate(entries))
    names = [f.name for f in frames]
    if len(set(names)) != len(names):
        duplicated = sorted({n for n in names if names.count(n) > 1})
        raise SceneError(meta_path, f"duplicate frame names {duplicated}")
    for attribute in ("timestamp", "radar_timestamp"):
        stamps = np.array([getattr(f, attribute) for f in frames])
        bad = np.nonzero(np.diff(stamps) <= 0)[0]
        if len(bad):
            i = int(bad[0])
            raise SceneError(meta_path, f"{attribute}s do not increase: frames[{i}] ({frames[i].name}) at "
                             f"{stamps[i]:.6f} s, frames[{i + 1}] ({frames[i + 1].name}) at {stamps[i + 1]:.6f} s")

    test_every = meta.get("test_every", DEFAULT_TEST_EVERY)
    if isinstance(test_every, bool) or not isinstance(test_every, int):
        raise SceneError(meta_path, f"test_every must be an integer, got {test_every!r}")
    source = meta.get("source", {})
    if not isinstance(source, Mapping):
        raise SceneError(meta_path, "'source' must be an object")

    image_files = tuple(_find_image(root, f.name) for f in frames)
    if check_files:
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
        for frame in frames:
            radar_path = root / "radar" / f"{frame.name}.npy"
            _check_radar_shape(radar_path, _load_npy(radar_path, mmap_mode="r"), fields)

    extra = {k: v for k, v in meta.items() if k not in _SCENE_KEYS}
    return Scene(root, str(meta.get("name", root.name)), camera, radar, frames, dict(source), test_every,
                 image_files, extra)


# --------------------------------------------------------------------------------------------
# Writing


def _listify(matrix: np.ndarray) -> list:
    return np.asarray(matrix, dtype=np.float64).tolist()


def scene_metadata(name: str, camera: Camera, radar: RadarSpec, frames: Iterable[Frame],
                   source: Mapping[str, Any] | None = None, test_every: int | None = None,
                   extra: Mapping[str, Any] | None = None) -> dict:
    """The ``scene.json`` object for the given parts."""
    frame_list = []
    for frame in frames:
        entry: dict[str, Any] = {"name": frame.name, "timestamp": float(frame.timestamp),
                                 "ego_to_world": _listify(frame.ego_to_world),
                                 "radar_timestamp": float(frame.radar_timestamp),
                                 "radar_ego_to_world": _listify(frame.radar_ego_to_world)}
        if frame.ego_velocity is not None:
            entry["ego_velocity"] = np.asarray(frame.ego_velocity, dtype=np.float64).tolist()
        entry.update(frame.extra)
        frame_list.append(entry)
    meta: dict[str, Any] = {
        "format": FORMAT_NAME, "version": FORMAT_VERSION, "name": name, "source": dict(source or {}),
        "camera": {"width": int(camera.width), "height": int(camera.height), "K": _listify(camera.K),
                   "cam_to_ego": _listify(camera.cam_to_ego)},
        "radar": {"radar_to_ego": _listify(radar.radar_to_ego), "fields": list(radar.fields)},
        "frames": frame_list,
    }
    if test_every is not None:
        meta["test_every"] = int(test_every)
    meta.update(extra or {})
    return meta


def _save_png(path: Path, array: np.ndarray) -> None:
    path.parent.mkdir(parents=True, exist_ok=True)
    Image.fromarray(array).save(path)


class SceneWriter:
    """Writes a scene folder frame by frame into a temporary folder, renamed into place by
    :meth:`finish`; an exception inside the ``with`` block leaves nothing behind.

    Example::

        with SceneWriter(out) as writer:
            for ...:
                writer.add_frame(frame, image, radar, gt_depth=depth)
            writer.finish(name, camera, radar_spec, source={...})
    """

    def __init__(self, out: str | Path, overwrite: bool = False, image_format: str = "png"):
        if image_format not in ("png", "jpg"):
            raise ValueError(f"image_format must be 'png' or 'jpg', got {image_format!r}")
        self.out = Path(out)
        self.overwrite = overwrite
        self.image_format = image_format
        self.frames: list[Frame] = []
        self._context = None
        self._tmp: Path | None = None
        self._finished = False

    def __enter__(self) -> "SceneWriter":
        self._context = atomic_directory(self.out, overwrite=self.overwrite)
        self._tmp = self._context.__enter__()
        return self

    def __exit__(self, exc_type, exc, tb) -> bool:
        if exc_type is None and not self._finished:
            exc_type, exc = RuntimeError, RuntimeError(f"{self.out}: SceneWriter closed without finish()")
            self._context.__exit__(exc_type, exc, None)
            raise exc
        return bool(self._context.__exit__(exc_type, exc, tb))

    @property
    def folder(self) -> Path:
        """The temporary folder being written (for extra files a converter wants to add)."""
        if self._tmp is None:
            raise RuntimeError("SceneWriter is used outside its `with` block")
        return self._tmp

    def add_frame(self, frame: Frame, image: np.ndarray, radar: np.ndarray, **optional: np.ndarray) -> None:
        """Write one frame's files.

        Args:
            frame: its metadata.
            image: (H, W, 3) uint8 RGB.
            radar: (N, F) float32 radar points in the radar frame.
            optional: arrays keyed by optional folder with ``/`` replaced by ``_``
                (``lidar``, ``priors_mono_depth``, ``priors_sky_mask``, ``gt_depth``,
                ``gt_dynamic_mask``, ``gt_sky_mask``, ``gt_flow``, ``gt_radar_labels``);
                masks may be bool or uint8 0/255.
        """
        folder = self.folder
        if image.dtype != np.uint8 or image.ndim != 3 or image.shape[2] != 3:
            raise ValueError(f"frame {frame.name}: image must be (H, W, 3) uint8, got {image.shape} {image.dtype}")
        _save_png(folder / "images" / f"{frame.name}.{self.image_format}", image)
        (folder / "radar").mkdir(exist_ok=True)
        np.save(folder / "radar" / f"{frame.name}.npy", np.ascontiguousarray(radar, dtype=np.float32))
        for key, value in optional.items():
            name = key.replace("_", "/", 1) if key.startswith(("gt_", "priors_")) else key
            if name not in OPTIONAL_FOLDERS:
                raise ValueError(f"unknown optional folder {key!r}")
            target = folder / name / f"{frame.name}{OPTIONAL_FOLDERS[name]}"
            target.parent.mkdir(parents=True, exist_ok=True)
            if OPTIONAL_FOLDERS[name] == ".png":
                mask = np.asarray(value)
                mask = np.where(mask > (0 if mask.dtype == bool else 127), 255, 0).astype(np.uint8)
                _save_png(target, mask)
            else:
                dtype = np.int8 if name == "gt/radar_labels" else np.float32
                np.save(target, np.ascontiguousarray(value, dtype=dtype))
        self.frames.append(frame)

    def finish(self, name: str, camera: Camera, radar: RadarSpec, source: Mapping[str, Any] | None = None,
               test_every: int | None = None, extra: Mapping[str, Any] | None = None) -> None:
        """Write ``scene.json``; the folder is renamed into place when the ``with`` block ends."""
        meta = scene_metadata(name, camera, radar, self.frames, source, test_every, extra)
        atomic_write_json(self.folder / "scene.json", meta)
        self._finished = True


def write_scene_json(scene_root: str | Path, meta: Mapping[str, Any]) -> Path:
    """Rewrite ``scene.json`` of an existing folder atomically (tools that edit metadata only)."""
    return atomic_write_json(Path(scene_root) / "scene.json", meta)


def save_array(path: str | Path, array: np.ndarray) -> Path:
    """Atomically save a .npy file (re-exported for stages that write beside a scene)."""
    return atomic_save_npy(path, array)
