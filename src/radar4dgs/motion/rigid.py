"""Whole-object translations: per connected component of the dynamic mask, the single 2D shift
that best carries the object from one image to the next, replacing the dense flow where it explains
the images better (``FlowConfig.rigid_objects``: the aperture problem of uniform objects)."""

from __future__ import annotations

import numpy as np

from radar4dgs.motion.sampling import bilinear_sample


def _photometric_error(gray_a: np.ndarray, gray_b: np.ndarray, pixels: np.ndarray, targets: np.ndarray) -> float:
    """Mean |a(pixels) - b(targets)| (grey levels), b sampled bilinearly; a target outside b counts
    as the largest error (255), so leaving the image is never cheap."""
    values, inside = bilinear_sample(gray_b, targets)
    source = gray_a[pixels[:, 1].astype(np.int64), pixels[:, 0].astype(np.int64)].astype(np.float64)
    return float(np.where(inside, np.abs(source - values), 255.0).mean())


def _shift_errors(source: np.ndarray, b: np.ndarray, pixels: np.ndarray, start: np.ndarray,
                  offsets: np.ndarray, offsets_v: np.ndarray | None = None) -> np.ndarray:
    """(Sv, S) mean absolute error of the (N,) ``source`` values at (N, 2) ``pixels`` against float image
    ``b`` shifted by ``start + (offsets[x], offsets_v[y])`` at ``[y, x]`` (``offsets_v`` defaults to
    ``offsets``); targets outside b cost 255."""
    offsets_v = offsets if offsets_v is None else offsets_v
    height, width = b.shape
    u = pixels[None, :, 0] + start[0] + offsets[:, None]  # (S, N)
    v = pixels[None, :, 1] + start[1] + offsets_v[:, None]  # (Sv, N)
    u_in, v_in = (u >= 0) & (u < width), (v >= 0) & (v < height)
    u, v = np.clip(u, 0, width - 1), np.clip(v, 0, height - 1)
    errors = np.empty((len(offsets_v), len(offsets)))
    for row, (v_row, v_ok) in enumerate(zip(v, v_in, strict=True)):
        diff = np.abs(source[None] - b[v_row[None], u])
        errors[row] = np.where(v_ok[None] & u_in, diff, 255.0).mean(axis=1)
    return errors


def _window_best(errors: np.ndarray) -> tuple[int, int, bool]:
    """Row, column of the least of a window's (S, S) ``errors``, and whether it lies on the border."""
    y, x = np.unravel_index(int(np.argmin(errors)), errors.shape)
    last = errors.shape[0] - 1
    return int(y), int(x), y in (0, last) or x in (0, last)


def _coarse_shift(gray_a: np.ndarray, gray_b: np.ndarray, pixels: np.ndarray, start: np.ndarray,
                  radius: int, vertical: int, max_pixels: int = 1000) -> np.ndarray:
    """(2,) int64 best offset from ``start`` among every second shift within +-``radius`` px across and
    +-``vertical`` px up and down, on images blurred (sigma 1.5 px) so that a shift one pixel off the
    truth still scores near it."""
    import cv2

    if len(pixels) > max_pixels:
        pixels = pixels[:: -(-len(pixels) // max_pixels)]
    blur_a, blur_b = (cv2.GaussianBlur(g.astype(np.float32), (0, 0), 1.5) for g in (gray_a, gray_b))
    across, updown = np.arange(-radius, radius + 1, 2), np.arange(-vertical, vertical + 1, 2)
    errors = _shift_errors(blur_a[pixels[:, 1], pixels[:, 0]], blur_b, pixels, start, across, updown)
    y, x = np.unravel_index(int(np.argmin(errors)), errors.shape)
    return np.array([across[x], updown[y]])


def object_translation(gray_a: np.ndarray, gray_b: np.ndarray, pixels: np.ndarray, start: np.ndarray,
                       search: int, max_pixels: int = 4000, wide_search: int = 0,
                       min_pixels: int = 10) -> tuple[np.ndarray, float] | None:
    """The 2D translation that best carries an object's pixels of image a onto image b.

    Exhaustive integer search of the mean absolute grey-level error over a (2 search + 1)^2
    window around ``start``, then a parabola through the neighbours of the best shift on each axis
    for the sub-pixel part. Written here: OpenCV's matchTemplate takes rectangular templates only,
    and an object's mask is not a rectangle.

    Args:
        gray_a, gray_b: (H, W) uint8 grey images.
        pixels: (N, 2) integer (u, v) of the object in image a.
        start: (2,) the window centre (du, dv) in pixels, rounded to integers.
        search: the window's radius in pixels.
        max_pixels: larger objects are matched on an evenly strided subset of their pixels.
        wide_search: when the window's best shift lies on its border and this is larger than
            ``search``, a coarse search over +-``wide_search`` px across and +-``search`` px up and
            down around ``start`` (every second shift, on blurred images, at most 1000 of the
            pixels) picks a new centre, and the window is searched there. A cyclist crossing at 27
            px a frame lies beyond a 12 px window around its dense flow (stuck to the background); a
            full-resolution window that wide costs its area on every object. Movers keep to the
            ground: far beyond the window they move across the image, and a wide vertical search
            found a uniformly coloured taxi 25 px above where it went (rush tuning seed 202).
        min_pixels: the pixels one window's search needs (``FlowConfig.rigid_min_pixels``); the wide
            search tries wide_search / search times as many shifts, so it needs that many times
            more pixels to be as unambiguous (on rush-traffic tuning seeds 214-218, objects of a few
            dozen pixels matched over a wide square window were mostly wrong).
    Returns:
        ((2,) float64 shift (du, dv), its mean error), or None when the best integer shift lies on
        the border of the (last) window searched (the true one may lie beyond it).
    """
    pixels = np.asarray(pixels, dtype=np.int64)
    wide = wide_search > search and len(pixels) >= min_pixels * wide_search / search
    if len(pixels) > max_pixels:
        pixels = pixels[:: -(-len(pixels) // max_pixels)]
    start = np.round(np.asarray(start, dtype=np.float64)).astype(np.int64)
    offsets = np.arange(-search, search + 1)
    source = gray_a[pixels[:, 1], pixels[:, 0]].astype(np.float32)
    b = gray_b.astype(np.float32)
    errors = _shift_errors(source, b, pixels, start, offsets)
    y, x, on_border = _window_best(errors)
    if on_border and wide:
        start = start + _coarse_shift(gray_a, gray_b, pixels, start, wide_search, search)
        errors = _shift_errors(source, b, pixels, start, offsets)
        y, x, on_border = _window_best(errors)
    if on_border:
        return None
    shift = (start + offsets[[x, y]]).astype(np.float64)
    for axis, (minus, centre, plus) in enumerate(((errors[y, x - 1], errors[y, x], errors[y, x + 1]),
                                                  (errors[y - 1, x], errors[y, x], errors[y + 1, x]))):
        curvature = minus - 2 * centre + plus
        if curvature > 0:
            shift[axis] += float(np.clip(0.5 * (minus - plus) / curvature, -0.5, 0.5))
    return shift, _photometric_error(gray_a, gray_b, pixels, pixels + shift)


def rigid_object_flow(gray_a: np.ndarray, gray_b: np.ndarray, flow: np.ndarray, mask: np.ndarray,
                      search: int = 12, accept: float = 0.9, min_pixels: int = 10, wide_search: int = 0) -> np.ndarray:
    """``flow`` with each object's pixels set to the object's single translation where that explains
    the images better (see ``FlowConfig.rigid_objects``).

    Args:
        gray_a, gray_b: (H, W) uint8 grey images a and b.
        flow: (H, W, 2) dense flow a -> b.
        mask: (H, W) bool dynamic mask of image a; its 8-connected components are the objects.
        search, accept, min_pixels, wide_search: ``FlowConfig.rigid_search``, ``rigid_accept``,
            ``rigid_min_pixels``, ``rigid_wide_search``.
    Returns:
        (H, W, 2) float32 flow (a copy).
    """
    import cv2

    out = np.array(flow, dtype=np.float32, copy=True)
    count, labels = cv2.connectedComponents(np.asarray(mask, dtype=np.uint8), connectivity=8)
    for label in range(1, count):
        rows, cols = np.nonzero(labels == label)
        if len(rows) < min_pixels:
            continue
        shift = component_translation(gray_a, gray_b, np.stack([cols, rows], axis=1),
                                      flow[rows, cols].astype(np.float64), search, accept, wide_search, min_pixels)
        if shift is not None:
            out[rows, cols] = shift
    return out


def component_translation(gray_a: np.ndarray, gray_b: np.ndarray, pixels: np.ndarray, dense: np.ndarray,
                          search: int, accept: float, wide_search: int = 0, min_pixels: int = 10) -> np.ndarray | None:
    """(2,) the object's translation when it explains the images better than its dense flow
    (error below ``accept`` x the dense flow's), else None.

    Args:
        pixels: (N, 2) integer (u, v) of one object in a; dense: (N, 2) their dense flow a -> b.
    """
    found = object_translation(gray_a, gray_b, pixels, np.median(dense, axis=0), search, wide_search=wide_search,
                               min_pixels=min_pixels)
    if found is None:
        return None
    shift, error = found
    return shift if error < accept * _photometric_error(gray_a, gray_b, pixels, pixels + dense) else None
