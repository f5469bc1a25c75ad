"""Dynamic masks per class of mover on prepared synthetic scenes: a checkpoint's mask IoU, recall and
precision over all frames, and its recall on each class (car, cyclist, pedestrian: the gt moving pixels
inside each mover's projected box). For comparing shipped or trained weights on traffic the
segmentation benchmark's calm scenes lack (pedestrians, cyclists, fast cars).

    python benchmarks/segmentation_classes.py --checkpoint segnet-small-traffic --label traffic \\
        --scenes SCENE ... [--work /tmp/radar4dgs-seg-classes] [--out benchmarks/results/F.json]
    python benchmarks/segmentation_classes.py --label anchors128 --set num_anchors=128 --scenes SCENE ...

Scenes are folders with ``prepared/radar`` (``radar4dgs prepare SCENE --only radar``, or the scenes
``benchmarks/motion.py --frontend-only --work W`` leaves in W) and generator ground truth. The masks
are written under --work/<scene>-<label>/ and reused.
"""

from __future__ import annotations

import argparse
import dataclasses
import itertools
import json
from pathlib import Path

import numpy as np

from radar4dgs.io.atomic import atomic_write_json
from radar4dgs.io.scene import read_scene
from radar4dgs.io.scene_files import read_mask_png
from radar4dgs.segment.config import SegInferConfig
from radar4dgs.segment.infer import prepare_masks
from scene_configs import prepare_config


def box_pixels(scene, obj: dict, frame: int) -> tuple[slice, slice] | None:
    """The image rows and columns of ``obj``'s 3-D box (scene.json synthetic object) in ``frame``,
    clipped to the image; None when it is behind the camera or outside."""
    pose = np.asarray(obj["poses"][frame])
    length, width, height = obj["dims"]
    corners = np.array([[sx * length / 2, sy * width / 2, z]
                        for sx, sy, z in itertools.product([-1, 1], [-1, 1], [0, height])])
    world = corners @ pose[:3, :3].T + pose[:3, 3]
    w2c = scene.world_to_camera(frame)
    cam = world @ w2c[:3, :3].T + w2c[:3, 3]
    if (cam[:, 2] < 0.5).any():
        return None
    uv, _ = scene.camera.project(cam)
    x0, y0 = np.maximum(np.floor(uv.min(axis=0)).astype(int), 0)
    x1, y1 = np.minimum(np.ceil(uv.max(axis=0)).astype(int), [scene.camera.width, scene.camera.height])
    return (slice(y0, y1), slice(x0, x1)) if x1 > x0 and y1 > y0 else None


def score_scene(scene, masks: list[np.ndarray]) -> dict:
    """Pixel counts (gt moving, predicted, both) over every frame, and per class (gt moving pixels in
    the class's boxes, and of them predicted)."""
    truth = [scene.load_optional("gt/dynamic_mask", i).astype(bool) for i in range(len(scene))]
    counts = {"truth": int(sum(t.sum() for t in truth)), "predicted": int(sum(m.sum() for m in masks)),
              "both": int(sum((t & m).sum() for t, m in zip(truth, masks, strict=True))), "classes": {}}
    for obj in (scene.extra.get("synthetic") or {}).get("objects", []):
        if obj.get("kind") != "moving" or "poses" not in obj:
            continue
        entry = counts["classes"].setdefault(obj.get("class", "car"), [0, 0])
        for i in range(len(scene)):
            box = box_pixels(scene, obj, i)
            if box is not None:
                entry[0] += int(truth[i][box].sum())
                entry[1] += int((truth[i][box] & masks[i][box]).sum())
    return counts


def rates(counts: dict) -> dict:
    truth, predicted, both = counts["truth"], counts["predicted"], counts["both"]
    return {"iou": both / max(truth + predicted - both, 1), "recall": both / max(truth, 1),
            "precision": both / max(predicted, 1),
            "class_recall": {k: v[1] / max(v[0], 1) for k, v in sorted(counts["classes"].items())}}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--scenes", type=Path, nargs="+", required=True)
    parser.add_argument("--checkpoint", default=None, help="best.pt or shipped weights' name (default: shipped)")
    parser.add_argument("--label", default="shipped")
    parser.add_argument("--threshold", type=float, default=SegInferConfig.threshold)
    parser.add_argument("--work", type=Path, default=Path("/tmp/radar4dgs-seg-classes"))
    parser.add_argument("--out", type=Path, default=None)
    parser.add_argument("--set", nargs="*", default=[], help="SegInferConfig fields, KEY=VALUE (num_anchors=128)")
    args = parser.parse_args()
    config = dataclasses.replace(prepare_config("small", [f"masks.{item}" for item in args.set]).masks,
                                 checkpoint=None if args.checkpoint is None else Path(args.checkpoint),
                                 threshold=args.threshold)
    report = {"checkpoint": args.checkpoint, "threshold": args.threshold, "set": args.set, "scenes": {}}
    total = {"truth": 0, "predicted": 0, "both": 0, "classes": {}}
    for folder in args.scenes:
        scene = read_scene(folder)
        out = args.work / f"{folder.name}-{args.label}"
        if not (out / "summary.json").is_file():
            prepare_masks(scene, folder / "prepared", config, out_dir=out)
        counts = score_scene(scene, [read_mask_png(out / f"{f.name}.png") for f in scene.frames])
        report["scenes"][folder.name] = {**counts, **rates(counts)}
        print(folder.name, args.label, json.dumps(rates(counts)), flush=True)
        for key in ("truth", "predicted", "both"):
            total[key] += counts[key]
        for name, (pixels, found) in counts["classes"].items():
            entry = total["classes"].setdefault(name, [0, 0])
            entry[0] += pixels
            entry[1] += found
    report["total"] = {**total, **rates(total)}
    print("total", args.label, json.dumps(rates(total)))
    if args.out is not None:
        atomic_write_json(args.out, report)


if __name__ == "__main__":
    main()
