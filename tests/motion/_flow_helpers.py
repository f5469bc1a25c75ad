"""Images with trackable texture for the optical-flow tests."""

from __future__ import annotations

import cv2
import numpy as np


def texture(height: int, width: int, seed: int = 0) -> np.ndarray:
    """(height, width) uint8 blurred noise: every patch has gradients in both directions."""
    rng = np.random.default_rng(seed)
    return cv2.GaussianBlur((rng.random((height, width)) * 255).astype(np.uint8), (0, 0), 1.5)
