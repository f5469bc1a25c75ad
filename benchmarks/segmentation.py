"""Benchmark of the radar–camera dynamic segmentation (issue 5) on synthetic scenes whose seeds
were never used in training.

    python benchmarks/segmentation.py                      # shipped checkpoint, seeds 1-3, small preset
    python benchmarks/segmentation.py --checkpoint RUN/best.pt --seeds 1-5

Measures, per method (the network with the default anchors — up to 64 dynamic points spread by
"cover" sampling, patches at 0.6 of the paper's size —, the network with the paper's anchors — 8
random dynamic points, full-size patches —, the non-learned baseline): mask IoU accumulated over all
frames of all scenes, the fraction of moving pixels left unmarked, the fraction of parked-car
pixels marked dynamic, and seconds per frame (network part: anchors, patches, forward,
paste-back; the radar front end is timed separately). Prints a table,
writes ``benchmarks/results/segmentation.json`` and the figure ``docs/images/segmentation.png``
(image with dynamic radar points and anchors, predicted mask, gt mask).
"""

from __future__ import annotations

import argparse
import json
import platform
import sys
import time
import warnings
from pathlib import Path

import cv2
import numpy as np
import torch

from radar4dgs.apps.seg_train import parse_seeds, synth_scenes
from radar4dgs.io.atomic import atomic_write_json
from radar4dgs.io.scene import SceneWarning, read_scene
from radar4dgs.segment.baseline import BaselineConfig, baseline_frame, depth_for_baseline
from radar4dgs.segment.dataset import load_radar_frame
from radar4dgs.segment.infer import DEFAULT_CARD, SegInferConfig, frame_rng, load_model, segment_frame
from radar4dgs.segment.metrics import ground_truth_masks, mask_scores
from radar4dgs.segment.patches import candidate_anchors

ROOT = Path(__file__).resolve().parents[1]
TARGETS = {"mask_iou_min": 0.75, "static_vehicle_fp_max": 0.02, "seconds_per_frame_max": 0.5}


def training_seeds(checkpoint: Path | None) -> list[int]:
    """Seeds the checkpoint was trained on (from its card / payload), to refuse overlapping ones."""
    if checkpoint is None:
        import importlib.resources

        card = importlib.resources.files("radar4dgs.segment").joinpath("weights", DEFAULT_CARD)
        if card.is_file():
            data = json.loads(card.read_text())
            return list(data.get("training", {}).get("synth_seeds", [])) + list(
                data.get("training", {}).get("validation_seeds", []))
        return []
    payload = torch.load(checkpoint, map_location="cpu", weights_only=True)
    return list(payload.get("synth_seeds", [])) + list(payload.get("validation_seeds", []))


def overlay(image: np.ndarray, mask: np.ndarray, colour: tuple[int, int, int]) -> np.ndarray:
    out = image.astype(np.float32)
    out[mask] = 0.45 * out[mask] + 0.55 * np.array(colour, np.float32)
    return out.astype(np.uint8)


def figure_row(image, radar, result, pred, gt, scale: int = 2) -> np.ndarray:
    """One row: image + dynamic radar points (yellow) and anchors (red squares), prediction, gt."""
    big = lambda x: cv2.resize(x, None, fx=scale, fy=scale, interpolation=cv2.INTER_NEAREST)  # noqa: E731
    points = big(image)
    for u, v in radar.uv[candidate_anchors(radar, image.shape[1], image.shape[0])]:
        centre = (int(scale * u + scale / 2), int(scale * v + scale / 2))
        cv2.circle(points, centre, 3, (0, 0, 0), -1)
        cv2.circle(points, centre, 2, (255, 255, 0), -1)
    for (x0, y0, x1, y1), (u, v) in zip(result.boxes, result.anchors, strict=True):
        cv2.rectangle(points, (scale * int(x0), scale * int(y0)), (scale * int(x1), scale * int(y1)), (255, 60, 60), 1)
        cv2.drawMarker(points, (int(scale * u + scale / 2), int(scale * v + scale / 2)), (255, 0, 0),
                       cv2.MARKER_SQUARE, 6, 2)
    return np.concatenate([points, big(overlay(image, pred, (255, 0, 255))), big(overlay(image, gt, (0, 255, 0)))],
                          axis=1)


def label_bar(width: int, titles: list[str]) -> np.ndarray:
    bar = np.full((22, width, 3), 255, np.uint8)
    step = width // len(titles)
    for k, title in enumerate(titles):
        cv2.putText(bar, title, (k * step + 6, 16), cv2.FONT_HERSHEY_SIMPLEX, 0.5, (0, 0, 0), 1, cv2.LINE_AA)
    return bar


def save_palette_png(path: Path, rgb: np.ndarray) -> None:
    """Save (H, W, 3) uint8 as a 256-colour PNG (a quarter of the RGB size; fine for a README)."""
    from io import BytesIO

    from PIL import Image

    from radar4dgs.io.atomic import atomic_write_bytes

    buffer = BytesIO()
    Image.fromarray(rgb).quantize(colors=256, method=Image.Quantize.MEDIANCUT).save(buffer, format="PNG", optimize=True)
    atomic_write_bytes(path, buffer.getvalue())


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--checkpoint", type=Path, default=None, help="seg-train best.pt (default: shipped weights)")
    parser.add_argument("--seeds", default="1-3", help="evaluation seeds, never used in training")
    parser.add_argument("--preset", default="small")
    parser.add_argument("--cache", type=Path, default=ROOT / "runs" / "benchmark-scenes")
    parser.add_argument("--dynamic-source", default="auto", help="auto/estimate (radar front end) or oracle")
    parser.add_argument("--anchor-sampling", default=SegInferConfig.anchor_sampling)
    parser.add_argument("--num-anchors", type=int, default=SegInferConfig.num_anchors)
    parser.add_argument("--cover-radius", type=float, default=SegInferConfig.cover_radius)
    parser.add_argument("--patch-scale", type=float, default=SegInferConfig.patch_scale)
    parser.add_argument("--threads", type=int, default=1, help="torch CPU threads for the timing")
    parser.add_argument("--json", type=Path, default=ROOT / "benchmarks" / "results" / "segmentation.json")
    parser.add_argument("--figure", type=Path, default=ROOT / "docs" / "images" / "segmentation.png")
    args = parser.parse_args(argv)
    torch.set_num_threads(args.threads)
    warnings.simplefilter("ignore", SceneWarning)

    seeds = parse_seeds(args.seeds)
    overlap = sorted(set(seeds) & set(training_seeds(args.checkpoint)))
    if overlap:
        print(f"refusing: seeds {overlap} were used in training", file=sys.stderr)
        return 2
    paths = synth_scenes(seeds, args.preset, args.cache, progress=False)
    model = load_model(args.checkpoint)
    configs = {
        "model": SegInferConfig(anchor_sampling=args.anchor_sampling, num_anchors=args.num_anchors,
                                cover_radius=args.cover_radius, patch_scale=args.patch_scale,
                                dynamic_source=args.dynamic_source),
        "model_paper_anchors": SegInferConfig(anchor_sampling="random", num_anchors=8, patch_scale=1.0,
                                              dynamic_source=args.dynamic_source),
    }
    masks: dict[str, list] = {name: [] for name in [*configs, "baseline"]}
    timing: dict[str, list] = {name: [] for name in [*configs, "baseline", "radar_front_end"]}
    scores: dict[str, dict] = {name: {"per_scene": {}} for name in masks}
    rows = []
    for path in paths:
        scene = read_scene(path)
        truth = ground_truth_masks(scene, len(scene))  # once per scene, shared by every method
        scene_masks: dict[str, list] = {name: [] for name in masks}
        for i in range(len(scene)):
            start = time.perf_counter()
            radar = load_radar_frame(scene, i, args.dynamic_source, None)
            timing["radar_front_end"].append(time.perf_counter() - start)
            image, gt = scene.load_image(i), truth[0][i]
            for name, config in configs.items():
                start = time.perf_counter()
                result = segment_frame(model, image, radar, config, frame_rng(config.seed, i))
                timing[name].append(time.perf_counter() - start)
                scene_masks[name].append(result.mask(config.threshold))
                if name == "model" and i in (10, 35) and len(rows) < 4:
                    rows.append(figure_row(image, radar, result, scene_masks[name][-1], gt))
            start = time.perf_counter()
            scene_masks["baseline"].append(baseline_frame(image, depth_for_baseline(scene, i, None), radar,
                                                          scene.camera.K, BaselineConfig()))
            timing["baseline"].append(time.perf_counter() - start)
        for name, frames in scene_masks.items():
            s = mask_scores(scene, frames, truth)
            scores[name]["per_scene"][scene.name] = {**{k: s[k] for k in ("mask_iou", "static_vehicle_fp")},
                                                     "missed": 1.0 - s["intersection"] / max(s["gt_pixels"], 1)}
            for key in ("intersection", "union", "gt_pixels", "parked_car_pixels"):
                scores[name][key] = scores[name].get(key, 0) + (s[key] or 0)
            scores[name]["parked_marked"] = scores[name].get("parked_marked", 0) + round(
                (s["static_vehicle_fp"] or 0) * (s["parked_car_pixels"] or 0))
        print(f"{scene.name}: " + ", ".join(f"{n} IoU {scores[n]['per_scene'][scene.name]['mask_iou']:.3f}"
                                            for n in masks), flush=True)

    results = {}
    for name, s in scores.items():
        results[name] = {"mask_iou": s["intersection"] / max(s["union"], 1),
                         "missed": 1.0 - s["intersection"] / max(s["gt_pixels"], 1),
                         "static_vehicle_fp": s["parked_marked"] / max(s["parked_car_pixels"], 1),
                         "seconds_per_frame": float(np.mean(timing[name])),
                         "seconds_per_frame_max": float(np.max(timing[name])), "per_scene": s["per_scene"]}
    m, b = results["model"], results["baseline"]
    checks = {"mask_iou>=0.75": m["mask_iou"] >= TARGETS["mask_iou_min"],
              "mask_iou>baseline": m["mask_iou"] > b["mask_iou"],
              "static_vehicle_fp<=0.02": m["static_vehicle_fp"] <= TARGETS["static_vehicle_fp_max"],
              "seconds_per_frame<=0.5": m["seconds_per_frame"] <= TARGETS["seconds_per_frame_max"]}
    report = {"seeds": seeds, "preset": args.preset, "frames": len(timing["radar_front_end"]),
              "checkpoint": str(args.checkpoint) if args.checkpoint else "shipped (radar4dgs/segment/weights)",
              "dynamic_source": args.dynamic_source, "threads": args.threads,
              "radar_front_end_seconds_per_frame": float(np.mean(timing["radar_front_end"])),
              "configs": {k: {"anchor_sampling": c.anchor_sampling, "num_anchors": c.num_anchors,
                              "cover_radius": c.cover_radius, "patch_scale": c.patch_scale,
                              "threshold": c.threshold} for k, c in configs.items()},
              "results": results, "targets": TARGETS, "checks": checks, "passed": all(checks.values()),
              "machine": {"python": platform.python_version(), "torch": torch.__version__,
                          "processor": platform.processor() or platform.machine()}}
    atomic_write_json(args.json, report)
    print(f"\n{'method':<22}{'mask IoU':>10}{'missed':>9}{'parked FP':>11}{'s/frame':>9}")
    for name, r in results.items():
        print(f"{name:<22}{r['mask_iou']:>10.3f}{100 * r['missed']:>8.1f}%{100 * r['static_vehicle_fp']:>10.2f}%"
              f"{r['seconds_per_frame']:>9.3f}")
    print(f"radar front end {report['radar_front_end_seconds_per_frame']:.3f} s/frame (not included)")
    print("checks: " + ", ".join(f"{k} {'PASS' if v else 'FAIL'}" for k, v in checks.items()))
    if rows:
        grid = np.concatenate(rows, axis=0)
        grid = np.concatenate([label_bar(grid.shape[1], ["image, dynamic radar (yellow), anchors+patches (red)",
                                                         "predicted mask", "gt dynamic mask"]), grid], axis=0)
        save_palette_png(args.figure, grid)
        print(f"figure {args.figure}")
    print(f"results {args.json}")
    return 0 if report["passed"] else 1


if __name__ == "__main__":
    sys.exit(main())
