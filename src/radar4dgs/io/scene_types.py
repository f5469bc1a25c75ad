"""The typed classes of a loaded scene folder (``SCENE_FORMAT.md``): the camera, the radar's
mounting and columns, one frame's metadata, one radar scan, and the :class:`Scene` with its
on-demand per-frame loaders and pose chains; plus the frame-time and train/test-split rules."""

from __future__ import annotations

import warnings
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Mapping

import numpy as np
from PIL import Image

from radar4dgs.io.scene_files import _check_optional_array, _check_radar_shape, _load_npy, read_mask_png, read_points
from radar4dgs.io.scene_format import (
    DEFAULT_TEST_EVERY,
    OPTIONAL_FOLDERS,
    POINTS_FILE,
    REQUIRED_RADAR_FIELDS,
    SceneError,
    SceneWarning,
)


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


def no_radar(root: Path | str) -> SceneError:
    """The error of a step that needs the radar of the radar-less scene ``root``."""
    return SceneError(root, "has no radar (scene.json has no 'radar' section), which this step needs")


class MissingRadar:
    """The ``radar`` of a radar-less scene: falsy, and any attribute (``fields``,
    ``radar_to_ego``) raises a :class:`SceneError` naming the scene, so every step that needs
    radar stops with one line instead of failing on None."""

    def __init__(self, root: Path | str):
        self.root = Path(root)

    def __bool__(self) -> bool:
        return False

    def __getattr__(self, name: str):
        if name.startswith("__"):  # copy, pickle and friends probe for these
            raise AttributeError(name)
        raise no_radar(self.root)

    def __eq__(self, other: object) -> bool:
        return isinstance(other, MissingRadar) and other.root == self.root

    def __hash__(self) -> int:
        return hash(("MissingRadar", self.root))

    def __repr__(self) -> str:
        return "MissingRadar()"


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
    """A loaded scene folder. Per-frame arrays are read on demand with the ``load_*`` methods.

    ``radar`` is a falsy :class:`MissingRadar` (or None) for a radar-less scene (``scene.json``
    without a ``radar`` section, as the nerfstudio and COLMAP converters write): every radar
    accessor then raises a :class:`SceneError` saying the scene has no radar."""

    root: Path
    name: str
    camera: Camera
    radar: RadarSpec | MissingRadar | None
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

    # ---- radar and the point cloud
    @property
    def has_radar(self) -> bool:
        return isinstance(self.radar, RadarSpec)

    def require_radar(self) -> RadarSpec:
        """The radar spec, or a :class:`SceneError` naming the scene: it has no radar."""
        if not isinstance(self.radar, RadarSpec):
            raise no_radar(self.root)
        return self.radar

    @property
    def has_points(self) -> bool:
        """True when the scene holds a point cloud (``POINTS_FILE``)."""
        return (self.root / POINTS_FILE).is_file()

    def load_points(self) -> tuple[np.ndarray, np.ndarray]:
        """The scene's point cloud: (M, 3) float64 world points and (M, 3) colours in [0, 1]."""
        return read_points(self.root / POINTS_FILE)

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
        radar = self.require_radar()
        path = self.root / "radar" / f"{self._frame(index).name}.npy"
        data = _load_npy(path)
        _check_radar_shape(path, data, radar.fields)
        data = data.astype(np.float32, copy=False)
        required = [radar.fields.index(name) for name in REQUIRED_RADAR_FIELDS]
        finite = np.isfinite(data[:, required]).all(axis=1)
        stored = len(data)
        if not finite.all():
            warnings.warn(f"{path}: dropped {int((~finite).sum())} of {stored} radar rows with NaN or "
                          f"inf in x, y, z or v_r", SceneWarning, stacklevel=2)
            data = data[finite]
        if len(data) == 0:
            warnings.warn(f"{path}: empty radar frame", SceneWarning, stacklevel=2)
        return RadarScan(np.ascontiguousarray(data), radar.fields, np.flatnonzero(finite), stored)

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
        return self._frame(index).radar_ego_to_world @ self.require_radar().radar_to_ego

    def radar_to_camera(self, index: int) -> np.ndarray:
        """(4, 4) radar frame to the camera (OpenCV axes) of frame ``index``.

        Goes through the world, so a radar captured at another time than the camera (its own
        ``radar_ego_to_world``) lands where it should.
        """
        return self.world_to_camera(index) @ self.radar_to_world(index)
