"""Actor discovery: the dynamic Gaussians of a trained model grouped into moving objects by their motion.

1. **Trajectories.** Every dynamic Gaussian is moved to every frame's time by whatever moves the
   dynamic set (the VGPT field; :meth:`~radar4dgs.model.scene_model.SceneModel.set_at`), giving
   ``(N, F, 3)`` world positions.
2. **Motion-affinity graph.** Two Gaussians are linked when their trajectories stay within
   ``link_distance`` of each other at every one of ``sample_frames`` sampled times (the Chebyshev
   distance of the stacked trajectories, so a ``cKDTree`` finds all pairs at once). Points of one rigid
   body keep their distances, so a chain of short links covers a car; two bodies that move differently
   are close at a few times at most, never at all of them. Still or faint Gaussians take no part.
3. **Components.** Connected components of that graph (``scipy.sparse.csgraph``) with at least
   ``min_gaussians`` members are actors; smaller ones join the nearest actor or stay unassigned.
4. **Shared radar returns.** Each actor's radar objects per frame (``<prepared>/radar/objects.json``,
   centroids inside its footprint) are attached; two actors that stay together and share a radar
   track most of the time are one object split in two, and are merged.
5. **Poses.** Per frame: centroid (mean of the actor's Gaussians, which moves exactly with a rigid
   body), velocity (its time derivative), heading (the velocity's direction, held while the actor is
   slower than 1 m/s), frames of visibility (enough of its Gaussians in the camera's view), size and a
   class guess from the footprint.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

import numpy as np

from radar4dgs.actors.config import ActorConfig

# Slower than this (m/s), the velocity's direction is noise: the heading is held from a faster frame.
HEADING_SPEED = 1.0


@dataclass
class Actor:
    """One discovered moving object.

    ``gaussians`` (K,) indices into the run's dynamic Gaussian set; ``frames`` (V,) indices of the
    frames it is visible in; per frame of the WHOLE sequence (F frames): ``centroid`` (F, 3) and
    ``velocity`` (F, 3) world, ``heading`` (F,) radians about world z; ``size`` (length, width, height)
    metres; ``radar`` per visible frame index the radar objects attached (track id, returns, rows).
    """

    id: int
    gaussians: np.ndarray
    frames: np.ndarray
    centroid: np.ndarray
    velocity: np.ndarray
    heading: np.ndarray
    size: tuple[float, float, float]
    category: str
    radar: dict[int, list[dict[str, Any]]] = field(default_factory=dict)

    @property
    def mean_speed(self) -> float:
        """Mean planar speed (m/s) over the frames of visibility."""
        if len(self.frames) == 0:
            return 0.0
        return float(np.linalg.norm(self.velocity[self.frames, :2], axis=1).mean())


def dynamic_trajectories(model, times: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """World positions (N, F, 3) and opacities (N, F) of the model's N dynamic Gaussians at each of
    the (F,) normalised ``times`` (float64 numpy). Raises ValueError when the model has no dynamic set."""
    import torch

    if model.dynamic is None or len(model.dynamic) == 0:
        raise ValueError("the run has no dynamic Gaussians (a static or baseline method?): no actors to find")
    means, opacities = [], []
    with torch.no_grad():
        for t in times:
            g = model.set_at("dynamic", float(t))
            means.append(g["means"].double().cpu().numpy())
            opacities.append(g["opacities"].double().cpu().numpy())
    return np.stack(means, axis=1), np.stack(opacities, axis=1)


def sample_indices(num_frames: int, count: int) -> np.ndarray:
    """(min(count, num_frames),) evenly spread frame indices, first and last included."""
    if num_frames <= count:
        return np.arange(num_frames)
    return np.unique(np.round(np.linspace(0, num_frames - 1, count)).astype(np.int64))


def moving_mask(trajectories: np.ndarray, opacities: np.ndarray, config: ActorConfig) -> np.ndarray:
    """(N,) bool: the Gaussians that take part in clustering: opaque enough at some time and moving
    more than ``min_motion`` (largest distance from their mean position)."""
    spread = np.linalg.norm(trajectories - trajectories.mean(axis=1, keepdims=True), axis=2).max(axis=1)
    return (opacities.max(axis=1) >= config.min_opacity) & (spread >= config.min_motion)


def motion_components(features: np.ndarray, config: ActorConfig) -> np.ndarray:
    """(N,) int64 actor label of each of N stacked trajectories ``features`` (N, T, 3), -1 for none:
    components of the graph linking trajectories within ``link_distance`` at every time, big ones
    first; members of small components join the nearest big one within ``attach_distance``."""
    from scipy.sparse import coo_matrix
    from scipy.sparse.csgraph import connected_components
    from scipy.spatial import cKDTree

    n = len(features)
    labels = np.full(n, -1, dtype=np.int64)
    if n == 0:
        return labels
    flat = features.reshape(n, -1)
    # The nearest `neighbours` within reach, not every pair: a car holds thousands of Gaussians packed
    # closer than link_distance, and a k-nearest-neighbour graph of it is as connected as the full one.
    k = min(config.neighbours + 1, n)
    distance, nearest = cKDTree(flat).query(flat, k=k, p=np.inf, distance_upper_bound=config.link_distance)
    rows, cols = np.nonzero(np.isfinite(distance.reshape(n, k)))
    graph = coo_matrix((np.ones(len(rows)), (rows, nearest.reshape(n, k)[rows, cols])), shape=(n, n))
    _, component = connected_components(graph, directed=False)
    sizes = np.bincount(component)
    big = np.flatnonzero(sizes >= config.min_gaussians)
    big = big[np.argsort(-sizes[big], kind="stable")]
    remap = np.full(len(sizes), -1, dtype=np.int64)
    remap[big] = np.arange(len(big))
    labels = remap[component]
    members, loose = np.flatnonzero(labels >= 0), np.flatnonzero(labels < 0)
    if len(members) and len(loose):
        distance, nearest = cKDTree(flat[members]).query(flat[loose], p=np.inf,
                                                           distance_upper_bound=config.attach_distance)
        close = np.isfinite(distance)
        labels[loose[close]] = labels[members[nearest[close]]]
    return labels


def visible_frames(points: np.ndarray, world_to_camera: np.ndarray, K: np.ndarray, width: int, height: int,
                   config: ActorConfig) -> np.ndarray:
    """(V,) indices of the frames where at least ``visible_fraction`` of an actor's points (K, F, 3)
    project inside the ``width`` x ``height`` image of the camera ``world_to_camera`` (F, 4, 4)
    with intrinsics ``K`` (3, 3), in front of it and within ``max_range``."""
    cam = np.einsum("fij,kfj->kfi", world_to_camera[:, :3, :3], points) + world_to_camera[None, :, :3, 3]
    z = cam[..., 2]
    safe = np.where(z > 1e-3, z, 1.0)
    u = K[0, 0] * cam[..., 0] / safe + K[0, 2]
    v = K[1, 1] * cam[..., 1] / safe + K[1, 2]
    inside = (z > 0.1) & (u >= -0.5) & (u < width - 0.5) & (v >= -0.5) & (v < height - 0.5)
    inside &= np.linalg.norm(cam, axis=2) <= config.max_range
    return np.flatnonzero(inside.mean(axis=0) >= config.visible_fraction)


def headings(velocity: np.ndarray, points: np.ndarray) -> np.ndarray:
    """(F,) heading (rad, about world z) of a body with velocity (F, 3): the velocity's direction where
    faster than :data:`HEADING_SPEED`, held from the nearest such frame elsewhere; a body never that fast
    takes the main axis of its points' footprint (K, F, 3) at the first frame."""
    speed = np.linalg.norm(velocity[:, :2], axis=1)
    fast = np.flatnonzero(speed > HEADING_SPEED)
    if len(fast) == 0:
        xy = points[:, 0, :2] - points[:, 0, :2].mean(axis=0)
        axis = np.linalg.svd(xy, full_matrices=False)[2][0] if len(xy) > 1 else np.array([1.0, 0.0])
        return np.full(len(velocity), float(np.arctan2(axis[1], axis[0])))
    angles = np.unwrap(np.arctan2(velocity[fast, 1], velocity[fast, 0]))
    nearest = fast[np.abs(np.arange(len(velocity))[:, None] - fast[None, :]).argmin(axis=1)]
    return angles[np.searchsorted(fast, nearest)]


def footprint_size(points: np.ndarray, heading: float) -> tuple[float, float, float]:
    """(length, width, height) metres of points (K, 3) in a body frame of ``heading``: 5-95 % extents
    (a few stray Gaussians do not stretch the box)."""
    c, s = np.cos(heading), np.sin(heading)
    local = points[:, :2] @ np.array([[c, -s], [s, c]])
    low, high = np.percentile(local, 5, axis=0), np.percentile(local, 95, axis=0)
    z_low, z_high = np.percentile(points[:, 2], [5, 95])
    return float(high[0] - low[0]), float(high[1] - low[1]), float(z_high - z_low)


def class_guess(size: tuple[float, float, float]) -> str:
    """``car`` | ``truck`` | ``cyclist`` | ``pedestrian`` | ``unknown`` from (length, width, height)
    metres. The camera sees one or two sides of a body, so the footprint's longer side is used: the rear of
    a followed car is ~1.8 m wide and ~0.5 m deep."""
    longest, height = max(size[0], size[1]), size[2]
    if longest >= 7.0:
        return "truck"
    if longest >= 1.4:
        return "car" if height < 2.2 or longest >= 2.5 else "cyclist"
    if longest >= 0.3 and height >= 1.0:
        return "pedestrian" if longest < 0.9 else "cyclist"
    return "unknown"


def radar_matches(points: np.ndarray, frames: np.ndarray, radar_objects: list[list[Any]] | None,
                  margin: float) -> dict[int, list[dict[str, Any]]]:
    """Per visible frame index, the radar objects (``load_radar_objects`` records) whose centroid lies
    within ``margin`` metres of the planar bounding box of the actor's points (K, F, 3) there:
    ``{"track", "num_returns", "points"}`` each (``points``: rows of ``scene.load_radar(frame)``)."""
    out: dict[int, list[dict[str, Any]]] = {}
    if not radar_objects:
        return out
    for f in frames:
        if f >= len(radar_objects):
            continue
        low, high = points[:, f, :2].min(axis=0) - margin, points[:, f, :2].max(axis=0) + margin
        hits = [{"track": int(o.track), "num_returns": int(o.num_returns), "points": o.points.tolist()}
                for o in radar_objects[f] if np.all(o.centroid[:2] >= low) and np.all(o.centroid[:2] <= high)]
        if hits:
            out[int(f)] = hits
    return out


def merge_groups(actors: list[Actor], config: ActorConfig) -> np.ndarray:
    """(A,) group label of each of A actors: actors i, j are one when their planar centroids stay within
    ``merge_distance`` at every frame both are visible in, and they share a radar track in at least half
    of those frames or their median planar velocity difference there is below ``merge_velocity``
    (transitively: connected components)."""
    from scipy.sparse import coo_matrix
    from scipy.sparse.csgraph import connected_components

    rows, cols = [], []
    for i, a in enumerate(actors):
        for j in range(i + 1, len(actors)):
            b = actors[j]
            common = np.intersect1d(a.frames, b.frames)
            if len(common) == 0:
                continue
            gap = np.linalg.norm(a.centroid[common, :2] - b.centroid[common, :2], axis=1).max()
            shared = sum(bool({o["track"] for o in a.radar.get(int(f), [])}
                              & {o["track"] for o in b.radar.get(int(f), [])}) for f in common)
            slip = np.median(np.linalg.norm(a.velocity[common, :2] - b.velocity[common, :2], axis=1))
            if gap <= config.merge_distance and (shared >= 0.5 * len(common) or slip <= config.merge_velocity):
                rows.append(i)
                cols.append(j)
    graph = coo_matrix((np.ones(len(rows)), (rows, cols)), shape=(len(actors),) * 2)
    return connected_components(graph, directed=False)[1]


def build_actor(index: int, gaussians: np.ndarray, trajectories: np.ndarray, timestamps: np.ndarray,
                cameras: tuple[np.ndarray, np.ndarray, int, int], radar_objects, config: ActorConfig) -> Actor:
    """The :class:`Actor` of ``gaussians`` (K,) from the dynamic set's ``trajectories`` (N, F, 3) at the
    frames' ``timestamps`` (F,) seconds; ``cameras`` = (world_to_camera (F, 4, 4), K, width, height)."""
    points = trajectories[gaussians]
    centroid = points.mean(axis=0)
    velocity = np.gradient(centroid, timestamps, axis=0) if len(timestamps) > 1 else np.zeros_like(centroid)
    heading = headings(velocity, points)
    frames = visible_frames(points, *cameras, config)
    reference = int(frames[len(frames) // 2]) if len(frames) else 0
    size = footprint_size(points[:, reference], float(heading[reference]))
    return Actor(index, np.sort(gaussians), frames, centroid, velocity, heading, size, class_guess(size),
                 radar_matches(points, frames, radar_objects, config.radar_margin))


def discover_actors(model, scene, radar_objects=None, config: ActorConfig | None = None) -> list[Actor]:
    """The actors of a trained ``model`` of ``scene`` (every frame's time and camera), biggest first,
    ids 0, 1, ...; ``radar_objects`` is ``load_radar_objects(prepared)`` or None (no radar returns).
    Actors visible in no frame are dropped."""
    from radar4dgs.io.scene import normalized_times

    config = config or ActorConfig()
    times = normalized_times(scene)
    timestamps = np.array([f.timestamp for f in scene.frames], dtype=np.float64)
    trajectories, opacities = dynamic_trajectories(model, times)
    cameras = (np.stack([scene.world_to_camera(i) for i in range(len(scene))]),
               np.asarray(scene.camera.K, dtype=np.float64), int(scene.camera.width), int(scene.camera.height))
    active = np.flatnonzero(moving_mask(trajectories, opacities, config))
    sampled = sample_indices(len(times), config.sample_frames)
    labels = motion_components(trajectories[active][:, sampled], config)
    groups = [active[labels == k] for k in range(int(labels.max()) + 1 if len(labels) else 0)]
    actors = [build_actor(k, g, trajectories, timestamps, cameras, radar_objects, config)
              for k, g in enumerate(groups)]
    if len(actors) > 1:
        merged = merge_groups(actors, config)
        groups = [np.concatenate([groups[i] for i in np.flatnonzero(merged == m)]) for m in np.unique(merged)]
        actors = [build_actor(k, g, trajectories, timestamps, cameras, radar_objects, config)
                  for k, g in enumerate(groups)]
    actors = sorted((a for a in actors if len(a.frames)), key=lambda a: -len(a.gaussians))
    for k, actor in enumerate(actors):
        actor.id = k
    return actors
