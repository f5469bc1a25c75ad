"""Every random draw of a training run comes from (seed, step) or (seed, epoch) alone."""

from __future__ import annotations

import numpy as np
import torch

from radar4dgs.train.determinism import frame_order, neighbour_row, step_generator


def test_random_draws_are_stateless():
    a = torch.rand(5, generator=step_generator(3, 17))
    b = torch.rand(5, generator=step_generator(3, 17))
    assert torch.equal(a, b)
    assert not torch.equal(a, torch.rand(5, generator=step_generator(3, 18)))
    order = frame_order(1, 4, 10)
    assert sorted(order.tolist()) == list(range(10))
    np.testing.assert_array_equal(order, frame_order(1, 4, 10))


def test_neighbour_rows_come_at_the_share_asked_from_both_sides_and_only_next_door():
    n, share = 7, 0.3
    drawn = [(row, neighbour_row(5, step, row, n, share)) for step in range(4000) for row in (step % n,)]
    others = [(row, other) for row, other in drawn if other is not None]
    assert abs(len(others) / len(drawn) - share) < 0.03
    assert all(abs(other - row) == 1 and 0 <= other < n for row, other in others)
    middle = [other - row for row, other in others if 0 < row < n - 1]
    assert abs(np.mean(np.array(middle) > 0) - 0.5) < 0.05
    assert {other for row, other in others if row == 0} == {1} and {other for row, other in others if row == 6} == {5}
    assert neighbour_row(5, 11, 3, n, share) == neighbour_row(5, 11, 3, n, share)  # stateless: resumable
    assert all(neighbour_row(5, step, 2, n, 0.0) is None for step in range(200))
    assert neighbour_row(5, 0, 0, 1, 1.0) is None  # one training frame: no neighbour
