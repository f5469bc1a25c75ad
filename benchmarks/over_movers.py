"""What the static Gaussians draw over the moving objects of trained runs, against the synthetic scene's truth.

For every frame (training views: ``recon``, held-out: ``nvs``), on the true moving pixels inside the prepared
mask, the share of the composite's blend weight drawn by static Gaussians where the dynamic layer rendered alone
is opaque (alpha >= 0.9; there the static weight can only come from Gaussians sorted in front of the car), split
by the pixel's place in its object (top, middle and bottom third of its rows), and the squared error each
category carries. Then an oracle bound, no training: each frame rendered again without the static Gaussians
whose 2-D footprint (centre and +-1 sigma) lies on true moving pixels from more than ``--margin`` (relative) in
front of the true depth there (what ``losses.over_movers_weight`` penalises in training, with the prepared
mask and depth), and its PSNR* and PSNR. With ``--in-front B ...``, also every frame's PSNR* and PSNR rendered
with the dynamic layer drawn ahead of static Gaussians up to B of its depth nearer (as ``render_in_front`` B
would draw the finished model), with no retraining.

    python benchmarks/over_movers.py RUN [RUN ...] [--margin 0.05] [--in-front 0.1 0.2] [--out JSON]
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path

import numpy as np
import torch
from scipy import ndimage

from radar4dgs.io.atomic import atomic_write_json
from radar4dgs.io.scene import normalized_times
from radar4dgs.io.scene_files import read_mask_png
from radar4dgs.metrics.image import psnr, summarize_frames
from radar4dgs.metrics.losses import movers_covered
from radar4dgs.model.run import load_run
from radar4dgs.model.view import frame_view

THIRDS = ("top", "middle", "bottom")


def row_thirds(moving: np.ndarray) -> np.ndarray:
    """(H, W) int: 0 / 1 / 2 for the top / middle / bottom third of the rows of each pixel's connected
    moving object (-1 off the objects)."""
    labels, _ = ndimage.label(moving)
    thirds = np.full(moving.shape, -1)
    rows = np.arange(moving.shape[0])[:, None].repeat(moving.shape[1], 1)
    for k, box in enumerate(ndimage.find_objects(labels), 1):
        inside = labels[box] == k
        span = max(box[0].stop - 1 - box[0].start, 1)
        thirds[box][inside] = np.minimum((rows[box] - box[0].start) * 3 // (span + 1), 2)[inside]
    return thirds


def counted_by_the_term(meta: dict, n_static: int, moving: np.ndarray, depth: np.ndarray, margin: float) -> np.ndarray:
    """(n_static,) bool: the static Gaussians ``losses.over_movers_weight`` counts on ``moving`` (H, W) bool at
    ``depth`` (H, W) m: those that cover some of it."""
    means2d, radii, depths = meta["means2d"][0, :n_static], meta["radii"][0, :n_static], meta["depths"][0, :n_static]
    covered = movers_covered(means2d, radii, depths, torch.as_tensor(moving),
                             torch.as_tensor(depth, dtype=means2d.dtype), margin)
    return (covered > 0).numpy()


@torch.no_grad()
def frame_scores(run, index: int, times: np.ndarray, margin: float) -> dict:
    """One frame's pixel categories (counts and summed squared error) and its oracle rescoring."""
    scene = run.scene
    height, width = scene.camera.height, scene.camera.width
    view = frame_view(scene, index, 1.0, times)
    full = run.model.render(view, run.config.raster)
    dynamic_alone = run.model.render(view, run.config.raster, include_static=False)["alpha"].numpy()
    moving = scene.load_optional("gt/dynamic_mask", index) > 0
    prepared = read_mask_png(run.prepared / "masks" / f"{scene.frames[index].name}.png", (height, width))
    truth = torch.as_tensor(scene.load_image(index).astype(np.float32) / 255.0)
    rgb = full["rgb"].clamp(0, 1)
    error = ((rgb - truth) ** 2).mean(-1).numpy()
    static_weight = 1.0 - full["dynamic"].numpy()
    pixels = moving & prepared
    covered = pixels & (static_weight > 0.1) & (dynamic_alone >= 0.9)
    thirds = row_thirds(moving)
    out: dict = {"moving": {"pixels": int(moving.sum()), "error": float(error[moving].sum())}}
    for k, name in enumerate(THIRDS):
        part = pixels & (thirds == k)
        out[name] = {"pixels": int(part.sum()), "static_weight": float(static_weight[part].sum()),
                     "covered": int((covered & part).sum()), "covered_error": float(error[covered & part].sum())}
    static = run.model.static.params["opacity_logits"]
    saved = static.data.clone()
    drop = counted_by_the_term(full["meta"], full["n_static"], moving,
                               scene.load_optional("gt/depth", index).astype(np.float64), margin)
    static.data[torch.as_tensor(drop)] = -30.0
    dropped = run.model.render(view, run.config.raster)["rgb"].clamp(0, 1)
    static.data.copy_(saved)
    mask = torch.as_tensor(moving)
    out["oracle"] = {"dropped": int(drop.sum()), "psnr_dyn": [psnr(rgb, truth, mask), psnr(dropped, truth, mask)],
                     "psnr": [psnr(rgb, truth), psnr(dropped, truth)]}
    return out


@torch.no_grad()
def scores_in_front(run, fraction: float) -> dict:
    """Mean PSNR* and PSNR per split (as the evaluation averages them) with the run's model drawn at
    ``dynamic_in_front`` = ``fraction``."""
    scene, times = run.scene, normalized_times(run.scene)
    test = set(scene.test_indices)
    kept, run.model.dynamic_in_front = run.model.dynamic_in_front, fraction
    frames: dict = {"recon": [], "nvs": []}
    for index in range(len(scene)):
        rgb = run.model.render(frame_view(scene, index, 1.0, times), run.config.raster)["rgb"].clamp(0, 1)
        truth = torch.as_tensor(scene.load_image(index).astype(np.float32) / 255.0)
        moving = torch.as_tensor(scene.load_optional("gt/dynamic_mask", index) > 0)
        frames["nvs" if index in test else "recon"].append(
            {"psnr": psnr(rgb, truth), "psnr_dyn": psnr(rgb, truth, moving) if bool(moving.any()) else None})
    run.model.dynamic_in_front = kept
    return {split: {key: summarize_frames(rows)[key] for key in ("psnr_dyn", "psnr")} for split, rows in frames.items()}


def run_summary(run_dir: Path, margin: float, in_front: list[float]) -> dict:
    """Per split: each third's share of the moving pixels, its mean static weight, the share of its pixels
    covered (static weight > 0.1 over an opaque dynamic layer) and their share of the split's squared error on
    the moving pixels; the oracle's mean PSNR* and PSNR before and after."""
    run = load_run(run_dir, device="cpu")
    scene, times = run.scene, normalized_times(run.scene)
    test = set(scene.test_indices)
    frames = {"recon": [], "nvs": []}
    for index in range(len(scene)):
        if (scene.load_optional("gt/dynamic_mask", index) > 0).any():
            frames["nvs" if index in test else "recon"].append(frame_scores(run, index, times, margin))
    summary = {}
    for split, rows in frames.items():
        total = sum(r["moving"]["error"] for r in rows)
        pixels = sum(sum(r[t]["pixels"] for t in THIRDS) for r in rows)
        split_summary = {}
        for name in THIRDS:
            n = sum(r[name]["pixels"] for r in rows)
            split_summary[name] = {"pixel_share": n / pixels,
                                   "static_weight": sum(r[name]["static_weight"] for r in rows) / n,
                                   "covered_share": sum(r[name]["covered"] for r in rows) / n,
                                   "covered_error_share": sum(r[name]["covered_error"] for r in rows) / total}
        for key in ("psnr_dyn", "psnr"):
            split_summary[f"oracle_{key}"] = [float(np.mean([r["oracle"][key][k] for r in rows])) for k in (0, 1)]
        split_summary["oracle_dropped_per_frame"] = float(np.mean([r["oracle"]["dropped"] for r in rows]))
        summary[split] = split_summary
    summary["in_front"] = {str(b): scores_in_front(run, b) for b in [run.model.dynamic_in_front, *in_front]}
    return summary


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("runs", type=Path, nargs="+")
    parser.add_argument("--margin", type=float, default=0.05)
    parser.add_argument("--in-front", type=float, nargs="*", default=[])
    parser.add_argument("--out", type=Path, default=Path("benchmarks/results/over-movers.json"))
    args = parser.parse_args()
    torch.set_num_threads(1)
    rows = json.loads(args.out.read_text())["rows"] if args.out.is_file() else []
    for run in args.runs:
        row = {"run": str(run.resolve()), "margin": args.margin, **run_summary(run, args.margin, args.in_front)}
        rows = [r for r in rows if (r["run"], r["margin"]) != (row["run"], row["margin"])] + [row]
        for split in ("recon", "nvs"):
            s = row[split]
            thirds = "  ".join(f"{t} weight {s[t]['static_weight']:.3f} covered {s[t]['covered_share']:.2f}"
                               for t in THIRDS)
            oracle = (f"oracle PSNR* {s['oracle_psnr_dyn'][0]:.2f} -> {s['oracle_psnr_dyn'][1]:.2f}  "
                      f"PSNR {s['oracle_psnr'][0]:.2f} -> {s['oracle_psnr'][1]:.2f}")
            print(f"{run} {split}: {thirds}  {oracle}", flush=True)
        for b, s in row["in_front"].items():
            print(f"{run} dynamic_in_front {b}: " + "  ".join(
                f"{split} PSNR* {s[split]['psnr_dyn']:.2f} PSNR {s[split]['psnr']:.2f}" for split in s), flush=True)
    atomic_write_json(args.out, {"description": __doc__.split("\n\n")[0],
                                 "command": "python benchmarks/over_movers.py RUN ...", "rows": rows})


if __name__ == "__main__":
    main()
