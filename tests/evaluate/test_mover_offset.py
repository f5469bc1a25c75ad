import numpy as np
from hypothesis import given, settings
from hypothesis import strategies as st

from radar4dgs.evaluate.mover_offset import largest_mover, mover_offset


def textured(shape, seed=0):
    rng = np.random.default_rng(seed)
    return rng.random((*shape, 3))


def blob(shape, top, left, height, width):
    mask = np.zeros(shape, dtype=bool)
    mask[top:top + height, left:left + width] = True
    return mask


@settings(max_examples=25, deadline=None)
@given(dy=st.integers(-6, 6), dx=st.integers(-6, 6), seed=st.integers(0, 1000))
def test_a_shifted_render_is_found_and_realigned_exactly(dy, dx, seed):
    truth = textured((60, 80), seed)
    mask = blob((60, 80), 20, 25, 15, 30)
    render = np.roll(truth, (dy, dx), axis=(0, 1))  # the mover's content drawn at (y + dy, x + dx)
    found = mover_offset(truth, render, mask, reach=8)
    assert (found["dy"], found["dx"]) == (dy, dx)
    assert found["offset_px"] == np.hypot(dy, dx)
    assert found["psnr_realigned"] > 60.0
    if (dy, dx) != (0, 0):
        # Uniform noise in [0, 1] against another draw of it: MSE 1/6, PSNR 7.8 dB.
        assert abs(found["psnr"] - 10 * np.log10(6)) < 1.0


def test_only_the_largest_mover_is_scored():
    truth = textured((60, 80), 1)
    mask = blob((60, 80), 5, 5, 4, 4) | blob((60, 80), 30, 30, 20, 20)
    assert largest_mover(mask).sum() == 400
    render = truth.copy()
    render[5:9, 5:9] = 0.0  # the small mover wrong, the large one in place
    found = mover_offset(truth, render, mask)
    assert (found["dy"], found["dx"], found["pixels"]) == (0, 0, 400)
    assert found["psnr"] > 60.0


def test_an_empty_mask_has_no_offset():
    assert mover_offset(textured((10, 10)), textured((10, 10), 2), np.zeros((10, 10), bool)) is None
