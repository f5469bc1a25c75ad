"""``radar4dgs train SCENE --out RUN``: the three-stage Gaussian training of a prepared scene."""

from __future__ import annotations

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
    # Overwrite: delete the run in --out (made with another config, or finished) and train from scratch.
    # Without it a run folder made with another config is refused with what differs.
    force: bool = False
    # Evaluate the run when training ends (as `radar4dgs eval RUN`).
    eval: bool = True
    # Hide the progress bar.
    quiet: bool = False
    # Log the loss terms, PSNR, Gaussian count and memory to TensorBoard in RUN/tb (then the
    # evaluation's metrics and a few test frames): `tensorboard --logdir RUN/tb`.
    tensorboard: bool = True

    PRESET_FIELDS: ClassVar[dict[str, type]] = {"config": TrainOptions}
    # A run that cannot train or resume (a non-finite loss, a checkpoint of another config) is a
    # one-line error too (radar4dgs.cli).
    USER_ERRORS: ClassVar[tuple[str, ...]] = ("radar4dgs.train.trainer.TrainingError",
                                               "radar4dgs.io.locks.FolderInUseError")

    def run(self) -> int:
        from radar4dgs.io.atomic import remove_dead_temporaries
        from radar4dgs.io.locks import folder_lock

        # One process per run folder (another one's is refused in one line); what dead runs left
        # half-written there (checkpoints, renders) is removed first.
        with folder_lock(self.out):
            remove_dead_temporaries(self.out, recursive=True)
            return self._train()

    def _train(self) -> int:
        from radar4dgs.evaluate.reconstruction import write_provenance
        from radar4dgs.train.trainer import train_run
        from radar4dgs.train.variants import apply_variant

        prepared = self.prepared if self.prepared is not None else self.scene / "prepared"
        config = apply_variant(self.config, self.method)  # a TrainConfig, the method's fields set
        conflict = existing_run_conflict(self.out, config, self.resume)
        if conflict and not self.force:
            raise FileExistsError(conflict)
        if conflict:
            from radar4dgs.apps.reuse import remove_run

            remove_run(self.out)
            print(f"--force: removed the earlier run in {self.out}")
        check_prepared_scene(self.scene, prepared)
        # A missing or malformed scene or prepared stage raises a user error: one line (radar4dgs.cli).
        train_run(self.scene, prepared, self.out, config, resume=self.resume and not conflict,
                  progress=not self.quiet, tensorboard=self.tensorboard)
        write_provenance(self.out, preset=self.preset, method=self.method,
                         command=f"radar4dgs train {self.scene} --out {self.out} --preset {self.preset} "
                                 f"--method {self.method} (other options: config.json)")
        print(f"trained: {self.out}")
        if self.eval:
            from radar4dgs.apps.eval import EvalCommand

            return EvalCommand(self.out).run()
        return 0


def existing_run_conflict(out: Path, config, resume: bool) -> str | None:
    """Why training ``config`` into ``out`` would mix with the run already there (None when there
    is none, or when ``resume`` continues a run of the same config): a run of another config,
    which neither a new run nor a resume may reuse, or a run of this config without ``resume``."""
    from radar4dgs.apps.reuse import FORCE_HINT, run_differences
    from radar4dgs.config import first_differences
    from radar4dgs.model.run import CHECKPOINT_DIR, CONFIG_FILE, LAST_CHECKPOINT, MODEL_FILE

    last, model = out / CHECKPOINT_DIR / LAST_CHECKPOINT, out / MODEL_FILE
    if not (last.is_file() or model.is_file()):
        return None  # nothing trained there yet: training writes it anew
    differences = run_differences(out, config)
    if differences:
        return (f"{out / CONFIG_FILE}: the run there was trained with another config "
                f"({first_differences(differences)}); {FORCE_HINT}, or choose another --out")
    if resume:
        return None
    what = "a finished run" if model.is_file() else f"a run (checkpoint {last})"
    return (f"{out}: holds {what} of this config already; pass --resume to continue it, --force to "
            f"train it again, or choose another --out")


def check_prepared_scene(scene: Path, prepared: Path) -> None:
    """Refuse (ValueError) a prepared folder whose stages were made for another ``scene.json``
    than ``scene``'s: a run trained on them would mix two scenes. A scene that cannot be read and
    stages that are missing are left to the trainer, which names them."""
    import hashlib
    import json

    from radar4dgs.apps.prepare import STAGE_MARKER, STAGES

    try:
        fingerprint = hashlib.sha256((scene / "scene.json").read_bytes()).hexdigest()
    except OSError:
        return
    for stage in STAGES:
        marker = prepared / stage.name / STAGE_MARKER
        try:
            made_for = json.loads(marker.read_text(encoding="utf-8")).get("scene")
        except (OSError, ValueError, AttributeError):
            continue
        if made_for != fingerprint:
            raise ValueError(f"{prepared / stage.name}: prepared for another scene.json than {scene / 'scene.json'}; "
                             f"run `radar4dgs prepare {scene} --out {prepared}`")
