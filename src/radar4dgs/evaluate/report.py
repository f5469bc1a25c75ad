"""One self-contained HTML evaluation report: what made the run, metrics and their caveats,
per-frame PSNR, loss curves, panels.

Everything is inside the one file (plots and images as base64 PNG data URIs, the resolved config
as text, inline CSS, no scripts, no external fonts or links), so it can be mailed, archived next
to a run, or opened offline. The only references are relative links to the files beside it in the
run folder (``config.json``, ``metrics.json``, the video), which work when the folder is opened.
Plots are drawn with matplotlib's Agg canvas directly (``matplotlib.figure.Figure``), never through
``pyplot``, so no GUI backend is ever touched and the global backend is left alone.
"""

from __future__ import annotations

import base64
import html
import io
import json
import math
import os
from pathlib import Path
from typing import Any, Mapping, Sequence

import numpy as np

from radar4dgs.io.atomic import atomic_write_text

SPLITS = ("recon", "nvs")
# (key, column header, format) of the per-split metrics, in table order.
METRIC_COLUMNS = (
    ("psnr", "PSNR (dB)", "{:.2f}"),
    ("ssim", "SSIM", "{:.4f}"),
    ("lpips_vgg", "LPIPS (VGG)", "{:.4f}"),
    ("lpips_alex", "LPIPS (Alex)", "{:.4f}"),
    ("psnr_dyn", "PSNR* (dynamic pixels, dB)", "{:.2f}"),
    ("n_frames", "frames", "{:d}"),
)
SPLIT_LABELS = {"recon": "reconstruction (train views)", "nvs": "novel views (test views)",
                "nvs_exposure_aligned": "novel views, exposure aligned (a colour transform per test view, "
                                        "fitted on the other half of its columns)"}

_CSS = """
body { font-family: system-ui, -apple-system, "Segoe UI", sans-serif; margin: 24px; color: #222;
       background: #fff; }
h1 { font-size: 1.5em; } h2 { font-size: 1.2em; margin-top: 1.6em; border-bottom: 1px solid #ccc; }
table { border-collapse: collapse; margin: 8px 0; }
th, td { border: 1px solid #ccc; padding: 4px 10px; text-align: right; }
th:first-child, td:first-child { text-align: left; }
th { background: #f0f0f0; }
.meta { color: #555; }
.plot { max-width: 100%; }
.panel { margin: 12px 0 20px; }
.panel h3 { font-size: 1em; margin: 4px 0; }
.caption { color: #555; font-size: 0.9em; margin: 2px 0 6px; }
.row { display: flex; flex-wrap: wrap; gap: 8px; }
figure { margin: 0; flex: 1 1 0; min-width: 160px; }
figure img { width: 100%; image-rendering: pixelated; border: 1px solid #ddd; }
figcaption { text-align: center; font-size: 0.9em; }
.flagged { background: #fff4d6; }
.caveat { background: #fff4d6; border-left: 4px solid #e0a000; padding: 6px 10px; margin: 6px 0; }
video { max-width: 100%; border: 1px solid #ddd; }
pre { background: #f6f6f6; padding: 8px; overflow-x: auto; font-size: 0.85em; }
"""


def _esc(value: Any) -> str:
    return html.escape(str(value), quote=True)


def _number(value: Any) -> float | None:
    """A finite float, or None for None / NaN / inf / non-numbers."""
    if value is None or isinstance(value, (bool, np.bool_)):
        return None
    try:
        out = float(value)
    except (TypeError, ValueError):
        return None
    return out if math.isfinite(out) else None


def _fmt(value: Any, fmt: str = "{:.4g}") -> str:
    if value is None:
        return "n/a"
    if isinstance(value, (bool, np.bool_)):
        return "yes" if value else "no"
    if isinstance(value, str):  # frame names such as "000003" stay text
        return value
    if fmt == "{:d}":
        number = _number(value)
        return "n/a" if number is None else str(int(round(number)))
    number = _number(value)
    if number is None:
        return "n/a"
    return fmt.format(number)


def _as_image(value: Any, where: str) -> np.ndarray:
    if hasattr(value, "detach") and hasattr(value, "cpu"):
        value = value.detach().cpu().numpy()
    image = np.asarray(value)
    if image.dtype != np.uint8:
        raise ValueError(f"{where}: images must be uint8 (H, W, 3), got dtype {image.dtype}")
    if image.ndim == 3 and image.shape[2] == 1:
        image = image[:, :, 0]
    if not (image.ndim == 2 or (image.ndim == 3 and image.shape[2] in (3, 4))) \
            or image.shape[0] == 0 or image.shape[1] == 0:
        raise ValueError(f"{where}: images must have shape (H, W, 3) (or (H, W), (H, W, 4)), "
                         f"got {image.shape}")
    return np.ascontiguousarray(image)


def png_data_uri(image: np.ndarray, max_width: int | None = None) -> str:
    """``data:image/png;base64,...`` of a uint8 (H, W), (H, W, 3) or (H, W, 4) image, optionally
    downscaled (aspect kept) to at most ``max_width`` pixels wide."""
    from PIL import Image

    picture = Image.fromarray(_as_image(image, "image"))
    if max_width is not None and picture.width > max_width:
        height = max(1, round(picture.height * max_width / picture.width))
        picture = picture.resize((max_width, height), Image.Resampling.LANCZOS)
    buffer = io.BytesIO()
    picture.save(buffer, format="PNG")
    return "data:image/png;base64," + base64.b64encode(buffer.getvalue()).decode("ascii")


def _figure_uri(fig) -> str:
    buffer = io.BytesIO()
    # metadata Software=None: no version string / URL baked into the PNG.
    fig.savefig(buffer, format="png", metadata={"Software": None})
    return "data:image/png;base64," + base64.b64encode(buffer.getvalue()).decode("ascii")


def _new_figure(width: float, height: float):
    from matplotlib.figure import Figure

    return Figure(figsize=(width, height), dpi=100, layout="constrained")


# --------------------------------------------------------------------------------------------
# Sections


def _metrics_section(metrics: Mapping[str, Any], flagged: Sequence[str] = ()) -> str:
    splits = [s for s in SPLITS if isinstance(metrics.get(s), Mapping)]
    splits += [k for k, v in metrics.items() if isinstance(v, Mapping) and k not in splits]
    known = {key for key, _, _ in METRIC_COLUMNS}
    extra: list[str] = []
    for split in splits:
        extra += [k for k in metrics[split] if k not in known and k not in extra]
    columns = list(METRIC_COLUMNS) + [(k, k, "{:.4g}") for k in extra]
    head = "".join(f"<th>{_esc(label)}</th>" for _, label, _ in columns)
    rows = []
    for split in (splits or list(SPLITS)):
        values = metrics.get(split) or {}
        cells = "".join(
            f"<td class=\"flagged\">{_esc(_fmt(values.get(key), fmt))} (flagged: see the caveats)</td>"
            if key == "psnr_dyn" and split in flagged else f"<td>{_esc(_fmt(values.get(key), fmt))}</td>"
            for key, _, fmt in columns)
        rows.append(f"<tr><td>{_esc(SPLIT_LABELS.get(split, split))}</td>{cells}</tr>")
    scalars = [(k, v) for k, v in metrics.items() if not isinstance(v, Mapping)]
    meta = "".join(f"<li>{_esc(k)}: <b>{_esc(_fmt(v))}</b></li>" for k, v in scalars)
    return (f"<h2>Metrics</h2>\n<table class=\"metrics\"><tr><th>split</th>{head}</tr>\n"
            + "\n".join(rows) + "</table>\n"
            + (f"<ul class=\"meta\">{meta}</ul>\n" if meta else ""))


def _relative(href: str) -> str:
    """``href`` if it names a file beside the report (no scheme, no folder, no parent), else raises."""
    if not href or "/" in href or "\\" in href or ":" in href or href.startswith("."):
        raise ValueError(f"report links must name a file beside the report, got {href!r}")
    return href


def _run_section(run_info: Mapping[str, Any], links: Mapping[str, str], video: str | None,
                 config: Mapping[str, Any] | None) -> str:
    if not (run_info or links or video or config):
        return ""
    rows = "".join(f"<tr><td>{_esc(k)}</td><td>{_esc(_fmt(v))}</td></tr>" for k, v in run_info.items())
    parts = ["<h2>Run</h2>"]
    if rows:
        parts.append(f"<table class=\"run\">{rows}</table>")
    if links:
        items = " &middot; ".join(f"<a href=\"{_esc(_relative(href))}\">{_esc(label)} ({_esc(href)})</a>"
                                  for label, href in links.items())
        parts.append(f"<p class=\"meta\">files: {items}</p>")
    if video:
        name = _esc(_relative(video))
        parts.append(f"<video controls loop muted preload=\"metadata\" src=\"{name}\">"
                     f"<a href=\"{name}\">{name}</a></video>")
    if config is not None:
        text = json.dumps(config, indent=2, sort_keys=False)
        parts.append(f"<details><summary>resolved config</summary><pre>{_esc(text)}</pre></details>")
    return "\n".join(parts) + "\n"


def _caveats_section(caveats: Sequence[str]) -> str:
    return "".join(f"<p class=\"caveat\">{_esc(c)}</p>\n" for c in caveats)


def _frame_key(entry: Mapping[str, Any], position: int) -> tuple[int | None, str]:
    """(numeric x or None, label) of a per-frame entry."""
    label = entry.get("frame", entry.get("name", entry.get("index", position)))
    index = entry.get("index")
    if isinstance(index, (int, np.integer)) and not isinstance(index, bool):
        return int(index), str(label)
    if isinstance(label, (int, np.integer)) and not isinstance(label, bool):
        return int(label), str(label)
    if isinstance(label, str) and label.isdigit():
        return int(label), label
    return None, str(label)


def _per_frame_section(per_frame: Mapping[str, Sequence[Mapping[str, Any]]]) -> str:
    series = {split: list(entries or []) for split, entries in per_frame.items()}
    if not any(series.values()):
        return "<h2>Per-frame PSNR</h2>\n<p class=\"meta\">no per-frame metrics</p>\n"
    keyed = {split: [_frame_key(e, i) for i, e in enumerate(entries)]
             for split, entries in series.items()}
    numeric = all(x is not None for keys in keyed.values() for x, _ in keys)
    if not numeric:  # categorical axis: frames in order of first appearance
        order: dict[str, int] = {}
        for keys in keyed.values():
            for _, label in keys:
                order.setdefault(label, len(order))

    fig = _new_figure(9.0, 3.4)
    ax = fig.subplots()
    plotted = False
    for split, entries in series.items():
        xs, ys = [], []
        for (x, label), entry in zip(keyed[split], entries, strict=True):
            y = _number(entry.get("psnr"))
            if y is not None:
                xs.append(x if numeric else order[label])
                ys.append(y)
        if xs:
            ax.plot(xs, ys, "o-", markersize=3, linewidth=1, label=SPLIT_LABELS.get(split, split))
            plotted = True
    ax.set_ylabel("PSNR (dB)")
    ax.set_xlabel("frame index" if numeric else "frame")
    if not numeric:
        labels = list(order)
        step = max(1, len(labels) // 20)  # at most ~20 tick labels stay legible
        ax.set_xticks(range(0, len(labels), step), labels[::step], rotation=45, ha="right")
    ax.grid(True, alpha=0.3)
    if plotted:
        ax.legend()
    plot = _figure_uri(fig)

    columns: list[str] = []
    for entries in series.values():
        for entry in entries:
            columns += [k for k in entry if k not in columns]
    head = "".join(f"<th>{_esc(c)}</th>" for c in columns)
    rows = []
    for split, entries in series.items():
        for entry in entries:
            cells = "".join(f"<td>{_esc(_fmt(entry.get(c)) if c in entry else '')}</td>"
                            for c in columns)
            rows.append(f"<tr><td>{_esc(split)}</td>{cells}</tr>")
    return (f"<h2>Per-frame PSNR</h2>\n<img class=\"plot\" alt=\"per-frame PSNR\" src=\"{plot}\">\n"
            f"<details><summary>per-frame table</summary>\n<table><tr><th>split</th>{head}</tr>\n"
            + "\n".join(rows) + "</table></details>\n")


def _history_section(history: Sequence[Mapping[str, Any]]) -> str:
    history = [h for h in history if _number(h.get("step")) is not None]
    if not history:
        return "<h2>Training curves</h2>\n<p class=\"meta\">no training history</p>\n"
    terms: list[str] = []
    for record in history:
        terms += [k for k, v in record.items()
                  if k not in ("step", "psnr") and k not in terms and _number(v) is not None]
    has_psnr = any(_number(h.get("psnr")) is not None for h in history)
    fig = _new_figure(11.0 if has_psnr else 9.0, 3.6)
    axes = fig.subplots(1, 2 if has_psnr else 1, squeeze=False)[0]
    loss_ax = axes[0]
    positive = True
    for term in terms:
        points = [(_number(h["step"]), _number(h.get(term))) for h in history]
        points = [(x, y) for x, y in points if y is not None]
        positive &= all(y > 0 for _, y in points)
        loss_ax.plot([x for x, _ in points], [y for _, y in points], linewidth=1, label=term)
    if terms and positive:
        loss_ax.set_yscale("log")  # loss terms span decades; log keeps the small ones visible
    loss_ax.set_xlabel("step")
    loss_ax.set_ylabel("loss")
    loss_ax.set_title("loss terms")
    loss_ax.grid(True, alpha=0.3)
    if terms:
        loss_ax.legend(fontsize="small")
    if has_psnr:
        points = [(_number(h["step"]), _number(h.get("psnr"))) for h in history]
        points = [(x, y) for x, y in points if y is not None]
        axes[1].plot([x for x, _ in points], [y for _, y in points], color="tab:green", linewidth=1)
        axes[1].set_xlabel("step")
        axes[1].set_ylabel("PSNR (dB)")
        axes[1].set_title("training PSNR")
        axes[1].grid(True, alpha=0.3)
    return (f"<h2>Training curves</h2>\n"
            f"<img class=\"plot\" alt=\"training curves\" src=\"{_figure_uri(fig)}\">\n")


def _poses_section(poses: Mapping[str, Any] | None) -> str:
    """The learned corrections per training frame (``RUN/poses.json``): translation (m) and
    rotation (deg) per camera axis, and the exposure gains where the run learned them."""
    frames = (poses or {}).get("frames") or []
    if not frames:
        return ""
    index = [f["index"] for f in frames]
    series = []
    if any("correction" in f for f in frames):
        t = np.array([f["correction"]["translation_m"] for f in frames])
        r = np.degrees(np.array([f["correction"]["rotation_rad"] for f in frames]))
        series += [("translation (m)", t, "xyz"), ("rotation (deg)", r, "xyz")]
    if any("appearance" in f for f in frames):
        gains = np.array([1.0 + np.diag(np.array(f["appearance"]["matrix"])) for f in frames])
        series.append(("exposure gain", gains, "rgb"))
    fig = _new_figure(4.0 * len(series), 3.2)
    for ax, (label, values, axes) in zip(fig.subplots(1, len(series), squeeze=False)[0], series, strict=True):
        for j, name in enumerate(axes):
            ax.plot(index, values[:, j], marker=".", linewidth=1, label=name)
        ax.set_xlabel("frame")
        ax.set_ylabel(label)
        ax.grid(True, alpha=0.3)
        ax.legend(fontsize="small")
    summary = (poses or {}).get("summary") or {}
    note = ", ".join(f"{k.rsplit('_', 1)[0].replace('_', ' ')} {_fmt(v)} {k.rsplit('_', 1)[-1]}"
                     for k, v in summary.items())
    return ("<h2>Pose and exposure refinement</h2>\n"
            "<p class=\"meta\">Learned per training frame, in camera axes (x right, y down, z forward); "
            f"{_esc(note)}</p>\n<img class=\"plot\" alt=\"pose corrections\" src=\"{_figure_uri(fig)}\">\n")


def _panels_section(panels: Sequence[Mapping[str, Any]], max_image_width: int | None) -> str:
    if not panels:
        return ""
    parts = ["<h2>Frames</h2>"]
    for i, panel in enumerate(panels):
        name = panel.get("name", f"panel {i}")
        figures, notes = [], []
        for key, value in panel.items():
            if key == "name" or value is None:
                continue
            if hasattr(value, "shape") and len(value.shape) >= 2:
                uri = png_data_uri(_as_image(value, f"panel {name!r} image {key!r}"), max_image_width)
                figures.append(f"<figure><img alt=\"{_esc(key)}\" src=\"{uri}\">"
                               f"<figcaption>{_esc(key)}</figcaption></figure>")
            else:
                notes.append(f"{_esc(key)}: {_esc(_fmt(value))}")
        caption = f"<p class=\"caption\">{' &middot; '.join(notes)}</p>" if notes else ""
        parts.append(f"<div class=\"panel\"><h3>{_esc(name)}</h3>{caption}"
                     f"<div class=\"row\">{''.join(figures)}</div></div>")
    return "\n".join(parts) + "\n"


def _actors_section(picture: bytes | None) -> str:
    """The actors' bird's-eye view (``RUN/actors.png``, PNG bytes), when there is one."""
    if not picture:
        return ""
    uri = "data:image/png;base64," + base64.b64encode(picture).decode("ascii")
    return ("<h2>Actors</h2>\n<p class=\"caption\">The moving objects found from the dynamic Gaussians' motion "
            "(<code>radar4dgs actors</code>, <code>actors.json</code>): their centroids' tracks over the static "
            f"map.</p>\n<img class=\"plot\" alt=\"actors\" src=\"{uri}\">\n")


def render_report(*, title: str, metrics: Mapping[str, Any],
                  per_frame: Mapping[str, Sequence[Mapping[str, Any]]],
                  history: Sequence[Mapping[str, Any]], panels: Sequence[Mapping[str, Any]],
                  max_image_width: int | None = None, run_info: Mapping[str, Any] | None = None,
                  caveats: Sequence[str] = (), links: Mapping[str, str] | None = None,
                  video: str | None = None, config: Mapping[str, Any] | None = None,
                  flagged: Sequence[str] = (), poses: Mapping[str, Any] | None = None,
                  actors_picture: bytes | None = None) -> str:
    """The report's HTML text (see :func:`write_report`)."""
    body = (_run_section(run_info or {}, links or {}, video, config) + _metrics_section(metrics, flagged)
            + _caveats_section(caveats) + _per_frame_section(per_frame) + _history_section(history)
            + _poses_section(poses) + _actors_section(actors_picture) + _panels_section(panels, max_image_width))
    return (f"<!DOCTYPE html>\n<html lang=\"en\">\n<head>\n<meta charset=\"utf-8\">\n"
            f"<title>{_esc(title)}</title>\n<style>{_CSS}</style>\n</head>\n<body>\n"
            f"<h1>{_esc(title)}</h1>\n{body}</body>\n</html>\n")


def write_report(path: str | os.PathLike, *, title: str, metrics: Mapping[str, Any],
                 per_frame: Mapping[str, Sequence[Mapping[str, Any]]],
                 history: Sequence[Mapping[str, Any]], panels: Sequence[Mapping[str, Any]],
                 max_image_width: int | None = None, run_info: Mapping[str, Any] | None = None,
                 caveats: Sequence[str] = (), links: Mapping[str, str] | None = None,
                 video: str | None = None, config: Mapping[str, Any] | None = None,
                 flagged: Sequence[str] = (), poses: Mapping[str, Any] | None = None) -> Path:
    """Write one self-contained HTML report to ``path`` (atomically); returns the path.

    ``metrics``: ``{"recon": {...}, "nvs": {...}, "mask_source": str, "lpips_available": bool}``,
    each split with ``psnr``, ``ssim``, ``lpips_vgg``, ``lpips_alex``, ``psnr_dyn`` (None or NaN
    shown as "n/a"), ``n_frames``; extra keys become extra columns / lines.
    ``per_frame``: split -> list of ``{"frame": name, "index": i (optional), "psnr": ..., ...}``;
    plotted against ``index`` (or the frame name when it is all digits, else by order).
    ``history``: list of ``{"step": int, <loss term>: float, ..., "psnr": float (optional)}``.
    ``panels``: list of ``{"name": str, <label>: uint8 (H, W, 3) image, ...}`` in display order
    (e.g. ``gt``, ``render``, ``error``, ``depth``, ``mask``, ``radar``); non-image values are
    shown as a caption. ``max_image_width`` downscales wider panel images to keep the file small.
    ``run_info``: what made the run (preset, method, config hash, times, ...), shown first as a
    table; ``caveats``: sentences shown highlighted under the metrics (e.g. PSNR* on near-empty
    masks); ``links``: label -> name of a file beside the report (``config.json``); ``video``: the
    name of a video beside the report, played in the page; ``config``: the resolved config, shown
    as JSON in a collapsed block; ``flagged``: the splits whose PSNR* is flagged by a caveat, marked
    in the metrics table; ``poses``: ``RUN/poses.json`` of a run that refined poses or exposure,
    plotted per frame. An ``actors.png`` beside ``path`` (``radar4dgs actors``) is shown too.
    """
    actors = Path(path).with_name("actors.png")
    text = render_report(title=title, metrics=metrics, per_frame=per_frame, history=history,
                         panels=panels, max_image_width=max_image_width, run_info=run_info,
                         caveats=caveats, links=links, video=video, config=config, flagged=flagged,
                         poses=poses, actors_picture=actors.read_bytes() if actors.is_file() else None)
    return atomic_write_text(path, text)
