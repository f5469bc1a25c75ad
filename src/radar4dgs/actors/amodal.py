"""An actor's body centre from the part of it the camera saw.

The Gaussians of a car lie on the surfaces the camera saw: a car followed from behind is its rear face
and little else, so the centroid of its Gaussians sits about half a car length in front of the body's
centre, on the camera's side (measured: every matched car of the tuning scenes had its error along the
camera ray, toward the camera, 0.3-1.7 m). A box fit to a partial view has the same ambiguity; the usual
answer (L-shape fitting of lidar clusters) anchors the box at the faces the sensor saw and extends it
away from the sensor to a size prior. That is what this does, per frame, in the actor's own frame.
"""

from __future__ import annotations

import numpy as np

# A body whose footprint (length along its heading, width across it; m) exceeds either of these is no
# pedestrian or cyclist (those are under ~1.9 x 0.8 m seen from any side): a car or bigger.
CAR_LIKE_LENGTH = 2.5
CAR_LIKE_WIDTH = 1.2
# The camera sees an axis's far face only when it looks along that axis: the completion along an axis
# is scaled by |cos| of the angle between the camera ray and that axis, full from this value up (60 deg
# off the axis), so a car seen squarely from behind is not widened to one side.
FULL_COMPLETION_COSINE = 0.5
# The fraction of a uniformly covered extent that its 5-95 % percentiles span.
SPAN = 0.9


def is_car_like(size: tuple[float, float, float]) -> bool:
    """Whether a footprint ``size`` (length, width, height; m) is a car's or bigger."""
    return size[0] >= CAR_LIKE_LENGTH or size[1] >= CAR_LIKE_WIDTH


def planar_extent(xy: np.ndarray, heading: float) -> tuple[np.ndarray, np.ndarray]:
    """(low (2,), high (2,)): the 5-95 % extents of planar points ``xy`` (K, 2) along ``heading`` (rad
    about world z) and across it (a few stray Gaussians do not stretch the body)."""
    c, s = np.cos(heading), np.sin(heading)
    local = xy @ np.array([[c, -s], [s, c]])
    return np.percentile(local, 5, axis=0), np.percentile(local, 95, axis=0)


def completed_centres(points: np.ndarray, weights: np.ndarray, centroid: np.ndarray, heading: np.ndarray,
                      camera_positions: np.ndarray, prior: tuple[float, float], min_opacity: float) -> np.ndarray:
    """(F, 3) body centres of a body whose points (K, F, 3) render with opacities ``weights`` (K, F),
    whose opacity-weighted ``centroid`` (F, 3) and ``heading`` (F,) rad about world z are known, seen
    from ``camera_positions`` (F, 3) world. Per frame, in the body frame: the extent of its opaque
    points (at least ``min_opacity``; robust percentiles) along its heading and across it; along each
    axis where it is shorter than ``prior`` (length, width; m), the centre is the extent's middle moved
    away from the camera by half the shortfall (the seen face stays where it is), scaled by how squarely
    the camera looks along that axis (:data:`FULL_COMPLETION_COSINE`); along an axis where it spans the
    prior or more, and in frames with fewer than 4 opaque points, and in height, the centroid stays."""
    centres = np.array(centroid, dtype=np.float64, copy=True)
    prior_extent = np.asarray(prior, dtype=np.float64)
    for f in range(points.shape[1]):
        opaque = weights[:, f] >= min_opacity
        if opaque.sum() < 4:
            continue
        c, s = np.cos(heading[f]), np.sin(heading[f])
        to_body = np.array([[c, s], [-s, c]])  # world planar -> (along heading, across it)
        low, high = planar_extent(points[opaque, f, :2] - centroid[f, :2], heading[f])
        # On a uniformly covered face the percentiles span SPAN of it: widened back to the whole face.
        middle, extent = (low + high) / 2, (high - low) / SPAN
        camera = to_body @ (camera_positions[f, :2] - centroid[f, :2])
        ray = camera / max(float(np.linalg.norm(camera)), 1e-9)
        squareness = np.clip(np.abs(ray) / FULL_COMPLETION_COSINE, 0.0, 1.0)
        shortfall = np.maximum(prior_extent - extent, 0.0)
        # Where the Gaussians span the prior or more, the body was seen whole (or is more than one car,
        # whose extent's middle may lie between them): the centroid stays there.
        centre = np.where(shortfall > 0, middle - np.sign(camera) * shortfall / 2 * squareness, 0.0)
        centres[f, :2] = centroid[f, :2] + to_body.T @ centre
    return centres
