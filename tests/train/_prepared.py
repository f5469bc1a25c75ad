"""A tiny synthetic scene, synthesised and prepared, for the trainer's tests."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np
import torch

from radar4dgs.apps.prepare import PrepareConfig, run_prepare
from radar4dgs.config import preset
from radar4dgs.datasets.synth import SynthConfig, synthesize
from radar4dgs.metrics.image import psnr
from radar4dgs.model.config import TrainConfig
from radar4dgs.train.trainer import Trainer


def prepared_tiny_scene(folder: Path, seed: int, num_frames: int = 8, **synth: Any) -> tuple[Path, Path]:
    """(scene, prepared) of an 8-frame tiny scene of ``seed`` made under ``folder``; ``synth`` overrides
    further SynthConfig fields."""
    scene = folder / "scene"
    synthesize(preset(SynthConfig, "tiny", seed=seed, num_frames=num_frames, **synth), scene, progress=False)
    run_prepare(scene, None, preset(PrepareConfig, "tiny"), progress=False)
    return scene, scene / "prepared"


def tiny_config(**overrides: Any) -> TrainConfig:
    """The trainer tests' config: ``tiny`` cut to 24 iterations and a few thousand Gaussians, densifying
    every 6 steps; ``overrides`` replace fields, dicts merged into the nested configs."""
    values = {"optim": {"iterations": 24}, "checkpoint_every": 8, "log_every": 1,
              "init": {"points_per_frame": 600, "max_static": 3000, "max_dynamic": 600},
              "densify": {"every": 6, "start": 0.0, "stop": 1.0, "grad_threshold": 1e-6, "max_gaussians": 4000},
              "losses": {"motion_batch": 64, "radar_points_per_frame": 100}, "threads": 1}
    for key, value in overrides.items():
        if isinstance(value, dict):
            values.setdefault(key, {}).update(value)
        else:
            values[key] = value
    return preset(TrainConfig, "tiny", **values)


def trained_and_initial_psnr(scene: Path, prepared: Path, model, config, folder: Path) -> tuple[float, float]:
    """Mean PSNR over the training frames of the trained ``model`` and of the Gaussians ``config`` starts from."""
    trainer = Trainer(scene, prepared, folder, config, progress=False)
    trainer._load()
    initial = trainer._fresh_state().model

    def mean_psnr(rendered) -> float:
        with torch.no_grad():
            return float(np.mean([psnr(rendered.render(t.view, directions=t.directions)["rgb"].clamp(0, 1), t.image)
                                  for t in trainer.targets]))

    return mean_psnr(model), mean_psnr(initial)
