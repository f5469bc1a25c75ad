"""Closed-form tests of the paper's plane votes and histogram voting."""

from __future__ import annotations

import math

import numpy as np
import pytest

from radar4dgs.depth import histogram_vote, plane_votes
from radar4dgs.depth.pairs import VALID


def test_plane_votes_formula():
    # Visual plane z = 2 (unscaled) seen along the optical axis; radar point at z = 6: s = 3.
    visual = np.array([[[0.0, 0.0, 2.0], [0.1, 0.0, 2.0], [0.0, 0.1, 2.0]]])
    votes, reason = plane_votes(np.array([[0.05, 0.05, 6.0]]), visual, 0.05, 0.1)
    assert reason[0] == VALID and votes[0] == pytest.approx(3.0)
    # Collinear neighbours: degenerate normal; a ray in the plane: grazing.
    collinear = np.array([[[0.0, 0.0, 2.0], [0.1, 0.0, 2.0], [0.2, 0.0, 2.0]]])
    assert np.isnan(plane_votes(np.array([[0.0, 0.0, 6.0]]), collinear, 0.05, 0.1)[0][0])
    _, reason = plane_votes(np.array([[1.0, 0.0, 0.0]]), visual, 0.05, 0.1)
    assert reason[0] != VALID


def test_histogram_vote_finds_the_mode():
    rng = np.random.default_rng(6)
    votes = np.concatenate([2.0 * np.exp(rng.normal(0, 0.01, 300)), rng.uniform(0.5, 10, 200)])
    assert histogram_vote(votes, 64) == pytest.approx(2.0, rel=0.01)
    assert math.isnan(histogram_vote(np.array([np.nan, -1.0]), 64))
    assert histogram_vote(np.array([3.0, 3.0, 3.0]), 64) == pytest.approx(3.0)
