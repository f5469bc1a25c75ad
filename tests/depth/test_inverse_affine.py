"""The robust inverse-depth affine fit on its own (no image, no pairing)."""

from __future__ import annotations

import numpy as np
import pytest

from radar4dgs.depth import fit_inverse_affine


def test_fit_inverse_affine_falls_back_to_scale_only_without_spread():
    rng = np.random.default_rng(7)
    z = 20 + rng.normal(0, 0.01, 50)  # every point at the same depth: shift is not observable
    x = 2.0 / z
    a, b, inliers, scale_only = fit_inverse_affine(x, z, 0.08, 128, 0.03, 10, 0.05, rng)
    assert scale_only and b == 0.0 and a == pytest.approx(0.5, rel=1e-3) and inliers.all()
