"""The batch's collected table: ``batch.json`` (settings, one record per scene, means),
``batch.md`` and ``index.html`` (one row per scene, linking its report), all written atomically."""

from __future__ import annotations

import html
from pathlib import Path
from typing import Any, Mapping, Sequence

from radar4dgs.apps.batch_engine import elapsed_text
from radar4dgs.io.atomic import atomic_write_json, atomic_write_text

BATCH_FILE = "batch.json"
BATCH_MD = "batch.md"
INDEX_HTML = "index.html"

# (split, metrics.json key, title, digits)
COLUMNS = (("recon", "psnr", "Recon. PSNR", 2), ("nvs", "psnr", "NVS PSNR", 2), ("nvs", "ssim", "NVS SSIM", 3),
           ("nvs", "lpips_vgg", "NVS LPIPS", 3), ("nvs", "psnr_dyn", "NVS PSNR*", 2))


def value(record: Mapping[str, Any], split: str, key: str) -> float | None:
    return ((record.get("metrics") or {}).get(split) or {}).get(key)


def means(records: Sequence[Mapping[str, Any]]) -> dict[str, Any]:
    """Each column's mean over the scenes that finished (None where none has it), and ``n``."""
    done = [r for r in records if r.get("status") == "ok"]
    out: dict[str, Any] = {"n": len(done)}
    for split, key, _, _ in COLUMNS:
        values = [v for v in (value(r, split, key) for r in done) if v is not None]
        out[f"{split}_{key}"] = sum(values) / len(values) if values else None
    return out


def payload(config: Mapping[str, Any], labels: Sequence[str], records: Mapping[str, Mapping[str, Any]]
            ) -> dict[str, Any]:
    """batch.json: the batch's ``config``, the scenes' records in the order given (those not
    finished yet under ``missing``), the means and the failed count."""
    scenes = [dict(records[label]) for label in labels if label in records]
    return {"config": dict(config), "scenes": scenes, "means": means(scenes),
            "failed": sum(r.get("status") != "ok" for r in scenes),
            "missing": [label for label in labels if label not in records]}


def report_link(record: Mapping[str, Any]) -> str | None:
    """The scene's report, relative to the batch folder (None before it exists)."""
    if record.get("status") != "ok":
        return None
    return f"scenes/{record['scene']}/run/report.html"


def _number(x: float | None, digits: int) -> str:
    return "–" if x is None else f"{x:.{digits}f}"


def _cells(record: Mapping[str, Any]) -> list[str]:
    status = record.get("status", "?")
    if status == "ok" and record.get("action") == "skipped":
        status = "ok (skipped)"
    attempts = record.get("attempts")
    return [status, *[_number(value(record, split, key), digits) for split, key, _, digits in COLUMNS],
            elapsed_text(record.get("seconds")), "" if attempts is None else str(attempts)]


def markdown(result: Mapping[str, Any]) -> str:
    """batch.md: a row per scene, then the mean row; a failed scene's one-line error below."""
    titles = ["Scene", "Status", *[title for _, _, title, _ in COLUMNS], "Time", "Attempts", "Report"]
    lines = ["| " + " | ".join(titles) + " |", "|" + "|".join([":---", ":---"] + ["---:"] * (len(titles) - 3)
                                                            + [":---"]) + "|"]
    for record in result["scenes"]:
        link = report_link(record)
        lines.append("| " + " | ".join([record["scene"], *_cells(record), f"[report]({link})" if link else ""]) + " |")
    mean = result["means"]
    lines.append("| **mean** | " + f"{mean['n']} ok | "
                 + " | ".join(_number(mean[f"{split}_{key}"], digits) for split, key, _, digits in COLUMNS)
                 + " | | | |")
    config = result["config"]
    lines += ["", f"Preset `{config.get('preset')}`, method `{config.get('method')}`, "
                  f"{config.get('iterations')} training iterations; means over the scenes that finished. "
                  "Recon. = training views, NVS = held-out views; PSNR* = PSNR on dynamic-object pixels."]
    failed = [r for r in result["scenes"] if r.get("status") != "ok"]
    if failed:
        lines += ["", "Failed:", "", *[f"- **{r['scene']}**: {r.get('error')}" for r in failed]]
    if result.get("missing"):
        lines += ["", f"Not finished: {', '.join(result['missing'])}"]
    return "\n".join(lines) + "\n"


def index_html(result: Mapping[str, Any]) -> str:
    """index.html: the table of :func:`markdown`, each scene linking its report."""
    e = html.escape
    titles = ["Scene", "Status", *[title for _, _, title, _ in COLUMNS], "Time", "Attempts", ""]
    rows = []
    for record in result["scenes"]:
        link = report_link(record)
        name = f'<a href="{e(link)}">{e(record["scene"])}</a>' if link else e(record["scene"])
        cells = [name, *[e(c) for c in _cells(record)],
                 f'<a href="{e(link)}">report</a>' if link else e(record.get("error") or "")]
        klass = "" if record.get("status") == "ok" else ' class="failed"'
        rows.append(f"<tr{klass}>" + "".join(f"<td>{c}</td>" for c in cells) + "</tr>")
    mean = result["means"]
    rows.append("<tr class=\"mean\"><td>mean</td><td>" + f"{mean['n']} ok</td>"
                + "".join(f"<td>{_number(mean[f'{s}_{k}'], d)}</td>" for s, k, _, d in COLUMNS)
                + "<td></td><td></td><td></td></tr>")
    config = result["config"]
    caption = (f"preset {config.get('preset')}, method {config.get('method')}, {config.get('iterations')} "
               f"iterations; {len(result['scenes'])} scene(s), {result['failed']} failed")
    if result.get("missing"):
        caption += f", not finished: {', '.join(result['missing'])}"
    return ("<!doctype html>\n<html><head><meta charset=\"utf-8\"><title>radar4dgs batch</title>\n<style>"
            "body{font-family:sans-serif;margin:2em}table{border-collapse:collapse}"
            "td,th{border:1px solid #ccc;padding:4px 8px;text-align:right}td:first-child,th:first-child,"
            "td:last-child{text-align:left}tr.failed{background:#fde8e8}tr.mean{font-weight:bold}"
            "</style></head>\n<body>\n<h1>radar4dgs batch</h1>\n"
            f"<p>{e(caption)}. Recon. = training views, NVS = held-out views; PSNR* = PSNR on dynamic-object "
            "pixels.</p>\n<table>\n<tr>" + "".join(f"<th>{e(t)}</th>" for t in titles) + "</tr>\n"
            + "\n".join(rows) + "\n</table>\n</body></html>\n")


def write_outputs(out: Path, result: Mapping[str, Any]) -> None:
    """batch.json, batch.md and index.html in ``out``."""
    atomic_write_json(out / BATCH_FILE, result)
    atomic_write_text(out / BATCH_MD, markdown(result))
    atomic_write_text(out / INDEX_HTML, index_html(result))
