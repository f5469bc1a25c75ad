"""Temporal consistency of the affine depth parameters (``DepthConfig.temporal_window``):
closed-form radar pairs whose true scale/shift drift slowly from frame to frame; and the
neighbour fallback of frames without a fit."""

from __future__ import annotations

import math

import numpy as np
import pytest

from radar4dgs.depth import DepthConfig, DepthWarning, fill_from_neighbours
from radar4dgs.depth.inverse_affine import affine_fit
from radar4dgs.depth.pairs import VALID, FrameFit, RadarPairs
from radar4dgs.depth.temporal import temporal_refine

FRAMES = 40


def truth(i: int) -> tuple[float, float]:
    """Slowly drifting (a_i, b_i): +-5 % scale and +-0.002 shift over the sequence, smooth."""
    return 0.5 * (1 + 0.05 * math.sin(2 * math.pi * i / FRAMES)), 0.01 + 0.002 * math.cos(2 * math.pi * i / FRAMES)


def pairs(i: int, rng: np.random.Generator, count: int = 300, noise: float = 0.03,
          drift=truth, clutter_fraction: float = 0.1) -> RadarPairs:
    """Radar pairs of frame i: true depths 4-60 m, the prior x from the frame's (a_i, b_i),
    the radar depth with relative noise, and clutter (10 % by default)."""
    a, b = drift(i)
    z_true = rng.uniform(4.0, 60.0, count)
    x = (1.0 / z_true - b) / a
    z = z_true * (1 + rng.normal(0, noise, count))
    clutter = rng.random(count) < clutter_fraction
    z[clutter] = rng.uniform(2.0, 80.0, int(clutter.sum()))
    return RadarPairs(np.zeros((count, 3)), np.zeros((count, 2)), z, x, np.zeros((count, 3), int),
                      np.full(count, VALID, np.int8))


def frame_fits(config: DepthConfig, seed: int = 0, **kwargs):
    rng = np.random.default_rng(seed)
    return [affine_fit(pairs(i, rng, **kwargs), config, np.random.default_rng(config.seed + i)) for i in range(FRAMES)]


def inverse_depth_error(fits) -> float:
    """RMS over frames and over x of the relative error of the fitted inverse depth a x + b."""
    errors = []
    for i, fit in enumerate(fits):
        a, b = truth(i)
        x = (1.0 / np.linspace(5.0, 60.0, 12) - b) / a
        errors.append((fit.a * x + fit.b) / (a * x + b) - 1)
    return float(np.sqrt(np.mean(np.square(errors))))


def test_window_recovers_drifting_parameters_better_than_per_frame_fits():
    config = DepthConfig(temporal_window=5)
    single = frame_fits(DepthConfig(temporal_window=1))
    refined = temporal_refine(single, config)
    before, after = inverse_depth_error(single), inverse_depth_error(refined)
    assert after < 0.8 * before, (before, after)
    # Frame-to-frame jitter of the scale at 20 m falls too.
    def ratio(fits):
        return np.array([(f.a * (1 / 20 - truth(i)[1]) / truth(i)[0] + f.b) * 20 for i, f in enumerate(fits)])

    assert np.std(np.diff(ratio(refined))) < 0.6 * np.std(np.diff(ratio(single)))
    for i, fit in enumerate(refined):
        assert fit.ok and fit.extra["frame_a"] == single[i].a and fit.extra["frame_b"] == single[i].b
        assert fit.extra["window_frames"] == list(range(max(0, i - 2), min(FRAMES, i + 3)))


def test_linear_drift_is_followed_without_bias_even_at_the_ends():
    # Noise-free pairs, scale and shift drifting linearly: the local-linear window model is exact.
    def linear(i):
        return 0.4 * (1 + 0.01 * i), 0.02 - 0.0003 * i

    rng = np.random.default_rng(3)
    config = DepthConfig(temporal_window=7)
    fits = [affine_fit(pairs(i, rng, noise=0.0, drift=linear, clutter_fraction=0.0), config, np.random.default_rng(i))
            for i in range(20)]
    for i, fit in enumerate(temporal_refine(fits, config)):
        a, b = linear(i)
        assert fit.a == pytest.approx(a, rel=1e-7) and fit.b == pytest.approx(b, rel=1e-6, abs=1e-9)


def test_window_one_reproduces_the_per_frame_fits_exactly():
    single = frame_fits(DepthConfig(temporal_window=1))
    again = temporal_refine(single, DepthConfig(temporal_window=1))
    assert [(f.a, f.b, f.ok) for f in again] == [(f.a, f.b, f.ok) for f in single]
    # And the per-frame fits do not depend on the window (it acts after them).
    windowed = frame_fits(DepthConfig(temporal_window=5))
    assert [(f.a, f.b) for f in windowed] == [(f.a, f.b) for f in single]


def test_failed_frames_are_not_used_and_still_fall_back_to_neighbours():
    config = DepthConfig(temporal_window=5)
    rng = np.random.default_rng(4)
    fits = [affine_fit(pairs(i, rng, count=5 if i == 3 else 300), config, np.random.default_rng(i))
            for i in range(8)]
    assert not fits[3].ok
    refined = temporal_refine(fits, config)
    assert not refined[3].ok and refined[3] is fits[3]
    assert 3 not in refined[2].extra["window_frames"] and 3 not in refined[4].extra["window_frames"]
    with pytest.warns(DepthWarning):
        params = fill_from_neighbours(refined, np.arange(8.0))
    assert params[3].source == "neighbours"
    assert params[3].a == pytest.approx(0.5 * (refined[2].a + refined[4].a))


def test_window_must_be_odd():
    with pytest.raises(ValueError, match="odd"):
        DepthConfig(temporal_window=4)


def _fit(ok, a=math.nan, b=math.nan):
    pairs = RadarPairs(np.zeros((0, 3)), np.zeros((0, 2)), np.zeros(0), np.zeros(0), np.zeros((0, 3), int),
                       np.zeros(0, np.int8))
    return FrameFit("affine", a, b, ok, "ok" if ok else "3 valid pairs < min_pairs 12", pairs, np.zeros(0, bool))


def test_too_few_pairs_fall_back_to_neighbours():
    fits = [_fit(False), _fit(True, 1.0, 0.1), _fit(False), _fit(True, 2.0, 0.3), _fit(False)]
    with pytest.warns(DepthWarning) as record:
        params = fill_from_neighbours(fits, [0.0, 1.0, 2.0, 3.0, 4.0])
    warned = [str(w.message) for w in record]
    assert [m.split(":")[1] for m in warned] == [" frame 0", " frame 2", " frame 4"]
    assert "frame(s) 1, 3" in warned[1]
    assert [p.source for p in params] == ["neighbours", "fit", "neighbours", "fit", "neighbours"]
    assert (params[0].a, params[0].b) == (1.0, 0.1)  # only a later neighbour
    assert params[2].a == pytest.approx(1.5) and params[2].b == pytest.approx(0.2)  # interpolated in time
    assert params[4].from_frames == (3,)
    with pytest.raises(ValueError, match="no frame has enough"):
        fill_from_neighbours([_fit(False)], [0.0])
