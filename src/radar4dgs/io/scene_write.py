"""Writing a scene folder: the ``scene.json`` object of typed parts, and the :class:`SceneWriter`
that writes frame by frame into a temporary folder renamed into place only when complete."""

from __future__ import annotations

import shutil
from pathlib import Path
from typing import Any, Iterable, Mapping

import numpy as np
from PIL import Image

from radar4dgs.io.atomic import atomic_directory, atomic_save_npy, atomic_write_json
from radar4dgs.io.scene_format import FORMAT_NAME, FORMAT_VERSION, OPTIONAL_FOLDERS, POINTS_FILE
from radar4dgs.io.scene_types import Camera, Frame, RadarSpec


def _listify(matrix: np.ndarray) -> list:
    return np.asarray(matrix, dtype=np.float64).tolist()


def scene_metadata(name: str, camera: Camera, radar: RadarSpec | None, frames: Iterable[Frame],
                   source: Mapping[str, Any] | None = None, test_every: int | None = None,
                   extra: Mapping[str, Any] | None = None) -> dict:
    """The ``scene.json`` object for the given parts (no ``radar`` section without a RadarSpec)."""
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
    }
    if isinstance(radar, RadarSpec):  # a radar-less scene (None or MissingRadar) has no section
        meta["radar"] = {"radar_to_ego": _listify(radar.radar_to_ego), "fields": list(radar.fields)}
    # After the radar, as before radar became optional: a radar scene's scene.json stays byte-identical.
    meta["frames"] = frame_list
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

    def add_frame(self, frame: Frame, image: np.ndarray | Path, radar: np.ndarray | None,
                  **optional: np.ndarray) -> None:
        """Write one frame's files.

        Args:
            frame: its metadata.
            image: (H, W, 3) uint8 RGB, or the path of a .png/.jpg file copied as it is.
            radar: (N, F) float32 radar points in the radar frame; None for a radar-less scene.
            optional: arrays keyed by optional folder with ``/`` replaced by ``_``
                (``lidar``, ``priors_mono_depth``, ``priors_sky_mask``, ``gt_depth``,
                ``gt_dynamic_mask``, ``gt_sky_mask``, ``gt_flow``, ``gt_radar_labels``);
                masks may be bool or uint8 0/255.
        """
        folder = self.folder
        if isinstance(image, Path):
            # An encoded image copied byte for byte (a converter's JPEGs are not re-encoded).
            (folder / "images").mkdir(exist_ok=True)
            shutil.copyfile(image, folder / "images" / f"{frame.name}{image.suffix.lower()}")
        elif image.dtype != np.uint8 or image.ndim != 3 or image.shape[2] != 3:
            raise ValueError(f"frame {frame.name}: image must be (H, W, 3) uint8, got {image.shape} {image.dtype}")
        else:
            _save_png(folder / "images" / f"{frame.name}.{self.image_format}", image)
        if radar is not None:
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

    def add_points(self, points: np.ndarray, colors: np.ndarray) -> None:
        """The scene's point cloud (``POINTS_FILE``): (M, 3) world points, (M, 3) colours in [0, 1]."""
        target = self.folder / POINTS_FILE
        target.parent.mkdir(parents=True, exist_ok=True)
        np.save(target, np.column_stack([np.asarray(points, np.float64).reshape(-1, 3),
                                         np.asarray(colors, np.float64).reshape(-1, 3)]).astype(np.float32))

    def finish(self, name: str, camera: Camera, radar: RadarSpec | None, source: Mapping[str, Any] | None = None,
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
