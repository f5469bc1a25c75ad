"""Benchmark of the radar front end (issue 3 "Done when"): prints numbers, writes JSON.

    python benchmarks/radar.py                       # everything (synthetic scenes are cached)
    python benchmarks/radar.py --seeds 0 1 --skip-aimotive

Sections:
  timing      ms per 1000-point scan on one core (threads pinned to 1 before numpy loads).
  synthetic   `small` synthetic scenes, default noise: ego-velocity RMSE, dynamic precision /
              recall, static residual, parked-car false-positive rate vs the static noise rate.
  clutter     the same scenes regenerated with 20 % of the points clutter (clutter_fraction 0.25).
  truck       the default scenes' real scans with one big truck injected per frame, as many points
              as the scan has (half the points), moving at 8 m/s in the world.
  aimotive    the real aiMotive sample: speed, smoothness, static residual, recall in moving boxes;
              and the same truck injection into its scans.
"""

from __future__ import annotations

import os

for _var in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ[_var] = "1"

import argparse  # noqa: E402
import json  # noqa: E402
import sys  # noqa: E402
import time  # noqa: E402
import warnings  # noqa: E402
from pathlib import Path  # noqa: E402

import numpy as np  # noqa: E402

from radar4dgs.apps.prepare import PrepareConfig, run_prepare  # noqa: E402
from radar4dgs.config import preset, to_dict  # noqa: E402
from radar4dgs.evaluate.frontend import evaluate_radar  # noqa: E402
from radar4dgs.io.atomic import atomic_write_json  # noqa: E402
from radar4dgs.io.scene import SceneWarning, read_scene  # noqa: E402
from radar4dgs.radar import RadarConfig, classify_dynamic, estimate_ego_motion, expected_radar_velocity  # noqa: E402
from radar4dgs.radar.process import load_radar_outputs  # noqa: E402

ROOT = Path(__file__).resolve().parents[1]
AIMOTIVE = ROOT.parent / "shared" / "fixtures" / "aimotive-night"
TRUCK_SPEED = 8.0          # m/s, world, along the ego's x axis
PARKED_MARGIN = 0.3        # m, box margin when collecting radar points on parked cars


def timing(repeats: int = 200) -> dict:
    """Median ms of estimate_ego_motion + classify_dynamic on a 1000-point scan, 30 % moving."""
    rng = np.random.default_rng(0)
    n, v = 1000, np.array([12.0, -0.3, 0.1])
    az, el = rng.uniform(-1.0, 1.0, n), rng.uniform(-0.17, 0.17, n)
    d = np.stack([np.cos(el) * np.cos(az), np.cos(el) * np.sin(az), np.sin(el)], axis=1)
    xyz = d * rng.uniform(3, 100, (n, 1))
    v_r = -d @ v + rng.normal(0, 0.08, n)
    moving = rng.random(n) < 0.3
    v_r[moving] += rng.uniform(2, 10, moving.sum()) * rng.choice([-1, 1], moving.sum())
    times = []
    for seed in range(repeats):
        t0 = time.perf_counter()
        ego = estimate_ego_motion(xyz, v_r, seed=seed)
        classify_dynamic(xyz, v_r, ego)
        times.append(time.perf_counter() - t0)
    return {"ms_per_1000_points_median": 1e3 * float(np.median(times)),
            "ms_p90": 1e3 * float(np.percentile(times, 90)), "repeats": repeats, "threads": 1}


# ---------------------------------------------------------------------------------------------
# Synthetic scenes


def synth_scene(work: Path, seed: int, variant: str) -> Path:
    from radar4dgs.datasets.synth import SynthConfig, synthesize

    out = work / f"s{seed}-{variant}"
    if (out / "scene.json").is_file():
        return out
    overrides = {"radar": {"clutter_fraction": 0.25}} if variant == "clutter" else {}
    config = preset(SynthConfig, "small", seed=seed, **overrides)
    synthesize(config, out, overwrite=True, progress=False, preset="small")
    return out


def _inside_boxes(points_world: np.ndarray, car: dict, frame: int, margin: float) -> np.ndarray:
    pose = np.asarray(car["poses"][frame])
    local = (points_world - pose[:3, 3]) @ pose[:3, :3]
    inside = np.zeros(len(points_world), dtype=bool)
    for box in car["boxes"]:
        inside |= np.all(np.abs(local - box["center"]) <= np.asarray(box["half_size"]) + margin, axis=1)
    return inside


def parked_car_rates(scene, prepared: Path) -> dict:
    """Dynamic-flag rate on points of parked cars vs on the other static points (the noise rate)."""
    parked = [o for o in scene.extra["synthetic"]["objects"] if o.get("kind") == "parked"]
    on_parked = flagged_parked = other = flagged_other = 0
    for i, frame in enumerate(scene.frames):
        out = load_radar_outputs(prepared / "radar", frame.name)
        with warnings.catch_warnings():
            warnings.simplefilter("ignore", SceneWarning)
            scan = scene.load_radar(i)
        labels = scene.load_optional("gt/radar_labels", i)
        T = scene.radar_to_world(i)
        world = scan.xyz.astype(np.float64) @ T[:3, :3].T + T[:3, 3]
        mask = np.zeros(len(scan), dtype=bool)
        for car in parked:
            mask |= _inside_boxes(world, car, i, PARKED_MARGIN)
        mask &= labels == 0
        static_other = (labels == 0) & ~mask
        on_parked += int(mask.sum())
        flagged_parked += int((out["dynamic"] & mask).sum())
        other += int(static_other.sum())
        flagged_other += int((out["dynamic"] & static_other).sum())
    return {"parked_points": on_parked, "parked_dynamic_rate": flagged_parked / on_parked if on_parked else None,
            "static_points": other, "static_dynamic_rate": flagged_other / other if other else None}


def evaluate_scene(root: Path, config: PrepareConfig, parked: bool) -> dict:
    scene = read_scene(root)
    prepared = root / "prepared"
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", SceneWarning)
        run_prepare(root, prepared, config, force=True, only=("radar",), progress=False)
        report = evaluate_radar(scene, prepared)
    if parked:
        report.update(parked_car_rates(scene, prepared))
    summary = json.loads((prepared / "radar" / "summary.json").read_text())
    report["reasons"] = sorted({f["reason"] for f in summary["frames"] if not f["ok"]})
    report["mean_points"] = float(np.mean([f["points"] for f in summary["frames"]]))
    return report


def inject_truck(xyz: np.ndarray, v_r: np.ndarray, v_radar: np.ndarray, radar_to_ego: np.ndarray,
                 rng: np.random.Generator, centre=(18.0, -4.0, 1.0), size=(12.0, 2.6, 3.8),
                 world_velocity=(TRUCK_SPEED, 0.0, 0.0), v_r_std=0.08) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Add as many truck points as the scan has (half the result), on the surface of a box at
    ``centre`` (ego frame) moving at ``world_velocity`` (ego axes): v_r = d . (v_truck - v_radar)."""
    n = max(len(xyz), 1)
    R, t = radar_to_ego[:3, :3], radar_to_ego[:3, 3]
    half = np.asarray(size) / 2
    # Points on the two faces the radar sees (rear and side facing the ego), jittered.
    u = rng.uniform(-1, 1, (n, 3)) * half
    face = rng.random(n) < 0.5
    u[face, 0] = -half[0]                       # rear face
    u[~face, 1] = half[1] * np.sign(-centre[1])  # side facing the ego's lane
    p_ego = np.asarray(centre) + u
    p_radar = (p_ego - t) @ R
    d = p_radar / np.linalg.norm(p_radar, axis=1, keepdims=True)
    v_truck = R.T @ np.asarray(world_velocity)
    vr_truck = d @ (v_truck - v_radar) + rng.normal(0, v_r_std, n)
    labels = np.concatenate([np.zeros(len(xyz), dtype=bool), np.ones(n, dtype=bool)])
    return np.vstack([xyz, p_radar]), np.concatenate([v_r, vr_truck]), labels


def truck_run(scans, truths, radar_to_ego, config: RadarConfig, seed: int, **truck) -> dict:
    """estimate + classify on scans with an injected truck; truths (T, 3) true radar velocity."""
    rng = np.random.default_rng(seed)
    errors, ok, found_static, tp, fp, truck_points, on_truck_inliers = [], 0, 0, 0, 0, 0, 0
    reasons = set()
    prior = None
    vertical = radar_to_ego[:3, :3].T @ np.array([0.0, 0.0, 1.0])
    for i, ((xyz, v_r), v_true) in enumerate(zip(scans, truths, strict=True)):
        xyz2, vr2, is_truck = inject_truck(xyz, v_r, v_true, radar_to_ego, rng, **truck)
        ego = estimate_ego_motion(xyz2, vr2, config, prior=prior, vertical_axis=vertical, seed=seed + i)
        prior = ego.velocity if ego.ok else None   # as radar.process.fit_frames
        if ego.ok:
            ok += 1
        else:
            reasons.add(ego.reason)
        err = float(np.linalg.norm(ego.velocity - v_true)) if np.all(np.isfinite(ego.velocity)) else float("nan")
        errors.append(err)
        found_static += int(np.isfinite(err) and err < 0.2)
        dynamic, _ = classify_dynamic(xyz2, vr2, ego, config)
        tp += int((dynamic & is_truck).sum())
        fp += int((dynamic & ~is_truck).sum())
        truck_points += int(is_truck.sum())
        on_truck_inliers += int((ego.inliers & is_truck).sum())
    errors = np.array(errors)
    return {"frames": len(scans), "ok_frames": ok, "frames_static_world_found (err<0.2)": found_static,
            "ego_velocity_rmse": float(np.sqrt(np.nanmean(errors ** 2))),
            "truck_recall": tp / truck_points, "truck_inlier_fraction": on_truck_inliers / truck_points,
            "dynamic_flags_off_truck": fp, "reasons": sorted(reasons)}


def synthetic_truck(root: Path, config: RadarConfig, seed: int) -> dict:
    scene = read_scene(root)
    truths, _ = expected_radar_velocity(scene)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", SceneWarning)
        scans = [(s.xyz.astype(np.float64), s.v_r.astype(np.float64))
                 for s in (scene.load_radar(i) for i in range(len(scene)))]
    return truck_run(scans, truths, scene.radar.radar_to_ego, config, seed)


# ---------------------------------------------------------------------------------------------
# aiMotive


def aimotive(work: Path, src: Path) -> dict:
    from radar4dgs.datasets.convert.aimotive import aimotive_radar_config, convert_aimotive

    root = work / "aimotive"
    if not (root / "scene.json").is_file():
        convert_aimotive(src, root, scale=0.25, overwrite=True, progress=False)
    radar_config = aimotive_radar_config()
    report = evaluate_scene(root, PrepareConfig(radar=radar_config), parked=False)
    scene = read_scene(root)
    summary = json.loads((root / "prepared" / "radar" / "summary.json").read_text())
    velocity = np.array([f["velocity"] for f in summary["frames"]], dtype=float)
    speed = np.linalg.norm(velocity, axis=1)
    # Unsmoothed per-frame fits as well: smoothing must not be what makes it smooth.
    raw = dict(radar_config.__dict__)
    raw["smoothing"] = "none"
    raw_root = work / "aimotive-raw-prepared"
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", SceneWarning)
        run_prepare(root, raw_root, PrepareConfig(radar=RadarConfig(**raw)), force=True, only=("radar",),
                    progress=False)
    raw_summary = json.loads((raw_root / "radar" / "summary.json").read_text())
    raw_speed = np.array([f["speed"] for f in raw_summary["frames"]], dtype=float)
    # False positives that look like noise (|v_r_comp| <= 2 m/s) vs fast unlabelled movers.
    noise_like = fast = flagged_unlabelled = 0
    for i, frame in enumerate(scene.frames):
        out = load_radar_outputs(root / "prepared" / "radar", frame.name)
        labels = scene.load_optional("gt/radar_labels", i)
        extra = out["dynamic"] & (labels == 0)
        flagged_unlabelled += int(extra.sum())
        noise_like += int((extra & (np.abs(out["v_r_comp"]) <= 2.0)).sum())
        fast += int((extra & (np.abs(out["v_r_comp"]) > 5.0)).sum())
    truths = velocity  # the smoothed radar estimate: the truck test measures robustness, not accuracy
    scans = [(s.xyz.astype(np.float64), s.v_r.astype(np.float64))
             for s in (scene.load_radar(i) for i in range(len(scene)))]
    # This radar has almost no elevation spread (+-2 deg): a flat truck, and a 3.8 m tall one whose
    # elevation spread must not make the fit 3-D (the static inliers decide the model).
    truck = truck_run(scans, truths, scene.radar.radar_to_ego, radar_config, 0, centre=(30.0, 3.5, 0.4),
                      size=(12.0, 2.6, 0.3))
    truck_tall = truck_run(scans, truths, scene.radar.radar_to_ego, radar_config, 0, centre=(30.0, 3.5, 1.5))
    return {
        "forward_speed_mean": float(velocity[:, 0].mean()),
        "speed_min": float(speed.min()), "speed_max": float(speed.max()),
        "frame_to_frame_change_std": float(np.std(np.diff(speed))),
        "frame_to_frame_change_std_unsmoothed": float(np.std(np.diff(raw_speed))),
        "static_residual_median": report["static_residual_median"],
        "recall_in_moving_boxes": report["dynamic_recall"],
        "precision_vs_boxes": report["dynamic_precision"],
        "dynamic_points": report["dynamic_points"],
        "flagged_outside_boxes": flagged_unlabelled,
        "flagged_outside_boxes_fast_(>5m/s)": fast,
        "flagged_outside_boxes_noise_like_(<=2m/s)": noise_like,
        "ok_frames": report["ok_frames"], "frames": report["frames"],
        "mean_points": report["mean_points"],
        "pose_model": scene.source.get("pose_model"),
        "truck_injection": truck,
        "truck_injection_tall_3d": truck_tall,
    }


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--seeds", type=int, nargs="+", default=[0, 1, 2, 3, 4])
    parser.add_argument("--work", type=Path, default=Path("/tmp/radar4dgs-bench-radar"))
    parser.add_argument("--aimotive", type=Path, default=AIMOTIVE)
    parser.add_argument("--out", type=Path, default=ROOT / "benchmarks" / "results" / "radar.json")
    parser.add_argument("--skip-synth", action="store_true")
    parser.add_argument("--skip-aimotive", action="store_true")
    args = parser.parse_args(argv)
    args.work.mkdir(parents=True, exist_ok=True)
    results: dict = {"command": "python benchmarks/radar.py " + " ".join(argv or sys.argv[1:]),
                     "config": to_dict(preset(RadarConfig, "small"))}

    results["timing"] = timing()
    print(f"timing: {results['timing']['ms_per_1000_points_median']:.2f} ms per 1000-point scan (1 thread)")

    if not args.skip_synth:
        config = preset(PrepareConfig, "small")
        for variant in ("default", "clutter"):
            per_seed = {}
            for seed in args.seeds:
                t0 = time.perf_counter()
                root = synth_scene(args.work, seed, variant)
                per_seed[seed] = evaluate_scene(root, config, parked=True)
                r = per_seed[seed]
                # Ablation: the per-frame fit without the ground-vehicle (vertical) prior.
                free = PrepareConfig(radar=RadarConfig(**{**config.radar.__dict__, "vertical_prior_std": 0.0}))
                r["ego_velocity_rmse_without_vertical_prior"] = evaluate_scene(
                    root, free, parked=False)["ego_velocity_rmse"]
                run_prepare(root, root / "prepared", config, force=True, only=("radar",), progress=False)
                print(f"{variant} seed {seed}: rmse {r['ego_velocity_rmse']:.4f} m/s (no vertical prior "
                      f"{r['ego_velocity_rmse_without_vertical_prior']:.4f}), precision "
                      f"{r['dynamic_precision']:.3f}, recall {r['dynamic_recall']:.3f}, static residual "
                      f"{r['static_residual_median']:.3f}, ok {r['ok_frames']}/{r['frames']}, parked rate "
                      f"{r['parked_dynamic_rate']}, static rate {r['static_dynamic_rate']:.4f} "
                      f"({time.perf_counter() - t0:.0f} s)")
            keys = ("ego_velocity_rmse", "ego_velocity_rmse_without_vertical_prior", "dynamic_precision",
                    "dynamic_recall", "static_residual_median", "parked_dynamic_rate", "static_dynamic_rate")
            results[variant] = {"per_seed": per_seed, "mean": {
                k: float(np.mean([r[k] for r in per_seed.values() if r[k] is not None])) for k in keys},
                "worst": {"ego_velocity_rmse": max(r["ego_velocity_rmse"] for r in per_seed.values()),
                          "dynamic_precision": min(r["dynamic_precision"] for r in per_seed.values()),
                          "dynamic_recall": min(r["dynamic_recall"] for r in per_seed.values())}}
            print(f"{variant} mean: " + ", ".join(f"{k} {v:.4f}" for k, v in results[variant]["mean"].items()))
        results["truck"] = {}
        for seed in args.seeds:
            r = synthetic_truck(args.work / f"s{seed}-default", config.radar, seed)
            results["truck"][seed] = r
            print(f"truck seed {seed}: ok {r['ok_frames']}/{r['frames']}, static world found "
                  f"{r['frames_static_world_found (err<0.2)']}, rmse {r['ego_velocity_rmse']:.4f}, truck recall "
                  f"{r['truck_recall']:.3f}, reasons {r['reasons']}")

    if not args.skip_aimotive and args.aimotive.is_dir():
        results["aimotive"] = a = aimotive(args.work, args.aimotive)
        print(f"aimotive: forward speed {a['forward_speed_mean']:.2f} m/s ({a['speed_min']:.2f}-{a['speed_max']:.2f}), "
              f"change std {a['frame_to_frame_change_std']:.3f} (unsmoothed "
              f"{a['frame_to_frame_change_std_unsmoothed']:.3f}), static residual median "
              f"{a['static_residual_median']:.3f}, recall in moving boxes {a['recall_in_moving_boxes']:.3f}, "
              f"precision vs boxes {a['precision_vs_boxes']:.3f} (outside boxes: {a['flagged_outside_boxes']}, "
              f"of which >5 m/s {a['flagged_outside_boxes_fast_(>5m/s)']}, <=2 m/s "
              f"{a['flagged_outside_boxes_noise_like_(<=2m/s)']})")
        t = a["truck_injection"]
        print(f"aimotive + truck: ok {t['ok_frames']}/{t['frames']}, static world found "
              f"{t['frames_static_world_found (err<0.2)']}, truck recall {t['truck_recall']:.3f}, "
              f"reasons {t['reasons']}")

    atomic_write_json(args.out, json.loads(json.dumps(results, default=float)))
    print(f"wrote {args.out}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
