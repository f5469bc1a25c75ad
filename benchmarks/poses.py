"""Benchmark of pose refinement and exposure compensation (issue 27): synthetic scenes whose
training-frame poses carry independent noise, or whose training images' exposure changes, trained
with and without the corrections; and the aiMotive clip before and after.

    python benchmarks/poses.py [--seeds 2 3] [--preset tiny] [--iterations 600]
                               [--noise-m 0.10] [--noise-deg 0.3] [--exposure 0.3] [--cells ...]
                               [--work /tmp/radar4dgs-poses-bench] [--aimotive]
                               [--out benchmarks/results/poses.json] [--poses KEY=VALUE ...]

Seeds: 1 is the tuning seed (the pose rates were chosen on it), 2 and 3 are reported only; fixed
before any tuning. Per seed (work/seed<N>/), cells (--cells, all by default):

- ``exact``: ``radar4dgs synth`` + ``prepare``, refinement off; ``exact-refined``: refinement on
  (does it cost anything where the poses are right?).
- ``noisy``: a copy of the scene folder whose TRAINING frames' poses are perturbed in scene.json
  (test frames exact): per frame, a camera-axes translation with N(0, noise_m) per axis and a
  rotation with N(0, noise_deg) per axis (camera_to_world @ exp(xi); the radar's pose moves with
  the ego, so the radar stays where it was relative to the camera); ``source`` says
  ``poses_from_odometry``. It is prepared on its own (its depth and flow see the noisy poses, as
  a real drive's would). ``noisy`` trains without refinement, ``noisy-refined`` with it.
- ``exposed``: a copy whose TRAINING images are scaled by a gain uniform in [1 - exposure,
  1 + exposure] per frame, prepared on its own; ``exposed`` trains without, ``exposed-compensated``
  with the per-frame colour transform.

Every run is evaluated (``metrics.json``: novel-view PSNR and PSNR* at the recorded test poses,
and for refined runs after test-view alignment; for every run also with each test frame's exposure
aligned, ``nvs_psnr_exposure_aligned``); the training frames' pose error against the
exact poses before (the noisy scene) and after refinement (``RUN/poses.json``). --aimotive
converts the aiMotive clip at 320x176 and trains it without and with refinement and compensation.
Finished runs are reused (a rerun only collects them, re-evaluating metrics older than the
exposure alignment); a run of some --cells keeps the seed's other cells in --out. Results go to --out after every seed.
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import shutil
import sys
import time
from pathlib import Path

import numpy as np

from radar4dgs.config import preset
from radar4dgs.datasets.convert.aimotive import HOOD_FRACTION
from radar4dgs.io.atomic import atomic_write_json

RESULTS = Path(__file__).parent / "results" / "poses.json"
FIXTURE = Path(__file__).resolve().parents[2] / "shared" / "fixtures" / "aimotive-night"


def perturb_scene(exact: Path, noisy: Path, noise_m: float, noise_deg: float, seed: int) -> None:
    """Copy scene folder ``exact`` to ``noisy`` and perturb its training frames' poses in scene.json."""
    import torch

    from radar4dgs.io.scene import read_scene
    from radar4dgs.model.pose_refine import se3_exp

    if (noisy / "scene.json").is_file():
        return
    scene = read_scene(exact)
    tmp = noisy.with_name(noisy.name + ".tmp")
    shutil.rmtree(tmp, ignore_errors=True)
    shutil.copytree(exact, tmp)
    meta = json.loads((tmp / "scene.json").read_text())
    rng = np.random.default_rng(1000 + seed)
    cam_to_ego = scene.camera.cam_to_ego
    for index in scene.train_indices:
        frame = meta["frames"][index]
        xi = np.concatenate([rng.normal(0, noise_m, 3), np.radians(rng.normal(0, noise_deg, 3))])
        ego_to_world = np.asarray(frame["ego_to_world"], dtype=np.float64)
        cam_to_world = ego_to_world @ cam_to_ego @ se3_exp(torch.as_tensor(xi)).numpy()
        new_ego = cam_to_world @ np.linalg.inv(cam_to_ego)
        frame["ego_to_world"] = new_ego.tolist()
        if "radar_ego_to_world" in frame:
            moved = new_ego @ np.linalg.inv(ego_to_world)
            frame["radar_ego_to_world"] = (moved @ np.asarray(frame["radar_ego_to_world"])).tolist()
    meta["source"] = {**meta.get("source", {}), "poses_from_odometry": True,
                      "pose_noise": {"translation_std_m": noise_m, "rotation_std_deg": noise_deg,
                                     "frames": "training", "axes": "camera", "seed": 1000 + seed}}
    (tmp / "scene.json").write_text(json.dumps(meta, indent=1))
    tmp.rename(noisy)


def expose_scene(exact: Path, out: Path, change: float, seed: int) -> None:
    """Copy scene folder ``exact`` to ``out`` with each TRAINING image's exposure scaled by a gain
    drawn uniformly in [1 - change, 1 + change] (clipped to 255); test images unchanged."""
    from PIL import Image

    from radar4dgs.io.scene import read_scene

    if (out / "scene.json").is_file():
        return
    scene = read_scene(exact)
    tmp = out.with_name(out.name + ".tmp")
    shutil.rmtree(tmp, ignore_errors=True)
    shutil.copytree(exact, tmp)
    rng = np.random.default_rng(2000 + seed)
    gains = {}
    for index in scene.train_indices:
        gain = float(rng.uniform(1 - change, 1 + change))
        path = tmp / scene.image_files[index].relative_to(exact)
        image = np.asarray(Image.open(path).convert("RGB"), dtype=np.float64)
        Image.fromarray(np.clip(image * gain + 0.5, 0, 255).astype(np.uint8)).save(path)
        gains[scene.frames[index].name] = gain
    meta = json.loads((tmp / "scene.json").read_text())
    meta["source"] = {**meta.get("source", {}), "exposure_change": {"range": change, "seed": 2000 + seed,
                                                                     "gains": gains}}
    (tmp / "scene.json").write_text(json.dumps(meta, indent=1))
    tmp.rename(out)


def pose_errors(truth_scene, estimated: dict[int, np.ndarray]) -> dict[str, float]:
    """Mean translation (m) and rotation (deg) error of ``estimated`` world_to_camera per frame index."""
    from radar4dgs.model.pose_refine import pose_error

    errors = np.array([pose_error(w2c, truth_scene.world_to_camera(i)) for i, w2c in estimated.items()])

    def centre(w2c: np.ndarray) -> np.ndarray:
        return -w2c[:3, :3].T @ w2c[:3, 3]

    # Camera centres' offsets with their common (mean) offset removed: the part no refinement can
    # see (moving every camera and the scene together changes no image) taken out, as ATE aligns.
    offsets = np.array([centre(w2c) - centre(truth_scene.world_to_camera(i)) for i, w2c in estimated.items()])
    return {"translation_m": float(errors[:, 0].mean()), "rotation_deg": float(errors[:, 1].mean()),
            "translation_rmse_m": float(np.sqrt((errors[:, 0] ** 2).mean())),
            "common_offset_m": offsets.mean(0).tolist(),
            "translation_without_common_offset_m": float(np.linalg.norm(offsets - offsets.mean(0), axis=1).mean())}


def smoothed_training_poses(scene) -> dict[int, np.ndarray]:
    """The training cameras moved onto their smoothed trajectory (PoseRefineConfig.smooth_trajectory:
    where refinement starts, before any image is seen)."""
    import torch

    from radar4dgs.model.pose_refine import se3_exp, trajectory_target

    w2c = np.stack([scene.world_to_camera(i) for i in scene.train_indices])
    times = np.array([scene.frames[i].timestamp for i in scene.train_indices])
    moved = se3_exp(torch.as_tensor(trajectory_target(times, w2c))).numpy() @ w2c
    return dict(zip(scene.train_indices, moved, strict=True))


def true_corrections(truth_scene, noisy_scene) -> dict[int, np.ndarray]:
    """Per training frame, the twist (rho m, omega rad) that moves the noisy camera onto the true one
    (``w2c_true = exp(xi) @ w2c_noisy``; first order: rho from the translation, omega from the
    rotation vector)."""
    from scipy.spatial.transform import Rotation

    out = {}
    for i in truth_scene.train_indices:
        delta = truth_scene.world_to_camera(i) @ np.linalg.inv(noisy_scene.world_to_camera(i))
        out[i] = np.concatenate([delta[:3, 3], Rotation.from_matrix(delta[:3, :3]).as_rotvec()])
    return out


def correction_figure(seed_dir: Path, path: Path) -> None:
    """Learned against true corrections (translation and rotation components) of one seed's
    ``noisy-refined`` run: the picture on docs/benchmarks.md."""
    from matplotlib.figure import Figure

    from radar4dgs.io.scene import read_scene

    truth = true_corrections(read_scene(seed_dir / "exact"), read_scene(seed_dir / "noisy"))
    frames = json.loads((seed_dir / "noisy-refined-run" / "poses.json").read_text())["frames"]
    learned = {f["index"]: np.array(f["correction"]["translation_m"] + f["correction"]["rotation_rad"])
               for f in frames}
    t = np.array([truth[i] for i in learned])
    ll = np.array([learned[i] for i in learned])
    fig = Figure(figsize=(8.0, 3.6), dpi=100, layout="constrained")
    for ax, cols, scale, unit in zip(fig.subplots(1, 2), (slice(0, 3), slice(3, 6)), (1.0, 180 / np.pi),
                                     ("m", "deg"), strict=True):
        for j, name in enumerate("xyz"):
            ax.scatter(t[:, cols][:, j] * scale, ll[:, cols][:, j] * scale, s=14, label=f"camera {name}")
        lim = np.abs(t[:, cols]).max() * scale * 1.1
        ax.plot([-lim, lim], [-lim, lim], color="grey", linewidth=0.8, label="learned = true")
        ax.set_xlabel(f"true correction ({unit})")
        ax.set_ylabel(f"learned correction ({unit})")
        ax.set_title("translation" if unit == "m" else "rotation")
        ax.grid(True, alpha=0.3)
        ax.legend(fontsize="small")
    path.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(path, metadata={"Software": None})


def train_and_eval(scene: Path, prepared: Path, run: Path, preset_name: str, iterations: int | None,
                   refine: str, appearance: str = "off", poses: dict | None = None) -> dict:
    from radar4dgs.evaluate.reconstruction import evaluate_run
    from radar4dgs.model.config import TrainConfig
    from radar4dgs.train.trainer import train_run

    seconds = None
    if not (run / "model.pt").is_file():
        overrides: dict = {"threads": 1, "poses": {**dataclasses.asdict(preset(TrainConfig, preset_name).poses),
                                                   **(poses or {}), "refine": refine, "appearance": appearance}}
        if iterations:
            overrides["optim"] = {"iterations": iterations}
        config = preset(TrainConfig, preset_name, **overrides)
        started = time.perf_counter()
        train_run(scene, prepared, run, config, resume=(run / "checkpoints" / "last.pt").is_file(), progress=False,
                  tensorboard=False)
        seconds = time.perf_counter() - started
    metrics_path = run / "metrics.json"
    m = json.loads(metrics_path.read_text()) if metrics_path.is_file() else {}
    # Metrics written before the exposure alignment existed are recomputed, the model reused.
    if "nvs_exposure_aligned" not in m:
        m = evaluate_run(run, lpips=False, video=False, report=False, progress=False)
    out = {"recon_psnr": m["recon"]["psnr"], "nvs_psnr": m["nvs"]["psnr"], "nvs_psnr_dyn": m["nvs"]["psnr_dyn"],
           "nvs_psnr_exposure_aligned": m["nvs_exposure_aligned"]["psnr"],
           "nvs_psnr_dyn_exposure_aligned": m["nvs_exposure_aligned"]["psnr_dyn"],
           "train_seconds": seconds if seconds is not None else (m.get("run") or {}).get("train_seconds")}
    for name, scores in (m.get("nvs_aligned") or {}).items():
        out[f"nvs_psnr_{name}"] = scores["psnr"]
        out[f"nvs_psnr_dyn_{name}"] = scores["psnr_dyn"]
    return out


def run_seed(seed: int, args: argparse.Namespace) -> dict:
    from radar4dgs.apps.prepare import PrepareConfig, run_prepare
    from radar4dgs.datasets.synth import SynthConfig, synthesize
    from radar4dgs.io.scene import read_scene
    from radar4dgs.model.run import read_refined_poses

    root = args.work / f"seed{seed}"
    exact, noisy, exposed = root / "exact", root / "noisy", root / "exposed"
    if not (exact / "scene.json").is_file():
        synthesize(preset(SynthConfig, args.preset, seed=seed), exact, overwrite=True, progress=False,
                   preset=args.preset)
    perturb_scene(exact, noisy, args.noise_m, args.noise_deg, seed)
    scenes = [exact, noisy]
    if {"exposed", "exposed-compensated"} & set(args.cells):
        expose_scene(exact, exposed, args.exposure, seed)
        scenes.append(exposed)
    for scene in scenes:
        run_prepare(scene, root / f"{scene.name}-prepared", preset(PrepareConfig, args.preset), progress=False)
    truth = read_scene(exact)
    noisy_scene = read_scene(noisy)
    result: dict = {"seed": seed, "tuning": seed == 1,
                    "pose_error_before": pose_errors(truth, {i: noisy_scene.world_to_camera(i)
                                                             for i in truth.train_indices}),
                    "pose_error_smoothed": pose_errors(truth, smoothed_training_poses(noisy_scene))}
    cells = {"exact": (exact, "off", "off"), "exact-refined": (exact, "on", "off"), "noisy": (noisy, "off", "off"),
             "noisy-refined": (noisy, "on", "off"), "exposed": (exposed, "off", "off"),
             "exposed-compensated": (exposed, "off", "on")}
    for name, (scene, refine, appearance) in cells.items():
        if name not in args.cells:
            continue
        run = root / f"{name}-run"
        result[name] = train_and_eval(scene, root / f"{scene.name}-prepared", run, args.preset, args.iterations,
                                      refine, appearance, poses=args.poses)
        if refine == "on" and scene == noisy:
            result["pose_error_after"] = pose_errors(truth, read_refined_poses(run / "poses.json"))
        print(f"seed {seed} {name}: {result[name]}", flush=True)
    return result


def frame_picture(scene_dir: Path, runs: list[tuple[Path, str]], path: Path) -> str:
    """Ground truth | each run's render (at the recorded pose) of the middle test frame of the scene
    at ``scene_dir``, labelled "label: PSNR", as a JPEG at ``path``; returns the frame's name. A
    shorter render (a hood-cropped run) is padded black at the bottom."""
    import cv2

    from radar4dgs.evaluate.visualize import side_by_side
    from radar4dgs.io.scene import read_scene

    scene = read_scene(scene_dir)
    index = scene.test_indices[len(scene.test_indices) // 2]
    name = scene.frames[index].name
    panels, labels = [scene.load_image(index)], ["ground truth"]
    for run, label in runs:
        panels.append(cv2.cvtColor(cv2.imread(str(run / "renders" / "nvs" / f"{name}.png")), cv2.COLOR_BGR2RGB))
        metrics = json.loads((run / "metrics.json").read_text())
        psnr = next(e["psnr"] for e in metrics["per_frame"]["nvs"] if e["frame"] == name)
        labels.append(f"{label}: {psnr:.1f} dB")
    path.parent.mkdir(parents=True, exist_ok=True)
    picture = cv2.cvtColor(side_by_side(panels, labels), cv2.COLOR_RGB2BGR)
    cv2.imwrite(str(path), picture, [cv2.IMWRITE_JPEG_QUALITY, 90])
    return name


def run_aimotive(args: argparse.Namespace) -> dict:
    """The aiMotive clip (converted at 320x176), prepared, trained without refinement and with pose
    refinement and exposure compensation (what "auto" turns on for it)."""
    from radar4dgs.apps.prepare import PrepareConfig, run_prepare
    from radar4dgs.datasets.convert.aimotive import convert_aimotive

    crop = args.aimotive_crop_bottom
    root = args.work / ("aimotive" if not crop else f"aimotive-crop{round(crop * 100)}")
    scene = root / "scene"
    if not (scene / "scene.json").is_file():  # 320x176, as reconstruct.py (320 x fewer rows when cropped)
        convert_aimotive(FIXTURE, scene, scale=0.25, overwrite=True, progress=False, crop_bottom=crop)
    run_prepare(scene, root / "prepared", preset(PrepareConfig, args.preset), progress=False)
    out = {}
    variants = {"before": ("off", "off"), "after": ("on", "on"), "poses-only": ("on", "off"),
                "appearance-only": ("off", "on")}
    for name in args.aimotive_cells:
        refine, appearance = variants[name]
        out[name] = train_and_eval(scene, root / "prepared", root / f"{name}-run", args.preset, args.iterations,
                                   refine, appearance, args.poses)
        print(f"aimotive {name}: {out[name]}", flush=True)
    if args.aimotive_picture:  # ground truth | before | after refinement
        out["picture_frame"] = frame_picture(scene, [(root / f"{r}-run", r) for r in ("before", "after")],
                                             args.aimotive_picture)
    uncropped_scene, uncropped = args.work / "aimotive" / "scene", args.work / "aimotive" / "before-run"
    if crop and (uncropped / "renders" / "nvs").is_dir():
        out["uncropped_before_on_kept_rows"] = kept_rows_psnr(uncropped, uncropped_scene, scene)
        if args.aimotive_hood_picture:
            out["hood_picture_frame"] = frame_picture(
                uncropped_scene, [(uncropped, "with the hood"), (root / "before-run", "hood cut off")],
                args.aimotive_hood_picture)
    return out


def kept_rows_psnr(run: Path, scene_dir: Path, cropped_scene_dir: Path) -> dict:
    """Novel-view PSNR of an uncropped run's saved test renders over the top rows that the
    hood-cropped conversion at ``cropped_scene_dir`` keeps, averaged over the test frames as
    ``metrics.json`` averages them: the cropped run's number on the same pixels. PSNR* needs no
    such cut: no moving object reaches the hood."""
    import torch
    from PIL import Image

    from radar4dgs.io.scene import read_scene
    from radar4dgs.metrics.image import psnr

    scene, rows = read_scene(scene_dir), read_scene(cropped_scene_dir).camera.height
    scores = []
    for i in scene.test_indices:
        render = np.asarray(Image.open(run / "renders" / "nvs" / f"{scene.frames[i].name}.png").convert("RGB"))
        truth = scene.load_image(i)
        scores.append(psnr(torch.from_numpy(render[:rows] / 255.0), torch.from_numpy(truth[:rows] / 255.0)))
    return {"rows": rows, "nvs_psnr": float(np.mean(scores))}


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--seeds", type=int, nargs="*", default=[2, 3])
    parser.add_argument("--preset", default="tiny")
    parser.add_argument("--iterations", type=int, default=600, help="training iterations (0 = the preset's)")
    parser.add_argument("--noise-m", type=float, default=0.10)
    parser.add_argument("--noise-deg", type=float, default=0.3)
    parser.add_argument("--exposure", type=float, default=0.3, help="exposure change of the 'exposed' cells")
    parser.add_argument("--cells", nargs="+", default=["exact", "exact-refined", "noisy", "noisy-refined", "exposed",
                                                       "exposed-compensated"])
    parser.add_argument("--work", type=Path, default=Path("/tmp/radar4dgs-poses-bench"))
    parser.add_argument("--aimotive", action="store_true")
    parser.add_argument("--aimotive-cells", nargs="+", default=["before", "after", "poses-only", "appearance-only"],
                        choices=["before", "after", "poses-only", "appearance-only"])
    parser.add_argument("--aimotive-crop-bottom", type=float, default=HOOD_FRACTION,
                        help="fraction of the clip's rows cut off at the bottom (the hood; the converter's default). "
                             "0 keeps them (work folder aimotive/); otherwise the uncropped 'before' run, when "
                             "there, is also scored on the kept rows")
    parser.add_argument("--aimotive-hood-picture", type=Path, default=None,
                        help="ground truth | uncropped | cropped 'before' runs of a test frame "
                             "(docs/images/aimotive_hood.jpg)")
    parser.add_argument("--aimotive-picture", type=Path, default=None,
                        help="ground truth | before | after of a test frame (docs/images/aimotive_pose_refine.jpg)")
    parser.add_argument("--out", type=Path, default=RESULTS)
    parser.add_argument("--figure", type=Path, default=None,
                        help="learned against true corrections of the first seed (docs/images/pose_refinement.png)")
    parser.add_argument("--poses", nargs="*", default=[], metavar="KEY=VALUE",
                        help="PoseRefineConfig overrides for every run (tuning), e.g. translation_lr=0.005")
    args = parser.parse_args(argv)
    args.poses = {k: float(v) for k, v in (item.split("=", 1) for item in args.poses)}
    results: dict = {"preset": args.preset, "iterations": args.iterations or None, "noise_m": args.noise_m,
                     "noise_deg": args.noise_deg, "exposure_change": args.exposure, "tuning_seeds": [1],
                     "pose_overrides": args.poses, "seeds": {}}
    if args.out.is_file():
        results = {**json.loads(args.out.read_text()), **{k: v for k, v in results.items() if k != "seeds"}}
    for seed in args.seeds:
        # A run of some cells keeps the seed's other cells from earlier runs.
        results["seeds"][str(seed)] = {**results["seeds"].get(str(seed), {}), **run_seed(seed, args)}
        atomic_write_json(args.out, results)
    if args.figure and args.seeds:
        correction_figure(args.work / f"seed{args.seeds[0]}", args.figure)
    if args.aimotive:
        key = "aimotive" if args.aimotive_crop_bottom else "aimotive_uncropped"
        results[key] = {**results.get(key, {}), **run_aimotive(args), "crop_bottom": args.aimotive_crop_bottom}
        atomic_write_json(args.out, results)
    return 0


if __name__ == "__main__":
    sys.exit(main())
