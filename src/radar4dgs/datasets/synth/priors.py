"""Stand-ins for external models' outputs (`priors/`): a Depth-Anything-like relative inverse
depth and a slightly wrong sky mask."""

from __future__ import annotations

import cv2
import numpy as np

from radar4dgs.datasets.synth.config import MonoPriorConfig
from radar4dgs.datasets.synth.texture import ValueNoise, value_noise


def distortion_field(noise: ValueNoise, width: int, height: int, amplitude: float, time: float) -> np.ndarray:
    """(H, W) smooth field in [-amplitude, amplitude]: a few blobs across the image, drifting slowly."""
    u, v = np.meshgrid(np.linspace(0.0, 2.5, width), np.linspace(0.0, 1.6, height))
    raw = (value_noise(noise, u + 0.05 * time + 11.0, v + 7.0)
           + 0.5 * value_noise(noise, 2 * u + 3.0, 2 * v - 0.03 * time))
    raw = raw - raw.mean()
    peak = np.abs(raw).max()
    return raw / peak * amplitude if peak > 0 else raw


def mono_depth(depth: np.ndarray, a: float, b: float, field: np.ndarray, config: MonoPriorConfig,
               rng: np.random.Generator) -> np.ndarray:
    """(H, W) float32 ``a / z * (1 + field + noise) + b`` from z-depth (H, W) (+inf sky -> b)."""
    inverse = a / depth  # +inf depth gives exactly 0
    noise = rng.normal(0.0, config.noise_std, depth.shape) if config.noise_std > 0 else 0.0
    prior = inverse * (1.0 + field + noise) + b
    sigma = config.blur_sigma * depth.shape[1]
    if sigma > 0:
        prior = cv2.GaussianBlur(prior, (0, 0), sigmaX=sigma, borderType=cv2.BORDER_REPLICATE)
    return prior.astype(np.float32)


def sky_mask(sky: np.ndarray, config: MonoPriorConfig, rng: np.random.Generator) -> np.ndarray:
    """(H, W) bool: the true sky mask grown or shrunk by up to ``sky_jitter_px`` pixels."""
    px = int(rng.integers(-config.sky_jitter_px, config.sky_jitter_px + 1)) if config.sky_jitter_px > 0 else 0
    if px == 0:
        return sky.copy()
    kernel = np.ones((2 * abs(px) + 1, 2 * abs(px) + 1), np.uint8)
    op = cv2.dilate if px > 0 else cv2.erode
    return op(sky.astype(np.uint8), kernel, borderType=cv2.BORDER_REPLICATE) > 0
