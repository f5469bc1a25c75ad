"""Scoring discovered actors against a synthetic scene's moving objects (``scene.json``
``synthetic.objects``, written by ``radar4dgs synth``): which movers count, how actors are matched to
them, and the errors the issue's "done when" names (recall, spurious actors, centroid and velocity
errors)."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

# A mover counts when its box centre is in the image, in front of the camera and within this range (m)
# in at least MIN_VISIBLE_FRAMES frames (issue 24: "visible within 60 m in >= 5 frames"). Occlusion is
# not modelled: a car hidden behind another still counts.
MAX_RANGE = 60.0
MIN_VISIBLE_FRAMES = 5
# An actor matches a mover when the median planar distance of their centres over the frames both are
# visible in is below this (m), over at least MIN_COMMON_FRAMES frames.
MATCH_GATE = 4.0
MIN_COMMON_FRAMES = 3


@dataclass
class Mover:
    """A generator's moving object: ``id``, ``category``, per frame ``centre`` (F, 3) of its box and
    ``velocity`` (F, 3) (world), ``visible`` (V,) frame indices by the rule above."""

    id: int
    category: str
    centre: np.ndarray
    velocity: np.ndarray
    visible: np.ndarray


def scene_movers(scene) -> list[Mover]:
    """The moving objects of a synthetic ``scene`` (objects of kind "moving" with per-frame poses),
    with their frames of visibility. Raises ValueError for a scene without generator ground truth."""
    objects = (scene.extra.get("synthetic") or {}).get("objects")
    if objects is None:
        raise ValueError(f"{scene.root}: no synthetic ground truth (scene.json has no synthetic.objects)")
    w2c = np.stack([scene.world_to_camera(i) for i in range(len(scene))])
    K, width, height = np.asarray(scene.camera.K), scene.camera.width, scene.camera.height
    movers = []
    for entry in objects:
        if entry.get("kind") != "moving" or "poses" not in entry:
            continue
        poses = np.asarray(entry["poses"], dtype=np.float64)
        centre = poses[:, :3, 3] + poses[:, :3, 2] * (entry["dims"][2] / 2)
        velocities = entry.get("velocities") or [entry["velocity"]] * len(poses)
        cam = np.einsum("fij,fj->fi", w2c[:, :3, :3], centre) + w2c[:, :3, 3]
        z = np.where(cam[:, 2] > 1e-3, cam[:, 2], 1.0)
        u, v = K[0, 0] * cam[:, 0] / z + K[0, 2], K[1, 1] * cam[:, 1] / z + K[1, 2]
        seen = (cam[:, 2] > 0.1) & (u >= 0) & (u <= width - 1) & (v >= 0) & (v <= height - 1)
        seen &= np.linalg.norm(cam, axis=1) <= MAX_RANGE
        movers.append(Mover(int(entry["id"]), str(entry.get("class", "car")), centre,
                            np.asarray(velocities, dtype=np.float64), np.flatnonzero(seen)))
    return movers


def match_actors(actors, movers: list[Mover]) -> list[tuple[int, int]]:
    """(actor index, mover index) pairs: Hungarian matching on the median planar centre distance over
    common frames, gated by :data:`MATCH_GATE` and :data:`MIN_COMMON_FRAMES`."""
    from scipy.optimize import linear_sum_assignment

    if not actors or not movers:
        return []
    cost = np.full((len(actors), len(movers)), 1e6)
    for i, actor in enumerate(actors):
        for j, mover in enumerate(movers):
            common = np.intersect1d(actor.frames, mover.visible)
            if len(common) >= MIN_COMMON_FRAMES:
                cost[i, j] = np.median(np.linalg.norm(actor.centroid[common, :2] - mover.centre[common, :2], axis=1))
    rows, cols = linear_sum_assignment(cost)
    return [(int(i), int(j)) for i, j in zip(rows, cols, strict=True) if cost[i, j] <= MATCH_GATE]


def score_actors(actors, movers: list[Mover]) -> dict:
    """Recall over the counted movers (visible in >= MIN_VISIBLE_FRAMES frames), precision over the
    actors, spurious actors (matched to nothing, counted movers or not), median planar centroid and
    velocity errors over every common frame of the matched pairs; ``missed``, the counted movers no
    actor matched (id, class, frames visible)."""
    counted = {j for j, m in enumerate(movers) if len(m.visible) >= MIN_VISIBLE_FRAMES}
    pairs = match_actors(actors, movers)
    matched_movers = {j for _, j in pairs}
    centroid, velocity = [], []
    for i, j in pairs:
        common = np.intersect1d(actors[i].frames, movers[j].visible)
        centroid += np.linalg.norm(actors[i].centroid[common, :2] - movers[j].centre[common, :2], axis=1).tolist()
        velocity += np.linalg.norm(actors[i].velocity[common, :2] - movers[j].velocity[common, :2], axis=1).tolist()
    hits = len(counted & matched_movers)
    return {"actors": len(actors), "movers": len(counted), "matched": len(pairs),
            "recall": hits / len(counted) if counted else None,
            "precision": len(pairs) / len(actors) if actors else None,
            "spurious": len(actors) - len(pairs),
            "centroid_error_median": float(np.median(centroid)) if centroid else None,
            "velocity_error_median": float(np.median(velocity)) if velocity else None,
            "pairs": [{"actor": actors[i].id, "mover": movers[j].id, "class": movers[j].category} for i, j in pairs],
            "missed": [{"mover": movers[j].id, "class": movers[j].category,
                        "visible_frames": int(len(movers[j].visible))} for j in sorted(counted - matched_movers)]}
