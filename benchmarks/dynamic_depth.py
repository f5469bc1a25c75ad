"""Where trained runs put their dynamic Gaussians in depth, against the synthetic scene's truth
(:mod:`radar4dgs.evaluate.dynamic_depth`), beside each run's novel-view PSNR* from its metrics.json and
the error of its prepared depth on the same moving pixels (the input the depth term pulls toward) and
of its rendered depth there, frame by frame (what the images show; the Gaussian count includes hidden ones),
and the trained field's scene-flow error on the true moving pixels (`field_epe`, m; as `radar4dgs fit-motion`
scores a standalone fit), also per moving object of the truth (`field_epe.by_object`,
:mod:`radar4dgs.evaluate.field_objects`).

    python benchmarks/dynamic_depth.py RUN [RUN ...] [--out JSON]

Rows of runs already in the results file are replaced, others kept, so runs can be added a few at a time.
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path

from radar4dgs.evaluate.dynamic_depth import run_dynamic_depth, run_prepared_depth, run_rendered_depth
from radar4dgs.evaluate.field_objects import ObjectErrors, format_objects
from radar4dgs.io.atomic import atomic_write_json
from radar4dgs.io.scene import normalized_times
from radar4dgs.model.run import load_run
from radar4dgs.train.fit_motion import evaluate_sceneflow


def field_epe(run_dir: Path) -> dict:
    """The run's trained field, scored as a standalone fit is: mean error (m) per pixel and by image motion,
    and per moving object (``by_object``)."""
    run = load_run(run_dir, device="cpu")
    times = normalized_times(run.scene)
    by_object = ObjectErrors(run.scene)
    result = evaluate_sceneflow(run.model.field, run.scene, times, on_pair=by_object.add)
    return {**{key: result[key] for key in ("epe", "epe_by_image_motion", "points")}, "by_object": by_object.summary()}


def run_row(run: Path) -> dict:
    config = json.loads((run / "config.json").read_text())["config"]
    metrics = json.loads((run / "metrics.json").read_text())
    return {"run": str(run.resolve()), "scene": json.loads((run / "run.json").read_text())["scene"],
            "train_seed": config["seed"], "dynamic_positions": config.get("dynamic_positions", "canonical"),
            "dynamic_stop": config["densify"]["dynamic_stop"],
            "dynamic_depth_weight": config["losses"].get("dynamic_depth_weight", 0.0),
            "dynamic_means_from_birth": config["optim"].get("dynamic_means_from_birth", False),
            "nvs_psnr_dyn": metrics["nvs"]["psnr_dyn"], "recon_psnr_dyn": metrics["recon"]["psnr_dyn"],
            "recon_psnr_dyn_by_frame": {r["index"]: r["psnr_dyn"] for r in metrics["per_frame"]["recon"]},
            "depth": run_dynamic_depth(run), "prepared_depth": run_prepared_depth(run),
            "rendered_depth": run_rendered_depth(run), "field_epe": field_epe(run)}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("runs", type=Path, nargs="+")
    parser.add_argument("--out", type=Path, default=Path("benchmarks/results/dynamic-depth.json"))
    args = parser.parse_args()
    rows = json.loads(args.out.read_text())["rows"] if args.out.is_file() else []
    for run in args.runs:
        row = run_row(run)
        rows = [r for r in rows if r["run"] != row["run"]] + [row]
        d = row["depth"]
        print(f"{run}  {row['dynamic_positions']:9s} seed {row['train_seed']}  depth error median {d['median']:+.3f}  "
              f"|p90| {d['p90_abs']:.3f}  >10 % behind {d['behind']:.2f}  (prepared depth "
              f"{row['prepared_depth']['median']:+.3f}, rendered {row['rendered_depth']['median']:+.3f})  "
              f"field {row['field_epe']['epe']:.3f} m  PSNR* {row['nvs_psnr_dyn']:.2f}", flush=True)
        print(*format_objects(row["field_epe"]["by_object"]), sep="\n", flush=True)
        atomic_write_json(args.out, {"command": "python benchmarks/dynamic_depth.py RUN [RUN ...]", "rows": rows})


if __name__ == "__main__":
    main()
