"""``radar4dgs train SCENE --out RUN``: the three-stage Gaussian training of a prepared scene.

``radar4dgs train RUN --resume`` continues a run from its last checkpoint with the run's own
config (``RUN/config.json``), scene and prepared folder (``RUN/run.json``); ``train SCENE --out RUN
--resume`` does the same when no config option is given. A config option given on resume is
refused naming what differs, except :data:`SAFE_ON_RESUME` (the iteration count), which is
accepted and recorded in ``RUN/provenance.json`` (``resumed``).
"""

from __future__ import annotations

import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Annotated, Any, ClassVar, Optional

import tyro

from radar4dgs.apps.options import default_is
from radar4dgs.apps.reuse import holds_run
from radar4dgs.config import PresetName
from radar4dgs.model.config import Method, TrainConfig
from radar4dgs.train.variants import MethodName

# --out's default: a run folder given as the positional path (train RUN --resume) takes its place.
DEFAULT_OUT = Path("runs/train")
# Config fields a resume may change (besides the runtime ones: threads, device, frame_cache): the
# run continues from its checkpoint to the new count (stages and schedules follow the new count
# from there on).
SAFE_ON_RESUME = ("optim.iterations",)


@dataclass
class TrainOptions(TrainConfig):
    """Everything the trainer does besides the method (``radar4dgs train --method`` sets that)."""

    # Not an option of its own: --method NAME sets it with the method's other fields.
    method: tyro.conf.Suppress[Method] = "ours"


@dataclass
class TrainCommand:
    """Train the Gaussian scene (static + dynamic Gaussians, VGPT field, sky) on a prepared scene."""

    # The scene folder; with --resume, or a run folder (train RUN --resume: the scene, prepared folder
    # and config the run was started with, from RUN/run.json and RUN/config.json).
    scene: tyro.conf.Positional[Path]
    # The run folder (config, checkpoints, model, then metrics and renders from `radar4dgs eval`).
    out: Path = DEFAULT_OUT
    # The prepared folder (run `radar4dgs prepare SCENE` first).
    prepared: Annotated[Optional[Path], default_is("SCENE/prepared")] = None
    # Preset the config starts from.
    preset: PresetName = "small"
    # Everything the trainer does (filled from --preset, then overridden by options).
    config: TrainOptions = field(default_factory=TrainOptions)
    # The method: ours, a baseline or an ablation (see radar4dgs.train.variants); it sets its own
    # config fields on top of the preset and the options.
    method: MethodName = "ours"
    # Continue the run in --out from its last checkpoint, with the run's own config (config options
    # given here must agree with it, except --config.optim.iterations).
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

        out, scene, prepared = self.folders()
        # One process per run folder (another one's is refused in one line); what dead runs left
        # half-written there (checkpoints, renders) is removed first.
        with folder_lock(out):
            remove_dead_temporaries(out, recursive=True)
            return self._train(out, scene, prepared)

    def folders(self) -> tuple[Path, Path, Path]:
        """(run folder, scene, prepared folder): from the options or, for ``train RUN --resume``
        (the positional path a run folder), from ``RUN/run.json``."""
        if not (self.resume and holds_run(self.scene)):
            return self.out, self.scene, self.prepared if self.prepared is not None else self.scene / "prepared"
        run = self.scene
        if self.out != DEFAULT_OUT and self.out.resolve() != run.resolve():
            raise ValueError(f"{run}: a run folder, resumed in place; drop --out {self.out} (or give the scene: "
                             f"`radar4dgs train SCENE --out {self.out}`)")
        scene, prepared = recorded_folders(run)
        return run, scene, self.prepared if self.prepared is not None else prepared

    def _train(self, out: Path, scene: Path, prepared: Path) -> int:
        from radar4dgs.train.trainer import train_run
        from radar4dgs.train.variants import apply_variant

        config = apply_variant(self.config, self.method)  # a TrainConfig, the method's fields set
        resume, provenance = self.resume, self._provenance(out, scene)
        if self.resume and holds_run(out):
            resumed, changes, conflict = self._resume_config(out, config)
            if not conflict:
                config = resumed
                if changes:
                    record = {"at": time.strftime("%Y-%m-%d %H:%M:%S %z"), "changed": changes}
                    provenance["resumed"] = [*provenance.get("resumed", []), record]
        else:
            conflict = existing_run_conflict(out, config, self.resume)
        if conflict and not self.force:
            raise FileExistsError(conflict)
        if conflict:
            from radar4dgs.apps.reuse import remove_run

            remove_run(out)
            print(f"--force: removed the earlier run in {out}")
            resume, provenance = False, self._provenance(out, scene, fresh=True)
        check_prepared_scene(scene, prepared)
        if resume and holds_run(out):
            # The iteration count a resume changed (now, or in a call killed before it trained).
            accept_resume_changes(out, config)
            if provenance.get("resumed"):
                write_run_provenance(out, provenance)
        # A missing or malformed scene or prepared stage raises a user error: one line (radar4dgs.cli).
        train_run(scene, prepared, out, config, resume=resume, progress=not self.quiet, tensorboard=self.tensorboard)
        write_run_provenance(out, provenance)
        print(f"trained: {out}")
        if self.eval:
            from radar4dgs.apps.eval import EvalCommand

            return EvalCommand(out).run()
        return 0

    def _resume_config(self, out: Path, requested: TrainConfig) -> tuple[TrainConfig, list[str], str | None]:
        """(the config that resuming the run in ``out`` continues with: the run's own, with the
        config options given here, those that differ from the preset's, on top; what that changes
        as ``"optim.iterations: 200 != 400"`` lines; why it may not, None when it may: a change
        outside :data:`SAFE_ON_RESUME`)."""
        from radar4dgs.apps.reuse import FORCE_HINT
        from radar4dgs.config import first_differences, preset
        from radar4dgs.model.run import CONFIG_FILE
        from radar4dgs.train.variants import apply_variant

        defaults = apply_variant(preset(TrainOptions, self.preset), self.method)
        config, changes = resumed_config(out, requested, defaults, self.method)
        unsafe = [line for line in changes if line.split(":", 1)[0] not in SAFE_ON_RESUME]
        if unsafe:
            return config, changes, (f"{out / CONFIG_FILE}: --resume continues the run with its own config, and "
                                     f"options given differ from it ({first_differences(unsafe)}); only "
                                     f"{', '.join(SAFE_ON_RESUME)} may change on resume; drop them, or "
                                     f"{FORCE_HINT} and train from scratch")
        print(f"resuming {out} with its config ({out / CONFIG_FILE})"
              + (f"; changed: {'; '.join(changes)}" if changes else ""))
        return config, changes, None

    def _provenance(self, out: Path, scene: Path, fresh: bool = False) -> dict[str, Any]:
        """What ``RUN/provenance.json`` records for this call: a resume keeps the preset, method and
        command that started the run, and the changes of earlier resumes (a run killed before its
        first training call ended has none recorded: the preset and method are then unknown, null;
        evaluation then names the config's method)."""
        from radar4dgs.apps.reuse import read_json
        from radar4dgs.evaluate.reconstruction import PROVENANCE_FILE

        earlier = None if fresh or not self.resume else read_json(out / PROVENANCE_FILE)
        if earlier and earlier.get("command"):
            return {k: earlier[k] for k in ("preset", "method", "command", "resumed") if k in earlier}
        unknown = self.resume and not fresh and holds_run(out)
        if unknown:
            return {"preset": None, "method": None,
                    "command": f"radar4dgs train {out} --resume (the run's first command was not recorded)"}
        return {"preset": self.preset, "method": self.method,
                "command": f"radar4dgs train {scene} --out {out} --preset {self.preset} --method {self.method} "
                           f"(other options: config.json)"}


def recorded_folders(run: Path) -> tuple[Path, Path]:
    """(scene, prepared folder) the run in ``run`` was trained on, from its ``run.json``; a
    ValueError names what is missing."""
    from radar4dgs.apps.reuse import read_json
    from radar4dgs.model.run import RUN_FILE

    recorded = read_json(run / RUN_FILE) or {}
    if not recorded.get("scene") or not recorded.get("prepared"):
        raise ValueError(f"{run / RUN_FILE}: names no scene and prepared folder; resume with "
                         f"`radar4dgs train SCENE --out {run} --resume`")
    scene, prepared = Path(recorded["scene"]), Path(recorded["prepared"])
    if not (scene / "scene.json").is_file():
        raise FileNotFoundError(f"{run / RUN_FILE}: the run's scene {scene} is gone (moved?); resume with "
                                f"`radar4dgs train SCENE --out {run} --resume`")
    return scene, prepared


def changed_values(base: dict, new: dict) -> dict:
    """The entries of config dict ``new`` that differ from ``base`` (nested dicts by key)."""
    out = {}
    for key, value in new.items():
        if isinstance(value, dict) and isinstance(base.get(key), dict):
            nested = changed_values(base[key], value)
            if nested:
                out[key] = nested
        elif base.get(key) != value:
            out[key] = value
    return out


def resumed_config(run: Path, requested: TrainConfig, defaults: TrainConfig,
                   method: str = "ours") -> tuple[TrainConfig, list[str]]:
    """(the run's own config, ``RUN/config.json``, with the options of ``requested`` that differ
    from ``defaults`` (the preset's) on top, and method ``method``'s fields; the lines where it
    differs from the run's, runtime fields not counted)."""
    from radar4dgs.config import from_dict, merge, read_config_dict, to_dict
    from radar4dgs.model.run import CONFIG_FILE
    from radar4dgs.train.run_config import run_config_difference, with_legacy_values
    from radar4dgs.train.variants import apply_variant

    saved = from_dict(TrainConfig, with_legacy_values(read_config_dict(TrainConfig, run / CONFIG_FILE)), partial=False)
    given = changed_values(to_dict(defaults), to_dict(requested))
    config = apply_variant(from_dict(TrainConfig, merge(to_dict(saved), given), partial=False), method)
    return config, run_config_difference(saved, config)


def accept_resume_changes(run: Path, config: TrainConfig) -> None:
    """Make the run in ``run`` continue with ``config`` (differing from its own in
    :data:`SAFE_ON_RESUME` only): its last checkpoint and ``config.json`` take it. A checkpoint
    already past ``config``'s iteration count is refused (ValueError)."""
    import torch

    from radar4dgs.config import save_config, to_dict
    from radar4dgs.io.atomic import atomic_save_torch
    from radar4dgs.model.run import CHECKPOINT_DIR, CONFIG_FILE, LAST_CHECKPOINT
    from radar4dgs.train.run_config import run_config_difference

    last = run / CHECKPOINT_DIR / LAST_CHECKPOINT
    if last.is_file():
        payload = torch.load(last, map_location="cpu", weights_only=True, mmap=True)
        step = int(payload["step"])
        if step > config.optim.iterations:
            raise ValueError(f"{last}: the run is at iteration {step} already, past --config.optim.iterations "
                             f"{config.optim.iterations}")
        changed = run_config_difference(payload.get("config") or {}, config)
        # Anything else differing is the trainer's to refuse.
        if changed and all(line.split(":", 1)[0] in SAFE_ON_RESUME for line in changed):
            payload["config"] = to_dict(config)
            atomic_save_torch(last, payload)
    save_config(config, run / CONFIG_FILE)


def write_run_provenance(run: Path, provenance: dict[str, Any]) -> None:
    """``RUN/provenance.json``: :func:`radar4dgs.evaluate.reconstruction.write_provenance`'s record
    with the changes accepted on resume (``resumed``: when, what)."""
    from radar4dgs.apps.reuse import read_json
    from radar4dgs.evaluate.reconstruction import write_provenance
    from radar4dgs.io.atomic import atomic_write_json

    path = write_provenance(run, preset=provenance["preset"], method=provenance["method"],
                            command=provenance["command"])
    if provenance.get("resumed"):
        atomic_write_json(path, {**(read_json(path) or {}), "resumed": provenance["resumed"]})


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
    than ``scene``'s, or from outputs of an earlier stage that was redone since (``prepare --only radar
    --force`` leaves the flow of the old radar objects): a run trained on them would mix two scenes or two
    front ends. A scene that cannot be read and stages that are missing are left to the trainer, which names them."""
    import json

    from radar4dgs.apps.prepare import STAGE_MARKER, STAGES, inputs_difference
    from radar4dgs.apps.reuse import scene_fingerprint

    fingerprint = scene_fingerprint(scene)
    if fingerprint is None:
        return
    for stage in STAGES:
        marker = prepared / stage.name / STAGE_MARKER
        try:
            saved = json.loads(marker.read_text(encoding="utf-8"))
            made_for = saved.get("scene")
        except (OSError, ValueError, AttributeError):
            continue
        if made_for != fingerprint:
            raise ValueError(f"{prepared / stage.name}: prepared for another scene.json than {scene / 'scene.json'}; "
                             f"run `radar4dgs prepare {scene} --out {prepared}`")
        redone = inputs_difference(prepared / stage.name, saved)
        if redone:
            raise ValueError(f"{redone}; run `radar4dgs prepare {scene} --out {prepared}` to bring it up to date")
