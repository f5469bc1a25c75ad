"""Fakes shared by the bench tests: a cell's metrics summary and a scene folder the checks accept."""

from __future__ import annotations

from pathlib import Path

KEYS = ("psnr", "ssim", "lpips_vgg", "psnr_dyn")


def fake_metrics(recon: tuple, nvs: tuple) -> dict:
    """A metrics.json summary from (psnr, ssim, lpips_vgg, psnr_dyn) per split."""
    def split(values):
        return {**dict(zip(KEYS, values, strict=True)), "lpips_alex": None, "n_frames": 6, "n_frames_dyn": 5}

    return {"recon": split(recon), "nvs": split(nvs), "method": "x", "num_gaussians": 10, "mask_source": "gt"}


def make_scene(root: Path, prepared: bool = True) -> Path:
    """A folder that passes the bench's checks (the fake runners never read it)."""
    root.mkdir(parents=True)
    (root / "scene.json").write_text("{}")
    if prepared:
        (root / "prepared" / "depth").mkdir(parents=True)
    return root
