"""The bench's table: per-method means over the finished cells, as markdown (best value in bold),
csv (with per-scene rows) and the ablation plot, written from a bench.json payload."""

from __future__ import annotations

import csv
import io
import math
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Mapping, Optional, Sequence

from radar4dgs.apps.bench_spec import dotted
from radar4dgs.io.atomic import atomic_path, atomic_write_text

TABLE_MD = "table.md"
TABLE_CSV = "table.csv"
PLOT_FILE = "ablation.png"
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


def write_outputs(out: Path, payload: Mapping[str, Any], descriptions: Mapping[str, str]) -> None:
    """Write table.md, table.csv and ablation.png from a bench.json ``payload``."""
    rows, per_scene = payload["means"], scene_rows(payload["cells"], payload["config"]["methods"])
    config = payload["config"]
    atomic_write_text(out / TABLE_MD, markdown_table(rows, descriptions, config["preset"], config["iterations"],
                                                     config.get("settings")))
    atomic_write_text(out / TABLE_CSV, csv_table(rows, per_scene))
    plot_ablation(rows, per_scene, out / PLOT_FILE)
