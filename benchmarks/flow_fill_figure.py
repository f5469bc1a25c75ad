"""Picture of the flow stage's fill of rejected pixels: for the adjacent training pair of a prepared
synthetic scene where the fill lowers the 2-D error on moving pixels most, the image, the true flow,
the stored flow with the fill off and with it on, each on the truly moving pixels only (torchvision's
flow colours, one scale for all three), cropped around the pixels the fill corrected. The fill-off
flow is recomputed in a temporary folder from the same prepared inputs (``flow.fill_min_lifted=0``).

    python benchmarks/flow_fill_figure.py SCENE [--out docs/images/flow_fill.jpg]
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import tempfile
from pathlib import Path

import cv2
import numpy as np
import torch
from torchvision.utils import flow_to_image

from radar4dgs.config import from_dict
from radar4dgs.io.scene import read_scene
from radar4dgs.motion.config import FlowConfig
from radar4dgs.motion.flow import load_flow_pairs, write_flow
from radar4dgs.motion.metrics import gt_flow_2d


def flow_colours(flows: list[np.ndarray], largest: float) -> list[np.ndarray]:
    """(H, W, 3) uint8 pictures of (H, W, 2) flows on one colour scale: norms clipped to ``largest``
    (px), the true flow's, so that a wrong flow of hundreds of pixels does not wash out the others
    (torchvision scales a batch by its largest norm)."""
    stacked = torch.as_tensor(np.stack(flows), dtype=torch.float32).permute(0, 3, 1, 2)
    norm = stacked.norm(dim=1, keepdim=True)
    stacked = stacked * (largest / norm.clamp_min(largest))
    return [image.permute(1, 2, 0).numpy() for image in flow_to_image(stacked)]


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("scene", type=Path)
    parser.add_argument("--out", type=Path, default=Path("docs/images/flow_fill.jpg"))
    args = parser.parse_args()
    scene = read_scene(args.scene)
    prepared = args.scene / "prepared"
    config = from_dict(FlowConfig, json.loads((prepared / "flow" / "config.json").read_text()))
    with tempfile.TemporaryDirectory() as tmp:
        write_flow(scene, Path(tmp) / "flow", dataclasses.replace(config, fill_min_lifted=0), prepared)
        unfilled = {int(p["index_i"]): p["flow"] for p in load_flow_pairs(tmp)}
    best = None
    for pair in load_flow_pairs(prepared):
        i = int(pair["index_i"])
        if int(pair["index_j"]) != i + 1:
            continue
        truth, valid = gt_flow_2d(scene, i)
        moving = scene.load_optional("gt/dynamic_mask", i) & valid
        error_off = np.linalg.norm(unfilled[i] - truth, axis=-1)[moving].sum()
        error_on = np.linalg.norm(pair["flow"] - truth, axis=-1)[moving].sum()
        if best is None or error_off - error_on > best[0]:
            best = (error_off - error_on, i, truth, moving, unfilled[i], pair["flow"])
    if best is None:
        raise SystemExit(f"{prepared / 'flow'}: no pair of adjacent frames to show")
    _, i, truth, moving, off, on = best
    gain = np.linalg.norm(off - truth, axis=-1) - np.linalg.norm(on - truth, axis=-1)
    rows, cols = np.nonzero(moving & (gain > 1.0))  # where the fill corrected a pixel by more than 1 px
    if len(rows) == 0:
        rows, cols = np.nonzero(moving)
    margin = 12
    top, bottom = max(rows.min() - margin, 0), min(rows.max() + margin + 1, moving.shape[0])
    left, right = max(cols.min() - margin, 0), min(cols.max() + margin + 1, moving.shape[1])
    image = scene.load_image(i)
    largest = float(np.linalg.norm(truth[moving], axis=1).max())
    panels = [image] + flow_colours([np.where(moving[..., None], flow, 0.0) for flow in (truth, off, on)], largest)
    crops = [cv2.resize(p[top:bottom, left:right], None, fx=3, fy=3, interpolation=cv2.INTER_NEAREST)
             for p in panels]
    figure = np.concatenate(crops, axis=1)
    args.out.parent.mkdir(parents=True, exist_ok=True)
    cv2.imwrite(str(args.out), cv2.cvtColor(figure, cv2.COLOR_RGB2BGR), [cv2.IMWRITE_JPEG_QUALITY, 90])
    print(f"frame {scene.frames[i].name}: image, true flow, fill off, fill on (moving pixels) -> {args.out}")


if __name__ == "__main__":
    main()
