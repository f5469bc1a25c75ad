"""Running the bench's cells: one cell brought to its metrics (reusing what its run folder holds),
a cell's failure recorded instead of raised, and the grid's cells one after the other or as Ray
tasks (:mod:`radar4dgs.apps.batch_engine`, the engine of ``radar4dgs batch``)."""

from __future__ import annotations

import json
import os
import time
import traceback
from typing import Any, Callable, Mapping, Sequence

from radar4dgs.apps.bench_spec import BenchError, CellSpec
from radar4dgs.apps.bench_table import SPLITS
from radar4dgs.train.variants import variant_config

METRICS_FILE = "metrics.json"  # as radar4dgs.evaluate.reconstruction, which imports torch


def cell_summary(metrics: Mapping[str, Any]) -> dict[str, Any]:
    """The part of a run's metrics.json the bench keeps: both splits' summaries, the Gaussian
    count and the PSNR* mask source (the per-frame lists stay in the run folder)."""
    return {**{split: dict(metrics[split]) for split in SPLITS},
            **{key: metrics.get(key) for key in ("method", "num_gaussians", "mask_source", "lpips_available")}}


def run_cell(spec: CellSpec) -> dict[str, Any]:
    """Bring one cell to a metrics.json and return ``{"action", "metrics"}`` (:func:`cell_summary`).

    action: "skipped" (metrics.json present), "evaluated" (model.pt present), "resumed" (from
    checkpoints/last.pt) or "trained". A run folder trained with another configuration than the
    bench's (other iterations, say) raises, saying what differs: its numbers would not belong in
    this table; with ``spec.force`` it is deleted and trained again.
    """
    from radar4dgs.apps.reuse import remove_run, run_differences
    from radar4dgs.config import first_differences
    from radar4dgs.evaluate.reconstruction import evaluate_run, write_provenance
    from radar4dgs.model.run import CHECKPOINT_DIR, LAST_CHECKPOINT, MODEL_FILE
    from radar4dgs.train.fit_motion import torch_threads
    from radar4dgs.train.trainer import train_run

    config = variant_config(spec.preset, spec.method, **spec.overrides)
    run = spec.run_dir
    if (run / METRICS_FILE).is_file():
        state = "skipped"
    elif (run / MODEL_FILE).is_file():
        state = "evaluated"
    elif (run / CHECKPOINT_DIR / LAST_CHECKPOINT).is_file():
        state = "resumed"
    else:
        state = "trained"
    changed = run_differences(run, config) if state != "trained" else None
    if changed and spec.force:
        remove_run(run)
        state = "trained"
    elif changed:
        raise BenchError(f"{run}: trained with another configuration ({first_differences(changed, 4)}); "
                         "pass --force to retrain it, or bench into another --out")
    if state == "skipped":
        return {"action": state, "metrics": cell_summary(json.loads((run / METRICS_FILE).read_text()))}
    if state in ("trained", "resumed"):
        train_run(spec.scene_path, spec.prepared, run, config, resume=state == "resumed", progress=spec.progress)
        write_provenance(run, preset=spec.preset, method=spec.method,
                         command=f"radar4dgs bench (cell {spec.scene}/{spec.method}, preset {spec.preset})")
    with torch_threads(config.threads):
        metrics = evaluate_run(run, lpips=spec.lpips, video=False, report=False, progress=spec.progress)
    return {"action": state, "metrics": cell_summary(metrics)}


def run_guarded(runner: Callable[[CellSpec], Mapping[str, Any]], spec: CellSpec) -> dict[str, Any]:
    """``runner(spec)`` as a bench.json cell record; an exception becomes a failed record (with
    its traceback) instead of ending the grid."""
    started = time.perf_counter()
    record: dict[str, Any] = {"scene": spec.scene, "method": spec.method, "run": str(spec.run_dir)}
    try:
        result = runner(spec)
    except Exception as exc:  # noqa: BLE001 - any failure of one cell is that cell's result
        return {**record, "status": "failed", "seconds": time.perf_counter() - started,
                "error": f"{type(exc).__name__}: {exc}", "traceback": traceback.format_exc()}
    return {**record, "status": "ok", "action": result["action"], "seconds": time.perf_counter() - started,
            "metrics": result["metrics"]}


def guarded_task(spec: CellSpec, runner: Callable[[CellSpec], Mapping[str, Any]]) -> dict[str, Any]:
    """:func:`run_guarded` with the engine's argument order (the item first): one Ray task."""
    return run_guarded(runner, spec)


def run_grid(specs: Sequence[CellSpec], runner: Callable[[CellSpec], Mapping[str, Any]], jobs: int,
             on_done: Callable[[dict[str, Any]], None], threads: int = 1, address: str | None = None,
             retries: int = 2) -> None:
    """Run every cell and call ``on_done(record)`` in this process as each finishes: one after the
    other in this process (``jobs`` 1 and no ``address``), else each cell one Ray task
    (:mod:`radar4dgs.apps.batch_engine`) declaring ``threads`` CPUs, ``jobs`` at once, on a local
    cluster sized for them or on the cluster at ``address``. A task whose worker dies is retried
    ``retries`` times and resumes from the cell's checkpoint (:func:`run_cell`). ``runner`` must
    be picklable (a module-level function) on Ray."""
    if address is None and (jobs <= 1 or len(specs) <= 1):
        for spec in specs:
            on_done(run_guarded(runner, spec))
        return
    from radar4dgs.apps.batch_engine import Resources, cluster, run_tasks

    def done(index: int, record: dict[str, Any] | None, error: str | None) -> None:
        if error is not None:  # the worker died (killed, out of memory) on every attempt
            spec = specs[index]
            record = {"scene": spec.scene, "method": spec.method, "run": str(spec.run_dir),
                      "status": "failed", "seconds": None, "error": error}
        on_done(record)

    # A local cluster with room for `jobs` cells of `threads` CPUs each: --jobs N runs N at once.
    num_cpus = max(os.cpu_count() or 1, jobs * threads) if address is None else None
    with cluster(address, num_cpus=num_cpus):
        run_tasks(guarded_task, specs, resources=Resources(cpus=threads), window=jobs, retries=retries,
                  retry_exceptions=False, on_done=done, args=(runner,))
