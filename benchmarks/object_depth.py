"""Benchmark of the object-depth stage: the prepared depth of the moving objects before and after each
is rescaled by its own radar returns (:mod:`radar4dgs.depth.objects`), against the synthetic truth.

Each scene is generated (``small`` preset, the traffic and frame rate given) and prepared up to the
object-depth stage (radar, depth, masks, object_depth; no flow); the rows are
:func:`radar4dgs.evaluate.dynamic_depth.object_depth_metrics` (pooled over every frame's truly moving pixels)
plus the same on the movers nearer than 15 m, where a few per cent of depth is a visible error, and
the image-motion statistics of the scene's dynamic pixels.

    python benchmarks/object_depth.py --traffic rush --fps 5 --seeds 214 215 --work /tmp/od
    python benchmarks/object_depth.py --traffic realistic --seeds 101 102 103 --work /tmp/od
    python benchmarks/object_depth.py --traffic rush --fps 5 --seeds 217 --work W --figure docs/images/object_depth.png

Rows of (traffic, fps, seed) already in the results file are replaced, others kept.
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).parent))
from radar4dgs.apps.prepare import run_prepare  # noqa: E402
from radar4dgs.evaluate.dynamic_depth import object_depth_metrics  # noqa: E402
from radar4dgs.io.atomic import atomic_write_json  # noqa: E402
from radar4dgs.io.preview import dynamic_motion_statistics  # noqa: E402
from radar4dgs.io.scene import read_scene  # noqa: E402
from radar4dgs.io.scene_files import prepared_depth_path  # noqa: E402
from scene_configs import prepare_config, synth_config, synthesize_once  # noqa: E402

RESULTS = Path(__file__).parent / "results" / "object-depth.json"
NEAR = 15.0  # m: the close movers, a car or two lengths ahead


def error_figure(scene, prepared: Path, path: Path) -> None:
    """The frame with the most near moving pixels: its image, and the signed depth error on the true
    moving pixels before and after the stage (the picture on docs/pipeline/depth.md)."""
    from matplotlib.figure import Figure

    def near(index: int) -> np.ndarray:
        truth = scene.load_optional("gt/depth", index)
        return scene.load_optional("gt/dynamic_mask", index) & np.isfinite(truth) & (truth > 0) & (truth < NEAR)

    index = max(range(len(scene)), key=lambda i: int(near(i).sum()))
    name, truth, moving = scene.frames[index].name, scene.load_optional("gt/depth", index), near(index)
    panels = [("image", scene.load_image(index))]
    for title, file in (("depth stage", prepared / "depth" / f"{name}.npy"),
                        ("object-depth stage", prepared_depth_path(prepared, name))):
        error = np.full(truth.shape, np.nan)
        error[moving] = (np.load(file)[moving] / truth[moving] - 1.0) * 100.0
        panels.append((f"{title}: movers < 15 m, median {np.nanmedian(error):+.1f} %", error))
    fig = Figure(figsize=(11.0, 2.6), dpi=100, layout="constrained")
    for ax, (title, data) in zip(fig.subplots(1, 3), panels, strict=True):
        if data.ndim == 3:
            ax.imshow(data)
        else:
            shown = ax.imshow(data, cmap="RdBu_r", vmin=-8, vmax=8)
        ax.set_title(title, fontsize="small")
        ax.set_axis_off()
    fig.colorbar(shown, ax=fig.axes, label="error (%), red: too deep", shrink=0.9)
    fig.suptitle(f"{scene.root.parent.name}, frame {name}", fontsize="small")
    path.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(path, metadata={"Software": None})


def near_errors(scene, prepared: Path) -> dict:
    """:func:`object_depth_metrics` on the true moving pixels nearer than NEAR, keys ``near_*``."""
    near = object_depth_metrics(scene, prepared, max_depth=NEAR)
    return {"near_pixels": near["mover_pixels"], "near_absrel_before": near["mover_absrel_before"],
            "near_absrel_after": near["mover_absrel_after"], "near_bias_before": near["mover_bias_before"],
            "near_bias_after": near["mover_bias_after"]}


def scene_row(seed: int, traffic: str, fps: float | None, work: Path) -> dict:
    root = work / f"{traffic}-{fps or 'default'}-seed{seed}"
    scene_dir, prepared = root / "scene", root / "prepared"
    synthesize_once(synth_config("small", seed, traffic, fps), scene_dir, "small")
    run_prepare(scene_dir, prepared, prepare_config("small"), only=("radar", "depth", "masks", "object_depth"),
                progress=False)
    scene = read_scene(scene_dir)
    return {"seed": seed, "traffic": traffic, "fps": fps, **object_depth_metrics(scene, prepared),
            **near_errors(scene, prepared), "image_motion_px": dynamic_motion_statistics(scene)}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--seeds", type=int, nargs="+", required=True)
    parser.add_argument("--traffic", default="calm")
    parser.add_argument("--fps", type=float, default=None)
    parser.add_argument("--work", type=Path, required=True)
    parser.add_argument("--out", type=Path, default=RESULTS)
    parser.add_argument("--figure", type=Path, default=None, help="write the error picture of the first seed here")
    args = parser.parse_args()
    old = json.loads(args.out.read_text())["rows"] if args.out.is_file() else []
    rows = []
    print(f"{'scene':<22}{'movers |err| before -> after':>30}{'bias before -> after':>24}"
          f"{'< 15 m |err| before -> after':>30}{'rescaled':>10}  image motion p50/p90/p99 px")
    for seed in args.seeds:
        row = scene_row(seed, args.traffic, args.fps, args.work)
        rows.append(row)
        motion = row["image_motion_px"] or {}
        near = (f"{row['near_absrel_before']:.4f} -> {row['near_absrel_after']:.4f}" if row["near_pixels"]
                else "no near movers")
        print(f"{args.traffic + ' ' + str(args.fps or '') + ' ' + str(seed):<22}"
              f"{row['mover_absrel_before']:>19.4f} -> {row['mover_absrel_after']:.4f}"
              f"{row['mover_bias_before']:>+15.4f} -> {row['mover_bias_after']:+.4f}{near:>30}"
              f"{row['rescaled']:>6}/{row['objects']:<4}"
              f"  {motion.get('p50')} / {motion.get('p90')} / {motion.get('p99')}", flush=True)
    if args.figure is not None:
        root = args.work / f"{args.traffic}-{args.fps or 'default'}-seed{args.seeds[0]}"
        error_figure(read_scene(root / "scene"), root / "prepared", args.figure)
    keys = {(r["traffic"], r["fps"], r["seed"]) for r in rows}
    kept = [r for r in old if (r["traffic"], r["fps"], r["seed"]) not in keys]
    args.out.parent.mkdir(parents=True, exist_ok=True)
    atomic_write_json(args.out, {"near_m": NEAR, "rows": kept + rows})


if __name__ == "__main__":
    main()
