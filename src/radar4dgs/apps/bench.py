"""``radar4dgs bench``: the baseline / ablation grid, every method on every scene, in one table.

Each cell (scene, method) is an ordinary run folder, ``OUT/runs/<scene>/<method>/``, trained with
the method's :func:`radar4dgs.train.variants.variant_config` and evaluated without video or report.
The grid is resumable: a cell with ``metrics.json`` is reused, one with ``model.pt`` is only
evaluated, one with a checkpoint resumes training. A cell that raises is recorded and the grid
goes on. Outputs, rewritten atomically:

- ``OUT/bench.json``: the bench's settings, every cell (status, seconds, metrics summary or error)
  and the per-method means; rewritten after every cell.
- ``OUT/table.md`` / ``OUT/table.csv``: one row per method, reconstruction and novel-view PSNR,
  SSIM, LPIPS and PSNR* averaged over the scenes that finished (the csv adds per-scene rows).
- ``OUT/ablation.png``: novel-view PSNR* and reconstruction PSNR per method, mean bar and
  per-scene dots.

With ``--synth-seeds`` the synthetic scenes are made and prepared first, into
``OUT/scenes/seed<N>/{scene,prepared}`` (reused when present).
"""

from __future__ import annotations

import csv
import io
import json
import math
import multiprocessing
import os
import sys
import time
import traceback
from collections import Counter
from concurrent.futures import ProcessPoolExecutor, as_completed
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Callable, Mapping, Optional, Sequence

from radar4dgs.config import PresetName, preset
from radar4dgs.io.atomic import atomic_path, atomic_write_json, atomic_write_text
from radar4dgs.train.variants import METHOD_NAMES, VARIANTS, MethodName, variant_config

BENCH_FILE = "bench.json"
TABLE_MD = "table.md"
TABLE_CSV = "table.csv"
PLOT_FILE = "ablation.png"
RUNS_DIR = "runs"
SCENES_DIR = "scenes"
METRICS_FILE = "metrics.json"  # as radar4dgs.evaluate.reconstruction, which imports torch
SPLITS = ("recon", "nvs")
SPLIT_TITLES = {"recon": "Recon.", "nvs": "NVS"}


@dataclass(frozen=True)
class Column:
    """One metric column of the table."""

    name: str  # the csv / bench.json key, "<split>_<metric>"
    split: str  # "recon" or "nvs"
    key: str  # the key in metrics.json's split summary
    title: str
    higher_is_better: bool
    digits: int


def _columns() -> tuple[Column, ...]:
    metrics = (("psnr", "psnr", "PSNR", True, 2), ("ssim", "ssim", "SSIM", True, 3),
               ("lpips", "lpips_vgg", "LPIPS", False, 3), ("psnr_dyn", "psnr_dyn", "PSNR*", True, 2))
    return tuple(Column(f"{split}_{name}", split, key, f"{SPLIT_TITLES[split]} {title}", higher, digits)
                 for split in SPLITS for name, key, title, higher, digits in metrics)


COLUMNS = _columns()
COLUMN_NAMES = tuple(c.name for c in COLUMNS)


class BenchError(ValueError):
    """A bench that cannot start (bad scene, method or option); the message says what to fix."""


@dataclass(frozen=True)
class BenchScene:
    """One scene of the grid: its label (the runs/ subfolder and table name) and its folders."""

    label: str
    scene: Path
    prepared: Path


@dataclass(frozen=True)
class CellSpec:
    """Everything a cell's worker needs; plain values, since it is pickled to a worker process."""

    scene: str  # the scene's label
    method: str
    scene_path: Path
    prepared: Path
    run_dir: Path
    preset: str
    # TrainConfig overrides on top of the method's variant (nested dicts).
    overrides: Mapping[str, Any]
    lpips: bool
    progress: bool


# --- scenes and methods ------------------------------------------------------------------------


def check_methods(methods: Sequence[str]) -> tuple[str, ...]:
    """``methods`` without repeats, in the given order; unknown names raise a BenchError listing the
    valid ones."""
    unknown = [m for m in methods if m not in VARIANTS]
    if unknown:
        raise BenchError(f"unknown method(s) {unknown}; methods are {list(METHOD_NAMES)}")
    if not methods:
        raise BenchError(f"no methods given; methods are {list(METHOD_NAMES)}")
    return tuple(dict.fromkeys(methods))


def check_scene(scene: Path) -> Path:
    """The prepared folder of scene folder ``scene``: ``<scene>/prepared`` (`radar4dgs prepare`'s
    default), else a ``prepared`` folder beside it (the demo's layout, ``DIR/{scene,prepared}``);
    a BenchError names what is missing."""
    if not (scene / "scene.json").is_file():
        raise BenchError(f"{scene}: not a scene folder (no scene.json)")
    for prepared in (scene / "prepared", scene.parent / "prepared"):
        if (prepared / "depth").is_dir():
            return prepared
    raise BenchError(f"{scene}: has no prepared folder ({scene / 'prepared'} or {scene.parent / 'prepared'}); "
                     f"run `radar4dgs prepare {scene}` first")


def parse_overrides(items: Sequence[str]) -> dict[str, Any]:
    """``["densify.max_gaussians=40000", "optim.dropout=0.2"]`` as the nested dict of TrainConfig
    fields they set; values are JSON (numbers, true/false, quoted strings) or else plain strings."""
    out: dict[str, Any] = {}
    for item in items:
        key, sep, text = item.partition("=")
        if not sep or not key.strip():
            raise BenchError(f"--set {item!r}: expected KEY=VALUE with a dotted TrainConfig field, "
                             f"e.g. densify.max_gaussians=40000")
        try:
            value = json.loads(text)
        except ValueError:
            value = text
        node = out
        *parents, leaf = key.strip().split(".")
        for part in parents:
            node = node.setdefault(part, {})
            if not isinstance(node, dict):
                raise BenchError(f"--set {item!r}: {part} is set as a value and as a group")
        node[leaf] = value
    return out


def scene_labels(paths: Sequence[Path], reserved: Sequence[str] = ()) -> list[str]:
    """A distinct label per scene folder: its name, or where names clash (with each other or with
    ``reserved``) its name preceded by parent folders until they do not ("seed1-scene").

    The same folder given twice raises a BenchError: its cells would share one run folder.
    """
    resolved = [Path(p).resolve() for p in paths]
    repeated = [str(p) for p, count in Counter(resolved).items() if count > 1]
    if repeated:
        raise BenchError(f"scene(s) given more than once: {repeated}")
    # parts[0] is the root ("/"); a label never includes it.
    parts = [p.parts[1:] for p in resolved]
    depth = [1] * len(paths)
    while True:
        labels = ["-".join(part[-d:]) for part, d in zip(parts, depth)]
        counts = Counter(labels + list(reserved))
        clashing = [i for i, label in enumerate(labels) if counts[label] > 1]
        if not clashing:
            return labels
        deeper = [i for i in clashing if depth[i] < len(parts[i])]
        if not deeper:  # whole paths that still clash ("a-b/c" and "a/b-c"): number them
            return [f"{label}-{i}" if i in clashing else label for i, label in enumerate(labels)]
        for i in deeper:
            depth[i] += 1


def synth_scene(seed: int, preset_name: str, root: Path, log: Callable[[str], None]) -> BenchScene:
    """Synthesize and prepare seed ``seed`` into ``root/seed<N>/{scene,prepared}``; a scene that
    exists is reused and only its stale prepare stages rerun."""
    from radar4dgs.datasets.synth import SynthConfig, synthesize
    from radar4dgs.apps.prepare import PrepareConfig, run_prepare

    scene = root / f"seed{seed}" / "scene"
    prepared = root / f"seed{seed}" / "prepared"
    if not (scene / "scene.json").is_file():
        log(f"synthesizing seed {seed} ({preset_name}) -> {scene}")
        synthesize(preset(SynthConfig, preset_name, seed=seed), scene, overwrite=True, progress=False,
                   preset=preset_name)
    status = run_prepare(scene, prepared, preset(PrepareConfig, preset_name), progress=False)
    ran = [stage for stage, state in status.items() if state == "ran"]
    if ran:
        log(f"prepared seed {seed}: {', '.join(ran)}")
    return BenchScene(f"seed{seed}", scene, prepared)


def resolve_scenes(scene_dirs: Sequence[Path], synth_seeds: Sequence[int], synth_preset: str, out: Path,
                   log: Callable[[str], None] = print) -> list[BenchScene]:
    """The grid's scenes: ``scene_dirs`` (checked first, so that a typo fails before any
    synthesis) then the synthetic seeds, made and prepared under ``out/scenes``."""
    if not scene_dirs and not synth_seeds:
        raise BenchError("no scenes: give --scenes DIR ... or --synth-seeds N ...")
    if len(set(synth_seeds)) != len(synth_seeds):
        raise BenchError(f"synthetic seed(s) given more than once: {sorted(synth_seeds)}")
    prepared = [check_scene(Path(s)) for s in scene_dirs]
    synth_labels = [f"seed{seed}" for seed in synth_seeds]
    labels = scene_labels(scene_dirs, reserved=synth_labels)
    scenes = [BenchScene(label, Path(s), p) for label, s, p in zip(labels, scene_dirs, prepared)]
    scenes += [synth_scene(seed, synth_preset, out / SCENES_DIR, log) for seed in synth_seeds]
    return scenes


# --- one cell ------------------------------------------------------------------------------------


def cell_summary(metrics: Mapping[str, Any]) -> dict[str, Any]:
    """The part of a run's metrics.json the bench keeps: both splits' summaries, the Gaussian
    count and the PSNR* mask source (the per-frame lists stay in the run folder)."""
    return {**{split: dict(metrics[split]) for split in SPLITS},
            **{key: metrics.get(key) for key in ("method", "num_gaussians", "mask_source", "lpips_available")}}


def run_cell(spec: CellSpec) -> dict[str, Any]:
    """Bring one cell to a metrics.json and return ``{"action", "metrics"}`` (:func:`cell_summary`).

    action: "skipped" (metrics.json present), "evaluated" (model.pt present), "resumed" (from
    checkpoints/last.pt) or "trained". A run folder trained with another configuration than the
    bench's (other iterations, say) raises: its numbers would not belong in this table.
    """
    from radar4dgs.config import read_config_dict
    from radar4dgs.evaluate.reconstruction import evaluate_run
    from radar4dgs.train.fit_motion import torch_threads
    from radar4dgs.model.config import TrainConfig
    from radar4dgs.model.run import CHECKPOINT_DIR, CONFIG_FILE, LAST_CHECKPOINT, MODEL_FILE
    from radar4dgs.train.trainer import run_config_difference, train_run

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
    if state != "trained" and (run / CONFIG_FILE).is_file():
        changed = run_config_difference(read_config_dict(TrainConfig, run / CONFIG_FILE), config)
        if changed:
            raise BenchError(f"{run}: trained with another configuration ({'; '.join(changed[:4])}); "
                             "delete the folder or bench into another --out")
    if state == "skipped":
        return {"action": state, "metrics": cell_summary(json.loads((run / METRICS_FILE).read_text()))}
    if state in ("trained", "resumed"):
        train_run(spec.scene_path, spec.prepared, run, config, resume=state == "resumed", progress=spec.progress)
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


def run_grid(specs: Sequence[CellSpec], runner: Callable[[CellSpec], Mapping[str, Any]], jobs: int,
             on_done: Callable[[dict[str, Any]], None]) -> None:
    """Run every cell, one after the other (jobs 1) or in ``jobs`` worker processes, calling
    ``on_done(record)`` in this process as each finishes. ``runner`` must be picklable (a
    module-level function) when jobs > 1."""
    if jobs <= 1 or len(specs) <= 1:
        for spec in specs:
            on_done(run_guarded(runner, spec))
        return
    # spawn: a forked child would inherit torch's thread pools and locks in whatever state they are.
    context = multiprocessing.get_context("spawn")
    with ProcessPoolExecutor(max_workers=min(jobs, len(specs)), mp_context=context) as pool:
        futures = {pool.submit(run_guarded, runner, spec): spec for spec in specs}
        for future in as_completed(futures):
            try:
                record = future.result()
            except Exception as exc:  # noqa: BLE001 - the worker died (killed, out of memory)
                spec = futures[future]
                record = {"scene": spec.scene, "method": spec.method, "run": str(spec.run_dir),
                          "status": "failed", "seconds": None, "error": f"{type(exc).__name__}: {exc}"}
            on_done(record)


# --- tables ----------------------------------------------------------------------------------------


def _mean(values: Sequence[Optional[float]]) -> Optional[float]:
    present = [v for v in values if v is not None]
    return float(sum(present) / len(present)) if present else None


def cell_values(metrics: Mapping[str, Any]) -> dict[str, Optional[float]]:
    """The table columns of one cell's metrics summary (None where the metric is missing)."""
    return {c.name: metrics.get(c.split, {}).get(c.key) for c in COLUMNS}


def finished(cells: Sequence[Mapping[str, Any]], method: str) -> list[Mapping[str, Any]]:
    """The cells of ``method`` that finished with metrics, in grid order."""
    return [c for c in cells if c["method"] == method and c.get("status") == "ok" and c.get("metrics")]


def summarize(cells: Sequence[Mapping[str, Any]], methods: Sequence[str] | None = None) -> list[dict[str, Any]]:
    """One row per method (``methods``' order, default the cells' order): ``method``, ``n`` (the
    scenes that finished), ``scenes`` (their labels) and every :data:`COLUMNS` value averaged over
    those scenes. A value a scene lacks (LPIPS without weights, PSNR* of a split with no dynamic
    pixel) is left out of that column's mean; a column no scene has is None. A method with no
    finished scene has n = 0 and None everywhere."""
    methods = list(dict.fromkeys(methods if methods is not None else [c["method"] for c in cells]))
    rows = []
    for method in methods:
        done = finished(cells, method)
        values = [cell_values(c["metrics"]) for c in done]
        rows.append({"method": method, "n": len(done), "scenes": [c["scene"] for c in done],
                     **{name: _mean([v[name] for v in values]) for name in COLUMN_NAMES}})
    return rows


def scene_rows(cells: Sequence[Mapping[str, Any]], methods: Sequence[str] | None = None) -> list[dict[str, Any]]:
    """One row per finished cell, grouped by method (``methods``' order) then in grid order:
    ``scene``, ``method`` and every :data:`COLUMNS` value."""
    methods = list(dict.fromkeys(methods if methods is not None else [c["method"] for c in cells]))
    return [{"scene": c["scene"], "method": method, **cell_values(c["metrics"])}
            for method in methods for c in finished(cells, method)]


def best_values(rows: Sequence[Mapping[str, Any]]) -> dict[str, Optional[float]]:
    """Per column, the best value as the table shows it (rounded to the column's digits, so that
    rows printed alike are bolded alike): the largest, or the smallest for LPIPS."""
    best = {}
    for c in COLUMNS:
        shown = [round(r[c.name], c.digits) for r in rows if r.get(c.name) is not None]
        best[c.name] = (max(shown) if c.higher_is_better else min(shown)) if shown else None
    return best


def markdown_table(rows: Sequence[Mapping[str, Any]], descriptions: Mapping[str, str] | None = None,
                   preset_name: str | None = None, iterations: int | None = None,
                   settings: Mapping[str, Any] | None = None) -> str:
    """The paper's layout as markdown: a row per method, reconstruction then novel-view PSNR /
    SSIM / LPIPS / PSNR*, then n; the best value of each column in bold, "–" where there is none.
    Below it, what the numbers are (with ``preset_name`` / ``iterations`` / the ``settings``
    overrides when given) and each method's one-line description from ``descriptions``."""
    best = best_values(rows)
    arrows = {True: "↑", False: "↓"}
    header = ["Method", *[f"{c.title} {arrows[c.higher_is_better]}" for c in COLUMNS], "n"]
    lines = ["| " + " | ".join(header) + " |", "|" + "|".join([":---"] + ["---:"] * (len(header) - 1)) + "|"]
    for row in rows:
        cells = [row["method"]]
        for c in COLUMNS:
            value = row.get(c.name)
            if value is None:
                cells.append("–")
                continue
            text = f"{value:.{c.digits}f}"
            cells.append(f"**{text}**" if round(value, c.digits) == best[c.name] else text)
        cells.append(str(row["n"]))
        lines.append("| " + " | ".join(cells) + " |")
    setting = []
    if preset_name is not None:
        setting.append(f"preset `{preset_name}`")
    if iterations is not None:
        setting.append(f"{iterations} training iterations")
    setting += [f"`{key}={value}`" for key, value in dotted(settings or {})]
    lines += ["", "Means over the n scenes each method finished"
              + (f" ({', '.join(setting)})" if setting else "")
              + ". Recon. = training views, NVS = held-out test views; PSNR* = PSNR on dynamic-object "
              "pixels; LPIPS = LPIPS-VGG (– without backbone weights). Best per column in bold."]
    if descriptions:
        lines += ["", *[f"- **{row['method']}**: {descriptions[row['method']]}" for row in rows
                        if row["method"] in descriptions]]
    return "\n".join(lines) + "\n"


def dotted(values: Mapping[str, Any], prefix: str = "") -> list[tuple[str, Any]]:
    """A nested dict as ``[("densify.max_gaussians", 40000), ...]`` (the inverse of
    :func:`parse_overrides`)."""
    out: list[tuple[str, Any]] = []
    for key, value in values.items():
        if isinstance(value, Mapping):
            out += dotted(value, f"{prefix}{key}.")
        else:
            out.append((f"{prefix}{key}", value))
    return out


def _csv_value(value: Any) -> Any:
    return "" if value is None else value


def csv_table(rows: Sequence[Mapping[str, Any]], per_scene: Sequence[Mapping[str, Any]] = ()) -> str:
    """The table as csv: columns ``scene, method, n`` and every :data:`COLUMNS` name; first the
    mean rows (scene "mean"), then the per-scene rows (n = 1). Missing values are empty."""
    buffer = io.StringIO()
    writer = csv.writer(buffer, lineterminator="\n")
    writer.writerow(["scene", "method", "n", *COLUMN_NAMES])
    for row in rows:
        writer.writerow(["mean", row["method"], row["n"], *[_csv_value(row.get(n)) for n in COLUMN_NAMES]])
    for row in per_scene:
        writer.writerow([row["scene"], row["method"], 1, *[_csv_value(row.get(n)) for n in COLUMN_NAMES]])
    return buffer.getvalue()


def plot_ablation(rows: Sequence[Mapping[str, Any]], per_scene: Sequence[Mapping[str, Any]], path: Path) -> Path:
    """A two-panel bar plot, written atomically to ``path`` (png): novel-view PSNR* above,
    reconstruction PSNR below; per method the mean bar and a dot per scene."""
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.figure import Figure

    methods = [row["method"] for row in rows]
    scenes = list(dict.fromkeys(r["scene"] for r in per_scene))
    figure = Figure(figsize=(max(6.0, 0.6 * len(methods) + 2.0), 6.5), layout="constrained")
    FigureCanvasAgg(figure)  # a canvas of its own: no pyplot, no process-wide backend switch
    axes = figure.subplots(2, 1, sharex=True)
    colors = [f"C{i % 10}" for i in range(len(scenes))]
    for ax, column, label in ((axes[0], "nvs_psnr_dyn", "novel-view PSNR* (dB)"),
                              (axes[1], "recon_psnr", "reconstruction PSNR (dB)")):
        means = [row.get(column) for row in rows]
        ax.bar(range(len(methods)), [math.nan if m is None else m for m in means], color="0.8", edgecolor="0.4",
               label="mean")
        shown = [m for m in means if m is not None]
        for s, scene in enumerate(scenes):
            points = [(methods.index(r["method"]), r[column]) for r in per_scene
                      if r["scene"] == scene and r.get(column) is not None and r["method"] in methods]
            # A small fixed offset per scene keeps equal values from hiding each other.
            offset = (s - (len(scenes) - 1) / 2) * min(0.08, 0.6 / max(1, len(scenes)))
            ax.scatter([x + offset for x, _ in points], [y for _, y in points], s=18, color=colors[s],
                       zorder=3, label=scene)
            shown += [y for _, y in points]
        if shown:
            # PSNR differences between methods are a few dB: an axis from 0 would flatten them.
            ax.set_ylim(min(shown) - 1.0, max(shown) + 1.0)
        ax.set_ylabel(label)
        ax.grid(axis="y", alpha=0.3)
    axes[0].legend(fontsize=7, ncols=min(6, len(scenes) + 1), loc="upper right")
    axes[1].set_xticks(range(len(methods)), methods, rotation=40, ha="right")
    with atomic_path(path, suffix=".png") as tmp:
        figure.savefig(tmp, format="png", dpi=110)
    return path


# --- the grid ------------------------------------------------------------------------------------


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


def write_outputs(out: Path, payload: Mapping[str, Any], descriptions: Mapping[str, str]) -> None:
    """Write table.md, table.csv and ablation.png from a bench.json ``payload``."""
    rows, per_scene = payload["means"], scene_rows(payload["cells"], payload["config"]["methods"])
    config = payload["config"]
    atomic_write_text(out / TABLE_MD, markdown_table(rows, descriptions, config["preset"], config["iterations"],
                                                     config.get("settings")))
    atomic_write_text(out / TABLE_CSV, csv_table(rows, per_scene))
    plot_ablation(rows, per_scene, out / PLOT_FILE)


def run_bench(scenes: Sequence[BenchScene], methods: Sequence[str], out: Path, preset_name: str = "small",
              iterations: int | None = None, jobs: int = 1, threads: int | None = None, lpips: bool = True,
              progress: bool = True, runner: Callable[[CellSpec], Mapping[str, Any]] | None = None,
              log: Callable[[str], None] = print, settings: Mapping[str, Any] | None = None) -> dict[str, Any]:
    """Run the grid ``scenes`` x ``methods`` into ``out`` and write bench.json (after every cell),
    table.md, table.csv and ablation.png (at the end, also when interrupted); returns bench.json.

    ``runner`` (default :func:`run_cell`) brings one cell to its metrics; ``threads`` (default
    :func:`default_threads`) is each job's torch thread count; ``settings`` (nested TrainConfig
    fields, :func:`parse_overrides`) change every cell's config before its method's own fields.
    """
    methods = check_methods(methods)
    if jobs < 1:
        raise BenchError(f"--jobs must be >= 1, got {jobs}")
    runner = runner if runner is not None else run_cell
    threads = threads if threads is not None else default_threads(jobs)
    from radar4dgs.train.variants import merge

    overrides: dict[str, Any] = merge(dict(settings or {}), {"threads": threads})
    if iterations is not None:
        overrides = merge(overrides, {"optim": {"iterations": iterations}})
    try:
        # Every method's config is built once here, so that a bad option fails before any training.
        resolved = {m: variant_config(preset_name, m, **overrides) for m in methods}
    except ValueError as exc:
        raise BenchError(str(exc)) from exc
    out = Path(out)
    specs = [CellSpec(scene.label, method, scene.scene, scene.prepared, out / RUNS_DIR / scene.label / method,
                      preset_name, overrides, lpips, progress and jobs == 1)
             for scene in scenes for method in methods]
    # Seconds of cells this call only reuses come from the previous bench.json.
    previous = {}
    if (out / BENCH_FILE).is_file():
        try:
            previous = {(c["scene"], c["method"]): c for c in json.loads((out / BENCH_FILE).read_text())["cells"]}
        except (OSError, ValueError, KeyError, TypeError):
            previous = {}
    config = {"preset": preset_name, "iterations": resolved[methods[0]].optim.iterations, "methods": list(methods),
              "scenes": [{"label": s.label, "scene": str(s.scene), "prepared": str(s.prepared)} for s in scenes],
              "settings": dict(settings or {}), "jobs": jobs, "threads_per_job": threads, "lpips": lpips}
    records: dict[tuple[str, str], dict[str, Any]] = {}

    def payload() -> dict[str, Any]:
        cells = [records[(s.scene, s.method)] for s in specs if (s.scene, s.method) in records]
        return {"config": config, "cells": cells, "means": summarize(cells, methods),
                "failed": sum(c["status"] != "ok" for c in cells),
                "missing": [f"{s.scene}/{s.method}" for s in specs if (s.scene, s.method) not in records]}

    def on_done(record: dict[str, Any]) -> None:
        key = (record["scene"], record["method"])
        if record.get("action") == "skipped" and previous.get(key, {}).get("seconds") is not None:
            record["seconds"] = previous[key]["seconds"]
        records[key] = record
        log(_cell_line(record, len(records), len(specs)))
        atomic_write_json(out / BENCH_FILE, payload())

    out.mkdir(parents=True, exist_ok=True)
    log(f"bench: {len(scenes)} scene(s) x {len(methods)} method(s) = {len(specs)} cell(s) -> {out / RUNS_DIR}")
    try:
        run_grid(specs, runner, jobs, on_done)
    finally:
        result = payload()
        atomic_write_json(out / BENCH_FILE, result)
        write_outputs(out, result, {m: VARIANTS[m][0] for m in methods})
    return result


@dataclass
class BenchCommand:
    """Train and evaluate every method (baselines and ablations) on every scene; one table."""

    # Scene folders, each prepared in <scene>/prepared (`radar4dgs prepare SCENE`).
    scenes: tuple[Path, ...] = ()
    # Synthetic scene seeds, synthesized and prepared into OUT/scenes/seed<N>/ (reused when present).
    synth_seeds: tuple[int, ...] = ()
    # Preset of the synthetic scenes and their preparation.
    synth_preset: PresetName = "small"
    # Methods, in table order (default: all of them; see radar4dgs.train.variants).
    methods: tuple[MethodName, ...] = METHOD_NAMES
    # Output folder: runs/<scene>/<method>/, bench.json, table.md, table.csv, ablation.png.
    out: Path = Path("runs/bench")
    # Training preset of every cell.
    preset: PresetName = "small"
    # Training iterations of every cell (default: the preset's).
    iterations: Optional[int] = None
    # Cells trained at once, each in its own process.
    jobs: int = 1
    # TrainConfig fields of every cell, as dotted KEY=VALUE (JSON values), e.g.
    # densify.max_gaussians=40000; a method's own fields (train.variants) still win.
    set: tuple[str, ...] = ()
    # Torch threads per job (default: the CPU count divided by --jobs).
    threads: Optional[int] = None
    # Compute LPIPS when the backbone weights are present (the column shows "–" otherwise).
    lpips: bool = True
    # Hide the training and evaluation progress bars (they are always hidden with --jobs > 1).
    quiet: bool = False

    def run(self) -> int:
        def log(line: str) -> None:
            print(line, flush=True)

        try:
            methods = check_methods(self.methods)
            scenes = resolve_scenes(self.scenes, self.synth_seeds, self.synth_preset, self.out, log)
            settings = parse_overrides(self.set)
            result = run_bench(scenes, methods, self.out, self.preset, self.iterations, self.jobs, self.threads,
                               self.lpips, progress=not self.quiet, log=log, settings=settings)
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
