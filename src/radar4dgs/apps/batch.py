"""``radar4dgs batch SCENE... --out DIR``: many scenes at once, each one Ray task (prepare -> train ->
eval -> report), on a local cluster started in this process or on an existing Ray cluster.

Each task declares its resources (CPUs, a GPU fraction, memory; from the preset, or ``--cpus`` /
``--gpus`` / ``--memory-gb``) and Ray runs as many at once as the cluster has room for (``--jobs``
caps it). A task whose worker dies (killed, out of memory, a node lost) is retried up to
``--retries`` times and continues from the scene's last checkpoint; a scene that fails for good
(bad input, a run of another config, a non-finite loss) is recorded with its one-line error while
the others go on. A scene finished by an earlier batch with the same request (scene, preset,
method, prepare and train config) is skipped. ``--out`` must be a folder every worker sees (the
same path on every node: a shared file system).

Outputs, all written atomically: ``OUT/scenes/<label>/`` per scene (:mod:`radar4dgs.apps.batch_scene`),
and the collected table ``OUT/batch.json``, ``OUT/batch.md``, ``OUT/index.html`` (linking each
scene's report), rewritten as each scene ends.
"""

from __future__ import annotations

import dataclasses
import sys
import time
import uuid
from dataclasses import dataclass
from pathlib import Path
from typing import Annotated, Any, Callable, ClassVar, Mapping, Optional, Sequence

import tyro

from radar4dgs.apps.batch_engine import EngineError, Resources, elapsed_text
from radar4dgs.apps.batch_scene import SCENES_DIR, BatchError, SceneSpec, failed_record, read_status, write_status
from radar4dgs.apps.batch_table import BATCH_FILE, BATCH_MD, INDEX_HTML, payload, write_outputs
from radar4dgs.apps.options import default_is
from radar4dgs.config import PresetName
from radar4dgs.train.variants import MethodName

# What one scene's task declares by default, per preset: tiny and small scenes train on CPU
# threads; the paper preset needs a GPU (and sets the run's device to cuda).
PRESET_RESOURCES: dict[str, Resources] = {
    "tiny": Resources(cpus=1, gpus=0, memory_gb=1),
    "small": Resources(cpus=2, gpus=0, memory_gb=3),
    "paper": Resources(cpus=4, gpus=1, memory_gb=12),
}


def task_resources(preset_name: str, cpus: float | None = None, gpus: float | None = None,
                   memory_gb: float | None = None) -> Resources:
    """The preset's :data:`PRESET_RESOURCES` with the given values instead."""
    base = PRESET_RESOURCES[preset_name]
    resources = Resources(base.cpus if cpus is None else cpus, base.gpus if gpus is None else gpus,
                          base.memory_gb if memory_gb is None else memory_gb)
    if resources.cpus <= 0 or resources.gpus < 0 or resources.memory_gb < 0:
        raise BatchError(f"resources must be positive: {resources.text()} (--cpus > 0, --gpus >= 0, --memory-gb >= 0)")
    return resources


def scene_overrides(settings: Mapping[str, Any] | None, resources: Resources, iterations: int | None
                    ) -> dict[str, Any]:
    """Every scene's TrainConfig overrides: ``settings``, torch threads = the task's CPUs (unless
    set), the device cuda when the task declares a GPU and cpu when it declares none (unless set:
    TrainConfig's "auto" would take a GPU the task did not reserve), ``iterations`` when given."""
    from radar4dgs.config import merge

    settings = dict(settings or {})
    overrides: dict[str, Any] = {"threads": max(1, int(resources.cpus))}
    overrides["device"] = "cuda" if resources.gpus > 0 else "cpu"
    overrides = merge(overrides, settings)
    if iterations is not None:
        overrides = merge(overrides, {"optim": {"iterations": iterations}})
    return overrides


class ProgressView:
    """Each scene's stage, iteration and ETA, read from its status.json: one tqdm bar per scene on
    a terminal, else a line whenever a scene's stage or iteration changes."""

    def __init__(self, specs: Sequence[SceneSpec], enabled: bool = True, log: Callable[[str], None] = print,
                 stream=None):
        self.specs, self.enabled, self.log = list(specs), enabled, log
        self.stream = stream if stream is not None else sys.stderr
        self.shown: dict[str, tuple] = {}
        self.bars: dict[str, Any] = {}
        self.tty = enabled and hasattr(self.stream, "isatty") and self.stream.isatty()

    @staticmethod
    def describe(label: str, status: Mapping[str, Any]) -> str:
        stage = status.get("stage") or "queued"
        text = f"{label}: {stage}"
        if stage == "train" and status.get("total"):
            step = status.get("step")
            text += f" {'?' if step is None else step}/{status['total']} it"
            if status.get("eta_s") is not None:
                left = status["eta_s"] - (time.time() - status.get("updated", time.time()))
                text += f", ETA {elapsed_text(max(0.0, left))}"
        if (status.get("attempt") or 1) > 1:
            text += f" (attempt {status['attempt']}, resumed)"
        if stage in ("failed", "retrying") and status.get("error"):
            text += f": {status['error']}"
        return text

    def refresh(self) -> None:
        if not self.enabled:
            return
        for position, spec in enumerate(self.specs):
            status = read_status(spec.out)
            key = (status.get("stage"), status.get("step"), status.get("attempt"))
            if self.tty:
                self._bar(spec.label, position, status)
            elif key != self.shown.get(spec.label) and status.get("stage") not in (None, "queued", "done", "failed"):
                self.shown[spec.label] = key
                self.log("  " + self.describe(spec.label, status))

    def _bar(self, label: str, position: int, status: Mapping[str, Any]) -> None:
        from tqdm import tqdm

        bar = self.bars.get(label)
        if bar is None:
            bar = self.bars[label] = tqdm(total=status.get("total") or 1, position=position, leave=True,
                                          file=self.stream, dynamic_ncols=True, unit="it",
                                          bar_format="{desc} |{bar}| {n_fmt}/{total_fmt}")
        if status.get("total"):
            bar.total = status["total"]
        bar.n = status.get("step") or 0
        bar.set_description_str(self.describe(label, status), refresh=False)
        bar.refresh()

    def close(self) -> None:
        for bar in self.bars.values():
            bar.close()
        self.bars.clear()


def _done_line(record: Mapping[str, Any], done: int, total: int) -> str:
    name = f"[{done}/{total}] {record['scene']}"
    if record["status"] != "ok":
        return f"{name}: FAILED: {record.get('error')}"
    nvs = (record.get("metrics") or {}).get("nvs") or {}
    psnr = f", novel-view PSNR {nvs['psnr']:.2f} dB" if nvs.get("psnr") is not None else ""
    if record.get("action") == "skipped":
        return f"{name}: skipped (finished with the same config){psnr}"
    attempts = f", {record['attempts']} attempts" if (record.get("attempts") or 1) > 1 else ""
    return f"{name}: {record['action']} in {elapsed_text(record.get('seconds'))}{attempts}{psnr}"


def run_batch(scenes: Sequence[Path], out: Path, preset_name: str = "small", method: str = "ours",
              address: str | None = None, resources: Resources | None = None, jobs: int | None = None,
              retries: int = 2, iterations: int | None = None, settings: Mapping[str, Any] | None = None,
              lpips: bool = True, video: bool = True, force: bool = False, progress: bool = True,
              log: Callable[[str], None] = print) -> dict[str, Any]:
    """Run every scene of ``scenes`` into ``out`` (see the module) and return batch.json."""
    from radar4dgs.apps.batch_engine import check_resources, cluster, run_tasks
    from radar4dgs.apps.batch_scene import finished_record, run_scene, train_config
    from radar4dgs.apps.bench_spec import scene_labels

    if not scenes:
        raise BatchError("no scenes given: radar4dgs batch SCENE... --out DIR")
    if jobs is not None and jobs < 1:
        raise BatchError(f"--jobs must be >= 1, got {jobs}")
    if retries < 0:
        raise BatchError(f"--retries must be >= 0, got {retries}")
    resources = resources if resources is not None else PRESET_RESOURCES[preset_name]
    out = Path(out)
    labels = scene_labels([Path(s) for s in scenes])
    overrides = scene_overrides(settings, resources, iterations)
    batch_id = uuid.uuid4().hex
    specs = [SceneSpec(label, Path(scene), out / SCENES_DIR / label, preset_name, method, overrides, lpips, video,
                       force, batch_id) for label, scene in zip(labels, scenes, strict=True)]
    try:
        config = train_config(specs[0])  # a bad --set fails here, before anything runs
    except (ValueError, TypeError) as exc:
        raise BatchError(str(exc)) from exc
    batch_config = {"preset": preset_name, "method": method, "iterations": config.optim.iterations,
                    "settings": dict(settings or {}), "resources": dataclasses.asdict(resources), "jobs": jobs,
                    "retries": retries, "address": address or "local", "lpips": lpips, "video": video,
                    "scenes": [{"label": s.label, "scene": str(s.scene)} for s in specs]}
    records: dict[str, dict[str, Any]] = {}
    for spec in specs:
        done = finished_record(spec)
        if done is not None:
            records[spec.label] = {**{k: done.get(k) for k in ("scene", "path", "status", "seconds", "attempts",
                                                                "run", "metrics")}, "action": "skipped"}
    pending = [s for s in specs if s.label not in records]
    out.mkdir(parents=True, exist_ok=True)
    log(f"batch: {len(specs)} scene(s), {len(specs) - len(pending)} finished already; preset {preset_name}, "
        f"method {method}, {config.optim.iterations} iterations; each task {resources.text()} -> {out}")
    for index, spec in enumerate(specs):
        if spec.label in records:
            log(_done_line(records[spec.label], index + 1, len(specs)))
    view = ProgressView(pending, enabled=progress, log=log)

    def on_done(index: int, record: dict[str, Any] | None, error: str | None) -> None:
        spec = pending[index]
        if error is not None:
            status = read_status(spec.out)
            record = failed_record(spec, error, None, status.get("attempt"))
            write_status(spec, stage="failed", error=error)
        view.refresh()
        records[spec.label] = record
        log(_done_line(record, len(records), len(specs)))
        write_outputs(out, payload(batch_config, labels, records))

    try:
        write_outputs(out, payload(batch_config, labels, records))
        if pending:
            for spec in pending:
                spec.out.mkdir(parents=True, exist_ok=True)
                write_status(spec, stage="queued", attempt=0)
            with cluster(address) as available:
                problems = check_resources(resources, available, local=address is None)
                if problems and address is None:
                    raise BatchError(f"a task asks for more than this machine has: {'; '.join(problems)}")
                for problem in problems:
                    log(f"radar4dgs batch: warning: {problem}; the tasks wait for a node with room "
                        f"(the autoscaler's)")
                run_tasks(run_scene, pending, resources=resources, window=jobs, retries=retries,
                          on_done=on_done, on_poll=view.refresh)
    except EngineError as exc:
        raise BatchError(str(exc)) from exc
    finally:
        view.close()
        result = payload(batch_config, labels, records)
        write_outputs(out, result)
    return result


@dataclass
class BatchCommand:
    """Reconstruct many scenes at once on Ray (prepare, train, eval, report per scene); one table."""

    # Scene folders (each is prepared into OUT/scenes/<label>/prepared; the folder itself is only read).
    scenes: tyro.conf.Positional[tuple[Path, ...]]
    # Output folder, seen by every worker: scenes/<label>/, batch.json, batch.md, index.html.
    out: Path = Path("runs/batch")
    # Preset of the front end and training, and of each task's resources.
    preset: PresetName = "small"
    # The method every scene is trained with (see radar4dgs.train.variants).
    method: MethodName = "ours"
    # Ray cluster: "auto" (the one this machine belongs to) or ray://HOST:10001.
    address: Annotated[Optional[str], default_is("a local cluster started for this batch")] = None
    # CPUs per task (also its torch threads).
    cpus: Annotated[Optional[float], default_is("the preset's: tiny 1, small 2, paper 4")] = None
    # GPUs per task (a fraction shares one); > 0 trains on cuda.
    gpus: Annotated[Optional[float], default_is("the preset's: paper 1, else 0")] = None
    # Memory per task, GiB (0: none declared).
    memory_gb: Annotated[Optional[float], default_is("the preset's: tiny 1, small 3, paper 12")] = None
    # At most this many scenes at once.
    jobs: Annotated[Optional[int], default_is("as many as the resources allow")] = None
    # Times a task is run again after its worker died or it raised unexpectedly (it resumes from its checkpoint).
    retries: int = 2
    # Training iterations of every scene.
    iterations: Annotated[Optional[int], default_is("the preset's")] = None
    # TrainConfig fields of every scene, as dotted KEY=VALUE (JSON values), e.g. checkpoint_every=100.
    set: Annotated[tuple[str, ...], default_is("none")] = ()
    # Compute LPIPS when the backbone weights are present.
    lpips: bool = True
    # Write each run's video.mp4 too.
    video: bool = True
    # Overwrite: retrain the scenes whose run in OUT was trained with another configuration, and redo
    # finished scenes. Without it such a scene fails, saying what differs.
    force: bool = False
    # No progress view (each scene's stage, iteration and ETA).
    quiet: bool = False

    USER_ERRORS: ClassVar[tuple[str, ...]] = ("radar4dgs.train.trainer.TrainingError",)

    def run(self) -> int:
        from radar4dgs.apps.bench_spec import parse_overrides

        resources = task_resources(self.preset, self.cpus, self.gpus, self.memory_gb)
        result = run_batch(self.scenes, self.out, self.preset, self.method, self.address, resources, self.jobs,
                           self.retries, self.iterations, parse_overrides(self.set), self.lpips, self.video,
                           self.force, progress=not self.quiet, log=lambda line: print(line, flush=True))
        print()
        print((self.out / BATCH_MD).read_text(), end="")
        print(f"\nwritten: {self.out / BATCH_MD}, {self.out / INDEX_HTML}, {self.out / BATCH_FILE}")
        if result["failed"]:
            failed = [r["scene"] for r in result["scenes"] if r["status"] != "ok"]
            print(f"radar4dgs batch: {len(failed)} scene(s) failed: {', '.join(failed)} (errors in "
                  f"{self.out / BATCH_MD}; rerun to retry them)", file=sys.stderr)
            return 1
        return 0
