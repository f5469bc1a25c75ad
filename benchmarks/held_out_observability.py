"""How much of a trained run's novel-view PSNR* is lost on movers the training frames never saw close.

For each held-out frame of each run (synthetic scenes, with ``gt/``), the share of its moving pixels that neither
adjacent training frame showed at even half their size (:mod:`radar4dgs.evaluate.observability`), its prepared-mask
recall and its PSNR*, rendered again with the held-out window ``--window`` (the run's own when omitted). Per run:
PSNR* over every frame (what ``radar4dgs eval`` reports), over the frames seen close (``nvs_seen``), over those whose
prepared masks also find at least ``--recall`` of the moving pixels, and over the frames left out.
``--figure`` draws the run's worst unseen frame: the training frame before, the held-out truth with the unseen
pixels outlined, and the render.

    python benchmarks/held_out_observability.py RUN [RUN ...] [--window 0.5] [--recall 0.9] [--figure PNG] [--out JSON]
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path

import numpy as np
import torch
from scipy import ndimage

from radar4dgs.evaluate.observability import UNSEEN_FRAME_SHARE, UNSEEN_RATIO, closest_seen, seen_summary, unseen_share
from radar4dgs.io.atomic import atomic_write_json
from radar4dgs.io.preview import save_png
from radar4dgs.io.scene import normalized_times
from radar4dgs.metrics.image import psnr
from radar4dgs.model.run import load_run
from radar4dgs.model.view import frame_view


def mean_or_none(values: list[float]) -> float | None:
    return float(np.mean(values)) if values else None


@torch.no_grad()
def run_frames(run_dir: Path, window: float | None) -> tuple[list[dict], dict]:
    """Per held-out frame with moving pixels: ``frame``, ``psnr_dyn``, ``pixels``, ``unseen_close_share``,
    ``mask_recall``; and the renders, truths and unseen masks by frame (for the figure)."""
    run = load_run(run_dir, device="cpu")
    scene, times = run.scene, normalized_times(run.scene)
    if window is not None:
        run.model.window_fraction = window
    hits = {f["index"]: f.get("trained_mask_hits") for f in
            json.loads((run_dir / "metrics.json").read_text())["per_frame"]["nvs"]}
    rows, pictures = [], {}
    for index in scene.test_indices:
        ratio = closest_seen(scene, index, scene.train_indices)
        moving = ~np.isnan(ratio)
        if not moving.any():
            continue
        truth = torch.as_tensor(scene.load_image(index).astype(np.float32) / 255.0)
        rgb = run.model.render(frame_view(scene, index, 1.0, times), run.config.raster)["rgb"].clamp(0, 1)
        rows.append({"frame": int(index), "psnr_dyn": psnr(rgb, truth, torch.as_tensor(moving)),
                     "pixels": int(moving.sum()), "unseen_close_share": unseen_share(ratio),
                     "mask_recall": None if hits.get(index) is None else hits[index] / int(moving.sum())})
        pictures[index] = (rgb.numpy(), moving & (ratio > UNSEEN_RATIO))
    return rows, {"scene": scene, "pictures": pictures}


def summary(rows: list[dict], recall: float) -> dict:
    seen = seen_summary(rows) or {"psnr_dyn": None, "n_frames": 0, "unseen_frames": []}
    unseen = set(seen["unseen_frames"])
    found = [r for r in rows
             if r["frame"] not in unseen and r["mask_recall"] is not None and r["mask_recall"] >= recall]
    return {"psnr_dyn": mean_or_none([r["psnr_dyn"] for r in rows]), "n_frames": len(rows),
            "seen": {"psnr_dyn": seen["psnr_dyn"], "n_frames": seen["n_frames"]},
            "seen_and_found": {"psnr_dyn": mean_or_none([r["psnr_dyn"] for r in found]), "n_frames": len(found)},
            "unseen": {"psnr_dyn": mean_or_none([r["psnr_dyn"] for r in rows if r["frame"] in unseen]),
                       "frames": [r["frame"] for r in rows if r["frame"] in unseen]}}


def figure(rows: list[dict], extra: dict, path: Path) -> int | None:
    """Training frame before | held-out truth, unseen pixels outlined in red | render, for the frame with the
    largest unseen share; returns its index (None when no frame is unseen)."""
    worst = max(rows, key=lambda r: r["unseen_close_share"], default=None)
    if worst is None or worst["unseen_close_share"] < UNSEEN_FRAME_SHARE:
        return None
    scene, index = extra["scene"], worst["frame"]
    render, unseen = extra["pictures"][index]
    truth = scene.load_image(index).copy()
    outline = unseen & ~ndimage.binary_erosion(unseen, iterations=2)
    truth[outline] = (255, 0, 0)
    panels = [scene.load_image(index - 1), truth, (render * 255 + 0.5).astype(np.uint8)]
    save_png(path, np.concatenate(panels, axis=1))
    return index


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("runs", type=Path, nargs="+")
    parser.add_argument("--window", type=float, default=None, help="held-out window (default: the run's)")
    parser.add_argument("--recall", type=float, default=0.9, help="mask recall for seen_and_found")
    parser.add_argument("--figure", type=Path, default=None, help="picture of the first run's worst unseen frame")
    parser.add_argument("--out", type=Path, default=Path("benchmarks/results/held-out-observability.json"))
    args = parser.parse_args()
    results = {}
    for k, run in enumerate(args.runs):
        rows, extra = run_frames(run, args.window)
        results[str(run)] = {"summary": summary(rows, args.recall), "frames": rows}
        if args.figure is not None and k == 0:
            results[str(run)]["figure_frame"] = figure(rows, extra, args.figure)
        s = results[str(run)]["summary"]
        fmt = lambda v: "n/a" if v is None else f"{v:.2f}"  # noqa: E731
        print(f"{run}: PSNR* {fmt(s['psnr_dyn'])} ({s['n_frames']} frames); seen close {fmt(s['seen']['psnr_dyn'])} "
              f"({s['seen']['n_frames']}); and masks found {fmt(s['seen_and_found']['psnr_dyn'])} "
              f"({s['seen_and_found']['n_frames']}); unseen {fmt(s['unseen']['psnr_dyn'])} {s['unseen']['frames']}",
              flush=True)
        # Written after every run, so a run that fails to load keeps the ones before it.
        atomic_write_json(args.out, {
            "command": "python benchmarks/held_out_observability.py " + " ".join(str(r) for r in args.runs)
                       + ("" if args.window is None else f" --window {args.window:g}") + f" --recall {args.recall:g}",
            "unseen_ratio": UNSEEN_RATIO, "unseen_frame_share": UNSEEN_FRAME_SHARE, "runs": results,
            "mean": {"all": mean_or_none([r["summary"]["psnr_dyn"] for r in results.values()
                                          if r["summary"]["psnr_dyn"] is not None]),
                     **{key: mean_or_none([r["summary"][key]["psnr_dyn"] for r in results.values()
                                           if r["summary"][key]["psnr_dyn"] is not None])
                        for key in ("seen", "seen_and_found")}}})


if __name__ == "__main__":
    main()
