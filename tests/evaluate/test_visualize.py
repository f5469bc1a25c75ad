import cv2
import numpy as np
import pytest
import torch

from radar4dgs.evaluate.visualize import (
    depth_to_rgb,
    error_to_rgb,
    image_to_rgb,
    mask_to_rgb,
    side_by_side,
)


def _cmap(index: int, colormap: int) -> np.ndarray:
    """OpenCV's colour of one 0..255 index, as RGB."""
    bgr = cv2.applyColorMap(np.array([[index]], np.uint8), colormap)
    return bgr[0, 0, ::-1]


def test_depth_colours_follow_the_inverse_depth():
    depth = np.array([[1.0, 4.0, 1.6], [np.nan, np.inf, 0.0], [-2.0, 8.0, 0.5]])
    rgb = depth_to_rgb(depth, near=1.0, far=4.0)
    assert rgb.dtype == np.uint8 and rgb.shape == (3, 3, 3)
    np.testing.assert_array_equal(rgb[0, 0], _cmap(255, cv2.COLORMAP_TURBO))  # near: red end
    np.testing.assert_array_equal(rgb[0, 1], _cmap(0, cv2.COLORMAP_TURBO))  # far: blue end
    # 1/1.6 = 0.625, halfway between 1/4 and 1/1 -> index round(127.5) = 128
    np.testing.assert_array_equal(rgb[0, 2], _cmap(128, cv2.COLORMAP_TURBO))
    np.testing.assert_array_equal(rgb[1], 0)  # NaN, inf and 0: black
    np.testing.assert_array_equal(rgb[2, 0], 0)  # negative: black
    np.testing.assert_array_equal(rgb[2, 1], _cmap(0, cv2.COLORMAP_TURBO))  # beyond far: clipped
    np.testing.assert_array_equal(rgb[2, 2], _cmap(255, cv2.COLORMAP_TURBO))  # nearer than near


def test_depth_range_defaults_to_the_image_and_torch_input_works():
    depth = torch.tensor([[2.0, 10.0], [float("nan"), 4.0]])
    rgb = depth_to_rgb(depth)
    np.testing.assert_array_equal(rgb[0, 0], _cmap(255, cv2.COLORMAP_TURBO))
    np.testing.assert_array_equal(rgb[0, 1], _cmap(0, cv2.COLORMAP_TURBO))
    np.testing.assert_array_equal(rgb[1, 0], 0)
    # 1/4 = 0.25 between 1/10 and 1/2: (0.25 - 0.1) / 0.4 = 0.375 -> index round(95.625) = 96
    np.testing.assert_array_equal(rgb[1, 1], _cmap(96, cv2.COLORMAP_TURBO))
    np.testing.assert_array_equal(depth_to_rgb(np.full((2, 3), np.nan)), 0)
    flat = depth_to_rgb(np.full((2, 3), 5.0))  # near == far: the middle colour
    np.testing.assert_array_equal(flat, np.broadcast_to(_cmap(128, cv2.COLORMAP_TURBO), (2, 3, 3)))
    with pytest.raises(ValueError):
        depth_to_rgb(np.ones((2, 3, 1)))


def test_masks_and_images_to_rgb():
    mask = np.array([[True, False], [False, True]])
    rgb = mask_to_rgb(torch.from_numpy(mask))
    assert rgb.dtype == np.uint8 and rgb.shape == (2, 2, 3)
    np.testing.assert_array_equal(rgb[..., 0], [[255, 0], [0, 255]])
    np.testing.assert_array_equal(rgb[..., 0], rgb[..., 2])
    np.testing.assert_array_equal(mask_to_rgb(np.array([[0.5, 2.0]]))[0, :, 1], [128, 255])
    np.testing.assert_array_equal(image_to_rgb(np.array([[[0.0, 0.5, 1.2]]]))[0, 0], [0, 128, 255])


def test_error_heat_map():
    gt = np.zeros((2, 3, 3))
    pred = gt.copy()
    pred[0, 1] = 0.1  # mean abs error 0.1 = half of vmax 0.2 -> index 128
    pred[0, 2] = [0.9, 0.0, 0.0]  # mean 0.3 > vmax: saturated
    pred[1, 0] = np.nan
    rgb = error_to_rgb(pred, gt)
    assert rgb.dtype == np.uint8 and rgb.shape == (2, 3, 3)
    np.testing.assert_array_equal(rgb[0, 0], _cmap(0, cv2.COLORMAP_INFERNO))
    np.testing.assert_array_equal(rgb[0, 1], _cmap(128, cv2.COLORMAP_INFERNO))
    np.testing.assert_array_equal(rgb[0, 2], _cmap(255, cv2.COLORMAP_INFERNO))
    np.testing.assert_array_equal(rgb[1, 0], _cmap(255, cv2.COLORMAP_INFERNO))
    # uint8 images on the same [0, 1] scale; torch tensors accepted.
    as_uint8 = error_to_rgb(np.full((1, 1, 3), 51, np.uint8), np.zeros((1, 1, 3), np.uint8), vmax=0.4)
    np.testing.assert_array_equal(as_uint8[0, 0], _cmap(128, cv2.COLORMAP_INFERNO))  # 0.2 / 0.4
    same = error_to_rgb(torch.ones(2, 2, 3), torch.ones(2, 2, 3))
    np.testing.assert_array_equal(same[0, 0], _cmap(0, cv2.COLORMAP_INFERNO))
    with pytest.raises(ValueError):
        error_to_rgb(np.zeros((2, 2, 3)), np.zeros((2, 3, 3)))


def test_side_by_side_layout_and_labels():
    a = np.full((10, 8, 3), 100, np.uint8)
    b = np.full((6, 5, 3), 200, np.uint8)
    out = side_by_side([a, b])
    assert out.dtype == np.uint8 and out.shape == (10, 13, 3)
    np.testing.assert_array_equal(out[:, :8], a)
    np.testing.assert_array_equal(out[:6, 8:], b)
    np.testing.assert_array_equal(out[6:, 8:], 0)  # the shorter panel padded with black

    big_a = np.full((60, 120, 3), 100, np.uint8)
    big_b = np.full((60, 120, 3), 100, np.uint8)
    labelled = side_by_side([big_a, big_b], ["render", ""])
    np.testing.assert_array_equal(big_a, 100)  # inputs untouched
    assert (labelled[:, :120] > 180).any() and (labelled[:, :120] == 0).any()  # white text, black box
    np.testing.assert_array_equal(labelled[:, 120:], 100)  # empty label: nothing drawn
    np.testing.assert_array_equal(labelled[40:, :120], 100)  # text stays near the top

    with pytest.raises(ValueError, match="labels"):
        side_by_side([a, b], ["one"])
    with pytest.raises(ValueError, match="uint8"):
        side_by_side([a.astype(np.float32)])
    with pytest.raises(ValueError):
        side_by_side([])
