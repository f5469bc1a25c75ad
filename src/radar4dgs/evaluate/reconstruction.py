"""``radar4dgs eval RUN``: deterministic evaluation of a trained run (DESIGN.md stage 8).

It reloads the run's saved config (``RUN/config.json``, ``RUN/run.json``) and model
(``RUN/model.pt``), renders every frame at the scene's full resolution with no dropout and no
gradient (never through the training loop), and writes:

- ``RUN/metrics.json``: ``{"recon": {...}, "nvs": {...}, "mask_source": ..., "mask_coverage": ...,
  "psnr_dyn_caveats": [...], "nvs_seen": {...}, "lpips_available": ..., "lpips_convention": {...}, "run": {...},
  "per_frame": {"recon": [...], "nvs": [...]}}``; each split holds ``psnr``, ``ssim``,
  ``lpips_vgg``, ``lpips_alex`` (null without backbone weights; computed as
  ``lpips_convention`` says: VGG on the [0, 1] images as-is, the 3DGS / gsplat convention,
  AlexNet on them mapped to [-1, 1]), ``psnr_dyn`` (PSNR* over the dynamic-mask pixels, averaged over
  frames whose mask is not empty) and ``n_frames``. Reconstruction = training frames, novel-view
  synthesis (nvs) = test frames (every 4th). ``mask_coverage``: per split, the fraction of the
  pixels the PSNR* masks cover; ``predicted_mask_recall``: per split, the fraction of the
  ground-truth dynamic pixels that the predicted masks the run trained on (``prepared/masks``)
  cover (null unless the scene has ``gt/dynamic_mask`` and the run's ``mask_source`` is
  "predicted"); ``psnr_dyn_caveats`` says when PSNR* means little (masks under
  :data:`MIN_MASK_COVERAGE` of the pixels, predicted masks finding under :data:`MIN_MASK_RECALL`
  of the ground-truth dynamic pixels, predicted masks as PSNR* masks) and ``psnr_dyn_flagged``,
  per split, whether one of the first two holds. ``nvs_seen`` (scenes with ``gt/depth``, ``gt/flow`` and
  ``gt/dynamic_mask``; :mod:`radar4dgs.evaluate.observability`): PSNR* over the test frames whose moving
  pixels the adjacent training frames saw at least half as large, and the frames left out (each test
  frame's ``unseen_close_share`` is in ``per_frame``); a caveat names them. ``run``
  (:func:`run_record`): what made the run (preset, method, config hash, code version, training time).
- ``RUN/renders/{recon,nvs}/<frame>.png`` and ``<frame>_depth.png``, ``<frame>_dynamic.png``.
- ``RUN/video.mp4``: ground truth | render | depth | dynamic mask, every frame in time order.
- ``RUN/tb/``: when the run has a TensorBoard log (training keeps one unless ``--no-tensorboard``),
  the metrics as ``val/*`` (test frames) and ``recon/*`` (training frames) and a few test frames.
- ``RUN/report.html``: what made the run, metrics and their caveats, per-frame PSNR, loss curves
  and test-frame panels (one file; it links ``config.json``, ``metrics.json`` and the video beside it).

``RUN/provenance.json`` (:func:`write_provenance`, written by the commands that train) names the
preset and method a run was made with, which its resolved config alone does not say.
"""

from __future__ import annotations

import contextlib
import hashlib
import json
import time
import warnings
from pathlib import Path
from typing import Any

import numpy as np
import torch

from radar4dgs.evaluate.alignment import (
    EXPOSURE_ALIGNMENT,
    aligned_metrics,
    exposure_aligned,
    learned_corrections,
    score_aligned,
)
from radar4dgs.evaluate.observability import seen_caveats, seen_summary, unseen_close_share
from radar4dgs.io.atomic import atomic_directory, atomic_write_json
from radar4dgs.io.preview import doppler_colors, draw_radar_overlay, radar_points_in_camera, save_png
from radar4dgs.io.scene import SceneWarning, normalized_times, read_mask_png
from radar4dgs.metrics.image import LpipsScorer, lpips_convention, lpips_or_none, psnr, ssim, summarize_frames
from radar4dgs.model.run import CONFIG_FILE, HISTORY_FILE, LOSS_TERMS, POSES_FILE, Run, load_run
from radar4dgs.model.run_log import TB_DIR, TensorBoard
from radar4dgs.model.view import View, frame_view

METRICS_FILE = "metrics.json"
RENDERS_DIR = "renders"
VIDEO_FILE = "video.mp4"
REPORT_FILE = "report.html"
PROVENANCE_FILE = "provenance.json"
# PSNR* is flagged as not meaningful when its masks cover less than this fraction of a split's pixels.
MIN_MASK_COVERAGE = 0.005
# PSNR* is flagged when the predicted masks a run trained on find less than this fraction of the
# ground-truth dynamic pixels: the run then modelled most moving pixels as static.
MIN_MASK_RECALL = 0.5
# One colour scale for every depth picture of a run, so the video does not flicker (metres).
DEPTH_NEAR, DEPTH_FAR = 2.0, 120.0
# Test frames (ground truth | render) added to the run's TensorBoard log.
TB_IMAGES = 4
# The per-split metrics added to TensorBoard: nvs as val/<key>, recon as recon/<key>.
TB_METRICS = ("psnr", "ssim", "lpips_vgg", "lpips_alex", "psnr_dyn")


def to_uint8(image: torch.Tensor) -> np.ndarray:
    """(H, W, 3) float in [0, 1] -> uint8."""
    return (image.detach().clamp(0, 1).cpu().numpy() * 255.0 + 0.5).astype(np.uint8)


@torch.no_grad()
def render_view(run: Run, view: View) -> dict[str, torch.Tensor]:
    """Render ``view`` with the run's model and rasterizer settings, no gradient, no dropout:
    ``rgb`` (H, W, 3), ``depth`` (H, W), ``alpha`` (H, W), ``dynamic`` (H, W)."""
    out = run.model.render(view, run.config.raster)
    return {k: out[k] for k in ("rgb", "depth", "alpha", "dynamic")}


def mask_source(run: Run) -> str:
    """Where the PSNR* masks come from: "gt" when the scene has a complete ``gt/dynamic_mask``,
    else "predicted" (the prepared masks)."""
    return "gt" if run.scene.has("gt/dynamic_mask") else "predicted"


def dynamic_mask(run: Run, index: int, source: str) -> np.ndarray:
    """The bool (H, W) PSNR* mask of frame ``index`` from ``source`` (:func:`mask_source`)."""
    if source == "gt":
        return run.scene.load_optional("gt/dynamic_mask", index)
    name = run.scene.frames[index].name
    shape = (run.scene.camera.height, run.scene.camera.width)
    return read_mask_png(run.prepared / "masks" / f"{name}.png", shape)


def _read_json(path: Path) -> dict[str, Any]:
    try:
        value = json.loads(path.read_text(encoding="utf-8"))
    except (OSError, json.JSONDecodeError):
        return {}
    return value if isinstance(value, dict) else {}


def write_provenance(run_dir: str | Path, *, preset: str | None, method: str | None, command: str) -> Path:
    """Record in ``RUN/provenance.json`` the preset and method names and the command that made the
    run, with the code version (the resolved config is ``RUN/config.json``)."""
    from radar4dgs import __version__

    return atomic_write_json(Path(run_dir) / PROVENANCE_FILE, {"preset": preset, "method": method,
                                                               "command": command, "code_version": __version__})


def config_hash(run_dir: str | Path) -> str | None:
    """The first 12 hex digits of the sha256 of the run's resolved config (``config.json``'s
    ``config``, keys sorted): two runs with one hash were made with one config."""
    config = _read_json(Path(run_dir) / CONFIG_FILE).get("config")
    if config is None:
        return None
    return hashlib.sha256(json.dumps(config, sort_keys=True).encode("utf-8")).hexdigest()[:12]


def run_record(run: Run) -> dict[str, Any]:
    """What made the run: ``preset``, ``method`` and ``command`` (from ``provenance.json``; null
    for a run trained without it), ``config_hash``, ``code_version`` (evaluating) and
    ``trained_with_version``, ``iterations`` and ``train_seconds`` (of the last training call:
    a resumed run counts only the part after its resume)."""
    from radar4dgs import __version__

    provenance = _read_json(run.root / PROVENANCE_FILE)
    history = _read_json(run.root / HISTORY_FILE)
    return {"preset": provenance.get("preset"), "method": provenance.get("method") or run.config.method,
            "command": provenance.get("command"), "config_hash": config_hash(run.root),
            "code_version": __version__, "trained_with_version": provenance.get("code_version"),
            "iterations": run.config.optim.iterations, "train_seconds": history.get("train_seconds_last_call")}


def trained_mask_recall(run: Run, index: int, source: str, gt_mask: np.ndarray) -> tuple[int, int] | None:
    """(ground-truth dynamic pixels the predicted masks the run trained on cover, ground-truth
    dynamic pixels) of frame ``index``; None unless the PSNR* masks are the ground truth
    (``source`` "gt"), the run trained on the predicted masks and frame ``index`` has one."""
    if source != "gt" or run.config.mask_source != "predicted":
        return None
    path = run.prepared / "masks" / f"{run.scene.frames[index].name}.png"
    if not path.is_file():
        return None
    truth = np.asarray(gt_mask, dtype=bool)
    predicted = np.asarray(read_mask_png(path, truth.shape), dtype=bool)
    return int((predicted & truth).sum()), int(truth.sum())


def mask_recall(per_frame: dict[str, list[dict]]) -> dict[str, float | None] | None:
    """Per split, the fraction of the ground-truth dynamic pixels the run's predicted masks cover
    (from the entries' ``trained_mask_hits`` / ``dynamic_pixels``); None when no frame has it."""
    if not any("trained_mask_hits" in e for entries in per_frame.values() for e in entries):
        return None
    out: dict[str, float | None] = {}
    for split, entries in per_frame.items():
        scored = [e for e in entries if "trained_mask_hits" in e]
        total = sum(e["dynamic_pixels"] for e in scored)
        out[split] = sum(e["trained_mask_hits"] for e in scored) / total if total else None
    return out


def recall_caveats(recall: dict[str, float | None] | None) -> list[str]:
    """The caveats on PSNR* of the splits where the predicted masks the run trained on find under
    :data:`MIN_MASK_RECALL` of the ground-truth dynamic pixels."""
    return [f"PSNR* ({split}): the predicted dynamic masks the run trained on (prepared/masks) find only "
            f"{value:.1%} of the ground-truth dynamic pixels, under {MIN_MASK_RECALL:.0%}: most moving pixels "
            f"were modelled as static, so PSNR* (on the ground-truth masks) measures the static scene there, "
            f"not the method's dynamic model"
            for split, value in (recall or {}).items() if value is not None and value < MIN_MASK_RECALL]


def psnr_dyn_flags(coverage: dict[str, float | None], recall: dict[str, float | None] | None
                   ) -> dict[str, bool]:
    """Per split, whether PSNR* is flagged: masks under :data:`MIN_MASK_COVERAGE` of the pixels
    (or empty), or the run's predicted masks finding under :data:`MIN_MASK_RECALL` of the
    ground-truth dynamic pixels."""
    flags = {}
    for split, covered in coverage.items():
        found = (recall or {}).get(split)
        flags[split] = (covered is not None and covered < MIN_MASK_COVERAGE) or (
            found is not None and found < MIN_MASK_RECALL)
    return flags


def mask_caveats(per_frame: dict[str, list[dict]], source: str, pixels_per_frame: int
                 ) -> tuple[dict[str, float | None], list[str]]:
    """Per split, the fraction of the pixels the PSNR* masks cover, and the caveats on PSNR*:
    masks under :data:`MIN_MASK_COVERAGE` of the pixels (PSNR* is then an average over a few
    pixels, typically of a missed object's edge, not a measure of the moving objects), masks empty
    in every frame, predicted masks (an object they miss is not scored)."""
    coverage: dict[str, float | None] = {}
    caveats = []
    for split, entries in per_frame.items():
        if not entries:
            coverage[split] = None
            continue
        covered = sum(e["dynamic_pixels"] for e in entries) / (len(entries) * pixels_per_frame)
        coverage[split] = covered
        with_mask = sum(e["dynamic_pixels"] > 0 for e in entries)
        if with_mask == 0:
            caveats.append(f"PSNR* ({split}): the {source} dynamic masks are empty in every frame; not computed")
        elif covered < MIN_MASK_COVERAGE:
            caveats.append(f"PSNR* ({split}) is computed on {covered:.2%} of the pixels ({source} masks, "
                           f"{with_mask} of {len(entries)} frames): under {MIN_MASK_COVERAGE:.1%}, too few "
                           f"pixels to measure the moving objects; it is not meaningful")
    if source == "predicted":
        caveats.append("PSNR* uses the predicted dynamic masks (the scene has no gt/dynamic_mask): a moving "
                       "object the masks miss is not scored")
    return coverage, caveats


def radar_overlay(scene, index: int, image: np.ndarray) -> np.ndarray:
    """``image`` with frame ``index``'s radar points drawn, coloured by raw v_r (``image`` itself for
    a scene without radar)."""
    if not scene.has_radar:
        return image
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", SceneWarning)
        scan = scene.load_radar(index)
    uv, z = scene.camera.project(radar_points_in_camera(scene, index, scan.xyz.astype(np.float64)))
    H, W = image.shape[:2]
    visible = (z > 0.1) & (uv[:, 0] >= 0) & (uv[:, 0] < W) & (uv[:, 1] >= 0) & (uv[:, 1] < H)
    limit = float(np.percentile(np.abs(scan.v_r), 95)) if len(scan) else 1.0
    order = np.argsort(-z[visible])
    return draw_radar_overlay(image, uv[visible][order], doppler_colors(scan.v_r[visible][order], limit),
                              radius=max(1, W // 240))


def score_frame(rgb: torch.Tensor, gt: torch.Tensor, mask: np.ndarray,
                scorers: dict[str, LpipsScorer | None]) -> dict[str, Any]:
    """``psnr``, ``ssim``, ``psnr_dyn`` (None for an empty ``mask``), ``dynamic_pixels`` and
    ``lpips_<net>`` (None without a scorer) of one frame's clamped render ``rgb`` against ``gt``."""
    entry = {"psnr": psnr(rgb, gt), "ssim": ssim(rgb, gt),
             "psnr_dyn": psnr(rgb, gt, torch.as_tensor(mask, device=rgb.device)) if mask.any() else None,
             "dynamic_pixels": int(mask.sum())}
    entry.update({f"lpips_{net}": scorer(rgb, gt) if scorer is not None else None for net, scorer in scorers.items()})
    return entry


def evaluate_run(run_dir: str | Path, device: str | None = None, lpips: bool = True, video: bool = True,
                 report: bool = True, progress: bool = True) -> dict[str, Any]:
    """Evaluate ``run_dir`` and write its metrics, renders, video and report; returns the metrics."""
    from radar4dgs.evaluate.visualize import depth_to_rgb, error_to_rgb, mask_to_rgb, side_by_side

    started = time.perf_counter()
    run = load_run(run_dir, device)
    scene = run.scene
    scorers: dict[str, LpipsScorer | None] = {net: (lpips_or_none(net) if lpips else None) for net in ("vgg", "alex")}
    test = set(scene.test_indices)
    times = normalized_times(scene)
    source = mask_source(run)
    per_frame: dict[str, list[dict]] = {"recon": [], "nvs": []}
    # Runs that refined their poses: the test views also aligned (evaluate.alignment).
    learned, aligned = learned_corrections(run), {}
    # Every run: the test views also scored with their exposure aligned (evaluate.alignment).
    exposure_scores: list[dict] = []
    frames_video, panels = [], []
    tb_images: dict[str, np.ndarray] | None = {} if (run.root / TB_DIR).is_dir() else None
    indices = range(len(scene))
    if progress:
        from tqdm import tqdm

        indices = tqdm(indices, desc="eval", unit="frame")
    # Each split's folder is replaced in one rename; other folders of renders/ (`radar4dgs render`
    # outputs) are left alone.
    with contextlib.ExitStack() as stack:
        folders = {split: stack.enter_context(atomic_directory(run.root / RENDERS_DIR / split, overwrite=True))
                   for split in per_frame}
        for index in indices:
            name = scene.frames[index].name
            split = "nvs" if index in test else "recon"
            view = frame_view(scene, index, 1.0, times)
            out = render_view(run, view)
            device_ = out["rgb"].device
            gt = torch.as_tensor(scene.load_image(index).astype(np.float32) / 255.0, device=device_)
            mask = dynamic_mask(run, index, source)
            rgb = out["rgb"].clamp(0, 1)
            entry = {"frame": name, "index": index, **score_frame(rgb, gt, mask, scorers)}
            found = trained_mask_recall(run, index, source, mask)
            if found is not None:
                entry["trained_mask_hits"] = found[0]
            share = unseen_close_share(scene, index, scene.train_indices) if split == "nvs" else None
            if share is not None:
                entry["unseen_close_share"] = share
            per_frame[split].append(entry)
            if split == "nvs":
                exposure_scores.append({"frame": name, **score_frame(exposure_aligned(rgb, gt), gt, mask, {})})
            if learned is not None and split == "nvs":
                score_aligned(run, view, gt, times[learned[0]], learned[1],
                              lambda rgb, gt=gt, mask=mask: score_frame(rgb, gt, mask, scorers), aligned, name)
            render_u8, gt_u8 = to_uint8(rgb), scene.load_image(index)
            depth_u8 = depth_to_rgb(np.where(out["alpha"].cpu().numpy() > 0.05, out["depth"].cpu().numpy(), np.nan),
                                    near=DEPTH_NEAR, far=DEPTH_FAR)
            dyn_u8 = mask_to_rgb(out["dynamic"].cpu().numpy() > 0.5)
            for suffix, image in (("", render_u8), ("_depth", depth_u8), ("_dynamic", dyn_u8)):
                save_png(folders[split] / f"{name}{suffix}.png", image)
            if tb_images is not None and split == "nvs" and len(tb_images) < TB_IMAGES:
                tb_images[f"val/gt_render/{name}"] = np.concatenate([gt_u8, render_u8], axis=1)
            if video:
                frames_video.append(side_by_side([gt_u8, render_u8, depth_u8, dyn_u8],
                                                 ["ground truth", f"render ({split})", "depth", "dynamic"]))
            if split == "nvs" and report:
                panels.append({"name": f"{name} (test frame)", "gt": gt_u8, "render": render_u8,
                               "error": error_to_rgb(render_u8, gt_u8), "depth": depth_u8,
                               "dynamic mask": dyn_u8, "radar": radar_overlay(scene, index, gt_u8),
                               "psnr": f"{entry['psnr']:.2f} dB"})
    coverage, caveats = mask_caveats(per_frame, source, scene.camera.width * scene.camera.height)
    recall = mask_recall(per_frame)
    caveats = recall_caveats(recall) + caveats
    nvs, seen = summarize_frames(per_frame["nvs"]), seen_summary(per_frame["nvs"])
    caveats += seen_caveats(seen, nvs["psnr_dyn"])
    metrics: dict[str, Any] = {
        "recon": summarize_frames(per_frame["recon"]), "nvs": nvs, "nvs_seen": seen,
        "mask_source": source, "mask_coverage": coverage, "predicted_mask_recall": recall,
        "psnr_dyn_flagged": psnr_dyn_flags(coverage, recall), "psnr_dyn_caveats": caveats,
        "lpips_available": all(s is not None for s in scorers.values()), "lpips_convention": lpips_convention(),
        "method": run.config.method, "num_gaussians": run.model.num_gaussians,
        "run": run_record(run),
        "nvs_exposure_aligned": summarize_frames(exposure_scores), "exposure_alignment": EXPOSURE_ALIGNMENT,
        "per_frame": per_frame,
    }
    metrics.update(aligned_metrics(run, aligned) if learned is not None else {})
    if video and frames_video:
        from radar4dgs.evaluate.video import write_video

        write_video(frames_video, run.root / VIDEO_FILE, fps=10)
    metrics["eval_seconds"] = time.perf_counter() - started
    atomic_write_json(run.root / METRICS_FILE, metrics)
    if tb_images is not None:
        log_tensorboard(run, metrics, tb_images)
    if report:
        write_run_report(run, metrics, per_frame, panels, video)
    return metrics


def write_run_report(run: Run, metrics: dict[str, Any], per_frame: dict[str, list[dict]], panels: list[dict],
                     video: bool) -> None:
    """``RUN/report.html`` of the evaluation ``metrics`` (``evaluate_run``'s), its ``per_frame``
    entries and test-frame ``panels``; ``video``: whether ``RUN/video.mp4`` was written."""
    from radar4dgs.evaluate.report import write_report

    history_path = run.root / HISTORY_FILE
    history = json.loads(history_path.read_text())["history"] if history_path.is_file() else []
    record = metrics["run"]
    run_info = {"preset": record["preset"] or "not recorded (no provenance.json)",
                "method": record["method"], "command": record["command"],
                "config hash": record["config_hash"], "iterations": record["iterations"],
                "training time": _duration(record["train_seconds"]),
                "evaluation time": _duration(metrics["eval_seconds"]),
                "code version": record["code_version"], "trained with version": record["trained_with_version"],
                "PSNR* masks": f"{metrics['mask_source']} ({_coverage_text(metrics['mask_coverage'])})"}
    recall = metrics["predicted_mask_recall"]
    if recall is not None:
        run_info["predicted masks' recall of the gt dynamic pixels"] = ", ".join(
            f"{split} {value:.1%}" for split, value in recall.items() if value is not None) or None
    links = {"resolved config": CONFIG_FILE, "metrics": METRICS_FILE}
    has_video = video and (run.root / VIDEO_FILE).is_file()
    if has_video:
        links["video"] = VIDEO_FILE
    write_report(run.root / REPORT_FILE, title=f"radar4dgs run {run.root.resolve()}",
                 metrics={k: metrics[k] for k in ("recon", "nvs", "nvs_exposure_aligned", "mask_source",
                                                  "lpips_available")},
                 per_frame=per_frame, history=loss_curves(history), panels=panels,
                 run_info=run_info, caveats=metrics["psnr_dyn_caveats"], links=links,
                 video=VIDEO_FILE if has_video else None,
                 config=_read_json(run.root / CONFIG_FILE).get("config"),
                 flagged=[split for split, flag in metrics["psnr_dyn_flagged"].items() if flag],
                 poses=_read_json(run.root / POSES_FILE) or None)


def log_tensorboard(run: Run, metrics: dict[str, Any], images: dict[str, np.ndarray]) -> None:
    """Add the evaluation to the run's TensorBoard log (``RUN/tb``, kept by training unless
    ``--no-tensorboard``) at the run's last iteration: ``val/<metric>`` of the test frames (as
    gsplat's ``val/psnr``, ...), ``recon/<metric>`` of the training frames, ``val/num_GS`` and
    ``images`` (ground truth | render). A failure is reported, never raised."""
    step = run.config.optim.iterations
    with TensorBoard(run.root / TB_DIR, log=lambda line: warnings.warn(line, stacklevel=2)) as tb:
        scalars = {f"{tag}/{key}": metrics[split].get(key) for split, tag in (("nvs", "val"), ("recon", "recon"))
                   for key in TB_METRICS}
        tb.scalars({**scalars, "val/num_GS": metrics["num_gaussians"]}, step)
        tb.images(images, step)


def _duration(seconds: float | None) -> str | None:
    if seconds is None:
        return None
    return f"{seconds:.1f} s" if seconds < 120 else f"{seconds / 60:.1f} min ({seconds:.0f} s)"


def _coverage_text(coverage: dict[str, float | None]) -> str:
    return ", ".join(f"{split} {value:.2%} of the pixels" for split, value in coverage.items() if value is not None)


def loss_curves(history: list[dict]) -> list[dict]:
    """The training log's loss terms and PSNR per logged step (densification events and
    bookkeeping such as the stage or the Gaussian count left out)."""
    keep = ("step", "psnr", "total", *LOSS_TERMS)
    return [{k: h[k] for k in keep if k in h} for h in history if "total" in h]


def format_metrics(metrics: dict[str, Any]) -> str:
    """A small table of the two splits."""
    def fmt(value, spec=".2f"):
        return "n/a" if value is None else format(value, spec)

    lines = [f"{'split':<7}{'frames':>7}{'PSNR':>8}{'SSIM':>8}{'LPIPS-vgg':>11}{'LPIPS-alex':>12}{'PSNR*':>8}"]
    for split in ("recon", "nvs"):
        m = metrics[split]
        lines.append(f"{split:<7}{m['n_frames']:>7}{fmt(m['psnr']):>8}{fmt(m['ssim'], '.4f'):>8}"
                     f"{fmt(m['lpips_vgg'], '.4f'):>11}{fmt(m['lpips_alex'], '.4f'):>12}{fmt(m['psnr_dyn']):>8}")
    exposure = metrics.get("nvs_exposure_aligned")
    if exposure and exposure.get("n_frames"):
        lines.append(f"nvs, exposure aligned (a colour transform fitted per test frame, cross-fitted halves): "
                     f"PSNR {fmt(exposure['psnr'])}, PSNR* {fmt(exposure['psnr_dyn'])}")
    coverage = metrics.get("mask_coverage") or {}
    covered = f" ({_coverage_text(coverage)})" if coverage else ""
    lines.append(f"PSNR* mask: {metrics['mask_source']}{covered}; "
                 f"LPIPS backbones present: {metrics['lpips_available']}")
    lines += [f"caveat: {caveat}" for caveat in metrics.get("psnr_dyn_caveats") or ()]
    return "\n".join(lines)
