"""The scene format's vocabulary (``SCENE_FORMAT.md``, version 1): its constants and the error and
warning types that every reader, loader and writer of a scene folder raises."""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

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
# The optional scene-level point cloud (a radar-less scene's initial points, from COLMAP's
# points3D or nerfstudio's ply_file_path): float32 (M, 6) x y z (world, m) r g b (0-1).
POINTS_FILE = "priors/points3d.npy"
# A rotation block is accepted as orthonormal when ||R^T R - I||_max stays below this; converters
# write float64 matrices, but float32 round trips in other tools lose about 1e-7.
ORTHONORMAL_TOLERANCE = 1e-4


class SceneError(ValueError):
    """A scene folder breaks the format; the message names the file and the problem."""

    def __init__(self, path: Path | str, problem: str):
        self.path = Path(path)
        self.problem = problem
        super().__init__(f"{path}: {problem}")


def read_json_file(path: Path) -> Any:
    """The JSON value in ``path``; a file that cannot be read or parsed is a :class:`SceneError`
    naming it (scene.json and every converter's JSON inputs)."""
    try:
        return json.loads(Path(path).read_text(encoding="utf-8"))
    except (OSError, UnicodeDecodeError, json.JSONDecodeError) as exc:
        raise SceneError(path, f"unreadable JSON ({exc})") from exc


class SceneWarning(UserWarning):
    """Something in a scene was repaired on load (dropped rows, an empty radar frame)."""
