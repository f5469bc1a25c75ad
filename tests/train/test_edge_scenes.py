"""Scenes outside the generator's defaults, prepared and trained end to end: nothing moves, or the ego
stands still among moving traffic (a red light). Both happen in real drives."""

from __future__ import annotations

import math

import numpy as np
import pytest
from _prepared import prepared_tiny_scene, tiny_config, trained_and_initial_psnr

from radar4dgs.io.scene import read_scene
from radar4dgs.train.trainer import train_run

pytestmark = pytest.mark.usefixtures("one_torch_thread")

EDGE_SCENES = {
    "nothing-moves": {"moving_cars": (0, 0), "crossing_probability": 0.0},
    "ego-stands-still": {"ego_speed": (0.0, 0.0)},
}


# A NaN on the way (a RuntimeWarning from numpy or scipy) fails the test too.
@pytest.mark.filterwarnings("error::RuntimeWarning")
@pytest.mark.parametrize("name", sorted(EDGE_SCENES))
def test_edge_scene_prepares_and_trains_better_than_its_start(name, tmp_path):
    scene_dir, prepared = prepared_tiny_scene(tmp_path, seed=3, num_frames=6, **EDGE_SCENES[name])
    scene = read_scene(scene_dir)
    moving = sum(int((scene.load_optional("gt/dynamic_mask", i) > 0).sum()) for i in range(len(scene)))
    assert (moving == 0) == (name == "nothing-moves")
    centres = [np.linalg.inv(scene.world_to_camera(i))[:3, 3] for i in range(len(scene))]
    travelled = max(float(np.linalg.norm(c - centres[0])) for c in centres)
    assert (travelled < 1e-6) == (name == "ego-stands-still")

    config = tiny_config(checkpoint_every=0)
    state = train_run(scene_dir, prepared, tmp_path / "run", config, progress=False)
    logged = [h for h in state.history if "total" in h]
    assert {h["stage"] for h in logged} == {1, 2, 3} and all(math.isfinite(h["total"]) for h in logged)
    trained, initial = trained_and_initial_psnr(scene_dir, prepared, state.model, config, tmp_path / "unused")
    assert trained > initial + 1.0
