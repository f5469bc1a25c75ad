"""The scene folder, version 1 (``SCENE_FORMAT.md``), as typed classes, a validating reader and an
atomic writer.

Every data source is converted into this layout once; every later stage reads only this layout.
The reader refuses a broken scene with a :class:`SceneError` that names the file and the problem.

This is the public entry point; the parts live in:

- :mod:`radar4dgs.io.scene_format`: constants, :class:`SceneError`, :class:`SceneWarning`;
- :mod:`radar4dgs.io.scene_files`: reading and checking one per-frame file;
- :mod:`radar4dgs.io.scene_types`: :class:`Camera`, :class:`RadarSpec`, :class:`Frame`,
  :class:`RadarScan`, :class:`Scene`, :func:`normalized_times`, :func:`split_indices`;
- :mod:`radar4dgs.io.scene_read`: :func:`read_scene` and its validation;
- :mod:`radar4dgs.io.scene_write`: :class:`SceneWriter` and ``scene.json`` writing.
"""

from __future__ import annotations

from radar4dgs.io.scene_files import read_mask_png
from radar4dgs.io.scene_format import (
                                       DEFAULT_TEST_EVERY,
                                       FORMAT_NAME,
                                       FORMAT_VERSION,
                                       IMAGE_SUFFIXES,
                                       OPTIONAL_FOLDERS,
                                       ORTHONORMAL_TOLERANCE,
                                       POINTS_FILE,
                                       REQUIRED_RADAR_FIELDS,
                                       SceneError,
                                       SceneWarning,
                                       read_json_file,
)
from radar4dgs.io.scene_read import read_scene
from radar4dgs.io.scene_types import Camera, Frame, RadarScan, RadarSpec, Scene, normalized_times, split_indices
from radar4dgs.io.scene_write import SceneWriter, save_array, scene_metadata, write_scene_json

__all__ = [
    "DEFAULT_TEST_EVERY", "FORMAT_NAME", "FORMAT_VERSION", "IMAGE_SUFFIXES", "OPTIONAL_FOLDERS",
    "ORTHONORMAL_TOLERANCE", "POINTS_FILE", "REQUIRED_RADAR_FIELDS", "Camera", "Frame", "RadarScan", "RadarSpec",
    "Scene",
    "SceneError", "SceneWarning", "SceneWriter", "normalized_times", "read_json_file", "read_mask_png", "read_scene",
    "save_array", "scene_metadata", "split_indices", "write_scene_json",
]
