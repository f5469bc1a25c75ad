"""Benchmark of the reconstruction (issue 8): train and evaluate synthetic scenes with the full method
and with dynamics switched off, check that a killed run resumes to the same metrics, and time it.

    python benchmarks/reconstruct.py [--seeds 1 2 3] [--preset small] [--methods ours static]
                                     [--work /tmp/radar4dgs-recon-bench] [--resume-check SEED]
                                     [--aimotive] [--traffic calm|realistic|rush] [--fps 5] [--threads N]
                                     [--set KEY=VALUE ...] [--prepare-set KEY=VALUE ...] [--out JSON]

Every cell (seed x method) is a run folder under --work, in the demo's layout
(seed<N>/{scene, prepared, run, static}); finished cells are reused, so an interrupted benchmark
continues where it stopped. For --demo-seed (default 1) the "ours" cell is `radar4dgs demo` itself,
timed end to end, unless --set or --prepare-set is given (the demo takes neither). Prints a table
and writes benchmarks/results/reconstruct.json after every cell.

--resume-check SEED trains that seed's "ours" run in a child process, kills it (SIGKILL) once its
first checkpoint exists, resumes it, evaluates it and compares with the unbroken run's metrics.
--aimotive converts the real aiMotive fixture (../shared/fixtures/aimotive-night), prepares,
trains and evaluates it, and reports its numbers.

--traffic realistic|rush (and --fps) makes the seeds' scenes with that traffic profile (and frame
rate), the seeds of benchmarks/motion.py (issue 21: rush traffic at 5 Hz, report seeds 209-213, is
the hard set); each seed's entry then holds its dynamic pixels' image motion (p50/p90/p99 px per
frame at its width), and no demo is run (the demo makes calm scenes).

--set KEY=VALUE sets (dotted) TrainConfig fields of every "ours" run, as `radar4dgs bench --set`
(rigid_actors_at=0.3); use its own --work and --out, the runs are reused by folder.
--prepare-set KEY=VALUE sets (dotted) PrepareConfig fields of every scene (the aiMotive clip's too): with
`depth.source=oracle flow.method=oracle flow.mask_source=oracle` and `--set mask_source=gt` every
front-end input is the generator's truth, the ceiling of what a better front end can give.
"""

from __future__ import annotations

import argparse
import json
import math
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

from radar4dgs.apps.bench_spec import parse_overrides
from radar4dgs.config import preset
from radar4dgs.io.atomic import atomic_write_json
from radar4dgs.io.preview import dynamic_motion_statistics
from radar4dgs.io.scene import read_scene
from scene_configs import prepare_config, synth_config, synthesize_once

RESULTS = Path(__file__).parent / "results" / "reconstruct.json"
FIXTURE = Path(__file__).resolve().parents[2] / "shared" / "fixtures" / "aimotive-night"


def prepare_scene(seed: int, preset_name: str, work: Path, traffic: str = "calm", fps: float | None = None,
                  prepare_set: list[str] = ()) -> tuple[Path, Path, float]:
    """The demo's layout: work/seed<N>/{scene, prepared}; ``prepare_set``: dotted PrepareConfig
    overrides (``flow.method=oracle``)."""
    from radar4dgs.apps.prepare import run_prepare

    scene = work / f"seed{seed}" / "scene"
    started = time.perf_counter()
    synthesize_once(synth_config(preset_name, seed, traffic, fps), scene, preset_name)
    run_prepare(scene, work / f"seed{seed}" / "prepared", prepare_config(preset_name, prepare_set), progress=False,
                wait=math.inf)
    return scene, work / f"seed{seed}" / "prepared", time.perf_counter() - started


def run_demo(seed: int, preset_name: str, work: Path) -> dict:
    """``radar4dgs demo`` itself, timed; its run is the "ours" cell of this seed."""
    out = work / f"seed{seed}"
    if (out / "run" / "metrics.json").is_file():
        return {}
    reused = (out / "run" / "model.pt").is_file()
    started = time.perf_counter()
    subprocess.run([sys.executable, "-m", "radar4dgs.cli", "demo", "--out", str(out), "--seed", str(seed),
                    "--preset", preset_name], check=True)
    # A demo that found its run trained already only evaluated it: its time is not the demo's.
    return {"demo_seconds": time.perf_counter() - started, "reused_trained_run": reused}


def run_dir(work: Path, seed: int, method: str) -> Path:
    return work / f"seed{seed}" / ("run" if method == "ours" else method)


def train_and_eval(scene: Path, prepared: Path, run: Path, preset_name: str, method: str,
                   threads: int | None = None, overrides: dict | None = None) -> dict:
    from radar4dgs.evaluate.reconstruction import evaluate_run
    from radar4dgs.model.config import TrainConfig
    from radar4dgs.train.trainer import train_run

    seconds = None
    if not (run / "model.pt").is_file():
        started = time.perf_counter()
        resume = (run / "checkpoints" / "last.pt").is_file()
        extra = {} if threads is None else {"threads": threads}
        config = preset(TrainConfig, preset_name, method=method, **extra, **(overrides or {}))
        train_run(scene, prepared, run, config, resume=resume, progress=True)
        seconds = time.perf_counter() - started
    if (run / "metrics.json").is_file():
        metrics = json.loads((run / "metrics.json").read_text())
    else:
        metrics = evaluate_run(run, progress=False)
    history = json.loads((run / "history.json").read_text())
    return {"train_seconds": seconds if seconds is not None else history.get("train_seconds_last_call"),
            "num_gaussians": metrics.get("num_gaussians"),
            **{f"{split}_{key}": metrics[split][key] for split in ("recon", "nvs")
               for key in ("psnr", "ssim", "lpips_vgg", "psnr_dyn")},
            "mask_source": metrics["mask_source"]}


def resume_check(seed: int, preset_name: str, work: Path, reference: dict) -> dict:
    """Kill a training child process after its first checkpoint, resume, compare metrics."""
    scene, prepared, _ = prepare_scene(seed, preset_name, work)
    run = work / f"seed{seed}" / "run-killed"
    if not (run / "model.pt").is_file():
        code = ("import sys; from pathlib import Path; from radar4dgs.config import preset; "
                "from radar4dgs.model.config import TrainConfig; from radar4dgs.train.trainer import train_run; "
                f"train_run(Path({str(scene)!r}), Path({str(prepared)!r}), Path({str(run)!r}), "
                f"preset(TrainConfig, {preset_name!r}), progress=False)")
        child = subprocess.Popen([sys.executable, "-c", code])
        checkpoint = run / "checkpoints" / "last.pt"
        while child.poll() is None and not checkpoint.is_file():
            time.sleep(1.0)
        time.sleep(5.0)  # a few more iterations past the checkpoint, lost by the kill
        killed_at = None
        if child.poll() is None:
            os.kill(child.pid, signal.SIGKILL)
            child.wait()
            import torch

            killed_at = int(torch.load(checkpoint, weights_only=True)["step"])
        resumed = train_and_eval(scene, prepared, run, preset_name, "ours")
    else:
        resumed = train_and_eval(scene, prepared, run, preset_name, "ours")
        killed_at = None
    return {"seed": seed, "resumed_from_step": killed_at,
            "unbroken": {k: reference[k] for k in ("recon_psnr", "nvs_psnr", "nvs_psnr_dyn")},
            "resumed": {k: resumed[k] for k in ("recon_psnr", "nvs_psnr", "nvs_psnr_dyn")},
            "max_abs_difference_db": max(abs(reference[k] - resumed[k])
                                         for k in ("recon_psnr", "nvs_psnr", "nvs_psnr_dyn"))}


def aimotive(work: Path, preset_name: str, threads: int | None = None, prepare_set: list[str] = ()) -> dict:
    """The real aiMotive fixture converted, prepared (``prepare_set``: dotted PrepareConfig overrides),
    trained and evaluated under ``work/aimotive``."""
    from radar4dgs.apps.prepare import run_prepare
    from radar4dgs.datasets.convert.aimotive import convert_aimotive

    scene = work / "aimotive" / "scene"
    started = time.perf_counter()
    if not (scene / "scene.json").is_file():
        convert_aimotive(FIXTURE, scene, scale=0.25, overwrite=True, progress=False)  # 320x141: 320x176 less the hood
    run_prepare(scene, None, prepare_config(preset_name, prepare_set), progress=False, wait=math.inf)
    prepare_seconds = time.perf_counter() - started
    result = train_and_eval(scene, scene / "prepared", work / "aimotive" / "ours", preset_name, "ours", threads)
    return {"prepare_seconds": prepare_seconds, **result}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--seeds", type=int, nargs="*", default=[1, 2, 3], help="synthetic seeds (none: aimotive only)")
    parser.add_argument("--preset", default="small")
    parser.add_argument("--methods", nargs="+", default=["ours", "static"])
    parser.add_argument("--work", type=Path, default=Path("/tmp/radar4dgs-recon-bench"))
    parser.add_argument("--resume-check", type=int, default=None)
    parser.add_argument("--demo-seed", type=int, default=1, help="run `radar4dgs demo` for this seed (timed)")
    parser.add_argument("--aimotive", action="store_true")
    parser.add_argument("--out", type=Path, default=RESULTS)
    parser.add_argument("--traffic", choices=("calm", "realistic", "rush"), default="calm")
    parser.add_argument("--fps", type=float, default=None, help="frame rate of the scenes (default: the preset's)")
    parser.add_argument("--threads", type=int, default=None,
                        help="torch threads of each training (default: the preset's)")
    parser.add_argument("--set", nargs="*", default=[], metavar="KEY=VALUE",
                        help="TrainConfig fields of the 'ours' runs, dotted (rigid_actors_at=0.3)")
    parser.add_argument("--prepare-set", nargs="*", default=[], metavar="KEY=VALUE",
                        help="PrepareConfig fields of every scene, dotted (flow.method=oracle depth.source=oracle)")
    args = parser.parse_args()
    overrides = parse_overrides(args.set)
    # The demo takes neither --set nor --prepare-set: with either, its seed is trained like the others.
    if args.traffic != "calm" or args.fps is not None or args.set or args.prepare_set:
        args.demo_seed = None

    results = json.loads(args.out.read_text()) if args.out.is_file() else {}
    results.setdefault("cells", {})
    # "threads" is each training's torch thread count (None: the preset's), "cpus" the machine's.
    results.update({"preset": args.preset, "threads": args.threads, "cpus": os.cpu_count(), "traffic": args.traffic,
                    "fps": args.fps, "set": args.set, "prepare_set": args.prepare_set})
    for seed in args.seeds:
        demo = run_demo(seed, args.preset, args.work) if seed == args.demo_seed else {}
        if demo:
            results["demo"] = {"seed": seed, **demo}
            atomic_write_json(args.out, results)
            print(f"radar4dgs demo (seed {seed}): {demo['demo_seconds']:.0f} s", flush=True)
        scene, prepared, prepare_seconds = prepare_scene(seed, args.preset, args.work, args.traffic, args.fps,
                                                         args.prepare_set)
        motion = None if args.traffic == "calm" else dynamic_motion_statistics(read_scene(scene))
        for method in args.methods:
            cell = train_and_eval(scene, prepared, run_dir(args.work, seed, method), args.preset, method, args.threads,
                                  overrides if method == "ours" else None)
            cell["prepare_seconds"] = prepare_seconds
            if motion is not None:
                cell["image_motion_px"] = motion
            results["cells"][f"seed{seed}/{method}"] = cell
            print(f"seed {seed} {method:<7} recon PSNR {cell['recon_psnr']:.2f}  nvs PSNR {cell['nvs_psnr']:.2f}  "
                  f"nvs PSNR* {cell['nvs_psnr_dyn']:.2f}  train {cell['train_seconds'] or 0:.0f} s", flush=True)
            atomic_write_json(args.out, results)
    cells = results["cells"]
    summary = {}
    for method in args.methods:
        rows = [cells[f"seed{s}/{method}"] for s in args.seeds if f"seed{s}/{method}" in cells]
        if rows:
            summary[method] = {key: sum(r[key] for r in rows) / len(rows)
                               for key in ("recon_psnr", "nvs_psnr", "nvs_psnr_dyn", "recon_ssim", "nvs_ssim")}
    if "ours" in summary and "static" in summary:
        summary["nvs_psnr_dyn_gain_over_static"] = {
            f"seed{s}": cells[f"seed{s}/ours"]["nvs_psnr_dyn"] - cells[f"seed{s}/static"]["nvs_psnr_dyn"]
            for s in args.seeds if f"seed{s}/ours" in cells and f"seed{s}/static" in cells}
    results["summary"] = summary
    atomic_write_json(args.out, results)
    print(json.dumps(summary, indent=1))
    if args.resume_check is not None:
        reference = cells[f"seed{args.resume_check}/ours"]
        results["resume"] = resume_check(args.resume_check, args.preset, args.work, reference)
        print("resume:", json.dumps(results["resume"]))
        atomic_write_json(args.out, results)
    if args.aimotive:
        results["aimotive"] = aimotive(args.work, args.preset, args.threads, args.prepare_set)
        print("aimotive:", json.dumps(results["aimotive"]))
        atomic_write_json(args.out, results)


if __name__ == "__main__":
    main()
