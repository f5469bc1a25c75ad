"""Dynamic-mask recall and precision against gt/dynamic_mask, overall and by image motion (issue 24).

Scores the masks stage's network masks with and without the radar-object completion
(``SegInferConfig.completion``, ``segment/complete.py``) on prepared synthetic scenes (their radar and
depth stages are read, nothing is written into them). Image motion is each gt-dynamic pixel's
displacement to the next frame (gt/flow), binned < 2, 2-10, 10-30, > 30 px per frame.

    OMP_NUM_THREADS=1 python benchmarks/masks.py SCENE [SCENE ...] --out benchmarks/results/masks.json \\
        [--margin 0.3 --tolerance 1.5]
"""

from __future__ import annotations

import argparse
import json
import sys
from dataclasses import replace
from pathlib import Path

import numpy as np

from radar4dgs.io.image_motion import dynamic_pixel_motion_map
from radar4dgs.io.scene import read_scene
from radar4dgs.radar.objects import load_radar_objects
from radar4dgs.radar.sync import prepared_synced_scene
from radar4dgs.segment.baseline import depth_for_baseline
from radar4dgs.segment.complete import complete_mask, frame_objects
from radar4dgs.segment.config import CompletionConfig, SegInferConfig
from radar4dgs.segment.infer import segment_scene

EDGES = (0.0, 2.0, 10.0, 30.0, np.inf)
BINS = ("<2", "2-10", "10-30", ">30")


class Tally:
    """Pixel counts of one method: overall gt / predicted / both, and gt and hits per motion bin."""

    def __init__(self):
        self.gt = self.pred = self.both = 0
        self.bin_gt, self.bin_hit = np.zeros(4), np.zeros(4)

    def add(self, gt: np.ndarray, pred: np.ndarray, motion: np.ndarray | None) -> None:
        self.gt += int(gt.sum())
        self.pred += int(pred.sum())
        self.both += int((gt & pred).sum())
        if motion is not None:
            fin = np.isfinite(motion) & gt
            b = np.digitize(motion[fin], EDGES) - 1
            for k in range(4):
                self.bin_gt[k] += (b == k).sum()
                self.bin_hit[k] += pred[fin][b == k].sum()

    def result(self) -> dict:
        return {"recall": round(self.both / max(self.gt, 1), 4), "precision": round(self.both / max(self.pred, 1), 4),
                "recall_by_motion": {n: round(float(h / max(g, 1)), 4) for n, h, g in
                                     zip(BINS, self.bin_hit, self.bin_gt, strict=True)},
                "gt_pixels_by_motion": {n: int(g) for n, g in zip(BINS, self.bin_gt, strict=True)}}


def score_scene(path: Path, completions: dict[str, CompletionConfig]) -> dict:
    """{method: Tally result} for one prepared scene over its training frames."""
    scene = read_scene(path)
    prepared = path / "prepared"
    synced = prepared_synced_scene(scene, prepared / "radar")
    objects = load_radar_objects(prepared)
    config = SegInferConfig()
    tallies = {name: Tally() for name in ["network", *completions]}
    train = set(scene.train_indices)
    for i, seg in segment_scene(synced, prepared, config):
        if i not in train:
            continue
        gt = scene.load_optional("gt/dynamic_mask", i) > 0
        motion = dynamic_pixel_motion_map(scene, i, inside_only=False) if i < len(scene) - 1 else None
        base = seg.mask(config.threshold)
        tallies["network"].add(gt, base, motion)
        depth = depth_for_baseline(scene, i, prepared)
        projected = frame_objects(synced, i, objects[i])
        for name, completion in completions.items():
            tallies[name].add(gt, complete_mask(base, depth, projected, scene.camera.K,
                                                        scene.camera.cam_to_ego, completion), motion)
    return {name: t.result() for name, t in tallies.items()}


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("scenes", nargs="+", type=Path, help="prepared scene folders (radar and depth stages)")
    parser.add_argument("--out", type=Path, help="write the results JSON here")
    parser.add_argument("--margin", type=float, nargs="+", default=[CompletionConfig.margin_m])
    parser.add_argument("--tolerance", type=float, nargs="+", default=[CompletionConfig.depth_tolerance_m])
    parser.add_argument("--height", type=float, nargs="+", default=[CompletionConfig.min_height_m])
    args = parser.parse_args(argv)
    completions = {f"completed m{m} t{t} h{h}": replace(CompletionConfig(), enabled=True, margin_m=m,
                                                        depth_tolerance_m=t, min_height_m=h)
                   for m in args.margin for t in args.tolerance for h in args.height}
    results = {}
    for path in args.scenes:
        results[path.name] = score_scene(path, completions)
        for name, r in results[path.name].items():
            print(f"{path.name:24s} {name:22s} recall {r['recall']:.3f} precision {r['precision']:.3f} "
                  f"by motion {r['recall_by_motion']}", flush=True)
    if args.out is not None:
        args.out.parent.mkdir(parents=True, exist_ok=True)
        args.out.write_text(json.dumps({"command": " ".join(sys.argv), "scenes": results}, indent=1) + "\n")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
