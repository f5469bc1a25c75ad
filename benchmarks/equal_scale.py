"""Novel-view PSNR* of stored runs scored at one common image size, so runs trained at different resolutions compare.

A run trained at 640×360 is scored by ``radar4dgs eval`` on four times the pixels of one trained at 320×180, and a
scene synthesized at 320 px is not the 640 px scene downsampled (its geometry edges are sampled once per pixel). So
the two ``psnr_dyn`` figures measure different things. This script area-averages each run's stored novel-view
renders (``RUN/renders/nvs``, written by ``radar4dgs eval``) and a truth scene's images to ``--size``, and scores the
moving pixels there: the truth scene's ``gt/dynamic_mask`` area-averaged to that size, kept where at least half
covered. Each argument is ``RUN`` (the truth is the run's own scene) or ``RUN@SCENE`` (the truth is ``SCENE``, the
same frames at any resolution, e.g. the 640 px scene for a run trained on its 320 px twin). Per run it prints
PSNR* at the run's own size (what ``eval`` reports) and at ``--size``, the mean of the frames' own PSNR* as
``eval`` takes it.

    python benchmarks/equal_scale.py RUN[@SCENE] [RUN[@SCENE] ...] [--size 320x180] [--out JSON]
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path

import cv2
import numpy as np
import torch

from radar4dgs.evaluate.motion_bins import RENDERS_DIR
from radar4dgs.io import read_scene
from radar4dgs.io.atomic import atomic_write_json
from radar4dgs.metrics.image import psnr
from scene_configs import parse_size


def area_resize(image: np.ndarray, size: tuple[int, int]) -> np.ndarray:
    """(H, W[, C]) float image -> (h, w[, C]) by area averaging (OpenCV INTER_AREA); ``size`` is (w, h)."""
    if image.shape[1] == size[0] and image.shape[0] == size[1]:
        return image
    return cv2.resize(image, size, interpolation=cv2.INTER_AREA)


def masked_psnr(render: np.ndarray, truth: np.ndarray, mask: np.ndarray) -> float | None:
    """PSNR* (dB) of (H, W, 3) ``render`` against ``truth``, both in [0, 1], over the bool (H, W) ``mask``."""
    return psnr(torch.as_tensor(render), torch.as_tensor(truth), torch.as_tensor(mask))


def score_run(run_dir: Path, truth_dir: Path | None, size: tuple[int, int]) -> dict:
    """``psnr_dyn_own`` (the novel-view PSNR* ``radar4dgs eval`` stored in the run's metrics.json) and
    ``psnr_dyn_at_size`` (renders and truth area-averaged to ``size``, against the truth scene: the mean over the
    held-out frames with moving pixels)."""
    from PIL import Image

    scene = read_scene(json.loads((run_dir / "run.json").read_text())["scene"])
    truth_scene = read_scene(truth_dir) if truth_dir is not None else scene
    if truth_scene.test_indices != scene.test_indices:
        raise ValueError(f"{truth_scene.root}: its held-out frames differ from {scene.root}'s")
    at_size = []
    for index in scene.test_indices:
        path = run_dir / RENDERS_DIR / "nvs" / f"{scene.frames[index].name}.png"
        if not path.is_file():
            raise FileNotFoundError(f"{path}: missing render; run `radar4dgs eval {run_dir}` first")
        with Image.open(path) as image:
            render = np.asarray(image.convert("RGB"), dtype=np.float32) / 255.0
        truth = truth_scene.load_image(index).astype(np.float32) / 255.0
        mask = area_resize(truth_scene.load_optional("gt/dynamic_mask", index).astype(np.float32), size) >= 0.5
        if mask.any():
            at_size.append(masked_psnr(area_resize(render, size), area_resize(truth, size), mask))
    return {"run": str(run_dir), "truth": str(truth_scene.root), "size": f"{size[0]}x{size[1]}",
            "trained_size": f"{scene.camera.width}x{scene.camera.height}", "frames": len(at_size),
            "psnr_dyn_own": json.loads((run_dir / "metrics.json").read_text())["nvs"].get("psnr_dyn"),
            "psnr_dyn_at_size": float(np.mean(at_size)) if at_size else None}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("runs", nargs="+", help="RUN or RUN@SCENE (the truth scene)")
    parser.add_argument("--size", type=parse_size, default=(320, 180), help="common size WxH (default 320x180)")
    parser.add_argument("--out", type=Path, default=None, help="write the rows as JSON here")
    args = parser.parse_args()
    rows = []
    for spec in args.runs:
        run, _, truth = spec.partition("@")
        row = score_run(Path(run), Path(truth) if truth else None, args.size)
        rows.append(row)
        print(f"{run}: trained at {row['trained_size']}, PSNR* {row['psnr_dyn_own']:.2f} dB there, "
              f"{row['psnr_dyn_at_size']:.2f} dB at {row['size']} against {row['truth']} ({row['frames']} frames)")
    if args.out is not None:
        atomic_write_json(args.out, {"command": "python benchmarks/equal_scale.py " + " ".join(args.runs)
                                     + f" --size {args.size[0]}x{args.size[1]}", "rows": rows})


if __name__ == "__main__":
    main()
