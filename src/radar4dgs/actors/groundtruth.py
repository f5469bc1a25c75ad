"""Scoring discovered actors against a synthetic scene's moving objects (``scene.json``
``synthetic.objects``, written by ``radar4dgs synth``): which movers count, how actors are matched to
them, and the errors the issue's "done when" names (recall, spurious actors, centroid and velocity
errors)."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from radar4dgs.motion.truth import in_boxes

# A mover is in view in a frame when its box centre is in the image, in front of the camera and within
# this range (m). It is visible there when, besides, at least MIN_OWN_PIXELS of its own surface show
# (pixels of gt/dynamic_mask whose gt/depth puts them inside its box): a pedestrian behind a passing car is
# in view, not visible. Movers visible in at least MIN_VISIBLE_FRAMES frames count (issue 24: "visible
# within 60 m in >= 5 frames"); so do, for the in-view recall, those in view in as many.
MAX_RANGE = 60.0
MIN_VISIBLE_FRAMES = 5
# Pixels at IMAGE_MOTION_REFERENCE_WIDTH (320 px) wide, scaled with the image's area: a 1.7 m pedestrian
# 45 m away covers ~15 of them, so a mover showing fewer is a few specks, if not hidden.
MIN_OWN_PIXELS = 10
# The box is grown by this (m) on every side for the own-pixel test: gt depth of its surface sits on it.
OWN_PIXEL_MARGIN = 0.25
# An actor matches a mover when the median planar distance of their centres over the frames both are
# in view in is below this (m), over at least MIN_COMMON_FRAMES frames.
MATCH_GATE = 4.0
MIN_COMMON_FRAMES = 3


@dataclass
class Mover:
    """A generator's moving object: ``id``, ``category``, per frame ``centre`` (F, 3) of its box and
    ``velocity`` (F, 3) (world), ``in_view`` and ``visible`` frame indices by the rules above (``visible``
    equals ``in_view`` for a scene without gt/depth and gt/dynamic_mask)."""

    id: int
    category: str
    centre: np.ndarray
    velocity: np.ndarray
    in_view: np.ndarray
    visible: np.ndarray


def own_pixel_counts(scene, frame: int, poses: np.ndarray, dims: np.ndarray) -> np.ndarray | None:
    """(M,) number of pixels of ``frame``'s gt/dynamic_mask whose gt/depth back-projects inside each of M
    boxes (``poses`` (M, 4, 4) box-to-world at the frame, origin at the bottom centre; ``dims`` (M, 3)
    length, width, height), grown by :data:`OWN_PIXEL_MARGIN`; None when the scene lacks either map."""
    from radar4dgs.actors.background import backproject

    mask, depth = scene.load_optional("gt/dynamic_mask", frame), scene.load_optional("gt/depth", frame)
    if mask is None or depth is None:
        return None
    pixels = np.argwhere((mask > 0) & np.isfinite(depth))
    world = backproject(depth, np.asarray(scene.camera.K, dtype=np.float64), scene.world_to_camera(frame), pixels)
    return in_boxes(world, poses, dims, OWN_PIXEL_MARGIN).sum(axis=1)


def scene_movers(scene) -> list[Mover]:
    """The moving objects of a synthetic ``scene`` (objects of kind "moving" with per-frame poses),
    with their frames in view and visible. Raises ValueError for a scene without generator ground truth."""
    from radar4dgs.io.image_motion import IMAGE_MOTION_REFERENCE_WIDTH

    objects = (scene.extra.get("synthetic") or {}).get("objects")
    if objects is None:
        raise ValueError(f"{scene.root}: no synthetic ground truth (scene.json has no synthetic.objects)")
    w2c = np.stack([scene.world_to_camera(i) for i in range(len(scene))])
    K, width, height = np.asarray(scene.camera.K), scene.camera.width, scene.camera.height
    entries, in_view = [], []
    for entry in objects:
        if entry.get("kind") != "moving" or "poses" not in entry:
            continue
        poses = np.asarray(entry["poses"], dtype=np.float64)
        centre = poses[:, :3, 3] + poses[:, :3, 2] * (entry["dims"][2] / 2)
        cam = np.einsum("fij,fj->fi", w2c[:, :3, :3], centre) + w2c[:, :3, 3]
        z = np.where(cam[:, 2] > 1e-3, cam[:, 2], 1.0)
        u, v = K[0, 0] * cam[:, 0] / z + K[0, 2], K[1, 1] * cam[:, 1] / z + K[1, 2]
        seen = (cam[:, 2] > 0.1) & (u >= 0) & (u <= width - 1) & (v >= 0) & (v <= height - 1)
        entries.append((entry, poses, centre))
        in_view.append(seen & (np.linalg.norm(cam, axis=1) <= MAX_RANGE))
    visible = [flags.copy() for flags in in_view]
    least = MIN_OWN_PIXELS * (width / IMAGE_MOTION_REFERENCE_WIDTH) ** 2
    for frame in range(len(scene)):
        boxes = [k for k, flags in enumerate(in_view) if flags[frame]]
        if not boxes:
            continue
        counts = own_pixel_counts(scene, frame, np.stack([entries[k][1][frame] for k in boxes]),
                                  np.array([entries[k][0]["dims"] for k in boxes], dtype=np.float64))
        if counts is None:
            break  # no ground-truth maps: visible = in view
        for k, count in zip(boxes, counts, strict=True):
            visible[k][frame] = count >= least
    movers = []
    for (entry, poses, centre), view_flags, visible_flags in zip(entries, in_view, visible, strict=True):
        velocities = entry.get("velocities") or [entry["velocity"]] * len(poses)
        movers.append(Mover(int(entry["id"]), str(entry.get("class", "car")), centre,
                            np.asarray(velocities, dtype=np.float64), np.flatnonzero(view_flags),
                            np.flatnonzero(visible_flags)))
    return movers


def match_actors(actors, movers: list[Mover]) -> list[tuple[int, int]]:
    """(actor index, mover index) pairs: the most pairs within :data:`MATCH_GATE` (median planar centre
    distance over at least :data:`MIN_COMMON_FRAMES` common frames), and among those the smallest summed
    distance (:func:`radar4dgs.radar.tracking.gated_assignment`)."""
    from radar4dgs.radar.tracking import gated_assignment

    cost = np.full((len(actors), len(movers)), np.inf)
    for i, actor in enumerate(actors):
        for j, mover in enumerate(movers):
            common = np.intersect1d(actor.frames, mover.in_view)
            if len(common) >= MIN_COMMON_FRAMES:
                cost[i, j] = np.median(np.linalg.norm(actor.centroid[common, :2] - mover.centre[common, :2], axis=1))
    return gated_assignment(cost, MATCH_GATE)


def score_actors(actors, movers: list[Mover]) -> dict:
    """Recall over the counted movers (visible in >= MIN_VISIBLE_FRAMES frames) and, as ``recall_in_view``,
    over those in view in as many (hidden ones included), precision over the actors, spurious actors
    (matched to nothing, counted movers or not), median planar centroid and velocity errors over every
    common frame in view of the matched pairs, the share of matched actors whose class guess is the
    mover's class (``class_accuracy``); ``missed``, the movers either rule counts that no actor
    matched (id, class, frames visible and in view)."""
    counted = {j for j, m in enumerate(movers) if len(m.visible) >= MIN_VISIBLE_FRAMES}
    counted_in_view = {j for j, m in enumerate(movers) if len(m.in_view) >= MIN_VISIBLE_FRAMES}
    pairs = match_actors(actors, movers)
    matched_movers = {j for _, j in pairs}
    centroid, velocity = [], []
    for i, j in pairs:
        common = np.intersect1d(actors[i].frames, movers[j].in_view)
        centroid += np.linalg.norm(actors[i].centroid[common, :2] - movers[j].centre[common, :2], axis=1).tolist()
        velocity += np.linalg.norm(actors[i].velocity[common, :2] - movers[j].velocity[common, :2], axis=1).tolist()
    return {"actors": len(actors), "movers": len(counted), "movers_in_view": len(counted_in_view),
            "matched": len(pairs),
            "recall": len(counted & matched_movers) / len(counted) if counted else None,
            "recall_in_view": len(counted_in_view & matched_movers) / len(counted_in_view) if counted_in_view else None,
            "precision": len(pairs) / len(actors) if actors else None,
            "spurious": len(actors) - len(pairs),
            "centroid_error_median": float(np.median(centroid)) if centroid else None,
            "velocity_error_median": float(np.median(velocity)) if velocity else None,
            "class_accuracy": (sum(actors[i].category == movers[j].category for i, j in pairs) / len(pairs)
                               if pairs else None),
            "pairs": [{"actor": actors[i].id, "mover": movers[j].id, "class": movers[j].category,
                       "guess": actors[i].category, "visible_frames": int(len(movers[j].visible))}
                      for i, j in pairs],
            "missed": [{"mover": movers[j].id, "class": movers[j].category,
                        "visible_frames": int(len(movers[j].visible)), "in_view_frames": int(len(movers[j].in_view))}
                       for j in sorted((counted | counted_in_view) - matched_movers)]}
