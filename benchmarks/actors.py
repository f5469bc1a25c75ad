"""Benchmark of actor discovery and clean backgrounds (issue 24) on synthetic scenes with ground truth.

    python benchmarks/actors.py --seeds 106 107 108 109 110 [--traffic realistic] [--fps 5] [--preset tiny]
                                [--iterations 600] [--work /tmp/radar4dgs-actors-bench]
                                [--out benchmarks/results/actors.json] [--run RUN ...]
                                [--discovery-set KEY=VALUE ...] [--oracle]

Seeds fixed before looking, the project's convention: realistic traffic 101-105 tune (the discovery
thresholds were set on 101 only), 106-110 report; the hard set (``--traffic rush --fps 5``) 214-215 tune
(none of its thresholds was set on them), 209-213 report. Per seed: `radar4dgs synth --traffic realistic`
at --preset, prepared, its background render (the generator's same world without its moving objects,
``gt/background``), trained with the preset's config and --iterations (CPU budget), then:

- actors (``radar4dgs.actors.discover``) against the generator's moving objects visible within 60 m
  in >= 5 frames (some of their own surface shows: a pedestrian behind a passing car is in view, not
  visible; ``radar4dgs.actors.groundtruth``): count, recall (and ``recall_in_view``, over the movers in
  view in >= 5 frames, hidden or not), precision, spurious actors, median planar centroid error (m) and
  median planar velocity error (m/s) over every common frame of the matched pairs;
- on the test frames (every 4th), over the pixels the moving objects cover (gt/dynamic_mask): PSNR
  of the render with every actor removed (the static layer) against the background render, and of
  the unedited render against it (what "not removing" leaves), pooled over the frames;
- the fraction of those pixels marked "never observed" (``radar4dgs.actors.background``), and the
  removed-actor PSNR over the others (where a training frame saw the static surface), and the static
  layer's PSNR over the pixels no mover covers (the background render equals the frame there).

``--oracle`` also makes each scene again without its moving objects (``radar4dgs synth --scene.without-movers``:
every frame is the background render), prepares and trains it with the run's own configs, and scores that
static layer on the same pixels (``oracle_psnr_*``): what the static layer reaches at the run's budget when
nothing ever hid the road, the ceiling of the removed-mover scores.

``--run RUN`` scores an already trained run of a synthetic scene too (its scene needs gt/background,
written here when missing). ``--discovery-set KEY=VALUE`` discovers with other ActorConfig values
(``min_gaussians=8``): with ``--seeds`` and ``--run``, a threshold is tried on trained runs without
training again. Finished runs under --work are reused. Writes the JSON after every scene.
"""

from __future__ import annotations

import argparse
import json
import math
import sys
import time
from pathlib import Path

import numpy as np

from radar4dgs.io.atomic import atomic_write_json
from scene_configs import prepare_config, synth_config, synthesize_once

RESULTS = Path(__file__).parent / "results"


def build_scene(seed: int, traffic: str, preset_name: str, work: Path, prepare_set: list[str] = (),
                fps: float | None = None) -> Path:
    """Synthesize and prepare one scene under work/scenes/, with its background render; reused.
    ``fps``: the scenes' frame rate (None: the preset's)."""
    from radar4dgs.apps.prepare import run_prepare
    from radar4dgs.datasets.synth.background import BACKGROUND_DIR, write_backgrounds
    from radar4dgs.io.scene import read_scene

    scene = work / "scenes" / (f"{preset_name}-{traffic}-s{seed}" + ("" if fps is None else f"-{fps:g}hz"))
    synthesize_once(synth_config(preset_name, seed, traffic, fps), scene, preset_name)
    if not (scene / "prepared" / "config.json").is_file():
        run_prepare(scene, scene / "prepared", prepare_config(preset_name, prepare_set), progress=False,
                    wait=math.inf)
    if not (scene / BACKGROUND_DIR).is_dir():
        write_backgrounds(scene, read_scene(scene).test_indices)  # only the test frames are scored
    return scene


def train_scene(scene: Path, preset_name: str, iterations: int, out: Path) -> Path:
    """Train ``scene`` into ``out`` (reused when its model exists)."""
    from radar4dgs.config import preset
    from radar4dgs.model.config import TrainConfig
    from radar4dgs.train.trainer import train_run

    if not (out / "model.pt").is_file():
        config = preset(TrainConfig, preset_name, threads=1, optim={"iterations": iterations})
        train_run(scene, scene / "prepared", out, config, progress=False, tensorboard=False)
    return out


def novel_view_scores(run_dir: Path) -> dict:
    """The run's reconstruction and novel-view PSNR and PSNR* (``radar4dgs eval`` without LPIPS, video
    or report; its metrics.json is reused when present)."""
    from radar4dgs.evaluate.reconstruction import evaluate_run

    path = run_dir / "metrics.json"
    metrics = (json.loads(path.read_text()) if path.is_file() else
               evaluate_run(run_dir, "cpu", lpips=False, video=False, report=False, progress=False))
    return {f"{split}_{key}": metrics[split].get(key) for split in ("recon", "nvs") for key in ("psnr", "psnr_dyn")}


def psnr(squared_error: float, count: int) -> float | None:
    return None if count == 0 else float(10 * np.log10(1.0 / max(squared_error / count, 1e-12)))


# "The same surface" for the generator's exact depths: a mismatch beyond this is an occlusion.
EXACT_DEPTH_TOLERANCE = (0.05, 0.3)


def truly_unseen(view, background_depth: np.ndarray, mask: np.ndarray, truth_views: list) -> np.ndarray:
    """(H, W) bool: the pixels of ``mask`` in the test ``view`` whose background surface
    (``background_depth`` (H, W), the generator's z-depth of the scene without its movers) no training
    frame saw, by the generator's depth of those frames (movers included, so a mover in front hides
    it): the truth the never-observed mask is scored against."""
    from radar4dgs.actors.background import backproject, seen_in

    depth = background_depth.astype(np.float64)
    pixels = np.argwhere(mask & np.isfinite(depth))
    points = backproject(depth, np.asarray(view.K), np.asarray(view.world_to_camera), pixels)
    seen = np.zeros(len(pixels), dtype=bool)
    for training in truth_views:
        seen |= seen_in(points, training, tolerance=EXACT_DEPTH_TOLERANCE)
    unseen = np.zeros_like(mask)
    unseen[pixels[~seen, 0], pixels[~seen, 1]] = True
    return unseen


def ground_truth_visibility(run) -> list:
    """The training frames as the generator saw them: its depth (movers included), nothing dynamic."""
    from radar4dgs.actors.background import TrainingView
    from radar4dgs.io.scene import normalized_times
    from radar4dgs.model.view import frame_view

    times, out = normalized_times(run.scene), []
    for j in run.scene.train_indices:
        view = frame_view(run.scene, j, 1.0, times)
        depth = run.scene.load_optional("gt/depth", j).astype(np.float64)
        out.append(TrainingView(np.asarray(view.world_to_camera), np.asarray(view.K), depth, np.zeros_like(depth)))
    return out


def oracle_run(run, work: Path) -> Path:
    """``run``'s scene made again without its moving objects, prepared and trained with the run's own
    prepare and train configs (one thread), under ``work/oracle/`` (reused): the ``--oracle`` ceiling."""
    from dataclasses import replace

    from radar4dgs.apps.prepare import PrepareConfig, run_prepare
    from radar4dgs.config import load_config
    from radar4dgs.datasets.synth.background import scene_config
    from radar4dgs.train.trainer import train_run

    folder = work / "oracle" / f"{run.scene.root.name}-without-movers"
    scene, out = folder / "scene", folder / "run"
    if not (scene / "scene.json").is_file():
        preset_name = json.loads((run.scene.root / "scene.json").read_text())["source"].get("preset")
        synthesize_once(replace(scene_config(run.scene.root), without_movers=True), scene, preset_name)
    if not (scene / "prepared" / "config.json").is_file():
        run_prepare(scene, scene / "prepared", load_config(PrepareConfig, run.prepared / "config.json"),
                    progress=False)
    if not (out / "model.pt").is_file():
        train_run(scene, scene / "prepared", out, replace(run.config, threads=1), progress=False, tensorboard=False)
    return out


def background_scores(run, actors, oracle=None) -> dict:
    """PSNR over the test frames' moving-object pixels: every actor removed vs the background render
    (with the repaired sky map `radar4dgs render` uses, and with the sky as trained), the unedited render
    vs it, and what `radar4dgs render --remove-actors all` writes (the never-observed pixels filled); the
    fraction of those pixels marked never observed, and how that mask agrees with the truth. ``oracle``: a
    run of the same scene without movers (:func:`oracle_run`), scored on the same pixels."""
    import cv2
    import torch

    from radar4dgs.actors.background import (
        background_sky,
        fill_never_observed,
        never_observed_mask,
        training_visibility,
    )
    from radar4dgs.actors.edit import edited_model
    from radar4dgs.actors.spec import ActorEdits
    from radar4dgs.apps.render import Unobserved
    from radar4dgs.datasets.synth.background import BACKGROUND_DIR, background_frame, scene_config
    from radar4dgs.evaluate.reconstruction import to_uint8
    from radar4dgs.io.scene import normalized_times
    from radar4dgs.model.view import frame_view

    scene, times = run.scene, normalized_times(run.scene)
    removed_trained_sky = edited_model(run.model, actors, ActorEdits(remove_all=True), times)
    removed = edited_model(run.model, actors, ActorEdits(remove_all=True), times, sky=background_sky(run))
    visibility = training_visibility(run, scale=1.0)
    rendered_fill = Unobserved.of(run, run.model, fill=True)
    truth_views = ground_truth_visibility(run)
    oracle_static = None if oracle is None else edited_model(oracle.model, [], ActorEdits(remove_all=True), times)
    generator = scene_config(scene.root)
    sums = {"removed": 0.0, "removed_trained_sky": 0.0, "filled_trained_sky": 0.0, "kept": 0.0, "observed": 0.0,
            "elsewhere": 0.0, "filled": 0.0, "truly_unseen": 0.0, "truly_seen": 0.0, "sky_behind": 0.0,
            "oracle": 0.0, "oracle_truly_seen": 0.0, "oracle_truly_unseen": 0.0, "oracle_elsewhere": 0.0}
    count = never = elsewhere = unseen_count = both = sky_count = 0
    for i in scene.test_indices:
        mask = scene.load_optional("gt/dynamic_mask", i) > 0
        if not mask.any():
            continue
        background = cv2.cvtColor(cv2.imread(str(scene.root / BACKGROUND_DIR / f"{scene.frames[i].name}.png")),
                                  cv2.COLOR_BGR2RGB).astype(np.float64) / 255
        view = frame_view(scene, i, 1.0, times)
        with torch.no_grad():
            edited = removed.render(view, run.config.raster)
            full = run.model.render(view, run.config.raster)
            trained_sky = removed_trained_sky.render(view, run.config.raster)
        for key, out in (("removed", edited), ("kept", full), ("removed_trained_sky", trained_sky)):
            rgb = out["rgb"].clamp(0, 1).double().cpu().numpy()
            sums[key] += float(((rgb - background)[mask] ** 2).sum() / 3)
        count += int(mask.sum())
        unseen = never_observed_mask(run, view, mask, visibility)
        never += int(unseen.sum())
        background_depth = background_frame(generator, i).depth
        truth = truly_unseen(view, background_depth, mask, truth_views)
        unseen_count += int(truth.sum())
        both += int((truth & unseen).sum())
        rgb = edited["rgb"].clamp(0, 1).double().cpu().numpy()
        # Where the error sits: surfaces no training frame saw, surfaces some did, and sky behind the movers.
        sky_behind = mask & ~np.isfinite(background_depth)
        truly_seen = mask & ~truth & ~sky_behind
        for key, where in (("truly_unseen", truth), ("truly_seen", truly_seen), ("sky_behind", sky_behind)):
            sums[key] += float(((rgb - background)[where] ** 2).sum() / 3)
        sky_count += int(sky_behind.sum())
        sums["observed"] += float(((rgb - background)[mask & ~unseen] ** 2).sum() / 3)
        # The same static layer where nothing moves, against the recorded frame: its quality elsewhere.
        sums["elsewhere"] += float(((rgb - background)[~mask] ** 2).sum() / 3)
        elsewhere += int((~mask).sum())
        if oracle_static is not None:
            with torch.no_grad():
                ceiling = oracle_static.render(view, oracle.config.raster)["rgb"].clamp(0, 1).double().cpu().numpy()
            for key, where in (("oracle", mask), ("oracle_truly_seen", truly_seen), ("oracle_truly_unseen", truth),
                               ("oracle_elsewhere", ~mask)):
                sums[key] += float(((ceiling - background)[where] ** 2).sum() / 3)
        fill = rendered_fill.mask(run, view, edited, unedited_render=full)
        for key, out in (("filled", edited), ("filled_trained_sky", trained_sky)):
            written = fill_never_observed(to_uint8(out["rgb"]), fill)
            sums[key] += float(((written.astype(np.float64) / 255 - background)[mask] ** 2).sum() / 3)
    seen_count = count - unseen_count - sky_count
    oracle_scores = {} if oracle is None else {
        "oracle_psnr_removed": psnr(sums["oracle"], count),
        "oracle_psnr_truly_seen": psnr(sums["oracle_truly_seen"], seen_count),
        "oracle_psnr_truly_unseen": psnr(sums["oracle_truly_unseen"], unseen_count),
        "oracle_psnr_static_elsewhere": psnr(sums["oracle_elsewhere"], elsewhere)}
    return {**oracle_scores, "psnr_removed": psnr(sums["removed"], count), "psnr_kept": psnr(sums["kept"], count),
            "psnr_removed_trained_sky": psnr(sums["removed_trained_sky"], count),
            "psnr_removed_filled": psnr(sums["filled"], count),
            "psnr_removed_filled_trained_sky": psnr(sums["filled_trained_sky"], count),
            "psnr_removed_observed": psnr(sums["observed"], count - never),
            "psnr_static_elsewhere": psnr(sums["elsewhere"], elsewhere),
            "psnr_removed_truly_unseen": psnr(sums["truly_unseen"], unseen_count),
            "psnr_removed_truly_seen": psnr(sums["truly_seen"], seen_count),
            "psnr_removed_sky_behind": psnr(sums["sky_behind"], sky_count),
            "sky_behind_fraction": sky_count / count if count else None,
            "pixels": count, "never_observed_fraction": never / count if count else None,
            "never_observed_truth": unseen_count / count if count else None,
            "never_observed_precision": both / never if never else None,
            "never_observed_recall": both / unseen_count if unseen_count else None}


def score_run(run_dir: Path, discovery=None, oracle_work: Path | None = None) -> dict:
    """Actors and background scores of one trained run of a synthetic scene; ``discovery``: the
    ActorConfig to discover with (None: the defaults); ``oracle_work``: train and score the run's
    :func:`oracle_run` there too."""
    from radar4dgs.actors.discover import discover_actors
    from radar4dgs.actors.groundtruth import scene_movers, score_actors
    from radar4dgs.datasets.synth.background import BACKGROUND_DIR, write_backgrounds
    from radar4dgs.model.run import load_run
    from radar4dgs.radar.objects import load_radar_objects

    run = load_run(run_dir, "cpu")
    if not (run.scene.root / BACKGROUND_DIR).is_dir():
        write_backgrounds(run.scene.root, run.scene.test_indices)
    oracle = None if oracle_work is None else load_run(oracle_run(run, oracle_work), "cpu")
    start = time.perf_counter()
    actors = discover_actors(run.model, run.scene, load_radar_objects(run.prepared), discovery)
    seconds = time.perf_counter() - start
    result = {"run": str(run_dir), "scene": str(run.scene.root), "discovery_seconds": round(seconds, 2),
              "n_dynamic": len(run.model.dynamic) if run.model.dynamic is not None else 0,
              **score_actors(actors, scene_movers(run.scene)), **background_scores(run, actors, oracle)}
    result["gain_db"] = (None if result["psnr_removed"] is None or result["psnr_kept"] is None
                         else result["psnr_removed"] - result["psnr_kept"])
    return result


def edit_figure(run_dir: Path, out: Path, actor: int, move: tuple[float, float], shift: float,
                frames: tuple[int, ...]) -> Path:
    """A picture of edits of one actor: per frame (rows) the unedited render, the actor moved by ``move``
    (lateral, longitudinal m), the actor ``shift`` seconds later, every actor removed."""
    import torch

    from radar4dgs.actors.background import background_sky
    from radar4dgs.actors.edit import edited_model
    from radar4dgs.actors.spec import ActorEdits
    from radar4dgs.actors.store import run_actors
    from radar4dgs.evaluate.reconstruction import to_uint8
    from radar4dgs.evaluate.visualize import side_by_side
    from radar4dgs.io.preview import save_png
    from radar4dgs.io.scene import normalized_times
    from radar4dgs.model.run import load_run
    from radar4dgs.model.view import frame_view

    run = load_run(run_dir, "cpu")
    actors, times = run_actors(run), normalized_times(run.scene)
    sky = background_sky(run)  # as `radar4dgs render` shows edits
    models = [run.model] + [edited_model(run.model, actors, edits, times, run.scene.duration, sky) for edits in (
        ActorEdits(move={actor: move}), ActorEdits(retime={actor: ("shift", shift)}), ActorEdits(remove_all=True))]
    labels = ["unedited", f"--move-actor {actor}:{move[0]:g},{move[1]:g}", f"--retime-actor {actor}:{shift:+g}",
              "--remove-actors all"]
    rows = []
    for index in frames:
        view = frame_view(run.scene, index, 1.0, times)
        with torch.no_grad():
            images = [to_uint8(m.render(view, run.config.raster)["rgb"]) for m in models]
        rows.append(side_by_side(images, [f"{label} (frame {index})" for label in labels]))
    picture = np.concatenate(rows, axis=0)
    if Path(out).suffix.lower() in (".jpg", ".jpeg"):  # photographs: a tenth of the PNG's size
        import cv2

        from radar4dgs.io.atomic import atomic_write_bytes

        ok, encoded = cv2.imencode(".jpg", cv2.cvtColor(picture, cv2.COLOR_RGB2BGR), [cv2.IMWRITE_JPEG_QUALITY, 88])
        return atomic_write_bytes(out, encoded.tobytes())
    return save_png(out, picture)


def summary(rows: list[dict]) -> dict:
    """Means over scenes of the headline numbers (None entries skipped)."""
    from radar4dgs.actors.groundtruth import MIN_VISIBLE_FRAMES

    keys = ("recall", "recall_in_view", "precision", "spurious", "centroid_error_median", "velocity_error_median",
            "class_accuracy",
            "psnr_removed", "psnr_kept", "gain_db", "psnr_removed_filled", "psnr_removed_observed",
            "psnr_removed_trained_sky", "psnr_removed_filled_trained_sky", "psnr_removed_truly_unseen",
            "psnr_removed_truly_seen", "psnr_removed_sky_behind", "sky_behind_fraction",
            "psnr_static_elsewhere", "never_observed_fraction", "never_observed_truth", "never_observed_precision",
            "never_observed_recall", "oracle_psnr_removed", "oracle_psnr_truly_seen", "oracle_psnr_truly_unseen",
            "oracle_psnr_static_elsewhere", "recon_psnr", "recon_psnr_dyn", "nvs_psnr", "nvs_psnr_dyn")
    out = {}
    for key in keys:
        values = [r[key] for r in rows if r.get(key) is not None]
        out[key] = float(np.mean(values)) if values else None
    # Which kinds of mover the discovery misses: [matched, missed] per class, summed over the scenes, of the
    # movers `recall` counts (one seen in too few frames, matched or not, is left out).
    by_class: dict[str, list[int]] = {}
    for row in rows:
        for column, key in ((0, "pairs"), (1, "missed")):
            for entry in row.get(key, []):
                if entry.get("visible_frames", MIN_VISIBLE_FRAMES) >= MIN_VISIBLE_FRAMES:
                    by_class.setdefault(entry["class"], [0, 0])[column] += 1
    out["found_missed_by_class"] = by_class
    return out


def discovery_config(parser: argparse.ArgumentParser, items: list[str]):
    """The ActorConfig that ``--discovery-set KEY=VALUE ...`` describes (values JSON, else strings)."""
    from dataclasses import fields, replace

    from radar4dgs.actors.config import ActorConfig
    from radar4dgs.apps.bench_spec import parse_overrides

    overrides = parse_overrides(items)
    unknown = sorted(set(overrides) - {f.name for f in fields(ActorConfig)})
    if unknown:
        parser.error(f"--discovery-set: {', '.join(unknown)} is not an ActorConfig field (radar4dgs.actors.config)")
    return replace(ActorConfig(), **overrides)


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--seeds", type=int, nargs="*", default=[106, 107, 108, 109, 110])
    parser.add_argument("--traffic", default="realistic")
    parser.add_argument("--fps", type=float, default=None, help="frame rate of the scenes (default: the preset's)")
    parser.add_argument("--preset", default="tiny")
    parser.add_argument("--iterations", type=int, default=600)
    parser.add_argument("--work", type=Path, default=Path("/tmp/radar4dgs-actors-bench"))
    parser.add_argument("--out", type=Path, default=RESULTS / "actors.json")
    parser.add_argument("--run", type=Path, nargs="*", default=[], help="already trained runs to score too")
    parser.add_argument("--prepare-set", nargs="*", default=[],
                        help="PrepareConfig fields of every scene, dotted KEY=VALUE (masks.completion.enabled=true)")
    parser.add_argument("--discovery-set", nargs="*", default=[],
                        help="ActorConfig fields for discovery, KEY=VALUE (min_gaussians=8); trained runs are reused")
    parser.add_argument("--oracle", action="store_true",
                        help="also train each scene without its movers (under --work) and score it: the ceiling")
    parser.add_argument("--figure", type=Path, default=None,
                        help="only draw the edit picture of the first --run's actor --figure-actor to this PNG")
    parser.add_argument("--figure-actor", type=int, default=0)
    parser.add_argument("--figure-frames", type=int, nargs="*", default=[10, 25, 40])
    args = parser.parse_args(argv)
    if args.figure is not None:
        edit_figure(args.run[0], args.figure, args.figure_actor, (-3.5, 0.0), -1.0, tuple(args.figure_frames))
        return 0
    discovery = discovery_config(parser, args.discovery_set)
    import torch

    torch.set_num_threads(1)
    rows: list[dict] = []
    discovery_settings = {"discovery_set": args.discovery_set} if args.discovery_set else {}
    settings = {"traffic": args.traffic, "fps": args.fps, "preset": args.preset, "iterations": args.iterations,
                "seeds": args.seeds, "prepare_set": args.prepare_set, "oracle": args.oracle, **discovery_settings}
    # Runs given with --run were trained elsewhere: the preset and iterations here say nothing about them.
    document = {"settings": settings if args.seeds else discovery_settings, "runs": [str(p) for p in args.run],
                "scenes": rows}
    jobs = [(f"s{seed}", seed) for seed in args.seeds] + [(str(path), path) for path in args.run]
    for label, job in jobs:
        start = time.perf_counter()
        if isinstance(job, int):
            scene = build_scene(job, args.traffic, args.preset, args.work, args.prepare_set, args.fps)
            run_dir = train_scene(scene, args.preset, args.iterations, args.work / "runs" / scene.name)
        else:
            run_dir = job
        row = {"label": label, **score_run(run_dir, discovery, args.work if args.oracle else None),
               **novel_view_scores(run_dir),
               "seconds": round(time.perf_counter() - start, 1)}
        rows.append(row)
        # Over the seeds' scenes when there are any, else over the --run runs (a rescoring of trained runs).
        document["summary"] = summary(rows[:len(args.seeds)] if args.seeds else rows)
        atomic_write_json(args.out, document)
        print(json.dumps({k: v for k, v in row.items() if k != "pairs"}), flush=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())
