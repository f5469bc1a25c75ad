"""Every random draw of a training run comes from (seed, step) or (seed, epoch) alone."""

from __future__ import annotations

import numpy as np
import torch
from hypothesis import given
from hypothesis import strategies as st

from radar4dgs.train.determinism import frame_order, step_generator


def test_random_draws_are_stateless():
    a = torch.rand(5, generator=step_generator(3, 17))
    b = torch.rand(5, generator=step_generator(3, 17))
    assert torch.equal(a, b)
    assert not torch.equal(a, torch.rand(5, generator=step_generator(3, 18)))
    order = frame_order(1, 4, 10)
    assert sorted(order.tolist()) == list(range(10))
    np.testing.assert_array_equal(order, frame_order(1, 4, 10))


def test_frame_probabilities_follow_the_moving_pixels_in_closed_form():
    from radar4dgs.train.determinism import frame_probabilities

    # mean fraction 0.1: 1 + m / 0.1 = 1, 2, 3, 2 over a sum of 8
    np.testing.assert_allclose(frame_probabilities(np.array([0.0, 0.1, 0.2, 0.1]), 1.0), [1 / 8, 2 / 8, 3 / 8, 2 / 8])
    np.testing.assert_allclose(frame_probabilities(np.zeros(4), 1.0), np.full(4, 0.25))
    np.testing.assert_allclose(frame_probabilities(np.array([0.0, 0.3]), 0.0), [0.5, 0.5])


@given(st.lists(st.floats(0.0, 1.0), min_size=1, max_size=40), st.floats(0.0, 10.0))
def test_frame_probabilities_are_a_distribution_ordered_like_the_fractions(fractions, weight):
    from radar4dgs.train.determinism import frame_probabilities

    p = frame_probabilities(np.array(fractions), weight)
    assert np.all(np.isfinite(p)) and abs(p.sum() - 1.0) < 1e-12
    order = np.argsort(fractions, kind="stable")
    assert np.all(np.diff(p[order]) >= -1e-15)


def test_training_frame_keeps_the_shuffled_order_or_draws_with_the_probabilities():
    from radar4dgs.train.determinism import training_frame

    assert [training_frame(2, 30 + k, 10) for k in range(10)] == frame_order(2, 3, 10).tolist()
    p = np.array([0.1, 0.6, 0.3])
    draws = np.array([training_frame(4, step, 3, p) for step in range(6000)])
    assert draws.tolist() == [training_frame(4, step, 3, p) for step in range(6000)]
    # 6000 draws: each frequency within 4 standard deviations (<= 0.026) of its probability
    np.testing.assert_allclose(np.bincount(draws, minlength=3) / len(draws), p, atol=0.026)
