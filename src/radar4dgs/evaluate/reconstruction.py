"""``radar4dgs eval RUN``: deterministic evaluation of a trained run (DESIGN.md stage 8).

It reloads the run's saved config (``RUN/config.json``, ``RUN/run.json``) and model
(``RUN/model.pt``), renders every frame at the scene's full resolution with no dropout and no
gradient (never through the training loop), and writes:

- ``RUN/metrics.json``: ``{"recon": {...}, "nvs": {...}, "mask_source": ..., "lpips_available": ...,
  "per_frame": {"recon": [...], "nvs": [...]}}``; each split holds ``psnr``, ``ssim``,
  ``lpips_vgg``, ``lpips_alex`` (null without backbone weights), ``psnr_dyn`` (PSNR* over the
  dynamic-mask pixels, averaged over frames whose mask is not empty) and ``n_frames``.
  Reconstruction = training frames, novel-view synthesis (nvs) = test frames (every 4th).
- ``RUN/renders/{recon,nvs}/<frame>.png`` and ``<frame>_depth.png``, ``<frame>_dynamic.png``.
- ``RUN/video.mp4``: ground truth | render | depth | dynamic mask, every frame in time order.
- ``RUN/report.html``: metrics, per-frame PSNR, loss curves and test-frame panels (one file).
"""

from __future__ import annotations

import contextlib
import json
import time
import warnings
from pathlib import Path
from typing import Any

import numpy as np
import torch

from radar4dgs.io.atomic import atomic_directory, atomic_write_json
from radar4dgs.io.preview import doppler_colors, draw_radar_overlay, radar_points_in_camera, save_png
from radar4dgs.io.scene import SceneWarning, normalized_times, read_mask_png
from radar4dgs.metrics.image import LpipsScorer, lpips_or_none, psnr, ssim, summarize_frames
from radar4dgs.model.run import HISTORY_FILE, LOSS_TERMS, Run, load_run
from radar4dgs.model.view import View, frame_view

METRICS_FILE = "metrics.json"
RENDERS_DIR = "renders"
VIDEO_FILE = "video.mp4"
REPORT_FILE = "report.html"
# One colour scale for every depth picture of a run, so the video does not flicker (metres).
DEPTH_NEAR, DEPTH_FAR = 2.0, 120.0


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


def radar_overlay(scene, index: int, image: np.ndarray) -> np.ndarray:
    """``image`` with frame ``index``'s radar points drawn, coloured by raw v_r."""
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
    frames_video, panels = [], []
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
            out = render_view(run, frame_view(scene, index, 1.0, times))
            device_ = out["rgb"].device
            gt = torch.as_tensor(scene.load_image(index).astype(np.float32) / 255.0, device=device_)
            mask = dynamic_mask(run, index, source)
            mask_t = torch.as_tensor(mask, device=device_)
            rgb = out["rgb"].clamp(0, 1)
            entry = {"frame": name, "index": index, "psnr": psnr(rgb, gt), "ssim": ssim(rgb, gt),
                     "psnr_dyn": psnr(rgb, gt, mask_t) if mask.any() else None,
                     "dynamic_pixels": int(mask.sum())}
            for net, scorer in scorers.items():
                entry[f"lpips_{net}"] = scorer(rgb, gt) if scorer is not None else None
            per_frame[split].append(entry)
            render_u8, gt_u8 = to_uint8(rgb), scene.load_image(index)
            depth_u8 = depth_to_rgb(np.where(out["alpha"].cpu().numpy() > 0.05, out["depth"].cpu().numpy(), np.nan),
                                    near=DEPTH_NEAR, far=DEPTH_FAR)
            dyn_u8 = mask_to_rgb(out["dynamic"].cpu().numpy() > 0.5)
            save_png(folders[split] / f"{name}.png", render_u8)
            save_png(folders[split] / f"{name}_depth.png", depth_u8)
            save_png(folders[split] / f"{name}_dynamic.png", dyn_u8)
            if video:
                frames_video.append(side_by_side([gt_u8, render_u8, depth_u8, dyn_u8],
                                                 ["ground truth", f"render ({split})", "depth", "dynamic"]))
            if split == "nvs" and report:
                panels.append({"name": f"{name} (test frame)", "gt": gt_u8, "render": render_u8,
                               "error": error_to_rgb(render_u8, gt_u8), "depth": depth_u8,
                               "dynamic mask": dyn_u8, "radar": radar_overlay(scene, index, gt_u8),
                               "psnr": f"{entry['psnr']:.2f} dB"})
    metrics: dict[str, Any] = {
        "recon": summarize_frames(per_frame["recon"]), "nvs": summarize_frames(per_frame["nvs"]),
        "mask_source": source,
        "lpips_available": all(s is not None for s in scorers.values()),
        "method": run.config.method, "num_gaussians": run.model.num_gaussians,
        "per_frame": per_frame,
    }
    if video and frames_video:
        from radar4dgs.evaluate.video import write_video

        write_video(frames_video, run.root / VIDEO_FILE, fps=10)
    metrics["eval_seconds"] = time.perf_counter() - started
    atomic_write_json(run.root / METRICS_FILE, metrics)
    if report:
        from radar4dgs.evaluate.report import write_report

        history_path = run.root / HISTORY_FILE
        history = json.loads(history_path.read_text())["history"] if history_path.is_file() else []
        write_report(run.root / REPORT_FILE, title=f"radar4dgs run {run.root.resolve()}",
                     metrics={k: metrics[k] for k in ("recon", "nvs", "mask_source", "lpips_available")},
                     per_frame=per_frame, history=loss_curves(history), panels=panels)
    return metrics


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
    lines.append(f"PSNR* mask: {metrics['mask_source']}; LPIPS backbones present: {metrics['lpips_available']}")
    return "\n".join(lines)
