"""One scene of ``radar4dgs batch``: the task a Ray worker runs (prepare -> train -> eval -> report),
its status file (the progress view's source), and whether a scene is finished already.

Everything a scene writes is under ``OUT/scenes/<label>/``: ``prepared/`` (the front end),
``run/`` (the run folder: config, checkpoints, model, metrics, renders, report), ``status.json``
(stage, iteration, ETA, worker pid and host, attempt; rewritten as the task goes), ``task.log``
(what the stages print, and a failure's traceback) and ``done.json`` (written last: the request the
scene was finished for, and its metrics summary). Every file is written atomically.

Training goes in chunks of ``checkpoint_every`` iterations, each ending on a checkpoint: the status
file's iteration and ETA move at each chunk, and a task retried after its worker died continues
from the last checkpoint (the trainer's resume, which continues exactly as the unbroken run would).
"""

from __future__ import annotations

import contextlib
import os
import re
import shutil
import socket
import time
import traceback
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Mapping

from radar4dgs.apps.reuse import config_digest, read_json, scene_fingerprint
from radar4dgs.io.atomic import atomic_write_json

SCENES_DIR = "scenes"
STATUS_FILE = "status.json"
DONE_FILE = "done.json"
LOG_FILE = "task.log"
PREPARED_DIR = "prepared"
RUN_DIR = "run"
METRICS_FILE = "metrics.json"  # as radar4dgs.evaluate.reconstruction, which imports torch
REPORT_FILE = "report.html"
# The stages a scene goes through, in order, as status.json names them.
STAGES = ("queued", "prepare", "train", "eval", "done", "failed", "skipped")

# The temporary names of radar4dgs.io.atomic (mkstemp/mkdtemp: ".<name>.<8 random chars><suffix>"):
# what an atomic write killed half-way leaves behind.
PARTIAL = re.compile(r"^\..+\.[a-z0-9_]{8}\.[A-Za-z0-9]+$")


class BatchError(ValueError):
    """A scene or a batch that cannot run as asked; the message says what to fix."""


@dataclass(frozen=True)
class SceneSpec:
    """Everything one scene's task needs (plain values: it is pickled to a Ray worker)."""

    label: str
    scene: Path  # the input scene folder (read only)
    out: Path  # OUT/scenes/<label>
    preset: str
    method: str
    # TrainConfig overrides on top of the preset and the method (nested dicts).
    overrides: Mapping[str, Any] = field(default_factory=dict)
    lpips: bool = True
    video: bool = False
    force: bool = False
    batch_id: str = ""

    @property
    def prepared(self) -> Path:
        return self.out / PREPARED_DIR

    @property
    def run(self) -> Path:
        return self.out / RUN_DIR


def train_config(spec: SceneSpec):
    """The scene's TrainConfig: the preset, the method's fields, then ``spec.overrides``."""
    from radar4dgs.train.variants import variant_config

    return variant_config(spec.preset, spec.method, **spec.overrides)


def request(spec: SceneSpec) -> dict[str, Any]:
    """What a finished scene must have been made from to be reused: the scene (path and
    fingerprint), the preset and method, and the prepare config's digest (the train config is
    compared field by field, through the run's config.json)."""
    from radar4dgs.apps.prepare import PrepareConfig
    from radar4dgs.config import preset

    return {"scene_path": str(Path(spec.scene).resolve()), "scene_sha256": scene_fingerprint(spec.scene),
            "preset": spec.preset, "method": spec.method,
            "prepare_config": config_digest(preset(PrepareConfig, spec.preset))}


def finished_record(spec: SceneSpec) -> dict[str, Any] | None:
    """The ``done.json`` of a scene finished with this same request and train config (None
    otherwise): a batch skips it."""
    from radar4dgs.apps.reuse import run_differences

    done = read_json(spec.out / DONE_FILE)
    if spec.force or done is None or not (spec.run / METRICS_FILE).is_file():
        return None
    if {key: done.get(key) for key in request(spec)} != request(spec):
        return None
    try:
        if run_differences(spec.run, train_config(spec)) != []:
            return None
    except ValueError:
        return None
    return done


def write_status(spec: SceneSpec, **fields: Any) -> dict[str, Any]:
    """Rewrite ``status.json`` with ``fields`` over what it holds for this batch."""
    path = spec.out / STATUS_FILE
    status = read_json(path) or {}
    if status.get("batch_id") != spec.batch_id:
        status = {"batch_id": spec.batch_id}
    status.update(fields, updated=time.time())
    atomic_write_json(path, status)
    return status


def read_status(out: Path) -> dict[str, Any]:
    return read_json(Path(out) / STATUS_FILE) or {}


def remove_partial_files(folder: Path) -> list[Path]:
    """Delete what atomic writes killed half-way left in ``folder`` (their temporary files and
    folders); returns them."""
    removed = []
    if not Path(folder).is_dir():
        return removed
    for root, dirs, files in os.walk(folder):
        for name in [*dirs, *files]:
            if PARTIAL.match(name):
                path = Path(root) / name
                shutil.rmtree(path) if path.is_dir() else path.unlink(missing_ok=True)
                removed.append(path)
        dirs[:] = [d for d in dirs if not PARTIAL.match(d)]
    return removed


def failed_record(spec: SceneSpec, error: str, seconds: float | None, attempt: int | None = None) -> dict[str, Any]:
    return {"scene": spec.label, "path": str(spec.scene), "status": "failed", "error": error,
            "seconds": seconds, "attempts": attempt, "run": str(spec.run)}


def run_scene(spec: SceneSpec) -> dict[str, Any]:
    """The task: bring one scene to its metrics and report; returns its batch.json record.

    A scene whose input or run folder is wrong (a bad scene, a run of another config, a
    non-finite loss) returns a failed record with its one-line error: retrying would fail alike.
    Anything else propagates, and Ray retries the task (a dead worker too); the retry continues
    from the run's last checkpoint.
    """
    from radar4dgs.apps.batch_engine import one_line

    started = time.perf_counter()
    spec.out.mkdir(parents=True, exist_ok=True)
    previous = read_status(spec.out)
    attempt = int(previous.get("attempt", 0)) + 1 if previous.get("batch_id") == spec.batch_id else 1
    write_status(spec, stage="prepare", attempt=attempt, pid=os.getpid(), host=socket.gethostname(),
                 step=None, total=None, eta_s=None, error=None, started=time.time())
    with open(spec.out / LOG_FILE, "a", encoding="utf-8") as log, contextlib.redirect_stdout(log), \
            contextlib.redirect_stderr(log):
        print(f"--- batch {spec.batch_id}, attempt {attempt}, pid {os.getpid()} on {socket.gethostname()}",
              flush=True)
        try:
            record = _run_stages(spec, attempt, started)
        except Exception as exc:
            traceback.print_exc()
            log.flush()
            if not _deterministic(exc):
                write_status(spec, stage="retrying", error=one_line(exc))
                raise
            error = one_line(exc) if not isinstance(exc, (ValueError, OSError)) else _message(exc)
            write_status(spec, stage="failed", error=error)
            return failed_record(spec, error, time.perf_counter() - started, attempt)
    return record


def _message(exc: BaseException) -> str:
    lines = str(exc).strip().splitlines()
    return lines[0] if lines else type(exc).__name__


def _deterministic(exc: BaseException) -> bool:
    """Whether a retry would fail the same way: bad input or a run that cannot train."""
    if isinstance(exc, (ValueError, OSError)) and not isinstance(exc, (ConnectionError, TimeoutError)):
        return True
    return type(exc).__name__ == "TrainingError"


def _run_stages(spec: SceneSpec, attempt: int, started: float) -> dict[str, Any]:
    from radar4dgs.apps.bench_cell import cell_summary
    from radar4dgs.apps.prepare import PrepareConfig, run_prepare
    from radar4dgs.apps.reuse import holds_run, remove_run, run_differences
    from radar4dgs.config import first_differences, preset
    from radar4dgs.evaluate.reconstruction import evaluate_run, write_provenance
    from radar4dgs.model.run import CHECKPOINT_DIR, LAST_CHECKPOINT, MODEL_FILE
    from radar4dgs.train.fit_motion import torch_threads
    from radar4dgs.train.trainer import train_run

    for path in remove_partial_files(spec.out):
        print(f"removed {path} (a write interrupted by the previous attempt)")
    config = train_config(spec)
    if not (spec.scene / "scene.json").is_file():
        raise BatchError(f"{spec.scene}: not a scene folder (no scene.json)")
    status = run_prepare(spec.scene, spec.prepared, preset(PrepareConfig, spec.preset), progress=False)
    run = spec.run
    if any(state == "ran" for state in status.values()) and (run / MODEL_FILE).exists():
        # A model trained on other prepared outputs (the scene or the prepare config changed).
        print(f"prepared stages reran ({', '.join(s for s, v in status.items() if v == 'ran')}): retraining")
        remove_run(run)
    if spec.force and attempt == 1 and holds_run(run):
        remove_run(run)  # a retry keeps what the first attempt trained
        print(f"--force: removed the earlier run in {run}")
    changed = run_differences(run, config)
    if changed:
        raise BatchError(f"{run}: trained with another configuration ({first_differences(changed, 4)}); "
                         "pass --force to retrain it, or batch into another --out")
    last = run / CHECKPOINT_DIR / LAST_CHECKPOINT
    if (run / MODEL_FILE).is_file():
        action = "evaluated"  # trained (and maybe evaluated, with done.json missing or stale)
    elif last.is_file():
        action = "resumed"
    else:
        action = "trained"
    total = config.optim.iterations
    if action != "evaluated":
        chunk = config.checkpoint_every if config.checkpoint_every > 0 else total
        write_status(spec, stage="train", step=None, total=total, action=action)
        train_started, done_before = time.perf_counter(), None
        while True:
            state = train_run(spec.scene, spec.prepared, run, config, resume=last.is_file(), progress=False,
                              stop_after=chunk)
            if done_before is None:  # the step the first chunk started from
                done_before = max(0, state.step - chunk)
            rate = (time.perf_counter() - train_started) / max(1, state.step - done_before)
            write_status(spec, stage="train", step=state.step, total=total, eta_s=rate * (total - state.step))
            if state.step >= total:
                break
        write_provenance(run, preset=spec.preset, method=spec.method,
                         command=f"radar4dgs batch (scene {spec.label}, preset {spec.preset}, method {spec.method})")
    write_status(spec, stage="eval", step=total, total=total, eta_s=None)
    with torch_threads(config.threads):
        metrics = evaluate_run(run, lpips=spec.lpips, video=spec.video, report=True, progress=False)
    seconds = time.perf_counter() - started
    record = {"scene": spec.label, "path": str(spec.scene), "status": "ok", "action": action, "seconds": seconds,
              "attempts": attempt, "run": str(run), "metrics": cell_summary(metrics)}
    atomic_write_json(spec.out / DONE_FILE, {**request(spec), **record})
    write_status(spec, stage="done", eta_s=0.0)
    return record
