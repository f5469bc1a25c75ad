"""Carry small mask components to the neighbouring frames by template matching.

The network segments patches around dynamic radar points, so a mover the radar misses in a frame is
unmarked there. A pedestrian has 0.4-1.6 returns a frame in a fraction of its frames: on the rush
5 Hz tuning seed 214 the masks cover it in 7 of the 32 frames it is seen in. Trained with the
generator's masks and scene flow it is found as an actor; with the masks alone or the flow alone it
is not (docs/pipeline/actors.md). This step follows each small component of a frame's mask into the
next and previous frames: the component's own grey pixels are matched (OpenCV ``matchTemplate``
with the component as the template's mask) in a window around where it was, and the footprint is
added where the match is distinct from the rest of the window. A component that runs into a mask
the network already made, leaves the image or stops matching ends its track.

Only small components are carried (``max_pixels``): a near car is marked in most of its frames, and
its image changes too fast between frames for one template.
"""

from __future__ import annotations

import cv2
import numpy as np

from radar4dgs.io.image_motion import IMAGE_MOTION_REFERENCE_WIDTH
from radar4dgs.segment.config import PropagationConfig


def scaled_pixels(value: float, width: int) -> int:
    """A pixel count given for a 320 px wide image, at ``width`` (areas scale with its square)."""
    return int(round(value * (width / IMAGE_MOTION_REFERENCE_WIDTH) ** 2))


def match_shift(gray: np.ndarray, template: np.ndarray, template_mask: np.ndarray, top_left: tuple[int, int],
                search: int, distinct: float) -> tuple[int, int] | None:
    """Where the masked ``template`` (h, w) uint8 lies in ``gray`` (H, W) uint8 within ``search`` px
    of ``top_left`` (row, col): the new top-left (row, col), or None when the window leaves the
    image or the best match is not distinct (its RMS grey error above ``distinct`` x the window's
    median)."""
    height, width = gray.shape
    h, w = template.shape
    row0, col0 = top_left[0] - search, top_left[1] - search
    if row0 < 0 or col0 < 0 or row0 + h + 2 * search > height or col0 + w + 2 * search > width:
        return None
    window = gray[row0:row0 + h + 2 * search, col0:col0 + w + 2 * search]
    scores = cv2.matchTemplate(window.astype(np.float32), template.astype(np.float32), cv2.TM_SQDIFF,
                               mask=template_mask.astype(np.float32))
    scores = np.sqrt(np.maximum(scores, 0.0) / max(int(template_mask.sum()), 1))
    best = np.unravel_index(int(np.argmin(scores)), scores.shape)
    if not scores[best] <= distinct * float(np.median(scores)):
        return None
    return row0 + int(best[0]), col0 + int(best[1])


def follow_component(grays: list[np.ndarray], masks: list[np.ndarray], start: int, component: np.ndarray,
                     direction: int, search: int, config: PropagationConfig) -> list[tuple[int, np.ndarray]]:
    """The footprints ``[(frame, (H, W) bool), ...]`` of ``component`` (H, W) bool of frame ``start``
    in frames ``start + direction``, ``start + 2 direction``, ... (at most ``config.frames``), by
    :func:`match_shift` of its pixels in frame ``start`` within ``search`` px; ``masks`` are the
    network's, unchanged."""
    rows, cols = np.nonzero(component)
    r0, r1, c0, c1 = rows.min(), rows.max() + 1, cols.min(), cols.max() + 1
    template, template_mask = grays[start][r0:r1, c0:c1], component[r0:r1, c0:c1]
    position, velocity, out = (int(r0), int(c0)), (0, 0), []
    for step in range(1, config.frames + 1):
        frame = start + direction * step
        if not 0 <= frame < len(grays):
            break
        guess = (position[0] + velocity[0], position[1] + velocity[1])
        found = match_shift(grays[frame], template, template_mask, guess, search, config.distinct)
        if found is None:
            break
        footprint = np.zeros_like(component)
        footprint[found[0]:found[0] + (r1 - r0), found[1]:found[1] + (c1 - c0)] = template_mask
        if (footprint & masks[frame]).sum() > config.max_overlap * footprint.sum():
            break  # the network marked it there: that frame's own component carries it on
        out.append((frame, footprint))
        velocity, position = (found[0] - position[0], found[1] - position[1]), found
    return out


def holds_a_point(component: np.ndarray, points: np.ndarray, margin: int) -> bool:
    """Whether one of ``points`` (M, 2) pixel (u, v) lies on ``component`` (H, W) bool grown by
    ``margin`` px."""
    height, width = component.shape
    uv = np.round(np.asarray(points, dtype=np.float64)).astype(np.int64).reshape(-1, 2)
    uv = uv[(uv[:, 0] >= 0) & (uv[:, 0] < width) & (uv[:, 1] >= 0) & (uv[:, 1] < height)]
    if len(uv) == 0:
        return False
    grown = cv2.dilate(component.astype(np.uint8), np.ones((2 * margin + 1, 2 * margin + 1), np.uint8)) > 0
    return bool(grown[uv[:, 1], uv[:, 0]].any())


def propagate_masks(images: list[np.ndarray], masks: list[np.ndarray], points: list[np.ndarray],
                    config: PropagationConfig) -> list[np.ndarray]:
    """The masks (H, W) bool of a sequence with every small component of each frame that holds one
    of the frame's dynamic radar ``points`` (M, 2) pixel (u, v) carried to its neighbours
    (:func:`follow_component`, both ways). ``images``: (H, W, 3) uint8 RGB in frame order. The
    point keeps the network's stray specks (a patch's region away from its anchor) in their frame."""
    grays = [cv2.cvtColor(np.ascontiguousarray(image), cv2.COLOR_RGB2GRAY) for image in images]
    width = grays[0].shape[1] if grays else IMAGE_MOTION_REFERENCE_WIDTH
    low, high = scaled_pixels(config.min_pixels, width), scaled_pixels(config.max_pixels, width)
    scale = width / IMAGE_MOTION_REFERENCE_WIDTH
    margin = max(0, int(round(config.point_margin_px * scale)))
    search = max(1, int(round(config.search_px * scale)))
    out = [np.array(mask, dtype=bool, copy=True) for mask in masks]
    for start, mask in enumerate(masks):
        count, labels, stats, _ = cv2.connectedComponentsWithStats(np.asarray(mask, np.uint8), connectivity=8)
        for label in range(1, count):
            if not low <= stats[label, cv2.CC_STAT_AREA] <= high:
                continue
            component = labels == label
            if not holds_a_point(component, points[start], margin):
                continue
            for direction in (1, -1):
                for frame, footprint in follow_component(grays, masks, start, component, direction, search,
                                                        config):
                    out[frame] |= footprint
    return out
