"""Metric depth from the per-frame parameters."""

from __future__ import annotations

import numpy as np
import pytest

from radar4dgs.depth import metric_depth


def test_metric_depth_guards_non_positive_inverse_depth():
    x = np.array([[1.0, 0.5, 0.0, np.nan, -1.0]])
    z, valid = metric_depth(x, 0.1, -0.02, 1.0, 100.0)
    assert valid.tolist() == [[True, True, False, False, False]]
    assert z[0, 0] == pytest.approx(12.5) and z[0, 1] == pytest.approx(1 / 0.03)
    assert (z[0, 2:] == 100.0).all() and z.dtype == np.float32
