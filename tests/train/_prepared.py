"""A tiny synthetic scene, synthesised and prepared, for the trainer's tests."""

from __future__ import annotations

from pathlib import Path

from radar4dgs.apps.prepare import PrepareConfig, run_prepare
from radar4dgs.config import preset
from radar4dgs.datasets.synth import SynthConfig, synthesize


def prepared_tiny_scene(folder: Path, seed: int, num_frames: int = 8) -> tuple[Path, Path]:
    """(scene, prepared) of an 8-frame tiny scene of ``seed`` made under ``folder``."""
    scene = folder / "scene"
    synthesize(preset(SynthConfig, "tiny", seed=seed, num_frames=num_frames), scene, progress=False)
    run_prepare(scene, None, preset(PrepareConfig, "tiny"), progress=False)
    return scene, scene / "prepared"
