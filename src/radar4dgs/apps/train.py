"""``radar4dgs train SCENE --out RUN``: the three-stage Gaussian training of a prepared scene."""

from __future__ import annotations

import sys
from dataclasses import dataclass, field
from pathlib import Path
from typing import ClassVar, Optional

import tyro

from radar4dgs.config import PresetName
from radar4dgs.model.config import TrainConfig
from radar4dgs.train.variants import MethodName


@dataclass
class TrainCommand:
    """Train the Gaussian scene (static + dynamic Gaussians, VGPT field, sky) on a prepared scene."""

    # The scene folder.
    scene: tyro.conf.Positional[Path]
    # The run folder (config, checkpoints, model, then metrics and renders from `radar4dgs eval`).
    out: Path = Path("runs/train")
    # The prepared folder; default <scene>/prepared (run `radar4dgs prepare SCENE` first).
    prepared: Optional[Path] = None
    # Preset the config starts from.
    preset: PresetName = "small"
    # Everything the trainer does (filled from --preset, then overridden by options).
    config: TrainConfig = field(default_factory=TrainConfig)
    # A named method (a baseline or an ablation, see the table in docs/guide.md); it sets its own config
    # fields on top of the preset and the options. Default: the config as given (ours).
    method: Optional[MethodName] = None
    # Continue the run in --out from its last checkpoint.
    resume: bool = False
    # Evaluate the run when training ends (as `radar4dgs eval RUN`).
    eval: bool = True
    # Hide the progress bar.
    quiet: bool = False

    PRESET_FIELDS: ClassVar[dict[str, type]] = {"config": TrainConfig}

    def run(self) -> int:
        from radar4dgs.io.scene import SceneError
        from radar4dgs.train.trainer import TrainingError, train_run
        from radar4dgs.train.variants import apply_variant

        prepared = self.prepared if self.prepared is not None else self.scene / "prepared"
        try:
            config = self.config if self.method is None else apply_variant(self.config, self.method)
            train_run(self.scene, prepared, self.out, config, resume=self.resume, progress=not self.quiet)
        except (SceneError, FileNotFoundError, ValueError, TrainingError) as exc:
            print(f"radar4dgs train: {exc}", file=sys.stderr)
            return 1
        print(f"trained: {self.out}")
        if self.eval:
            from radar4dgs.apps.eval import EvalCommand

            return EvalCommand(self.out).run()
        return 0
