"""The run folder's format and its loader: what ``radar4dgs train`` writes and what evaluation,
trajectory rendering, export and the viewer reload.

RUN/
  run.json        {"scene": ..., "prepared": ...}: the inputs the run was trained on
  config.json     the resolved :class:`~radar4dgs.model.config.TrainConfig`
  model.pt        the final :class:`~radar4dgs.model.scene_model.SceneModel`
  history.json    the logged loss terms (LOSS_TERMS) and timings per step
  checkpoints/last.pt   the latest resumable state
"""

from __future__ import annotations

import json
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from radar4dgs.config import load_config
from radar4dgs.io.scene import read_scene
from radar4dgs.model.config import TrainConfig
from radar4dgs.model.scene_model import SceneModel, load_model

RUN_FILE = "run.json"
CONFIG_FILE = "config.json"
MODEL_FILE = "model.pt"
CHECKPOINT_DIR = "checkpoints"
LAST_CHECKPOINT = "last.pt"
HISTORY_FILE = "history.json"
# The named terms of the training loss, as logged in history.json.
LOSS_TERMS = ("l1", "ssim", "depth", "object", "sky", "flow", "radar", "velocity")


@dataclass
class Run:
    """A trained run folder, reloaded: the scene, its prepared folder, config and model."""

    root: Path
    scene: Any
    prepared: Path
    config: TrainConfig
    model: SceneModel


def load_run(run_dir: str | Path, device: str | None = None) -> Run:
    """Reload ``run_dir`` (written by ``radar4dgs train``); errors name the missing file."""
    root = Path(run_dir)
    for name in (RUN_FILE, CONFIG_FILE, MODEL_FILE):
        if not (root / name).is_file():
            raise FileNotFoundError(f"{root / name}: missing; is {root} a finished `radar4dgs train` run?")
    paths = json.loads((root / RUN_FILE).read_text())
    config = load_config(TrainConfig, root / CONFIG_FILE)
    scene = read_scene(paths["scene"])
    model = load_model(root / MODEL_FILE, device=device or config.device)
    return Run(root, scene, Path(paths["prepared"]), config, model)
