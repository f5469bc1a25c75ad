"""Stage 1: scene folders (read, validate, write), synthetic scenes and dataset converters."""

from radar4dgs.io.scene import (
                                  Camera,
                                  Frame,
                                  RadarScan,
                                  RadarSpec,
                                  Scene,
                                  SceneError,
                                  SceneWarning,
                                  SceneWriter,
                                  read_scene,
                                  split_indices,
)

__all__ = ["Camera", "Frame", "RadarScan", "RadarSpec", "Scene", "SceneError", "SceneWarning", "SceneWriter",
           "read_scene", "split_indices"]
