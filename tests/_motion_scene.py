"""A hand-built scene with closed-form image motion, for the tests of image motion and 2D flow
metrics: the ego drives along x and sees a wall with a dynamic block moving sideways."""

from __future__ import annotations

import numpy as np

from radar4dgs.io import read_scene
from radar4dgs.io.scene_types import Camera, Frame, RadarSpec
from radar4dgs.io.scene_write import SceneWriter

F = 100.0  # focal length (px)
K = np.array([[F, 0.0, 40.0], [0.0, F, 30.0], [0.0, 0.0, 1.0]])
CV_TO_EGO = np.array([[0, 0, 1, 0], [-1, 0, 0, 0], [0, -1, 0, 1.5], [0, 0, 0, 1.0]])  # camera looks along ego x


def translation(x: float, y: float = 0.0, z: float = 0.0) -> np.ndarray:
    matrix = np.eye(4)
    matrix[:3, 3] = (x, y, z)
    return matrix


def write_scene(out, frames=3, speed=1.0, flow_y=-0.2, depth=10.0):
    """A scene whose ego drives along x at ``speed`` m per frame, seeing a wall at ``depth`` m with
    a dynamic 4x4 block that moves ``flow_y`` m sideways (world y) per frame."""
    camera = Camera(80, 60, K, CV_TO_EGO)
    mask = np.zeros((60, 80), bool)
    mask[28:32, 38:42] = True
    flow = np.zeros((60, 80, 3), np.float32)
    flow[mask] = (0.0, flow_y, 0.0)
    with SceneWriter(out) as writer:
        for i in range(frames):
            frame = Frame(f"{i:06d}", 0.1 * i, translation(speed * i), 0.1 * i, translation(speed * i))
            writer.add_frame(frame, np.zeros((60, 80, 3), np.uint8), np.zeros((1, 4), np.float32),
                             gt_depth=np.full((60, 80), depth - speed * i, np.float32), gt_dynamic_mask=mask,
                             gt_flow=flow)
        writer.finish("motion", camera, RadarSpec(np.eye(4), ("x", "y", "z", "v_r")))
    return read_scene(out)
