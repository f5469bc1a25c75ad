"""Every random draw of a training run comes from (seed, step) or (seed, epoch) alone."""

from __future__ import annotations

import numpy as np
import torch

from radar4dgs.train.determinism import frame_order, step_generator


def test_random_draws_are_stateless():
    a = torch.rand(5, generator=step_generator(3, 17))
    b = torch.rand(5, generator=step_generator(3, 17))
    assert torch.equal(a, b)
    assert not torch.equal(a, torch.rand(5, generator=step_generator(3, 18)))
    order = frame_order(1, 4, 10)
    assert sorted(order.tolist()) == list(range(10))
    np.testing.assert_array_equal(order, frame_order(1, 4, 10))
