"""PSNR of dynamic pixels binned by their ground-truth image motion."""

from __future__ import annotations

import json
import math

import numpy as np
from hypothesis import given, settings
from hypothesis import strategies as st
from PIL import Image

from radar4dgs.evaluate.motion_bins import (
    DEFAULT_EDGES,
    binned_squared_error,
    bins_to_psnr,
    run_psnr_by_image_motion,
)
from radar4dgs.io.image_motion import dynamic_pixel_motion_map
from radar4dgs.io.scene import read_scene


@settings(max_examples=30, deadline=None)
@given(errors=st.lists(st.integers(1, 60), min_size=3, max_size=3), seed=st.integers(0, 1000))
def test_each_bin_gets_the_psnr_of_its_own_error(errors, seed):
    """Pixels of bin b are off by errors[b] grey levels in every channel: PSNR_b = 20 log10(255 / e_b)."""
    rng = np.random.default_rng(seed)
    edges = (0.0, 2.0, 10.0, math.inf)
    motion = rng.choice([0.5, 5.0, 50.0, np.nan], size=(12, 16))
    gt = rng.integers(70, 180, size=(12, 16, 3)).astype(np.uint8)
    offset = np.select([motion < 2, motion < 10, motion >= 10], errors, 0)
    render = (gt.astype(int) + offset[..., None]).astype(np.uint8)
    rows = bins_to_psnr(*binned_squared_error(render, gt, motion, edges), edges)
    for row, error, value in zip(rows, errors, (0.5, 5.0, 50.0), strict=True):
        assert row["pixels"] == int((motion == value).sum())
        if row["pixels"]:
            assert math.isclose(row["psnr"], 20 * math.log10(255 / error), rel_tol=1e-9)
        else:
            assert row["psnr"] is None
    assert rows[-1]["high"] is None and rows[0]["low"] == 0.0


def test_run_bins_match_a_naive_per_pixel_reference(tiny_trained_run, tmp_path):
    """Renders that are exact except on fast pixels: the slow bins score 100 dB, and the fast ones
    the MSE a per-pixel loop over every frame gives."""
    scene = read_scene(tiny_trained_run / "scene")
    run = tmp_path / "run"
    run.mkdir()
    (run / "run.json").write_text(json.dumps({"scene": str(scene.root), "prepared": ""}))
    width_scale = scene.camera.width / 320
    threshold = DEFAULT_EDGES[1] * width_scale  # calm tiny scenes: few pixels move further
    squared, count = 0.0, 0
    for index in range(len(scene)):
        split = "nvs" if index in set(scene.test_indices) else "recon"
        gt = scene.load_image(index)
        motion = dynamic_pixel_motion_map(scene, index)
        render = gt.copy()
        fast = np.nan_to_num(motion, nan=-1.0) >= threshold
        render[fast] = 255 - render[fast]
        for v, u in zip(*np.nonzero(fast), strict=True):
            squared += float(np.mean((render[v, u] / 255.0 - gt[v, u] / 255.0) ** 2))
            count += 1
        (run / "renders" / split).mkdir(parents=True, exist_ok=True)
        Image.fromarray(render).save(run / "renders" / split / f"{scene.frames[index].name}.png")
    result = run_psnr_by_image_motion(run)
    assert result["edges_px"][1] == DEFAULT_EDGES[1] * width_scale
    rows = {split: result[split] for split in ("recon", "nvs")}
    fast_pixels = sum(r["pixels"] for split in rows.values() for r in split if r["low"] >= threshold)
    assert fast_pixels == count > 0
    for split in rows.values():
        for row in split:
            if row["pixels"] and row["low"] < threshold:
                assert row["psnr"] == 100.0
    fast_sum = sum(10 ** (-r["psnr"] / 10) * r["pixels"] for split in rows.values() for r in split
                   if r["low"] >= threshold and r["pixels"])
    assert math.isclose(fast_sum / count, squared / count, rel_tol=1e-9)
