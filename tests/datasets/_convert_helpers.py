"""Small pose builders shared by the converter tests' fake datasets."""

from __future__ import annotations

import numpy as np


def rigid(R: np.ndarray, t) -> np.ndarray:
    """(4, 4) transform with rotation ``R`` (3, 3) and translation ``t`` (3,)."""
    T = np.eye(4)
    T[:3, :3] = R
    T[:3, 3] = t
    return T


def yaw(angle: float) -> np.ndarray:
    """(3, 3) rotation by ``angle`` radians about z."""
    c, s = np.cos(angle), np.sin(angle)
    return np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])
