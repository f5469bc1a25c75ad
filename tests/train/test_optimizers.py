"""The learning-rate schedule of a run."""

from __future__ import annotations

import pytest

from radar4dgs.train.optimizers import exponential_lr


def test_exponential_lr_is_log_linear():
    assert exponential_lr(1e-2, 1e-4, 0.5) == pytest.approx(1e-3)
