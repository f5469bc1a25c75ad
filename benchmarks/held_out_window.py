"""Score trained runs with the held-out window (``TrainConfig.held_out_window``) at evaluation: each run's
model is copied to a temporary run folder, given its scene's training-frame times and the window
fraction, and evaluated; its own metrics.json is the "before". Training is not touched (the window
changes nothing at training frames), so runs trained before the option existed can be scored as if
trained with it.

    python benchmarks/held_out_window.py RUN [RUN ...] [--fractions 0 0.25 0.5] [--out JSON]
"""

from __future__ import annotations

import argparse
import json
import shutil
import tempfile
from pathlib import Path

import numpy as np
import torch

from radar4dgs.evaluate.reconstruction import evaluate_run
from radar4dgs.io.atomic import atomic_write_json
from radar4dgs.io.scene import normalized_times, read_scene

RUN_FILES = ("config.json", "history.json", "run.json", "model.pt")


def scores(metrics: dict) -> dict:
    """The compared numbers of a metrics.json."""
    return {f"{split}_{key}": metrics[split][key] for split, key in
            (("recon", "psnr_dyn"), ("nvs", "psnr_dyn"), ("nvs", "psnr"))}


def training_times(run: Path) -> list[float]:
    """The normalised times of the run's scene's training frames (what the trainer gives the model)."""
    scene = read_scene(json.loads((run / "run.json").read_text())["scene"])
    times = normalized_times(scene)
    return [float(times[i]) for i in scene.train_indices]


def score_with_window(run: Path, key_times: list[float], fraction: float) -> dict:
    """Evaluate a copy of ``run`` whose model renders with the held-out window ``fraction``."""
    with tempfile.TemporaryDirectory() as tmp:
        copy = Path(tmp) / "run"
        copy.mkdir()
        for name in RUN_FILES:
            shutil.copy(run / name, copy / name)
        saved = torch.load(copy / "model.pt", map_location="cpu", weights_only=True)
        saved["model"]["held_out_window"] = {"key_times": key_times, "fraction": fraction}
        torch.save(saved, copy / "model.pt")
        return scores(evaluate_run(copy, lpips=False, video=False, report=False, progress=False))


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("runs", type=Path, nargs="+")
    parser.add_argument("--fractions", type=float, nargs="+", default=[0.25])
    parser.add_argument("--out", type=Path, default=Path("benchmarks/results/held-out-window.json"))
    args = parser.parse_args()
    rows = []
    for run in args.runs:
        before = scores(json.loads((run / "metrics.json").read_text()))
        key_times = training_times(run)
        row = {"run": str(run), "as_trained": before,
               "window": {f"{f:g}": score_with_window(run, key_times, f) for f in args.fractions}}
        rows.append(row)
        for fraction, after in row["window"].items():
            print(f"{run}  window {fraction}: " + "  ".join(
                f"{key} {value:.2f} -> {after[key]:.2f}" for key, value in before.items()), flush=True)
        atomic_write_json(args.out, {"command": "python benchmarks/held_out_window.py " + " ".join(
            str(r) for r in args.runs) + " --fractions " + " ".join(f"{f:g}" for f in args.fractions),
            "rows": rows, "mean_nvs_psnr_dyn_gain": {
                f"{f:g}": float(np.mean([r["window"][f"{f:g}"]["nvs_psnr_dyn"] - r["as_trained"]["nvs_psnr_dyn"]
                                         for r in rows])) for f in args.fractions}})


if __name__ == "__main__":
    main()
