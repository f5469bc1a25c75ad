"""Focus steps: the moving-pixel error against a naive loop, the draw probabilities, the draws themselves, and a run
that trains only its moving part on them and resumes exactly."""

from __future__ import annotations

import numpy as np
import pytest
import torch
from _prepared import prepared_tiny_scene, tiny_config
from hypothesis import given, settings
from hypothesis import strategies as st

from radar4dgs.train.focus import focus_row, focus_weights, is_focus_step, moving_pixel_error
from radar4dgs.train.trainer import train_run

pytestmark = pytest.mark.usefixtures("one_torch_thread")


def test_moving_pixel_error_is_the_mean_absolute_error_over_the_mask():
    rng = np.random.default_rng(0)
    rgb, image = rng.uniform(-0.2, 1.2, (2, 6, 5, 3))
    mask = rng.uniform(size=(6, 5)) < 0.4
    rows, cols = np.nonzero(mask)
    naive = np.mean([np.abs(np.clip(rgb[r, c], 0, 1) - image[r, c]).mean() for r, c in zip(rows, cols, strict=True)])
    error = moving_pixel_error(torch.as_tensor(rgb), torch.as_tensor(image), torch.as_tensor(mask))
    assert error == pytest.approx(naive, rel=1e-12)
    assert moving_pixel_error(torch.as_tensor(rgb), torch.as_tensor(image), torch.zeros(6, 5, dtype=torch.bool)) == 0


def test_weights_go_with_the_square_of_the_error():
    np.testing.assert_allclose(focus_weights(np.array([0.01, 0.02, 0.0, 0.01])), [1 / 6, 4 / 6, 0, 1 / 6])
    np.testing.assert_allclose(focus_weights(np.zeros(4)), np.full(4, 0.25))
    assert [is_focus_step(0.5, 10, s) for s in range(4, 10)] == [False, False, True, False, True, False]
    assert not any(is_focus_step(0.0, 10, s) for s in range(10))


@settings(max_examples=25, deadline=None)
@given(st.lists(st.floats(0.0, 1.0), min_size=2, max_size=12), st.integers(0, 2**31))
def test_draws_follow_the_weights_and_never_pick_a_frame_without_error(errors, seed):
    weights = focus_weights(np.array(errors))
    draws = np.array([focus_row(seed, step, weights) for step in range(2000)])
    assert all(weights[draws] > 0)
    counts = np.bincount(draws, minlength=len(weights)) / len(draws)
    np.testing.assert_allclose(counts, weights, atol=0.05)
    assert focus_row(seed, 7, weights) == focus_row(seed, 7, weights)


@pytest.fixture(scope="module")
def prepared(tmp_path_factory):
    return prepared_tiny_scene(tmp_path_factory.mktemp("focus"), seed=2)


def test_focus_steps_train_only_the_moving_part_and_resume_exactly(prepared, tmp_path):
    scene, prep = prepared
    config = tiny_config(focus_at=0.7)  # 24 iterations: focus steps 18, 20, 22
    unbroken = train_run(scene, prep, tmp_path / "a", config, progress=False)
    assert unbroken.focus is not None and unbroken.focus.sum() == pytest.approx(1.0)
    frames = {h["step"]: h["frame"] for h in unbroken.history if "frame" in h}
    names = sorted({h["frame"] for h in unbroken.history if "frame" in h})
    assert len(names) == len(unbroken.focus)
    for step in (18, 20, 22):
        assert frames[step] == names[focus_row(config.seed, step, unbroken.focus)]

    checkpoint = tmp_path / "b" / "checkpoints" / "last.pt"
    train_run(scene, prep, tmp_path / "b", config, progress=False, stop_after=18)
    before = torch.load(checkpoint, weights_only=True)["model"]["static"]["means"]
    train_run(scene, prep, tmp_path / "b", config, progress=False, resume=True, stop_after=1)  # focus step 18
    after_focus = torch.load(checkpoint, weights_only=True)["model"]["static"]["means"]
    train_run(scene, prep, tmp_path / "b", config, progress=False, resume=True, stop_after=1)  # plain step 19
    after_plain = torch.load(checkpoint, weights_only=True)["model"]["static"]["means"]
    torch.testing.assert_close(after_focus, before, rtol=0, atol=0)
    assert not torch.equal(after_plain, after_focus)
    resumed = train_run(scene, prep, tmp_path / "b", config, resume=True, progress=False)
    np.testing.assert_array_equal(resumed.focus, unbroken.focus)
    for name in ("static", "dynamic"):
        a, b = getattr(unbroken.model, name), getattr(resumed.model, name)
        for key in a.params:
            torch.testing.assert_close(a.params[key], b.params[key], rtol=1e-5, atol=1e-6)
