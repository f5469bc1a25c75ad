"""Does the pseudo scene flow need more pairs or better ones? (issue 21). Trains a hard-traffic seed at
the full ``small`` preset on its prepared folder with the flow pairs changed in one way each:

    python benchmarks/flow_coverage.py --seed 214 --arms prepared accurate true-positions object-median filled
        [--train-seed N] [--work W] [--out JSON]

- ``prepared``: the pairs as prepared (today's defaults);
- ``accurate``: the same pixels and start points, each pair's motion replaced by the generator's true
  motion of that pixel (what perfect motion is worth at today's coverage);
- ``true-positions``: the same pixels, both ends of each pair the generator's true surface point (the
  true depth as well as the true motion, so the start points leave the prepared depth the dynamic
  Gaussians are initialised from);
- ``object-median``: the same pixels and start points, each pair's motion the median motion of its mask
  component's pairs (per-pair noise removed, a bias the object shares kept);
- ``filled``: today's pairs plus every dynamic-mask pixel without one (finite depth, not on a depth
  edge) moved by the median 3-D motion of its mask component's pairs (what more coverage is worth).

Each arm is a copy of the prepared folder (``W/seed<N>/prepared-<arm>``) trained into
``W/seed<N>/run-<arm>`` (``run-<arm>-train<K>`` for ``--train-seed K`` other than 0: the same arm trained
from another random start, to tell a change from one run's luck) with one thread; finished runs are reused.
Prints and writes (``--out``) the novel-view PSNR* and its split by image motion, with the pairs' count,
coverage of the ground-truth moving pixels and scene-flow error. The evaluation-only truth (``gt/``)
builds the ``accurate`` and ``true-positions`` arms; it is never a method.
"""

from __future__ import annotations

import argparse
import json
import shutil
from pathlib import Path

import cv2
import numpy as np

from radar4dgs.evaluate.motion_bins import run_psnr_by_image_motion
from radar4dgs.io.atomic import atomic_save_npz, atomic_write_json
from radar4dgs.io.scene import read_scene
from radar4dgs.motion.flow import load_depth, load_mask
from radar4dgs.motion.lift import backproject, sample_depth
from radar4dgs.motion.metrics import motion_frontend_metrics
from radar4dgs.motion.truth import gt_scene_flow
from reconstruct import prepare_scene, train_and_eval

RESULTS = Path(__file__).parent / "results" / "flow-coverage.json"
ARMS = ("prepared", "accurate", "true-positions", "object-median", "filled")


def truth_at_pairs(scene, pair: dict) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The generator's true surface point of each pair's pixel at both times, (M, 3) each, and (M,) bool
    where it is known (:func:`gt_scene_flow`'s ``valid``)."""
    world_i, world_j, valid = gt_scene_flow(scene, int(pair["index_i"]), int(pair["index_j"]))
    cols, rows = pair["pixels"][:, 0].astype(np.int64), pair["pixels"][:, 1].astype(np.int64)
    return world_i[rows, cols], world_j[rows, cols], valid[rows, cols]


def pair_components(scene, prepared: Path, pair: dict) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Frame i's prepared dynamic mask (H, W) bool, its 8-connected component labels (H, W) and the
    (M,) label of each pair's pixel (one component is one object)."""
    mask = load_mask(scene, int(pair["index_i"]), "prepared", prepared)
    _, labels = cv2.connectedComponents(mask.astype(np.uint8), connectivity=8)
    return mask, labels, labels[pair["pixels"][:, 1].astype(np.int64), pair["pixels"][:, 0].astype(np.int64)]


def accurate_pairs(scene, pair: dict) -> dict:
    """``pair`` (a flow/*.npz as a dict) with each pair's motion the truth at its pixel; pairs whose
    pixel has no true motion are dropped."""
    world_i, world_j, known = truth_at_pairs(scene, pair)
    start = pair["points_i"].astype(np.float64)
    moved = start + (world_j - world_i)
    return {**pair, "points_i": start[known].astype(np.float32), "points_j": moved[known].astype(np.float32),
            "pixels": pair["pixels"][known]}


def true_position_pairs(scene, pair: dict) -> dict:
    """``pair`` with both ends of each pair the truth at its pixel (dropped where unknown)."""
    world_i, world_j, known = truth_at_pairs(scene, pair)
    return {**pair, "points_i": world_i[known].astype(np.float32), "points_j": world_j[known].astype(np.float32),
            "pixels": pair["pixels"][known]}


def object_median_pairs(scene, prepared: Path, pair: dict) -> dict:
    """``pair`` with each pair's motion the median motion of its mask component's pairs."""
    _, _, pair_label = pair_components(scene, prepared, pair)
    motion = (pair["points_j"] - pair["points_i"]).astype(np.float64)
    for label in np.unique(pair_label):
        motion[pair_label == label] = np.median(motion[pair_label == label], axis=0)
    return {**pair, "points_j": (pair["points_i"].astype(np.float64) + motion).astype(np.float32)}


def filled_pairs(scene, prepared: Path, pair: dict, edge_tolerance: float = 0.1) -> dict:
    """``pair`` plus a pair for every mask pixel of frame i without one (finite depth off depth
    edges), moved by the median 3-D motion of its mask component's pairs (components with < 3 none)."""
    index = int(pair["index_i"])
    mask, labels, pair_label = pair_components(scene, prepared, pair)
    depth = load_depth(scene, index, "prepared", prepared)
    has_pair = np.zeros_like(mask)
    has_pair[pair["pixels"][:, 1].astype(np.int64), pair["pixels"][:, 0].astype(np.int64)] = True
    motion = (pair["points_j"] - pair["points_i"]).astype(np.float64)
    fill_rows, fill_cols = np.nonzero(mask & ~has_pair & np.isfinite(depth) & (depth > 0))
    pixels = np.stack([fill_cols, fill_rows], axis=1).astype(np.float64)
    _, off_edges = sample_depth(depth, pixels, edge_tolerance)
    pixels, fill_label = pixels[off_edges], labels[fill_rows[off_edges], fill_cols[off_edges]]
    starts, ends, kept = [pair["points_i"].astype(np.float64)], [pair["points_j"].astype(np.float64)], [pair["pixels"]]
    for label in np.unique(fill_label):
        if (pair_label == label).sum() < 3:
            continue
        chosen = pixels[fill_label == label]
        start = backproject(chosen, depth[chosen[:, 1].astype(np.int64), chosen[:, 0].astype(np.int64)],
                            scene.camera.K, scene.world_to_camera(index))
        starts.append(start)
        ends.append(start + np.median(motion[pair_label == label], axis=0))
        kept.append(chosen.astype(np.float32))
    return {**pair, "points_i": np.concatenate(starts).astype(np.float32),
            "points_j": np.concatenate(ends).astype(np.float32), "pixels": np.concatenate(kept)}


# Each arm's change of one pair: (scene, prepared folder, pair) -> pair.
CHANGES = {"accurate": lambda scene, prepared, pair: accurate_pairs(scene, pair),
           "true-positions": lambda scene, prepared, pair: true_position_pairs(scene, pair),
           "object-median": object_median_pairs,
           "filled": filled_pairs}


def make_arm(scene, prepared: Path, arm: str) -> Path:
    """The prepared folder of ``arm`` (a copy of ``prepared`` with its flow pairs changed)."""
    if arm == "prepared":
        return prepared
    out = prepared.with_name(f"prepared-{arm}")
    if (out / "done").is_file():
        return out
    if out.exists():
        shutil.rmtree(out)
    shutil.copytree(prepared, out)
    for path in sorted((out / "flow").glob("*.npz")):
        with np.load(path, allow_pickle=False) as data:
            pair = {key: data[key] for key in data.files}
        pair = CHANGES[arm](scene, prepared, pair)
        atomic_save_npz(path, pair)
    (out / "done").write_text("")
    return out


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--seed", type=int, default=214, help="a hard-traffic (rush, 5 Hz) tuning seed")
    parser.add_argument("--arms", nargs="+", choices=ARMS, default=list(ARMS))
    parser.add_argument("--train-seed", type=int, default=0, help="the training seed (TrainConfig.seed)")
    parser.add_argument("--work", type=Path, default=Path("/tmp/radar4dgs-flow-coverage"))
    parser.add_argument("--out", type=Path, default=RESULTS)
    args = parser.parse_args()
    scene_dir, prepared, _ = prepare_scene(args.seed, "small", args.work, "rush", 5.0)
    scene = read_scene(scene_dir)
    # Keep the file's other keys (references, notes on earlier rows); only rows and description change.
    results = json.loads(args.out.read_text()) if args.out.is_file() else {}
    rows = results.get("rows", [])
    for arm in args.arms:
        folder = make_arm(scene, prepared, arm)
        front = motion_frontend_metrics(scene, folder)
        run = prepared.with_name(f"run-{arm}" + (f"-train{args.train_seed}" if args.train_seed else ""))
        result = train_and_eval(scene_dir, folder, run, "small", "ours", threads=1, overrides={"seed": args.train_seed})
        bins = run_psnr_by_image_motion(run)["nvs"]
        # Runs before the held-out window (TrainConfig.held_out_window) existed have no such key: 0.
        window = json.loads((run / "config.json").read_text())["config"].get("held_out_window", 0.0)
        row = {"seed": args.seed, "arm": arm, "train_seed": args.train_seed, "budget": "small, 1800 iterations",
               "held_out_window": window,
               "nvs_psnr_dyn": result["nvs_psnr_dyn"], "nvs_psnr": result["nvs_psnr"],
               "nvs_psnr_dyn_by_motion": {f"{b['low']}-{b['high']}": b["psnr"] for b in bins},
               "sceneflow_coverage": front["sceneflow_coverage"],
               "sceneflow_epe_dynamic": front["sceneflow_epe_dynamic"]}
        print(json.dumps(row), flush=True)
        key = (args.seed, arm, window, args.train_seed)
        rows = [r for r in rows if (r["seed"], r["arm"], r.get("held_out_window", 0.0), r.get("train_seed", 0)) != key]
        rows.append(row)
        atomic_write_json(args.out, {**results, "description": __doc__, "rows": rows})


if __name__ == "__main__":
    main()
