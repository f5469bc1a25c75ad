"""Picture of rigid actors against the field alone: for the held-out frame where rigid actors gain
most on dynamic pixels, the ground truth, the field-alone run's render and the rigid-actor run's,
cropped around the moving objects (renders written by each run's evaluation).

    python benchmarks/rigid_figure.py SCENE FIELD_RUN RIGID_RUN [--out docs/images/rigid_actors.jpg]
"""

from __future__ import annotations

import argparse
from pathlib import Path

import cv2
import numpy as np
import torch

from radar4dgs.io.scene import read_scene
from radar4dgs.metrics.image import psnr


def dynamic_psnr(render: np.ndarray, truth: np.ndarray, mask: np.ndarray) -> float:
    """PSNR of (H, W, 3) uint8 ``render`` against ``truth`` on the (H, W) bool ``mask``, the project's
    :func:`~radar4dgs.metrics.image.psnr` (as metrics.json's PSNR*)."""
    render_unit, truth_unit = (torch.tensor(image, dtype=torch.float64) / 255.0 for image in (render, truth))
    return psnr(render_unit, truth_unit, torch.as_tensor(mask))


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("scene", type=Path)
    parser.add_argument("field_run", type=Path)
    parser.add_argument("rigid_run", type=Path)
    parser.add_argument("--out", type=Path, default=Path("docs/images/rigid_actors.jpg"))
    args = parser.parse_args()
    scene = read_scene(args.scene)
    best = None
    for i in scene.test_indices:
        name = scene.frames[i].name
        mask = scene.load_optional("gt/dynamic_mask", i) > 0
        if mask.sum() < 200:
            continue
        truth = scene.load_image(i)
        renders = [cv2.cvtColor(cv2.imread(str(run / "renders" / "nvs" / f"{name}.png")), cv2.COLOR_BGR2RGB)
                   for run in (args.field_run, args.rigid_run)]
        scores = [dynamic_psnr(r, truth, mask) for r in renders]
        if best is None or scores[1] - scores[0] > best[0]:
            best = (scores[1] - scores[0], name, truth, renders, scores, mask)
    gain, name, truth, renders, scores, mask = best
    rows, cols = np.nonzero(mask)
    pad = 12
    y0, y1 = max(rows.min() - pad, 0), min(rows.max() + pad, mask.shape[0])
    x0, x1 = max(cols.min() - pad, 0), min(cols.max() + pad, mask.shape[1])
    panels = []
    for image, label in ((truth, "ground truth"), (renders[0], f"field alone {scores[0]:.1f} dB"),
                         (renders[1], f"rigid actors {scores[1]:.1f} dB")):
        crop = cv2.resize(np.ascontiguousarray(image[y0:y1, x0:x1]), None, fx=3, fy=3, interpolation=cv2.INTER_NEAREST)
        cv2.putText(crop, label, (6, 18), cv2.FONT_HERSHEY_SIMPLEX, 0.5, (255, 255, 255), 1, cv2.LINE_AA)
        panels.append(crop)
    args.out.parent.mkdir(parents=True, exist_ok=True)
    cv2.imwrite(str(args.out), cv2.cvtColor(np.concatenate(panels, axis=1), cv2.COLOR_RGB2BGR),
                [cv2.IMWRITE_JPEG_QUALITY, 90])
    print(f"frame {name}: dynamic-pixel PSNR {scores[0]:.2f} -> {scores[1]:.2f} dB; wrote {args.out}")


if __name__ == "__main__":
    main()
