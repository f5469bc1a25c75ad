"""Bilinear sampling against closed forms."""

from __future__ import annotations

import numpy as np
import pytest

from radar4dgs.motion.sampling import bilinear_sample

H, W = 60, 80


def test_bilinear_sample_is_exact_on_linear_functions_and_flags_outside():
    v, u = np.mgrid[0:H, 0:W].astype(np.float64)
    image = 2 * u + 3 * v + 1
    xy = np.array([[0.5, 0.5], [10.25, 20.75], [W - 1.0, H - 1.0], [-0.1, 3.0], [3.0, H - 0.5]])
    values, inside = bilinear_sample(image, xy)
    assert inside.tolist() == [True, True, True, False, False]
    assert values[:3] == pytest.approx(2 * xy[:3, 0] + 3 * xy[:3, 1] + 1)
    stacked, _ = bilinear_sample(np.stack([image, -image], axis=-1), xy[:2])
    assert stacked[:, 1] == pytest.approx(-stacked[:, 0])
