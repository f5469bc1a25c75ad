"""Overlap tests for placing movers: oriented footprints against each other, the ego and the street.

Movers are upright boxes on the ground, so two of them overlap exactly when their footprint
rectangles overlap (separating-axis test) at some sampled time. Poses are sampled from each
mover's trajectory, so any motion model (a lane change, a turn) is checked as it really moves.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from radar4dgs.datasets.synth.motion import Trajectory, footprint_track
from radar4dgs.datasets.synth.raycast import Primitives

STATIC_MIN_TOP = 0.3  # static boxes lower than this (sidewalks, curbs) are walked or driven over


@dataclass(frozen=True)
class Track:
    """A footprint rectangle over time: (T, 2) centres, (T,) headings (rad), (2,) half length and
    width (m), and the body's height range (m) above the road."""

    center: np.ndarray
    yaw: np.ndarray
    half: np.ndarray
    z_range: tuple[float, float]


def track(trajectory: Trajectory, length: float, width: float, z_range: tuple[float, float],
          times: np.ndarray) -> Track:
    """The :class:`Track` of a body of footprint ``length`` x ``width`` moving along ``trajectory``."""
    center, yaw = footprint_track(trajectory, times)
    return Track(center, yaw, np.array([length / 2, width / 2]), z_range)


def _axes(yaw: np.ndarray) -> np.ndarray:
    """(T, 2, 2) unit body x and y axes (rows) in the road plane."""
    c, s = np.cos(yaw), np.sin(yaw)
    return np.stack([np.stack([c, s], -1), np.stack([-s, c], -1)], axis=1)


def rects_overlap(center_a: np.ndarray, yaw_a: np.ndarray, half_a: np.ndarray, center_b: np.ndarray,
                  yaw_b: np.ndarray, half_b: np.ndarray, margin: float) -> np.ndarray:
    """(T,) bool: rectangles A and B, each grown by ``margin`` / 2 on every side, overlap.

    Args:
        center_a, center_b: (T, 2) centres. yaw_a, yaw_b: (T,) headings. half_a, half_b: (2,) or
            (T, 2) half length and width.
    """
    axes_a, axes_b = _axes(yaw_a), _axes(yaw_b)
    half_a = np.broadcast_to(half_a, center_a.shape) + margin / 2
    half_b = np.broadcast_to(half_b, center_b.shape) + margin / 2
    gap = center_b - center_a
    separated = np.zeros(len(gap), bool)
    for axis in (axes_a[:, 0], axes_a[:, 1], axes_b[:, 0], axes_b[:, 1]):  # (T, 2) each
        # Half extent of each rectangle along the axis: sum over its own axes of half * |cos|.
        reach_a = np.einsum("ti,ti->t", half_a, np.abs(np.einsum("tij,tj->ti", axes_a, axis)))
        reach_b = np.einsum("ti,ti->t", half_b, np.abs(np.einsum("tij,tj->ti", axes_b, axis)))
        separated |= np.abs(np.einsum("ti,ti->t", gap, axis)) > reach_a + reach_b
    return ~separated


def tracks_overlap(a: Track, b: Track, margin: float) -> bool:
    """Whether two movers' footprints come closer than ``margin`` at any common sample time."""
    return bool(rects_overlap(a.center, a.yaw, a.half, b.center, b.yaw, b.half, margin).any())


def gap_ahead(ego: Track, other: Track) -> np.ndarray:
    """(T,) bumper-to-bumper gap (m) from the ego to ``other`` along the ego's heading, at times when
    ``other`` is ahead and its footprint overlaps the ego's lane corridor (the ego's width); +inf
    at other times."""
    axes = _axes(ego.yaw)
    rel = np.einsum("tij,tj->ti", axes, other.center - ego.center)  # (T, 2) in ego axes
    other_axes = np.einsum("tij,tkj->tik", _axes(other.yaw), axes)  # other's axes in ego axes
    extent = np.abs(other_axes) * other.half[None, :, None]  # (T, 2 axes, 2 coords)
    reach = extent.sum(axis=1)  # (T, 2): half extent of other along ego x and y
    in_corridor = np.abs(rel[:, 1]) < ego.half[1] + reach[:, 1]
    gap = rel[:, 0] - ego.half[0] - reach[:, 0]
    ahead = rel[:, 0] > 0
    return np.where(in_corridor & ahead, gap, np.inf)


def clear_of_static(mover: Track, static: Primitives, step: int = 5) -> bool:
    """Whether the mover's box stays clear of static boxes taller than STATIC_MIN_TOP and of
    spheres (as their bounding boxes), checked at every ``step``-th sample time.

    Static boxes are axis-aligned (the street is built that way), so each is a rectangle at yaw 0.
    """
    lo = np.concatenate([static.box_center - static.box_half,
                         static.sphere_center - static.sphere_radius[:, None]])
    hi = np.concatenate([static.box_center + static.box_half,
                         static.sphere_center + static.sphere_radius[:, None]])
    z0, z1 = mover.z_range
    solid = (hi[:, 2] > STATIC_MIN_TOP) & (hi[:, 2] > z0) & (lo[:, 2] < z1)
    if not solid.any():
        return True
    lo, hi = lo[solid], hi[solid]
    center, yaw = mover.center[::step], mover.yaw[::step]
    t, b = len(center), len(lo)
    overlap = rects_overlap(np.repeat(center, b, axis=0), np.repeat(yaw, b), mover.half,
                            np.tile((lo[:, :2] + hi[:, :2]) / 2, (t, 1)), np.zeros(t * b),
                            np.tile((hi[:, :2] - lo[:, :2]) / 2, (t, 1)), margin=0.1)
    return not overlap.any()
