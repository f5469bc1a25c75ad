"""Benchmark of reconstruction under realistic traffic (issue 21): the bench grid (ours, ours without
radar, PVG, bspline, ...) on calm, realistic or rush-traffic scenes, with every cell's dynamic-pixel
PSNR split by how far the pixels move in the image, beside each scene's image-motion statistics.

    python benchmarks/traffic.py --seeds 201 --traffic calm|realistic|rush [--fps 10]
                                 [--supersample 2] [--size 640x360]
                                 [--methods ours ours-no-radar pvg bspline] [--iterations 600] [--jobs 2]
                                 [--work /tmp/radar4dgs-traffic-bench]
                                 [--out benchmarks/results/traffic-rush.json] [--set KEY=VALUE ...]

Seeds are those of benchmarks/motion.py, fixed before any tuning: calm (the demo's traffic) 1-5 tune;
realistic 10 Hz 101-105 tune, 106-110 report; realistic 5 Hz 111-112 report; rush 10 Hz 201-203 tune,
204-208 report; rush 5 Hz (the hard set) 209-213 report, 214-243 tune; rush 5 Hz at 640x360 with p90 >= 40 px a
frame (the strict hard set, picked by benchmarks/hard_seeds.py) 306/309/313/322/326 report (from 300 on),
404/406/409/411/412 tune (from 400 on).
The grid budget is the bench's (600 iterations, init.max_static=30000, densify.max_gaussians=40000,
no LPIPS) unless --iterations / --set say otherwise. Cells are `radar4dgs bench` cells under
--work (finished ones are reused, so an interrupted run continues). Writes the JSON after every
seed: per scene its image motion (p50/p90/p99 px per frame at its width), per cell recon / novel-view
PSNR, PSNR* and PSNR per image-motion bin; per scene the margins the issue asks for (ours minus the
best of bspline / PVG, ours minus ours-no-radar, novel-view PSNR*).
"""

from __future__ import annotations

import argparse
import json
import math
import subprocess
import sys
from pathlib import Path

from radar4dgs.io.atomic import atomic_write_json
from scene_configs import parse_size, prepare_config, scene_label, synth_config, synthesize_once

GRID_SETTINGS = ["init.max_static=30000", "densify.max_gaussians=40000"]
RESULTS = Path(__file__).parent / "results"


def prepare_scene(seed: int, traffic: str, fps: float | None, preset_name: str, work: Path,
                  prepare_set: list[str] = (), supersample: int = 1,
                  size: tuple[int, int] | None = None) -> tuple[Path, dict]:
    """Synthesize (traffic profile, fps, image size) and prepare one scene into work/scenes/<label>/
    (PrepareConfig fields overridden by dotted ``prepare_set`` items); reused."""
    from radar4dgs.apps.prepare import run_prepare
    from radar4dgs.io.preview import dynamic_motion_statistics
    from radar4dgs.io.scene import read_scene

    scene = work / "scenes" / scene_label(traffic, seed, fps, supersample, size)
    synthesize_once(synth_config(preset_name, seed, traffic, fps, supersample, size), scene, preset_name)
    run_prepare(scene, scene / "prepared", prepare_config(preset_name, prepare_set), progress=False, wait=math.inf)
    return scene, dynamic_motion_statistics(read_scene(scene))


def cell_summary(run: Path) -> dict:
    """The run's metrics that the table compares, and its PSNR per image-motion bin."""
    from radar4dgs.evaluate.motion_bins import run_psnr_by_image_motion

    metrics = json.loads((run / "metrics.json").read_text())
    summary = {f"{split}_{key}": metrics[split].get(key) for split in ("recon", "nvs") for key in ("psnr", "psnr_dyn")}
    summary["psnr_by_image_motion"] = run_psnr_by_image_motion(run)
    return summary


def margins(cells: dict[str, dict]) -> dict:
    """Novel-view PSNR* margins of ours over the best of bspline / PVG and over ours without radar."""
    def nvs_dyn(method: str) -> float | None:
        return cells.get(method, {}).get("nvs_psnr_dyn")

    out: dict = {"ours_nvs_psnr_dyn": nvs_dyn("ours")}
    baselines = [v for m in ("bspline", "pvg") if (v := nvs_dyn(m)) is not None]
    if nvs_dyn("ours") is not None and baselines:
        out["ours_minus_best_baseline"] = nvs_dyn("ours") - max(baselines)
    if nvs_dyn("ours") is not None and nvs_dyn("ours-no-radar") is not None:
        out["radar_gain"] = nvs_dyn("ours") - nvs_dyn("ours-no-radar")
    return out


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--seeds", type=int, nargs="+", required=True)
    parser.add_argument("--traffic", choices=("calm", "realistic", "rush"), default="rush")
    parser.add_argument("--fps", type=float, default=None, help="frame rate of the scenes (default: the preset's)")
    parser.add_argument("--supersample", type=int, default=1,
                        help="rays a pixel along each axis in the synthesized images (default 1, the pixel centre)")
    parser.add_argument("--size", type=parse_size, default=None,
                        help="image size WxH of the synthesized scenes (default: the preset's; 640x360 is the "
                             "independent scenes' size)")
    parser.add_argument("--preset", default="small")
    parser.add_argument("--methods", nargs="+", default=["ours", "ours-no-radar", "pvg", "bspline"])
    parser.add_argument("--iterations", type=int, default=600)
    parser.add_argument("--jobs", type=int, default=2)
    parser.add_argument("--set", nargs="*", default=[], help="extra TrainConfig fields of every cell (KEY=VALUE)")
    parser.add_argument("--prepare-set", nargs="*", default=[],
                        help="PrepareConfig fields of every scene, dotted KEY=VALUE (masks.completion.enabled=true)")
    parser.add_argument("--work", type=Path, default=Path("/tmp/radar4dgs-traffic-bench"))
    parser.add_argument("--grid", default="grid", help="the grid's folder under --work (one per --set variant; "
                                                        "the scenes under --work/scenes are shared)")
    parser.add_argument("--out", type=Path, default=None)
    args = parser.parse_args()
    out = args.out or RESULTS / f"traffic-{args.traffic}.json"
    settings = GRID_SETTINGS + list(args.set)
    report = {"command": " ".join(["python", "benchmarks/traffic.py"] + sys.argv[1:]),
              "grid": {"preset": args.preset, "iterations": args.iterations, "set": settings, "methods": args.methods,
                       "prepare_set": args.prepare_set},
              "scenes": {}}
    for seed in args.seeds:
        scene, motion = prepare_scene(seed, args.traffic, args.fps, args.preset, args.work, args.prepare_set,
                                      args.supersample, args.size)
        grid = args.work / args.grid
        subprocess.run([sys.executable, "-m", "radar4dgs.cli", "bench", "--scenes", str(scene), "--methods",
                        *args.methods, "--out", str(grid), "--preset", args.preset, "--iterations",
                        str(args.iterations), "--jobs", str(args.jobs), "--no-lpips", "--quiet",
                        "--set", *settings], check=True)
        cells = {method: cell_summary(grid / "runs" / scene.name / method) for method in args.methods}
        report["scenes"][scene.name] = {"seed": seed, "image_motion_px": motion, "cells": cells,
                                        "margins": margins(cells)}
        atomic_write_json(out, report)
        summarize(scene.name, report["scenes"][scene.name])
    print(f"wrote {out}")


def summarize(label: str, entry: dict) -> None:
    motion = entry["image_motion_px"] or {}
    print(f"\n{label}: dynamic pixels move p50 {motion.get('p50')} / p90 {motion.get('p90')} / "
          f"p99 {motion.get('p99')} px per frame")
    for method, cell in entry["cells"].items():
        bins = " ".join(f"{'-' if r['psnr'] is None else format(r['psnr'], '.1f')}"
                        for r in cell["psnr_by_image_motion"]["nvs"])
        print(f"  {method:16s} recon {cell.get('recon_psnr', 0):6.2f}  nvs {cell.get('nvs_psnr', 0):6.2f}  "
              f"nvs PSNR* {cell.get('nvs_psnr_dyn') or float('nan'):6.2f}  nvs PSNR by motion bin: {bins}")
    print(f"  margins: {entry['margins']}")


if __name__ == "__main__":
    main()
