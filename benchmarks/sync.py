"""Benchmark of the camera-radar time sync (issue 27 item 4): prints numbers, writes JSON.

    python benchmarks/sync.py                        # seeds 1-3, offsets 0, +-0.05, +-0.1 s, aiMotive check
    python benchmarks/sync.py --seeds 1 --offsets 0.1 --skip-aimotive
    python benchmarks/sync.py --train 1              # + tiny 600-iteration runs: sync off / auto / no offset

Tiny synthetic scenes (20 frames, 1.9 s) whose ego speed swings by +-2 m/s over 4 s
(``--scene.ego-speed-swing 2``) and whose radar clock is skewed by the injected offset
(``--scene.radar-time-offset``): every scan is of its camera frame's time, stamped and posed
``offset`` earlier. Per scene, ``prepare``'s radar stage with ``sync`` off (report only) and auto:
  estimate        the estimated offset and its error against the injected one.
  front end       ego-velocity RMSE, dynamic precision / recall, object velocity error (median, p90)
                  and unmatched objects (radar4dgs.evaluate.frontend.evaluate_radar).
  placement       mean / max world distance (m) between the static radar points (gt label 0) placed
                  with the stage's radar pose and with the true one (the camera-time pose): what the
                  depth stage, the masks and the object points inherit.
The same scenes at constant speed (swing 0, every scene the generator made before) show the offset
unobservable there: nothing is applied. ``aimotive`` converts the real clip (poses from its radar) and
checks that ``sync`` auto writes byte-identical radar outputs to ``sync`` off.
"""

from __future__ import annotations

import os

for _var in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ[_var] = "1"

import argparse  # noqa: E402
import json  # noqa: E402
import sys  # noqa: E402
import warnings  # noqa: E402
from pathlib import Path  # noqa: E402

import numpy as np  # noqa: E402

from radar4dgs.config import preset  # noqa: E402
from radar4dgs.datasets.synth import SynthConfig, synthesize  # noqa: E402
from radar4dgs.evaluate.frontend import evaluate_radar  # noqa: E402
from radar4dgs.io.atomic import atomic_write_json  # noqa: E402
from radar4dgs.io.scene import SceneWarning, read_scene  # noqa: E402
from radar4dgs.radar.config import RadarConfig  # noqa: E402
from radar4dgs.radar.process import prepare_radar  # noqa: E402
from radar4dgs.radar.sync import prepared_synced_scene  # noqa: E402

ROOT = Path(__file__).resolve().parents[1]
AIMOTIVE = ROOT.parent / "shared" / "fixtures" / "aimotive-night"
FRONT_END = ("ego_velocity_rmse", "dynamic_precision", "dynamic_recall", "object_velocity_error_median",
             "object_velocity_error_p90", "object_count", "object_unmatched")


def placement_error(scene, synced) -> dict:
    """Mean and max distance (m) between static radar points placed by ``synced``'s radar poses and
    by the truth (each scan is of its camera frame's time: ``ego_to_world @ radar_to_ego``)."""
    errors = []
    for i, frame in enumerate(scene.frames):
        with warnings.catch_warnings():
            warnings.simplefilter("ignore", SceneWarning)
            scan = scene.load_radar(i)
        labels = scan.align(scene.load_optional("gt/radar_labels", i),
                            scene.root / "gt" / "radar_labels" / f"{frame.name}.npy")
        xyz = np.c_[scan.xyz[labels == 0].astype(np.float64), np.ones(int((labels == 0).sum()))]
        truth = frame.ego_to_world @ scene.radar.radar_to_ego
        errors.append(np.linalg.norm((xyz @ (synced.radar_to_world(i) - truth).T)[:, :3], axis=1))
    errors = np.concatenate(errors)
    return {"placement_error_mean": float(errors.mean()), "placement_error_max": float(errors.max())}


def run_scene(work: Path, seed: int, swing: float, offset: float) -> dict:
    root = work / f"s{seed}-swing{swing:g}-offset{offset:+g}"
    if not (root / "scene.json").is_file():
        synthesize(preset(SynthConfig, "tiny", seed=seed, ego_speed_swing=swing, radar_time_offset=offset),
                   root, overwrite=True, progress=False)
    scene = read_scene(root)
    out: dict = {}
    for mode in ("off", "auto"):
        prepared = root / f"prepared-{mode}"
        summary = prepare_radar(scene, prepared / "radar", preset(RadarConfig, "tiny", sync=mode))
        sync = summary["time_sync"]
        metrics = evaluate_radar(scene, prepared)
        out[mode] = {"estimate_s": sync["offset_s"], "observable": sync["observable"],
                     "applied_s": sync["applied_s"], "action": sync["action"],
                     **{k: metrics[k] for k in FRONT_END},
                     **placement_error(scene, prepared_synced_scene(scene, prepared / "radar"))}
    estimate = out["auto"]["estimate_s"]
    out["estimate_error_s"] = None if estimate is None else estimate - offset
    return out


def aimotive(work: Path, src: Path) -> dict:
    """The real clip with ``sync`` auto and off: the estimate, what was done, identical outputs."""
    from radar4dgs.datasets.convert.aimotive import aimotive_radar_config, convert_aimotive

    root = work / "aimotive"
    if not (root / "scene.json").is_file():
        convert_aimotive(src, root, scale=0.25, overwrite=True, progress=False)
    scene = read_scene(root)
    runs = {}
    for mode in ("off", "auto"):
        config = aimotive_radar_config()
        config.sync = mode
        summary = prepare_radar(scene, root / f"prepared-{mode}" / "radar", config)
        runs[mode] = summary["time_sync"]
    off, auto = (sorted((root / f"prepared-{m}" / "radar").iterdir()) for m in ("off", "auto"))
    same = [a.name == b.name and (a.name == "summary.json" or a.read_bytes() == b.read_bytes())
            for a, b in zip(off, auto, strict=True)]
    return {"time_sync_auto": runs["auto"], "applied_s": runs["auto"]["applied_s"],
            "outputs_identical_except_summary": bool(all(same)) and len(off) == len(auto)}


def train_comparison(work: Path, seed: int, offset: float, iterations: int) -> dict:
    """Novel-view PSNR / PSNR* of ``tiny`` runs (``iterations``) on the swung scene of ``seed`` with
    ``offset`` injected, prepared with ``sync`` off and auto, and on the scene without an offset
    (reference). Runs with a metrics.json in ``work/train`` are reused."""
    from radar4dgs.cli import main as cli

    out = {}
    for name, scene_offset, mode in (("off", offset, "off"), ("auto", offset, "auto"), ("no_offset", 0.0, "auto")):
        scene = work / f"s{seed}-swing2-offset{scene_offset:+g}"
        prepared, run = work / "train" / f"prep-{name}", work / "train" / f"run-{name}"
        if not (run / "metrics.json").is_file():
            cli(["prepare", str(scene), "--out", str(prepared), "--preset", "tiny", "--config.radar.sync", mode,
                 "--quiet"])
            cli(["train", str(scene), "--prepared", str(prepared), "--out", str(run), "--preset", "tiny",
                 "--config.optim.iterations", str(iterations), "--quiet", "--force"])
            cli(["eval", str(run), "--no-lpips", "--no-video", "--no-report", "--no-actors"])
        nvs = json.loads((run / "metrics.json").read_text())["nvs"]
        out[name] = {"nvs_psnr": nvs["psnr"], "nvs_psnr_star": nvs["psnr_dyn"], "nvs_ssim": nvs["ssim"]}
    return {"seed": seed, "offset_s": offset, "iterations": iterations, "preset": "tiny", **out}


def summarise(per_scene: dict) -> dict:
    swung = [r for key, r in per_scene.items() if "swing2" in key]
    errors = [abs(r["estimate_error_s"]) for r in swung if r["estimate_error_s"] is not None]
    out = {"estimate_abs_error_mean_s": float(np.mean(errors)) if errors else None,
           "estimate_abs_error_max_s": float(np.max(errors)) if errors else None,
           "observable": f"{len(errors)}/{len(swung)}"}
    for mode in ("off", "auto"):
        for key in ("placement_error_mean", "ego_velocity_rmse", "dynamic_precision", "dynamic_recall",
                    "object_velocity_error_median"):
            values = [r[mode][key] for r in swung if r[mode][key] is not None]
            out[f"{key}_{mode}"] = float(np.mean(values)) if values else None
    return out


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--seeds", type=int, nargs="+", default=[1, 2, 3])
    parser.add_argument("--offsets", type=float, nargs="+", default=[0.0, 0.05, -0.05, 0.1, -0.1])
    parser.add_argument("--work", type=Path, default=Path("/tmp/radar4dgs-bench-sync"))
    parser.add_argument("--aimotive", type=Path, default=AIMOTIVE)
    parser.add_argument("--skip-aimotive", action="store_true")
    parser.add_argument("--train", type=int, metavar="SEED", help="also train off / auto / no offset on this seed")
    parser.add_argument("--train-offset", type=float, default=0.1)
    parser.add_argument("--iterations", type=int, default=600)
    parser.add_argument("--out", type=Path, default=ROOT / "benchmarks" / "results" / "radar-sync.json")
    args = parser.parse_args(argv)
    args.work.mkdir(parents=True, exist_ok=True)
    results: dict = {"command": "python benchmarks/sync.py " + " ".join(argv or sys.argv[1:]),
                     "scenes": "tiny synthetic, 20 frames at 10 Hz; ego speed swing +-2 m/s over 4 s",
                     "per_scene": {}}
    cases = [(seed, 2.0, o) for seed in args.seeds for o in args.offsets]
    cases += [(seed, 0.0, o) for seed in args.seeds for o in args.offsets if abs(o) == max(map(abs, args.offsets))]
    for seed, swing, offset in cases:
        key = f"seed{seed}-swing{swing:g}-offset{offset:+g}"
        results["per_scene"][key] = r = run_scene(args.work, seed, swing, offset)
        est = r["auto"]["estimate_s"]
        print(f"{key}: estimate {'unobservable' if est is None else f'{est:+.4f} s'}; placement "
              f"{r['off']['placement_error_mean']:.3f} -> {r['auto']['placement_error_mean']:.3f} m; object "
              f"velocity {r['off']['object_velocity_error_median']} -> {r['auto']['object_velocity_error_median']}"
              f"; ego rmse {r['off']['ego_velocity_rmse']:.4f} -> {r['auto']['ego_velocity_rmse']:.4f}")
    results["summary"] = summarise(results["per_scene"])
    print(json.dumps(results["summary"], indent=1))
    if not args.skip_aimotive and args.aimotive.is_dir():
        results["aimotive"] = a = aimotive(args.work, args.aimotive)
        print(f"aimotive: applied {a['applied_s']} ({a['time_sync_auto']['action']}), outputs identical "
              f"{a['outputs_identical_except_summary']}")
    if args.train is not None:
        results["training"] = t = train_comparison(args.work, args.train, args.train_offset, args.iterations)
        print("training (novel-view PSNR / PSNR*): " + ", ".join(
            f"{k} {t[k]['nvs_psnr']:.2f} / {t[k]['nvs_psnr_star']:.2f}" for k in ("off", "auto", "no_offset")))
    atomic_write_json(args.out, json.loads(json.dumps(results, default=float)))
    print(f"wrote {args.out}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
