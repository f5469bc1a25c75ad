"""Reading and checking one per-frame file of a scene folder (a ``.npy`` array or a mask PNG),
with a :class:`~radar4dgs.io.scene_format.SceneError` naming the file when it is missing,
unreadable or of the wrong shape."""

from __future__ import annotations

from pathlib import Path
from typing import TYPE_CHECKING, Sequence

import numpy as np
from PIL import Image

from radar4dgs.io.scene_format import SceneError

if TYPE_CHECKING:
    from radar4dgs.io.scene_types import Camera

# Subfolder of <prepared>/masks/ with the masks completed by the radar objects for the flow stage
# alone (segment.config.CompletionConfig.for_flow): the segmentation stage writes it, the flow
# stage reads it in place of the masks when it exists. Here because neither stage imports the other.
FLOW_MASKS = "flow"
# <prepared>/<OBJECT_DEPTH>/<frame>.npy: the prepared depth with the movers rescaled by their radar
# returns (radar4dgs.depth.objects), written only for frames where some mover was rescaled. Every
# reader of the prepared depth after that stage goes through prepared_depth_path.
OBJECT_DEPTH = "object_depth"


def prepared_depth_path(prepared: str | Path, frame: str) -> Path:
    """The metric depth of frame ``frame`` that the stages after the object-depth stage use:
    ``<prepared>/object_depth/<frame>.npy`` where that stage rescaled a mover in it, else
    ``<prepared>/depth/<frame>.npy`` (it may not exist: the caller names it when missing)."""
    rescaled = Path(prepared) / OBJECT_DEPTH / f"{frame}.npy"
    return rescaled if rescaled.is_file() else Path(prepared) / "depth" / f"{frame}.npy"


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
    """Refuse a radar array that is not (N, len(fields))."""
    if data.ndim != 2 or data.shape[1] != len(fields):
        raise SceneError(path, f"radar array has shape {data.shape}, but scene.json names "
                         f"{len(fields)} columns {list(fields)}; expected (N, {len(fields)})")


def _check_optional_array(path: Path, folder: str, array: np.ndarray, camera: Camera) -> None:
    """Refuse an array of optional ``folder`` whose shape breaks the format: (H, W) depth, (H, W, 3)
    flow, (N, 4) lidar, (N,) radar labels."""
    hw = (camera.height, camera.width)
    expected = {"priors/mono_depth": hw, "gt/depth": hw, "gt/flow": hw + (3,)}.get(folder)
    if expected is not None and array.shape != expected:
        raise SceneError(path, f"array has shape {array.shape}, expected {expected}")
    if folder == "lidar" and (array.ndim != 2 or array.shape[1] != 4):
        raise SceneError(path, f"lidar array has shape {array.shape}, expected (N, 4)")
    if folder == "gt/radar_labels" and array.ndim != 1:
        raise SceneError(path, f"radar labels have shape {array.shape}, expected (N,)")


def read_points(path: Path) -> tuple[np.ndarray, np.ndarray]:
    """The scene's point cloud (``POINTS_FILE``): (M, 3) float64 world points and (M, 3) float64
    colours in [0, 1]; a :class:`SceneError` naming the file when it is not finite (M, 6)."""
    data = _load_npy(path)
    if data.ndim != 2 or data.shape[1] != 6:
        raise SceneError(path, f"point cloud has shape {data.shape}, expected (M, 6): x y z r g b")
    if not np.isfinite(data).all():
        raise SceneError(path, "point cloud contains NaN or inf")
    data = data.astype(np.float64)
    return data[:, :3], np.clip(data[:, 3:], 0.0, 1.0)
