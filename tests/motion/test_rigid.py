"""Whole-object translations: sub-pixel matching of a masked object and its use over dense flow."""

from __future__ import annotations

import cv2
import numpy as np
import pytest
from _flow_helpers import texture
from hypothesis import given, settings
from hypothesis import strategies as st

from radar4dgs.motion.optical_flow import dis_flow
from radar4dgs.motion.rigid import object_translation, rigid_object_flow


def shifted(image: np.ndarray, du: float, dv: float) -> np.ndarray:
    """``image`` with its content moved by (du, dv) pixels (bilinear, edges replicated)."""
    matrix = np.array([[1.0, 0.0, du], [0.0, 1.0, dv]])
    return cv2.warpAffine(image, matrix, image.shape[::-1], flags=cv2.INTER_LINEAR,
                          borderMode=cv2.BORDER_REPLICATE)


@settings(max_examples=12, deadline=None)
@given(du=st.floats(-9.0, 9.0), dv=st.floats(-9.0, 9.0))
def test_object_translation_recovers_a_sub_pixel_shift(du, dv):
    a = texture(90, 160, seed=3)
    b = shifted(a, du, dv)
    rows, cols = np.mgrid[30:60, 50:110]
    pixels = np.stack([cols.ravel(), rows.ravel()], axis=1)
    shift, error = object_translation(a, b, pixels, np.zeros(2), search=12)
    assert shift == pytest.approx([du, dv], abs=0.2)
    assert error < 3.0  # grey levels; the wrong shift costs tens


def test_object_translation_refuses_a_best_shift_on_the_window_border():
    # A wide smooth blob: the error falls steadily towards the true shift, so the best shift in a
    # window too small to hold it is on the window's border.
    v, u = np.mgrid[0:90, 0:160]
    a = (20 + 210 * np.exp(-((u - 80.0) ** 2 + (v - 45.0) ** 2) / (2 * 30.0 ** 2))).astype(np.uint8)
    b = shifted(a, 10.0, 0.0)
    rows, cols = np.mgrid[30:60, 50:110]
    pixels = np.stack([cols.ravel(), rows.ravel()], axis=1)
    assert object_translation(a, b, pixels, np.zeros(2), search=6) is None
    shift, _ = object_translation(a, b, pixels, np.array([8.0, 0.0]), search=6)
    assert shift == pytest.approx([10.0, 0.0], abs=0.2)


def test_object_translation_searches_wide_when_the_window_is_too_small():
    # The smooth blob moved 30 px: beyond a 6 px window around 0, within a 40 px wide search.
    v, u = np.mgrid[0:90, 0:200]
    a = (20 + 210 * np.exp(-((u - 80.0) ** 2 + (v - 45.0) ** 2) / (2 * 30.0 ** 2))).astype(np.uint8)
    b = shifted(a, 30.0, -3.0)
    rows, cols = np.mgrid[30:60, 50:110]
    pixels = np.stack([cols.ravel(), rows.ravel()], axis=1)
    assert object_translation(a, b, pixels, np.zeros(2), search=6, wide_search=20) is None  # still too narrow
    shift, error = object_translation(a, b, pixels, np.zeros(2), search=6, wide_search=40)
    assert shift == pytest.approx([30.0, -3.0], abs=0.2)
    assert error < 2.0


@pytest.mark.parametrize("motion", [-31, 17, 26])
def test_rigid_object_flow_searches_wide_for_a_fast_object(motion):
    a, b, mask = bar_scene(motion=motion)
    dense = np.zeros((*mask.shape, 2), dtype=np.float32)  # a dense flow stuck to the background
    assert np.array_equal(rigid_object_flow(a, b, dense, mask), dense)  # one 12 px window: nothing found
    fixed = rigid_object_flow(a, b, dense, mask, wide_search=40)
    assert fixed[mask] == pytest.approx(np.tile([float(motion), 0.0], (int(mask.sum()), 1)), abs=0.2)


def bar_scene(motion: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """A uniformly coloured bar (12 x 60 px, texture only at its two ends) moving ``motion`` px to
    the right over a textured static background: grey images a and b and the bar's mask in a."""
    background = texture(90, 160, seed=5)
    mask = np.zeros((90, 160), dtype=bool)
    mask[40:52, 40:100] = True

    def draw(offset: int) -> np.ndarray:
        image = background.copy()
        image[40:52, 40 + offset:100 + offset] = 200
        image[40:52, 40 + offset:43 + offset] = 30  # dark ends: the only texture
        image[40:52, 97 + offset:100 + offset] = 30
        return image

    return draw(0), draw(motion), mask


def test_rigid_object_flow_fixes_the_aperture_problem_of_a_uniform_object():
    a, b, mask = bar_scene(motion=5)
    dense = dis_flow(a, b, "medium")
    # The premise: inside the bar DIS loses most of the motion.
    assert abs(np.median(dense[mask][:, 0]) - 5.0) > 1.0
    fixed = rigid_object_flow(a, b, dense, mask)
    assert fixed[mask] == pytest.approx(np.tile([5.0, 0.0], (int(mask.sum()), 1)), abs=0.2)
    assert np.array_equal(fixed[~mask], dense[~mask])


def test_rigid_object_flow_keeps_a_dense_flow_that_explains_the_images_better():
    # An object growing by 20 % about its centre (a car coming closer): no translation explains it,
    # the exact dense flow does, so the dense flow stays.
    a = texture(90, 160, seed=6)
    centre = np.array([80.0, 45.0])
    matrix = np.hstack([1.2 * np.eye(2), ((1 - 1.2) * centre)[:, None]])
    b = cv2.warpAffine(a, matrix, (160, 90), flags=cv2.INTER_LINEAR, borderMode=cv2.BORDER_REPLICATE)
    v, u = np.mgrid[0:90, 0:160].astype(np.float32)
    exact = np.stack([0.2 * (u - centre[0]), 0.2 * (v - centre[1])], axis=-1).astype(np.float32)
    mask = (np.abs(u - centre[0]) < 25) & (np.abs(v - centre[1]) < 15)
    assert np.array_equal(rigid_object_flow(a, b, exact, mask), exact)
    # Components below min_pixels are left alone too.
    bar_a, bar_b, bar_mask = bar_scene(motion=5)
    zero = np.zeros((90, 160, 2), dtype=np.float32)
    assert np.array_equal(rigid_object_flow(bar_a, bar_b, zero, bar_mask, min_pixels=10_000), zero)
