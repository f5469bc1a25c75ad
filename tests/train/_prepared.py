"""A tiny synthetic scene, synthesised and prepared, for the trainer's tests."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import torch

from radar4dgs.apps.prepare import PrepareConfig, run_prepare
from radar4dgs.config import preset
from radar4dgs.datasets.synth import SynthConfig, synthesize
from radar4dgs.metrics.image import psnr
from radar4dgs.train.trainer import Trainer


def prepared_tiny_scene(folder: Path, seed: int, num_frames: int = 8) -> tuple[Path, Path]:
    """(scene, prepared) of an 8-frame tiny scene of ``seed`` made under ``folder``."""
    scene = folder / "scene"
    synthesize(preset(SynthConfig, "tiny", seed=seed, num_frames=num_frames), scene, progress=False)
    run_prepare(scene, None, preset(PrepareConfig, "tiny"), progress=False)
    return scene, scene / "prepared"


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
