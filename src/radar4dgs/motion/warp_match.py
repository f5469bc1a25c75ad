"""Matching one masked object between two images with an affine warp (translation, scale change,
shear): a translation search around a predicted warp, then OpenCV's ECC refinement of all six
parameters, and the photometric error that decides between candidate motions.

Affine convention: ``A`` (2, 3) maps a pixel ``x`` of image a to ``A[:, :2] x + A[:, 2]`` in image b.
"""

from __future__ import annotations

import numpy as np

from radar4dgs.motion.sampling import bilinear_sample


def affine_targets(affine: np.ndarray, pixels: np.ndarray) -> np.ndarray:
    """(N, 2) images of (N, 2) pixels under the (2, 3) affine."""
    return np.asarray(pixels, dtype=np.float64) @ affine[:, :2].T + affine[:, 2]


def fit_similarity(source: np.ndarray, target: np.ndarray) -> np.ndarray | None:
    """(2, 3) similarity (rotation, isotropic scale, translation) carrying (N, 2) ``source`` onto
    (N, 2) ``target`` (NaN rows ignored), least median of squares (``cv2.estimateAffinePartial2D``,
    LMEDS); None with fewer than 3 finite rows or no fit.

    Not a full affine: predicted targets inherit the depth map's noise, and mask pixels on the
    background carry the background's depth; a 6-parameter least-squares fit turns those into
    shear (seen: 7 % on an 86-pixel car) that then misleads the search.
    """
    import cv2

    finite = np.isfinite(target).all(axis=1)
    if finite.sum() < 3:
        return None
    affine, _ = cv2.estimateAffinePartial2D(np.asarray(source, dtype=np.float32)[finite],
                                            np.asarray(target, dtype=np.float32)[finite], method=cv2.LMEDS)
    return None if affine is None else affine.astype(np.float64)


def invert_affine(affine: np.ndarray) -> np.ndarray:
    """(2, 3) inverse of a (2, 3) affine with an invertible linear part."""
    linear = np.linalg.inv(affine[:, :2])
    return np.column_stack([linear, -linear @ affine[:, 2]])


def shape_change(affine: np.ndarray, reference: np.ndarray) -> float:
    """max |log singular value| of ``affine``'s linear part relative to ``reference``'s (both (2, 3)):
    0 for the same scale and shear, log(1.2) for 20 % more stretch in some direction."""
    relative = affine[:, :2] @ np.linalg.inv(reference[:, :2])
    singular = np.linalg.svd(relative, compute_uv=False)
    return float(np.max(np.abs(np.log(np.maximum(singular, 1e-12)))))


def mean_abs_error(gray_a: np.ndarray, gray_b: np.ndarray, pixels: np.ndarray, targets: np.ndarray,
                   min_inside: float) -> float:
    """Mean |a(pixels) - b(targets)| (grey levels) over the targets inside b (bilinear).

    Pixels that leave the image carry no evidence either way (a car passing the camera leaves it
    within a frame or two); a motion that keeps fewer than ``min_inside`` (a fraction) of them in
    view cannot be verified and costs inf.

    Args:
        gray_a, gray_b: (H, W) uint8. pixels: (N, 2) integer (u, v) of a. targets: (N, 2) in b.
    """
    values, inside = bilinear_sample(gray_b, np.nan_to_num(targets, nan=-1.0))
    if len(pixels) == 0 or inside.sum() < max(min_inside * len(pixels), 1):
        return float("inf")
    rows, cols = pixels[inside, 1].astype(np.int64), pixels[inside, 0].astype(np.int64)
    return float(np.abs(gray_a[rows, cols].astype(np.float64) - values[inside]).mean())


def _correlate(image: np.ndarray, template: np.ndarray) -> np.ndarray:
    """``out[y, x] = sum template(p) image(p + (x, y))`` (cv2.TM_CCORR, float32)."""
    import cv2

    return cv2.matchTemplate(image.astype(np.float32), template.astype(np.float32), cv2.TM_CCORR).astype(np.float64)


def _subpixel(costs: np.ndarray, y: int, x: int) -> np.ndarray:
    """(2,) parabola offsets (dx, dy) in [-0.5, 0.5] of the minimum at (y, x) of a cost grid."""
    offset = np.zeros(2)
    for axis, (minus, centre, plus) in enumerate(((costs[y, x - 1], costs[y, x], costs[y, x + 1]),
                                                  (costs[y - 1, x], costs[y, x], costs[y + 1, x]))):
        curvature = minus - 2 * centre + plus
        if np.isfinite(curvature) and curvature > 0:
            offset[axis] = float(np.clip(0.5 * (minus - plus) / curvature, -0.5, 0.5))
    return offset


def search_translation(gray_a: np.ndarray, gray_b: np.ndarray, mask: np.ndarray, affine: np.ndarray,
                       search: int, min_inside: float) -> np.ndarray | None:
    """The affine ``affine`` corrected by the residual translation that best matches the object.

    Image b is warped back by ``affine`` (so the object keeps its shape and scale in a's frame),
    then every integer shift within ``search`` px is scored by the masked sum of squared
    differences divided by the number of object pixels still inside b (masked correlation as in
    Padfield, "Masked object registration in the Fourier domain", IEEE TIP 2012, from four
    ``cv2.matchTemplate`` correlations). Dividing by the overlap keeps an object that leaves the
    image from being pulled back into view; shifts keeping fewer than ``min_inside`` of its pixels
    inside are not considered.

    Args:
        gray_a, gray_b: (H, W) uint8. mask: (H, W) bool, the object in a.
        affine: (2, 3) predicted warp a -> b. search: window radius (px).
    Returns:
        (2, 3) affine, or None when the best shift is on the window's border or nothing overlaps.
    """
    import cv2

    rows, cols = np.nonzero(mask)
    if len(rows) == 0:
        return None
    x0, y0, x1, y1 = cols.min(), rows.min(), cols.max() + 1, rows.max() + 1
    weight = mask[y0:y1, x0:x1].astype(np.float64)
    template = gray_a[y0:y1, x0:x1].astype(np.float64)
    centre = float(template[weight > 0].mean())
    template = (template - centre) * weight
    # Warp b into a's frame over the window's region (origin (x0 - search, y0 - search)).
    linear = affine[:, :2]
    origin = np.array([x0 - search, y0 - search], dtype=np.float64)
    crop = np.column_stack([linear, linear @ origin + affine[:, 2]])
    size = (int(x1 - x0 + 2 * search), int(y1 - y0 + 2 * search))
    flags = cv2.INTER_LINEAR | cv2.WARP_INVERSE_MAP
    warped = cv2.warpAffine(gray_b.astype(np.float32), crop, size, flags=flags, borderValue=0.0)
    inside = cv2.warpAffine(np.ones(gray_b.shape, np.float32), crop, size, flags=flags, borderValue=0.0)
    inside = (inside > 0.999).astype(np.float64)
    image = (warped - centre) * inside
    count = _correlate(inside, weight)
    ssd = _correlate(inside, template ** 2) - 2 * _correlate(image, template) + _correlate(image ** 2, weight)
    costs = np.where(count >= max(min_inside * weight.sum(), 1.0), ssd / np.maximum(count, 1.0), np.inf)
    if not np.isfinite(costs).any():
        return None
    y, x = np.unravel_index(int(np.argmin(costs)), costs.shape)
    if y in (0, costs.shape[0] - 1) or x in (0, costs.shape[1] - 1):
        return None
    shift = np.array([x - search, y - search], dtype=np.float64) + _subpixel(costs, y, x)
    return np.column_stack([linear, linear @ shift + affine[:, 2]])


def _boxes(mask: np.ndarray, affine: np.ndarray, margin: int) -> tuple[np.ndarray, ...] | None:
    """(a0, a1, b0, b1): (2,) int (x, y) start and stop of the object's box in a and of the box
    ``affine`` carries it to in b, each grown by ``margin`` px and clipped to the image; None when
    the object is empty or (almost) out of b's view."""
    height, width = mask.shape
    rows, cols = np.nonzero(mask)
    if len(rows) < 3:
        return None
    a0 = np.array([max(cols.min() - margin, 0), max(rows.min() - margin, 0)])
    a1 = np.array([min(cols.max() + margin + 1, width), min(rows.max() + margin + 1, height)])
    corners = affine_targets(affine, np.array([[a0[0], a0[1]], [a1[0], a0[1]], [a0[0], a1[1]], [a1[0], a1[1]]]))
    b0 = np.maximum(np.floor(corners.min(axis=0)).astype(np.int64) - margin, 0)
    b1 = np.minimum(np.ceil(corners.max(axis=0)).astype(np.int64) + margin + 1, [width, height])
    return None if np.any(b1 - b0 < 8) else (a0, a1, b0, b1)


def _crop(image: np.ndarray, start: np.ndarray, stop: np.ndarray) -> np.ndarray:
    return np.ascontiguousarray(image[start[1]:stop[1], start[0]:stop[0]])


def _shifted(affine: np.ndarray, source: np.ndarray, target: np.ndarray) -> np.ndarray:
    """(2, 3) ``affine`` in crop coordinates: ``x - source`` maps to ``affine(x) - target``."""
    return np.column_stack([affine[:, :2], affine[:, :2] @ source + affine[:, 2] - target])


def _ecc(template: np.ndarray, image: np.ndarray, warp: np.ndarray, template_mask: np.ndarray | None,
         image_mask: np.ndarray, iterations: int) -> np.ndarray | None:
    """(2, 3) float64 affine ECC warp (template coordinates -> image coordinates), or None when ECC
    raises (no convergence, empty overlap). ``template_mask`` None: the masks-on-input-only API.

    Two runs, the second from the first's result: ECC stops on a small gain of the correlation
    while the scale still drifts (synthetic 40-80 px shifts with 0-25 % zoom, swapped roles: worst
    pixel error 1.1 -> 0.67 px; a smaller epsilon or more iterations did not do it)."""
    import cv2

    criteria = (cv2.TERM_CRITERIA_COUNT | cv2.TERM_CRITERIA_EPS, iterations, 1e-5)
    warp, found = warp.astype(np.float32), None
    for _ in range(2):
        try:
            if template_mask is None:
                _, warp = cv2.findTransformECC(template, image, warp, cv2.MOTION_AFFINE, criteria, image_mask, 3)
            else:
                _, warp = cv2.findTransformECCWithMask(template, image, template_mask, image_mask, warp,
                                                       cv2.MOTION_AFFINE, criteria, 3)
        except cv2.error:
            break
        found = warp.astype(np.float64)  # a copy: ECC updates its warp argument in place
    return found if found is not None and np.all(np.isfinite(found)) else None


def refine_affine(gray_a: np.ndarray, gray_b: np.ndarray, mask: np.ndarray, affine: np.ndarray,
                  iterations: int, margin: int = 4) -> np.ndarray | None:
    """``affine`` refined by ECC (Evangelidis & Psarakis, TPAMI 2008; OpenCV, MOTION_AFFINE) on
    the object's pixels; None when ECC fails or the object left image b.

    With ``cv2.findTransformECCWithMask`` (OpenCV >= 4.13) the template is a with the object's
    mask. Older OpenCV masks the input image only, so the roles are swapped there: the template is
    b around the predicted place, the input a with the mask, and the warp found (b -> a) is
    inverted. The swapped form is less precise (the valid region moves with the warp): worst pixel
    error on the synthetic shift+zoom pair of the tests 0.04 px direct, 0.5-1.1 px swapped.

    Args:
        gray_a, gray_b: (H, W) uint8. mask: (H, W) bool, the object in a.
        affine: (2, 3) initial warp a -> b (within a few px). iterations: ECC's iteration cap.
        margin: px added around the object's boxes.
    """
    import cv2

    boxes = _boxes(mask, affine, margin)
    if boxes is None:
        return None
    a0, a1, b0, b1 = boxes
    crop_a, crop_b = _crop(gray_a, a0, a1).astype(np.float32), _crop(gray_b, b0, b1).astype(np.float32)
    crop_mask = _crop(mask, a0, a1).astype(np.uint8)
    if hasattr(cv2, "findTransformECCWithMask"):
        warp = _ecc(crop_a, crop_b, _shifted(affine, a0, b0), crop_mask, np.ones_like(crop_b, np.uint8),
                    iterations)
        full = None if warp is None else _shifted(warp, -a0, -b0)
    else:
        warp = _ecc(crop_b, crop_a, _shifted(invert_affine(affine), b0, a0), None, crop_mask, iterations)
        invertible = warp is not None and abs(np.linalg.det(warp[:, :2])) >= 1e-6
        full = invert_affine(_shifted(warp, -b0, -a0)) if invertible else None
    if full is None or abs(np.linalg.det(full[:, :2])) < 1e-6:
        return None
    return full
