"""A small valid scene written with :class:`SceneWriter`, shared by the scene and preview tests."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np

from radar4dgs.io.scene_types import Camera, Frame, RadarSpec
from radar4dgs.io.scene_write import SceneWriter

WIDTH, HEIGHT, FRAMES = 16, 12, 6
FIELDS = ("x", "y", "z", "v_r", "rcs")


def pose(x: float, yaw: float = 0.0) -> np.ndarray:
    """(4, 4) rigid transform: a yaw about z, then a shift of ``x`` along x."""
    matrix = np.eye(4)
    c, s = np.cos(yaw), np.sin(yaw)
    matrix[:3, :3] = [[c, -s, 0], [s, c, 0], [0, 0, 1]]
    matrix[0, 3] = x
    return matrix


def write_valid_scene(out: Path, rng_seed: int = 0) -> Path:
    rng = np.random.default_rng(rng_seed)
    camera = Camera(WIDTH, HEIGHT, np.array([[10.0, 0, 8], [0, 10.0, 6], [0, 0, 1]]),
                    np.array([[0, 0, 1, 1.5], [-1, 0, 0, 0], [0, -1, 0, 1.5], [0, 0, 0, 1.0]]))
    radar = RadarSpec(pose(3.6), FIELDS)
    with SceneWriter(out) as writer:
        for i in range(FRAMES):
            frame = Frame(f"{i:06d}", 0.1 * i, pose(1.0 * i, 0.01 * i), 0.1 * i + 0.01, pose(1.0 * i + 0.1),
                          ego_velocity=np.array([10.0, 0, 0]), extra={"weather": "dry"})
            image = rng.integers(0, 255, (HEIGHT, WIDTH, 3), dtype=np.uint8)
            points = rng.normal(size=(5 + i, len(FIELDS))).astype(np.float32)
            writer.add_frame(frame, image, points, gt_depth=rng.uniform(1, 50, (HEIGHT, WIDTH)),
                             gt_dynamic_mask=rng.random((HEIGHT, WIDTH)) > 0.5,
                             gt_radar_labels=np.zeros(5 + i, np.int8))
        writer.finish("unit", camera, radar, source={"dataset": "unit-test"}, test_every=3, extra={"note": 1})
    return out


def edit_json(root: Path, edit) -> None:
    meta = json.loads((root / "scene.json").read_text())
    edit(meta)
    (root / "scene.json").write_text(json.dumps(meta))
