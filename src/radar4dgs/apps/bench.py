"""``radar4dgs bench``: the baseline / ablation grid, every method on every scene, in one table.

Each cell (scene, method) is an ordinary run folder, ``OUT/runs/<scene>/<method>/``, trained with
the method's :func:`radar4dgs.train.variants.variant_config` and evaluated without video or report.
The grid is resumable: a cell with ``metrics.json`` is reused, one with ``model.pt`` is only
evaluated, one with a checkpoint resumes training, each only when its ``config.json`` is the
cell's config; a cell trained with another config fails saying what differs (``--force``
retrains it). A cell that raises is recorded and the grid goes on. With ``--jobs 1`` the cells run
one after the other in this process; with ``--jobs N`` (N > 1) or ``--address`` each cell is one
Ray task on the engine of ``radar4dgs batch`` (:mod:`radar4dgs.apps.batch_engine`), N at once,
retried from its checkpoint when its worker dies. Outputs, rewritten atomically:

- ``OUT/bench.json``: the bench's settings, every cell (status, seconds, metrics summary or error)
  and the per-method means; rewritten after every cell.
- ``OUT/table.md`` / ``OUT/table.csv``: one row per method, reconstruction and novel-view PSNR,
  SSIM, LPIPS and PSNR* averaged over the scenes that finished (the csv adds per-scene rows).
- ``OUT/ablation.png``: novel-view PSNR* and reconstruction PSNR per method, mean bar and
  per-scene dots.

With ``--synth-seeds`` the synthetic scenes are made and prepared first, into
``OUT/scenes/seed<N>/{scene,prepared}``, reused when made with the same preset and generator
config; a scene made with another stops the bench saying what differs (``--force`` makes it
again and retrains its cells).
"""

from __future__ import annotations

import json
import os
import sys
from dataclasses import dataclass
from pathlib import Path
from typing import Annotated, Any, Callable, Mapping, Optional, Sequence

from radar4dgs.apps.bench_cell import run_cell, run_grid
from radar4dgs.apps.bench_spec import BenchError, BenchScene, CellSpec, check_methods, parse_overrides, resolve_scenes
from radar4dgs.apps.bench_table import PLOT_FILE, TABLE_CSV, TABLE_MD, summarize, write_outputs
from radar4dgs.apps.options import default_is
from radar4dgs.config import PresetName, merge
from radar4dgs.io.atomic import atomic_write_json
from radar4dgs.train.variants import METHOD_NAMES, VARIANTS, MethodName, variant_config

BENCH_FILE = "bench.json"
RUNS_DIR = "runs"


def default_threads(jobs: int) -> int:
    """Torch threads per job: the CPUs shared out, so that parallel jobs do not oversubscribe."""
    return max(1, (os.cpu_count() or 1) // max(1, jobs))


def _cell_line(record: Mapping[str, Any], done: int, total: int) -> str:
    name = f"[{done}/{total}] {record['scene']}/{record['method']}"
    seconds = record.get("seconds")
    took = f"{seconds:.0f} s" if seconds is not None else "?"
    if record["status"] != "ok":
        return f"{name}: FAILED after {took}: {record['error']}"
    value = record["metrics"]["nvs"].get("psnr_dyn")
    psnr_dyn = f"novel-view PSNR* {value:.2f} dB" if value is not None else "no novel-view PSNR*"
    if record["action"] == "skipped":
        return f"{name}: skipped (metrics.json present), {psnr_dyn}"
    return f"{name}: {record['action']} in {took}, {psnr_dyn}"


def cell_overrides(settings: Mapping[str, Any] | None, threads: int, iterations: int | None) -> dict[str, Any]:
    """Every cell's TrainConfig overrides (nested dicts): ``settings``, then the torch thread count,
    then ``iterations`` when given."""
    overrides: dict[str, Any] = merge(dict(settings or {}), {"threads": threads})
    if iterations is not None:
        overrides = merge(overrides, {"optim": {"iterations": iterations}})
    return overrides


def previous_cells(path: Path) -> dict[tuple[str, str], dict[str, Any]]:
    """The cells of the bench.json at ``path`` by (scene, method); empty when there is none or it
    cannot be read."""
    previous = {}
    if path.is_file():
        try:
            previous = {(c["scene"], c["method"]): c for c in json.loads(path.read_text())["cells"]}
        except (OSError, ValueError, KeyError, TypeError):
            previous = {}
    return previous


def bench_payload(config: Mapping[str, Any], specs: Sequence[CellSpec], records: Mapping[tuple[str, str], Any],
                  methods: Sequence[str]) -> dict[str, Any]:
    """bench.json: the bench's ``config``, the cells recorded so far (grid order), the per-method
    means, the failed count and the cells still missing."""
    cells = [records[(s.scene, s.method)] for s in specs if (s.scene, s.method) in records]
    return {"config": config, "cells": cells, "means": summarize(cells, methods),
            "failed": sum(c["status"] != "ok" for c in cells),
            "missing": [f"{s.scene}/{s.method}" for s in specs if (s.scene, s.method) not in records]}


def run_bench(scenes: Sequence[BenchScene], methods: Sequence[str], out: Path, preset_name: str = "small",
              iterations: int | None = None, jobs: int = 1, threads: int | None = None, lpips: bool = True,
              progress: bool = True, runner: Callable[[CellSpec], Mapping[str, Any]] | None = None,
              log: Callable[[str], None] = print, settings: Mapping[str, Any] | None = None,
              force: bool = False, address: str | None = None) -> dict[str, Any]:
    """Run the grid ``scenes`` x ``methods`` into ``out`` and write bench.json (after every cell),
    table.md, table.csv and ablation.png (at the end, also when interrupted); returns bench.json.

    ``runner`` (default :func:`run_cell`) brings one cell to its metrics; ``threads`` (default: the
    ``threads`` of ``settings``, else :func:`default_threads`) is each job's torch thread count;
    ``settings`` (nested TrainConfig fields, :func:`parse_overrides`) change every cell's config
    before its method's own fields;
    ``force`` retrains the cells whose run folder was trained with another configuration.
    ``jobs`` > 1 or an ``address`` runs the cells as Ray tasks (``jobs`` at once, each declaring
    ``threads`` CPUs) on a local cluster or on the Ray cluster at ``address``
    (:func:`radar4dgs.apps.bench_cell.run_grid`).
    """
    methods = check_methods(methods)
    if jobs < 1:
        raise BenchError(f"--jobs must be >= 1, got {jobs}")
    runner = runner if runner is not None else run_cell
    # A `--set threads=N` is the user's thread count too: the default must not override it (it did,
    # and two parallel benchmarks each ran 2 threads on 2 cores, several times slower).
    threads = threads if threads is not None else (settings or {}).get("threads", default_threads(jobs))
    overrides = cell_overrides(settings, threads, iterations)
    try:
        # Every method's config is built once here, so that a bad option fails before any training.
        resolved = {m: variant_config(preset_name, m, **overrides) for m in methods}
    except ValueError as exc:
        raise BenchError(str(exc)) from exc
    out = Path(out)
    specs = [CellSpec(scene.label, method, scene.scene, scene.prepared, out / RUNS_DIR / scene.label / method,
                      preset_name, overrides, lpips, progress and jobs == 1 and address is None, force)
             for scene in scenes for method in methods]
    # Seconds of cells this call only reuses come from the previous bench.json.
    previous = previous_cells(out / BENCH_FILE)
    config = {"preset": preset_name, "iterations": resolved[methods[0]].optim.iterations, "methods": list(methods),
              "scenes": [{"label": s.label, "scene": str(s.scene), "prepared": str(s.prepared)} for s in scenes],
              "settings": dict(settings or {}), "jobs": jobs, "threads_per_job": threads, "lpips": lpips}
    records: dict[tuple[str, str], dict[str, Any]] = {}

    def on_done(record: dict[str, Any]) -> None:
        key = (record["scene"], record["method"])
        if record.get("action") == "skipped" and previous.get(key, {}).get("seconds") is not None:
            record["seconds"] = previous[key]["seconds"]
        records[key] = record
        log(_cell_line(record, len(records), len(specs)))
        atomic_write_json(out / BENCH_FILE, bench_payload(config, specs, records, methods))

    out.mkdir(parents=True, exist_ok=True)
    log(f"bench: {len(scenes)} scene(s) x {len(methods)} method(s) = {len(specs)} cell(s) -> {out / RUNS_DIR}")
    try:
        run_grid(specs, runner, jobs, on_done, threads=threads, address=address)
    finally:
        result = bench_payload(config, specs, records, methods)
        atomic_write_json(out / BENCH_FILE, result)
        write_outputs(out, result, {m: VARIANTS[m][0] for m in methods})
    return result


@dataclass
class BenchCommand:
    """Train and evaluate every method (baselines and ablations) on every scene; one table."""

    # Scene folders, each prepared in <scene>/prepared (`radar4dgs prepare SCENE`).
    scenes: Annotated[tuple[Path, ...], default_is("none")] = ()
    # Synthetic scene seeds, synthesized and prepared into OUT/scenes/seed<N>/ (reused when present).
    synth_seeds: Annotated[tuple[int, ...], default_is("none")] = ()
    # Preset of the synthetic scenes and their preparation.
    synth_preset: PresetName = "small"
    # Methods, in table order (see radar4dgs.train.variants).
    methods: tuple[MethodName, ...] = METHOD_NAMES
    # Output folder: runs/<scene>/<method>/, bench.json, table.md, table.csv, ablation.png.
    out: Path = Path("runs/bench")
    # Training preset of every cell.
    preset: PresetName = "small"
    # Training iterations of every cell.
    iterations: Annotated[Optional[int], default_is("the preset's")] = None
    # Cells trained at once, each a Ray task (1: one after the other in this process).
    jobs: int = 1
    # Ray cluster for the cells: "auto" or ray://HOST:10001 (with --jobs cells at once there).
    address: Annotated[Optional[str], default_is("a local cluster when --jobs > 1")] = None
    # TrainConfig fields of every cell, as dotted KEY=VALUE (JSON values), e.g.
    # densify.max_gaussians=40000; a method's own fields (train.variants) still win.
    set: Annotated[tuple[str, ...], default_is("none")] = ()
    # Torch threads per job.
    threads: Annotated[Optional[int], default_is("the CPU count divided by --jobs")] = None
    # Compute LPIPS when the backbone weights are present (the column shows "–" otherwise).
    lpips: bool = True
    # Hide the training and evaluation progress bars (they are always hidden with --jobs > 1).
    quiet: bool = False
    # Overwrite: retrain the cells in OUT trained with another configuration, and make again the synthetic
    # scenes made with another preset (and retrain their cells). Without it such a cell fails, saying what
    # differs, and such a scene stops the bench.
    force: bool = False

    def run(self) -> int:
        def log(line: str) -> None:
            print(line, flush=True)

        try:
            methods = check_methods(self.methods)
            scenes = resolve_scenes(self.scenes, self.synth_seeds, self.synth_preset, self.out, log, self.force)
            settings = parse_overrides(self.set)
            result = run_bench(scenes, methods, self.out, self.preset, self.iterations, self.jobs, self.threads,
                               self.lpips, progress=not self.quiet, log=log, settings=settings, force=self.force,
                               address=self.address)
        except BenchError as exc:
            print(f"radar4dgs bench: {exc}", file=sys.stderr)
            return 2
        print()
        print((self.out / TABLE_MD).read_text(), end="")
        print(f"\nwritten: {self.out / TABLE_MD}, {self.out / TABLE_CSV}, {self.out / PLOT_FILE}, "
              f"{self.out / BENCH_FILE}")
        if result["failed"]:
            failed = [f"{c['scene']}/{c['method']}" for c in result["cells"] if c["status"] != "ok"]
            print(f"radar4dgs bench: {len(failed)} cell(s) failed: {', '.join(failed)} (errors in "
                  f"{self.out / BENCH_FILE}; rerun to retry them)", file=sys.stderr)
            return 1
        return 0
