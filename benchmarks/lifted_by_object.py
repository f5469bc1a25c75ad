"""The pseudo scene flow of a prepared synthetic scene, per moving object of the ground truth: how many of each mover's
pixels the flow stage lifted, their 3-D motion error and the stored 2-D flow's error.

``radar4dgs frontend-eval`` scores all moving pixels together, where the cars near the ego outweigh everything else;
this splits the figure by mover, to show which kind of mover the flow fails (crossing cars 40-60 m ahead, say).
A moving pixel belongs to the mover whose generator box holds its true surface point in frame i
(:func:`radar4dgs.evaluate.field_objects.box_owners`, as the field's per-object error assigns them).

    python benchmarks/lifted_by_object.py SCENE [SCENE ...] [--prepared-name prepared] [--tag TAG]
                                          [--out benchmarks/results/lifted-by-object.json]

``--tag`` names the setting the scenes were prepared with; results of other tags already in ``--out`` are kept.
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path

import numpy as np

from radar4dgs.evaluate.field_objects import box_owners
from radar4dgs.evaluate.frontend import moving_ground_truth
from radar4dgs.io.atomic import atomic_write_json
from radar4dgs.io.scene import read_scene
from radar4dgs.motion.flow import load_flow_pairs
from radar4dgs.motion.metrics import gt_flow_2d
from radar4dgs.motion.truth import gt_scene_flow

RESULTS = Path(__file__).parent / "results"


def quantiles(values: list[float]) -> dict[str, float | None]:
    """Median and 90th percentile of ``values`` (None when empty)."""
    if not values:
        return {"median": None, "p90": None}
    return {"median": float(np.median(values)), "p90": float(np.percentile(values, 90))}


def scene_by_object(root: Path, prepared_name: str) -> list[dict]:
    """One record per ground-truth mover of the scene at ``root``: pixels, lifted, errors (module doc)."""
    scene = read_scene(root)
    truth = [obj for obj in moving_ground_truth(scene) if len(obj.get("dims") or ()) == 3]
    records = {o["id"]: {"id": o["id"], "role": o.get("role"), "class": o.get("class"), "pixels": 0,
                         "scene_flow": [], "flow_2d": []} for o in truth}
    for pair in load_flow_pairs(root / prepared_name):
        i, j = int(pair["index_i"]), int(pair["index_j"])
        world_i, world_j, valid = gt_scene_flow(scene, i, j)
        motion = world_j - world_i
        moving = (scene.load_optional("gt/dynamic_mask", i) > 0) & valid
        owners = np.full(moving.shape, -1, dtype=np.int64)
        owners[moving] = box_owners(world_i[moving], truth, i)
        flow_truth, flow_valid = gt_flow_2d(scene, i, j)
        cols, rows = pair["pixels"][:, 0].astype(np.int64), pair["pixels"][:, 1].astype(np.int64)
        for k, obj in enumerate(truth):
            own = owners == k
            record = records[obj["id"]]
            record["pixels"] += int(own.sum())
            record["flow_2d"] += np.linalg.norm(pair["flow"] - flow_truth, axis=-1)[own & flow_valid].tolist()
            lifted = own[rows, cols]
            error = (pair["points_j"] - pair["points_i"])[lifted] - motion[rows[lifted], cols[lifted]]
            record["scene_flow"] += np.linalg.norm(error, axis=1).tolist()
    out = []
    for record in records.values():
        if record["pixels"] == 0:
            continue
        out.append({**{k: record[k] for k in ("id", "role", "class", "pixels")},
                    "lifted": len(record["scene_flow"]), "scene_flow_error_m": quantiles(record["scene_flow"]),
                    "flow_2d_error_px": quantiles(record["flow_2d"])})
    return out


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("scenes", type=Path, nargs="+")
    parser.add_argument("--prepared-name", default="prepared", help="the prepared folder inside each scene")
    parser.add_argument("--tag", default="defaults", help="the setting the scenes were prepared with")
    parser.add_argument("--out", type=Path, default=RESULTS / "lifted-by-object.json")
    args = parser.parse_args()
    report = json.loads(args.out.read_text(encoding="utf-8")) if args.out.is_file() else {}
    report.setdefault("what", __doc__.splitlines()[0])
    report.setdefault("tags", {})[args.tag] = {
        "command": f"python benchmarks/lifted_by_object.py SCENE ... --tag {args.tag}", "scenes": {}}
    for root in args.scenes:
        rows = scene_by_object(root, args.prepared_name)
        report["tags"][args.tag]["scenes"][root.name] = rows
        print(root.name)
        for row in rows:
            sf, f2 = row["scene_flow_error_m"], row["flow_2d_error_px"]
            print(f"  {row['id']:>3} {row['role'] or '':10s} pixels {row['pixels']:6d} lifted {row['lifted']:6d}  "
                  f"scene flow {sf['median'] or float('nan'):.2f} / {sf['p90'] or float('nan'):.2f} m  "
                  f"2-D {f2['median'] or float('nan'):.2f} / {f2['p90'] or float('nan'):.1f} px")
        atomic_write_json(args.out, report)
    print(f"wrote {args.out}")


if __name__ == "__main__":
    main()
