"""Long drives (issue 26): peak memory, time and disk of `prepare` and `train` as the drive grows.

    python benchmarks/scale.py [--frames 50 200 800] [--preset tiny] [--train-preset tiny]
                               [--iterations 200] [--frame-cache N] [--seed 1]
                               [--work /tmp/radar4dgs-scale] [--out benchmarks/results/scale.json]

For each frame count: a synthetic scene (`radar4dgs synth --preset P --scene.num-frames N`, made
once under --work and reused), then `radar4dgs prepare` (every stage, the prepared folder deleted
first) and `radar4dgs train --no-eval --no-tensorboard` (`--iterations`, one thread, the train
preset's `frame_cache` unless `--frame-cache`), each in its own process with OMP_NUM_THREADS=1.
Per command: the wall time, the peak resident memory of the process (ru_maxrss from os.wait4 of
that child) and the disk its outputs take. For training also the loop's own time
(history.json's train_seconds_last_call, the set-up excluded) per iteration, and the Gaussian
counts at the end, since the cost of an iteration follows them. The growth per frame of each
quantity is the least-squares slope against the frame count. The machine's load average before and
after each command is recorded (other jobs may share the cores: timings depend on it). Prints a
table and writes the JSON (atomically, after every command).
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import shutil
import subprocess
import sys
import time
from pathlib import Path

import numpy as np

from radar4dgs.io.atomic import atomic_write_json

RESULTS = Path(__file__).parent / "results" / "scale.json"
ENV = {**os.environ, "OMP_NUM_THREADS": "1", "MKL_NUM_THREADS": "1"}


def load_average() -> list[float]:
    return [round(value, 2) for value in os.getloadavg()]


def disk_mb(folder: Path) -> float:
    """Size of the files under ``folder`` (MB)."""
    return round(sum(p.stat().st_size for p in folder.rglob("*") if p.is_file()) / 1e6, 2)


def measured(argv: list[str], log: Path) -> dict:
    """Run ``radar4dgs argv`` in its own process: wall seconds, peak RSS (MB) of that process,
    exit status and the load average before and after; its output goes to ``log``."""
    before = load_average()
    started = time.perf_counter()
    with open(log, "w") as out:
        process = subprocess.Popen([sys.executable, "-m", "radar4dgs.cli", *map(str, argv)], env=ENV, stdout=out,
                                   stderr=subprocess.STDOUT)
        _, status, usage = os.wait4(process.pid, 0)
    process.returncode = os.waitstatus_to_exitcode(status)
    wall = time.perf_counter() - started
    if process.returncode != 0:
        raise SystemExit(f"radar4dgs {' '.join(map(str, argv))} failed ({process.returncode}); see {log}")
    # ru_maxrss is in kB on Linux, bytes on macOS.
    peak = usage.ru_maxrss / (1e6 if sys.platform == "darwin" else 1e3)
    return {"wall_s": round(wall, 2), "peak_rss_mb": round(peak, 1), "load_avg_before": before,
            "load_avg_after": load_average()}


def scene_for(frames: int, args) -> Path:
    scene = args.work / f"scene-{args.preset}-{frames}"
    if not (scene / "scene.json").is_file():
        measured(["synth", scene, "--preset", args.preset, "--seed", args.seed, "--scene.num-frames", frames,
                  "--force"], args.work / f"synth-{frames}.log")
    return scene


def one_size(frames: int, args) -> dict:
    scene = scene_for(frames, args)
    prepared, run = scene / "prepared", args.work / f"run-{args.preset}-{frames}"
    shutil.rmtree(prepared, ignore_errors=True)
    prepare = measured(["prepare", scene, "--preset", args.preset, "--quiet"], args.work / f"prepare-{frames}.log")
    prepare["disk_mb"] = disk_mb(prepared)
    print(f"  {frames} frames: prepare {prepare['wall_s']:.1f} s, {prepare['peak_rss_mb']:.0f} MB", flush=True)
    argv = ["train", scene, "--out", run, "--preset", args.train_preset, "--force", "--quiet", "--no-eval",
            "--no-tensorboard", "--config.threads", 1, "--config.optim.iterations", args.iterations]
    if args.frame_cache is not None:
        argv += ["--config.frame-cache", args.frame_cache]
    train = measured(argv, args.work / f"train-{frames}.log")
    history = json.loads((run / "history.json").read_text())
    config = json.loads((run / "config.json").read_text())["config"]
    loop = history["train_seconds_last_call"]
    train.update({"loop_s": round(loop, 2), "s_per_iteration": round(loop / args.iterations, 4),
                  "setup_s": round(train["wall_s"] - loop, 2), "num_static": history["num_static"],
                  "num_dynamic": history["num_dynamic"], "frame_cache": config["frame_cache"],
                  "disk_mb": disk_mb(run)})
    print(f"  {frames} frames: train {train['wall_s']:.1f} s ({train['s_per_iteration']:.3f} s/it), "
          f"{train['peak_rss_mb']:.0f} MB", flush=True)
    return {"frames": frames, "scene_disk_mb": disk_mb(scene) - prepare["disk_mb"], "prepare": prepare, "train": train}


def slope(xs: list[float], ys: list[float]) -> float | None:
    """Least-squares slope of ys against xs (None with fewer than two points)."""
    return float(np.polyfit(xs, ys, 1)[0]) if len(xs) >= 2 else None


def growth(sizes: list[dict]) -> dict:
    frames = [s["frames"] for s in sizes]
    out = {}
    for stage, keys in (("prepare", ("wall_s", "peak_rss_mb", "disk_mb")),
                        ("train", ("wall_s", "peak_rss_mb", "s_per_iteration", "setup_s", "disk_mb"))):
        for key in keys:
            value = slope(frames, [s[stage][key] for s in sizes])
            out[f"{stage}.{key}_per_frame"] = None if value is None else round(value, 5)
    return out


def print_table(report: dict) -> None:
    print(f"\n{report['machine']['cpu_count']} CPUs; scenes preset {report['preset']}, train preset "
          f"{report['train_preset']}, {report['iterations']} iterations")
    print(f"  {'frames':>6} | {'prepare s':>9} {'MB':>6} {'disk MB':>8} | {'train s':>8} {'setup s':>7} "
          f"{'s/it':>6} {'MB':>6} {'static':>7} {'dynamic':>7} | load")
    for s in report["sizes"]:
        p, t = s["prepare"], s["train"]
        print(f"  {s['frames']:>6} | {p['wall_s']:>9.1f} {p['peak_rss_mb']:>6.0f} {p['disk_mb']:>8.1f} | "
              f"{t['wall_s']:>8.1f} {t['setup_s']:>7.1f} {t['s_per_iteration']:>6.3f} {t['peak_rss_mb']:>6.0f} "
              f"{t['num_static']:>7} {t['num_dynamic']:>7} | {t['load_avg_before'][0]}")
    print("  growth per frame: " + ", ".join(f"{k} {v:+.4g}" for k, v in report["growth"].items() if v is not None))


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--frames", type=int, nargs="+", default=[50, 200, 800])
    parser.add_argument("--preset", default="tiny", help="synth and prepare preset")
    parser.add_argument("--train-preset", default="tiny")
    parser.add_argument("--iterations", type=int, default=200)
    parser.add_argument("--frame-cache", type=int, default=None, help="TrainConfig.frame_cache (default: preset's)")
    parser.add_argument("--seed", type=int, default=1)
    parser.add_argument("--work", type=Path, default=Path("/tmp/radar4dgs-scale"))
    parser.add_argument("--out", type=Path, default=RESULTS)
    args = parser.parse_args()
    args.work.mkdir(parents=True, exist_ok=True)
    report = {"preset": args.preset, "train_preset": args.train_preset, "iterations": args.iterations,
              "seed": args.seed, "command": " ".join(sys.argv),
              "machine": {"cpu_count": os.cpu_count(), "platform": platform.platform(),
                          "python": platform.python_version()},
              "sizes": [], "growth": {}}
    for frames in sorted(args.frames):
        report["sizes"].append(one_size(frames, args))
        report["growth"] = growth(report["sizes"])
        atomic_write_json(args.out, report)
    print_table(report)
    print(f"wrote {args.out}")


if __name__ == "__main__":
    main()
