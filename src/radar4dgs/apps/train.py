"""``radar4dgs train SCENE --out RUN``: the three-stage Gaussian training of a prepared scene."""

from __future__ import annotations

import sys
from dataclasses import dataclass, field
from pathlib import Path
from typing import Annotated, ClassVar, Optional

import tyro

from radar4dgs.apps.options import default_is
from radar4dgs.config import PresetName
from radar4dgs.model.config import Method, TrainConfig
from radar4dgs.train.variants import MethodName


@dataclass
class TrainOptions(TrainConfig):
    """Everything the trainer does besides the method (``radar4dgs train --method`` sets that)."""

    # Not an option of its own: --method NAME sets it with the method's other fields.
    method: tyro.conf.Suppress[Method] = "ours"


@dataclass
class TrainCommand:
    """Train the Gaussian scene (static + dynamic Gaussians, VGPT field, sky) on a prepared scene."""

    # The scene folder.
    scene: tyro.conf.Positional[Path]
    # The run folder (config, checkpoints, model, then metrics and renders from `radar4dgs eval`).
    out: Path = Path("runs/train")
    # The prepared folder (run `radar4dgs prepare SCENE` first).
    prepared: Annotated[Optional[Path], default_is("SCENE/prepared")] = None
    # Preset the config starts from.
    preset: PresetName = "small"
    # Everything the trainer does (filled from --preset, then overridden by options).
    config: TrainOptions = field(default_factory=TrainOptions)
    # The method: ours, a baseline or an ablation (see radar4dgs.train.variants); it sets its own
    # config fields on top of the preset and the options.
    method: MethodName = "ours"
    # Continue the run in --out from its last checkpoint.
    resume: bool = False
    # Evaluate the run when training ends (as `radar4dgs eval RUN`).
    eval: bool = True
    # Hide the progress bar.
    quiet: bool = False

    PRESET_FIELDS: ClassVar[dict[str, type]] = {"config": TrainOptions}

    def run(self) -> int:
        from radar4dgs.evaluate.reconstruction import write_provenance
        from radar4dgs.io.scene import SceneError
        from radar4dgs.train.trainer import TrainingError, train_run
        from radar4dgs.train.variants import apply_variant

        prepared = self.prepared if self.prepared is not None else self.scene / "prepared"
        try:
            config = apply_variant(self.config, self.method)  # a TrainConfig, the method's fields set
            train_run(self.scene, prepared, self.out, config, resume=self.resume, progress=not self.quiet)
        except (SceneError, FileNotFoundError, ValueError, TrainingError) as exc:
            print(f"radar4dgs train: {exc}", file=sys.stderr)
            return 1
        write_provenance(self.out, preset=self.preset, method=self.method,
                         command=f"radar4dgs train {self.scene} --out {self.out} --preset {self.preset} "
                                 f"--method {self.method} (other options: config.json)")
        print(f"trained: {self.out}")
        if self.eval:
            from radar4dgs.apps.eval import EvalCommand

            return EvalCommand(self.out).run()
        return 0
