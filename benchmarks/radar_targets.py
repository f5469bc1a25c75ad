"""How wrong are the radar term's targets? (issue 21). ``L_rad`` gives each sampled dynamic-mask pixel
of a training frame the compensated radial velocity of its nearest dynamic radar return within the
association gate (``losses.radar_gate``). This scores those targets against the generator's truth,
for one or more gates, on prepared scenes (no training):

    python benchmarks/radar_targets.py [--seeds 214 215 216 217 218 219] [--traffic rush] [--fps 5 (0: the preset's)]
        [--gates 2.0 1.0] [--work W] [--scenes DIR ...] [--out JSON]

For each sample, the residual a perfect field would leave, ``|true displacement . d - v_r dt|`` (m over
the frame pair, d the unit direction radar -> sample point; :func:`radar_residual`), is split by the
generator's image motion of the pixel (bins of :data:`IMAGE_MOTION_EDGES` at 320 px), by ``static``
(the mask marks a pixel that does not move: spill onto the road or a parked car) and ``unknown`` (no
true correspondence in the next frame). Scenes are made and prepared as ``benchmarks/reconstruct.py``
makes them (``W/seed<N>/{scene, prepared}``), or taken as they are with ``--scenes`` (each a scene
folder with its ``prepared/``). The evaluation-only truth (``gt/``) scores the targets; it is never a
method. Default seeds: the hard tuning seeds.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np
import torch

from radar4dgs.evaluate.motion_bins import motion_bin_index
from radar4dgs.io.atomic import atomic_write_json
from radar4dgs.io.image_motion import dynamic_pixel_motion_map, image_motion_edges
from radar4dgs.io.preview import dynamic_motion_statistics
from radar4dgs.io.scene import read_scene
from radar4dgs.metrics.losses import radar_residual
from radar4dgs.model.config import TrainConfig
from radar4dgs.motion.association import associate_velocities, load_radar_dynamics
from radar4dgs.motion.flow import frame_pairs, load_depth, load_mask
from radar4dgs.motion.lift import backproject
from radar4dgs.motion.truth import gt_scene_flow
from radar4dgs.train.fit_motion import dynamic_pixels

RESULTS = Path(__file__).parent / "results" / "radar-targets.json"
BIN_NAMES = ("static", "< 2 px", "2-10 px", "10-30 px", "> 30 px", "unknown")


def pixel_bins(scene, index: int, rows: np.ndarray, cols: np.ndarray) -> np.ndarray:
    """(M,) bin index into :data:`BIN_NAMES` of each sampled pixel of frame ``index``."""
    moving = scene.load_optional("gt/dynamic_mask", index)[rows, cols]
    motion = dynamic_pixel_motion_map(scene, index)[rows, cols]
    edges = image_motion_edges(scene.camera.width)
    by_motion = 1 + motion_bin_index(np.nan_to_num(motion, nan=0.0), edges)
    return np.where(~moving, 0, np.where(np.isfinite(motion), by_motion, len(BIN_NAMES) - 1))


def frame_residuals(scene, prepared: Path, i: int, j: int, gates: list[float], limit: int,
                    rng: np.random.Generator) -> tuple[np.ndarray, dict[float, np.ndarray]]:
    """(M,) bin of each sampled pixel of frame ``i`` and, per gate, (M,) residual in metres (NaN where
    the gate leaves the pixel unmatched or its truth is unknown)."""
    depth = load_depth(scene, i, "prepared", prepared)
    rows, cols = dynamic_pixels(depth, load_mask(scene, i, "prepared", prepared), limit, rng)
    points = backproject(np.stack([cols, rows], axis=1).astype(np.float64), depth[rows, cols], scene.camera.K,
                         scene.world_to_camera(i))
    world_i, world_j, valid = gt_scene_flow(scene, i, j)
    truth = np.where(valid[rows, cols, None], (world_j - world_i)[rows, cols], np.nan)
    radar = load_radar_dynamics(scene, i, "prepared", prepared)
    dt = scene.frames[j].timestamp - scene.frames[i].timestamp
    residuals = {}
    for gate in gates:
        v_r = associate_velocities(points, radar, gate)
        residuals[gate] = radar_residual(torch.as_tensor(truth), torch.as_tensor(points),
                                         torch.as_tensor(radar.centre), torch.as_tensor(v_r), dt).numpy()
    return pixel_bins(scene, i, rows, cols), residuals


def score_scene(scene_dir: Path, prepared: Path, gates: list[float], limit: int, seed: int = 0) -> dict:
    """Per gate: samples, mean residual (m) and its split by :data:`BIN_NAMES`, over every training pair."""
    scene = read_scene(scene_dir)
    rng = np.random.default_rng(seed)
    bins, residuals = [], {g: [] for g in gates}
    for i, j in frame_pairs(scene):
        frame_bins, frame = frame_residuals(scene, prepared, i, j, gates, limit, rng)
        bins.append(frame_bins)
        for gate in gates:
            residuals[gate].append(frame[gate])
    bins_all = np.concatenate(bins)
    out = {"image_motion_px": dynamic_motion_statistics(scene), "gates": {}}
    for gate in gates:
        r = np.concatenate(residuals[gate])
        scored = np.isfinite(r)
        split = {}
        for b, name in enumerate(BIN_NAMES):
            sel = scored & (bins_all == b)
            split[name] = {"samples": int(sel.sum()), "mean_m": float(r[sel].mean()) if sel.any() else None}
        total, on_static = float(r[scored].sum()), float(r[scored & (bins_all == 0)].sum())
        out["gates"][str(gate)] = {"samples": int(scored.sum()),
                                   "mean_m": float(r[scored].mean()) if scored.any() else None,
                                   "l1_share_static": on_static / total if total else None,
                                   "by_bin": split}
    return out


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--seeds", type=int, nargs="*", default=[214, 215, 216, 217, 218, 219])
    parser.add_argument("--traffic", default="rush")
    parser.add_argument("--fps", type=float, default=5.0, help="frame rate of made scenes; 0 = the preset's")
    parser.add_argument("--preset", default="small")
    parser.add_argument("--gates", type=float, nargs="+", default=[2.0, 1.0])
    parser.add_argument("--scenes", type=Path, nargs="*", default=[],
                        help="prepared scene folders to score instead of making --seeds")
    parser.add_argument("--work", type=Path, default=Path("/tmp/radar4dgs-radar-targets"))
    parser.add_argument("--out", type=Path, default=RESULTS)
    args = parser.parse_args()
    limit = TrainConfig().losses.radar_points_per_frame
    if args.scenes:
        folders = {p.name: (p, p / "prepared") for p in args.scenes}
    else:
        from reconstruct import prepare_scene

        folders = {}
        for seed in args.seeds:
            scene, prepared, _ = prepare_scene(seed, args.preset, args.work, args.traffic, args.fps or None)
            folders[f"seed{seed}"] = (scene, prepared)
    results = {"what": "L_rad's targets against the truth (residual of a perfect field, m per training pair)",
               "command": " ".join(["python benchmarks/radar_targets.py", *sys.argv[1:]]),
               "samples_per_frame": limit, "scenes": {}}
    for name, (scene, prepared) in folders.items():
        entry = score_scene(scene, prepared, args.gates, limit)
        results["scenes"][name] = entry
        motion = entry["image_motion_px"]
        print(f"{name}  image motion p50/p90/p99 {motion['p50']}/{motion['p90']}/{motion['p99']} px")
        for gate, g in entry["gates"].items():
            bins = "  ".join(f"{b} {v['mean_m']:.3f} ({v['samples']})" for b, v in g["by_bin"].items()
                             if v["mean_m"] is not None)
            if g["mean_m"] is None:
                print(f"  gate {gate} m: no sample within the gate")
                continue
            print(f"  gate {gate} m: {g['samples']} samples, mean {g['mean_m']:.4f} m, "
                  f"static share {g['l1_share_static']:.2f} | {bins}", flush=True)
        atomic_write_json(args.out, results)
    print(f"wrote {args.out}")


if __name__ == "__main__":
    main()
