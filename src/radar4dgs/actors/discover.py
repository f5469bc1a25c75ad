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
4. **Opacity-weighted tracks.** A dynamic Gaussian renders only during its life span; outside it the
   field still moves it, to places that mean nothing. An actor's centroid and velocity per frame are
   therefore weighted by its Gaussians' opacities there, and it is "there" in the frames where its
   opacity mass is a fair part of its largest.
5. **Merging pieces.** The graph above also compares the meaningless out-of-life positions, so one car
   comes out in pieces. Pieces seen together that stay within a car length along the heading and
   ``merge_lateral`` across it at the same velocity (medians over their common frames) are one body;
   so are pieces of which one takes over where the other stops (constant-velocity extrapolation over
   at most ``handover_seconds``). Side-by-side cars in adjacent lanes fail the lateral test.
6. **Radar cues** (:mod:`radar4dgs.actors.radar_cues`, when the prepared folder has radar objects):
   pieces on one radar chain merge, pieces on two chains seen at the same time never link; actors the
   radar supports in fewer than ``min_radar_frames`` frames are dropped; chains no actor took seed
   actors from the free moving Gaussians along them; the velocity is the radar's where it saw the actor.
7. **Spurious-actor filter.** Actors seen in fewer than ``min_frames`` frames, or whose centroid moves
   less than ``min_displacement`` between their first and last frame, are dropped.
8. **Poses and radar.** Per frame: centroid and velocity (above), heading (the velocity's direction,
   held while the actor is slower than 1 m/s), frames of visibility (there, and enough of its opacity
   in the camera's view), size and a class guess from the footprint of its opaque Gaussians, and the
   radar objects (``<prepared>/radar/objects.json``) whose centroids fall inside the footprint of its
   Gaussians that render there.
9. **Body centres.** A car-like actor's centroid is that of the faces the camera saw; it becomes the
   centre of a ``car_size`` body anchored at those faces (:mod:`radar4dgs.actors.amodal`).
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

import numpy as np

from radar4dgs.actors.amodal import completed_centres, is_car_like, planar_extent
from radar4dgs.actors.config import ActorConfig
from radar4dgs.actors.radar_cues import (
    RadarChains,
    distinct_objects,
    main_chain,
    radar_chains,
    radar_velocity,
    seed_members,
    support,
)
from radar4dgs.model.pose_refine import camera_centres

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


def opacity_track(points: np.ndarray, weights: np.ndarray, timestamps: np.ndarray) -> tuple[np.ndarray, ...]:
    """Centroid (F, 3), velocity (F, 3) and opacity mass (F,) of points (K, F, 3) weighted per frame by
    their opacities ``weights`` (K, F) at the frames' ``timestamps`` (F,) s. A dynamic Gaussian only
    renders during its life span; outside it the field still moves it, to places that mean nothing, so
    only the opaque ones count. The velocity is the weighted mean of each point's own velocity, not the
    centroid's derivative (which jumps when Gaussians fade in or out). Frames with no opacity at all
    take the plain mean."""
    mass = weights.sum(axis=0)
    some = mass > 1e-9
    safe = np.where(some, mass, 1.0)[:, None]
    rates = np.gradient(points, timestamps, axis=1) if len(timestamps) > 1 else np.zeros_like(points)
    centroid = np.where(some[:, None], np.einsum("kf,kfi->fi", weights, points) / safe, points.mean(axis=0))
    velocity = np.where(some[:, None], np.einsum("kf,kfi->fi", weights, rates) / safe, rates.mean(axis=0))
    return centroid, velocity, mass


def visible_frames(points: np.ndarray, weights: np.ndarray, world_to_camera: np.ndarray, K: np.ndarray,
                   width: int, height: int, config: ActorConfig) -> np.ndarray:
    """(V,) indices of the frames where the actor is there and seen: its opacity mass (``weights``
    (K, F) of its points (K, F, 3)) is at least ``presence_fraction`` of its largest, and at least
    ``visible_fraction`` of that mass projects inside the ``width`` x ``height`` image of the camera
    ``world_to_camera`` (F, 4, 4) with intrinsics ``K`` (3, 3), in front of it and within ``max_range``."""
    cam = np.einsum("fij,kfj->kfi", world_to_camera[:, :3, :3], points) + world_to_camera[None, :, :3, 3]
    z = cam[..., 2]
    safe = np.where(z > 1e-3, z, 1.0)
    u = K[0, 0] * cam[..., 0] / safe + K[0, 2]
    v = K[1, 1] * cam[..., 1] / safe + K[1, 2]
    inside = (z > 0.1) & (u >= -0.5) & (u < width - 0.5) & (v >= -0.5) & (v < height - 0.5)
    inside &= np.linalg.norm(cam, axis=2) <= config.max_range
    mass = weights.sum(axis=0)
    present = (mass > 0) & (mass >= config.presence_fraction * mass.max())
    return np.flatnonzero(present & ((weights * inside).sum(axis=0) >= config.visible_fraction * mass))


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
    low, high = planar_extent(points[:, :2], heading)
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


def radar_matches(points: np.ndarray, weights: np.ndarray, frames: np.ndarray, radar_objects: list[list[Any]] | None,
                  config: ActorConfig) -> dict[int, list[dict[str, Any]]]:
    """Per visible frame index, the radar objects (``load_radar_objects`` records) whose centroid lies
    within ``radar_margin`` metres of the planar bounding box of the actor's points (K, F, 3) that render
    there (opacity ``weights`` (K, F) at least ``min_opacity``; all when fewer than 4 do: out of their
    life span the field flings Gaussians far away): ``{"track", "num_returns", "points"}`` each
    (``points``: rows of ``scene.load_radar(frame)``)."""
    out: dict[int, list[dict[str, Any]]] = {}
    if not radar_objects:
        return out
    for f in frames:
        if f >= len(radar_objects):
            continue
        opaque = weights[:, f] >= config.min_opacity
        xy = points[opaque if opaque.sum() >= 4 else slice(None), f, :2]
        low, high = xy.min(axis=0) - config.radar_margin, xy.max(axis=0) + config.radar_margin
        hits = [{"track": int(o.track), "num_returns": int(o.num_returns), "points": o.points.tolist()}
                for o in radar_objects[f] if np.all(o.centroid[:2] >= low) and np.all(o.centroid[:2] <= high)]
        if hits:
            out[int(f)] = hits
    return out


def body_offsets(a: Actor, b: Actor, frames: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(longitudinal, lateral) absolute planar offsets (each (len(frames),), m) of ``b``'s centroid from
    ``a``'s in ``a``'s own frame (its heading) at ``frames``."""
    d = b.centroid[frames, :2] - a.centroid[frames, :2]
    c, s = np.cos(a.heading[frames]), np.sin(a.heading[frames])
    return np.abs(d[:, 0] * c + d[:, 1] * s), np.abs(d[:, 1] * c - d[:, 0] * s)


def moves_together(a: Actor, b: Actor, config: ActorConfig) -> bool:
    """Whether two actors seen together in at least ``merge_frames`` frames are pieces of one rigid body
    there: median offsets within ``merge_distance`` along ``a``'s heading and ``merge_lateral`` across
    it, and median planar velocity difference below ``merge_velocity``. Cars side by side in adjacent
    lanes (~3.5 m apart, same speed) fail the lateral test; cars that pass each other the velocity one."""
    common = np.intersect1d(a.frames, b.frames)
    if len(common) < config.merge_frames:
        return False
    longitudinal, lateral = body_offsets(a, b, common)
    slip = np.linalg.norm(a.velocity[common, :2] - b.velocity[common, :2], axis=1)
    return bool(np.median(longitudinal) <= config.merge_distance and np.median(lateral) <= config.merge_lateral
                and np.median(slip) <= config.merge_velocity)


def hands_over(a: Actor, b: Actor, timestamps: np.ndarray, config: ActorConfig) -> bool:
    """Whether one actor takes over where the other stops (one car whose Gaussians of its first and last
    seconds came apart): the later one starts at most ``handover_seconds`` after the earlier one's last
    frame (or overlaps it by fewer than ``merge_frames``), where either's constant-velocity extrapolation
    puts the other (offsets as :func:`moves_together`), at a velocity within ``merge_velocity``."""
    if len(a.frames) == 0 or len(b.frames) == 0:
        return False
    if a.frames[0] > b.frames[0]:
        a, b = b, a
    end, start = int(a.frames[-1]), int(b.frames[0])
    dt = timestamps[start] - timestamps[end]
    if start < end - config.merge_frames + 1 or dt > config.handover_seconds:
        return False
    if np.linalg.norm(a.velocity[end, :2] - b.velocity[start, :2]) > config.merge_velocity:
        return False
    c, s = np.cos(a.heading[end]), np.sin(a.heading[end])
    for gap in (a.centroid[end, :2] + a.velocity[end, :2] * dt - b.centroid[start, :2],
                a.centroid[end, :2] - b.centroid[start, :2] + b.velocity[start, :2] * dt):
        if abs(gap[0] * c + gap[1] * s) <= config.merge_distance and \
                abs(gap[1] * c - gap[0] * s) <= config.merge_lateral:
            return True
    return False


def merge_groups(actors: list[Actor], timestamps: np.ndarray, config: ActorConfig,
                 chains: tuple[list[int], RadarChains] | None = None) -> np.ndarray:
    """(A,) group label of each of A actors: pieces that :func:`moves_together` or :func:`hands_over`
    are one (transitively: connected components). With ``chains`` (each piece's main radar chain, -1 for
    none, and the :class:`RadarChains`): pieces on one chain are one, and pieces on two chains seen at the
    same time are never linked directly."""
    from scipy.sparse import coo_matrix
    from scipy.sparse.csgraph import connected_components

    def linked(i: int, j: int) -> bool:
        if chains is not None:
            main, radar = chains
            if distinct_objects(main[i], main[j], radar):
                return False
            if main[i] >= 0 and main[i] == main[j]:
                return True
        return moves_together(actors[i], actors[j], config) or hands_over(actors[i], actors[j], timestamps, config)

    pairs = [(i, j) for i in range(len(actors)) for j in range(i + 1, len(actors)) if linked(i, j)]
    rows, cols = (list(x) for x in zip(*pairs, strict=True)) if pairs else ([], [])
    graph = coo_matrix((np.ones(len(rows)), (rows, cols)), shape=(len(actors),) * 2)
    return connected_components(graph, directed=False)[1]


def is_actor(actor: Actor, config: ActorConfig) -> bool:
    """The spurious-actor filter: seen in at least ``min_frames`` frames, and its centroid moving at least
    ``min_displacement`` (m, planar) between its first and last of them."""
    if len(actor.frames) < config.min_frames:
        return False
    first, last = actor.centroid[actor.frames[0], :2], actor.centroid[actor.frames[-1], :2]
    return bool(np.linalg.norm(last - first) >= config.min_displacement)


def radar_supported(actor: Actor, radar: RadarChains | None, config: ActorConfig) -> bool:
    """The radar part of the spurious-actor filter: a confirmed radar chain within ``radar_gate`` of the
    actor's centroid in at least ``min_radar_frames`` of its frames of visibility (always true without
    radar)."""
    if radar is None or config.min_radar_frames <= 0:
        return True
    return int((support(actor.centroid, actor.frames, radar, config.radar_gate) >= 0).sum()) >= config.min_radar_frames


def radar_seeded(actors: list[Actor], groups: list[np.ndarray], active: np.ndarray, radar: RadarChains,
                 trajectories: np.ndarray, opacities: np.ndarray, config: ActorConfig) -> list[np.ndarray]:
    """Groups (each (K,) dynamic indices) seeded by the confirmed radar chains that none of the ``actors``
    (of ``groups``) took (its main chain, or one supporting it in ``radar_chain_frames`` frames): the
    ``active`` Gaussians of no group along the chain's path (:func:`seed_members`), when at least
    ``min_gaussians``."""
    taken_chains: set[int] = set()
    for actor in actors:
        supported = support(actor.centroid, actor.frames, radar, config.radar_gate)
        counts = np.bincount(supported[supported >= 0], minlength=1)
        taken_chains |= {main_chain(supported)} | set(np.flatnonzero(counts >= config.radar_chain_frames).tolist())
    free = np.setdiff1d(active, np.concatenate(groups) if groups else np.zeros(0, dtype=np.int64))
    seeds = []
    for chain in radar.frames:
        if chain in taken_chains:
            continue
        members = seed_members(chain, radar, trajectories, opacities, free, config)
        if len(members) >= config.min_gaussians:
            seeds.append(members)
            free = np.setdiff1d(free, members)
    return seeds


def build_actor(index: int, gaussians: np.ndarray, trajectories: np.ndarray, opacities: np.ndarray,
                timestamps: np.ndarray, cameras: tuple[np.ndarray, np.ndarray, int, int], radar_objects,
                config: ActorConfig, radar: RadarChains | None = None) -> Actor:
    """The :class:`Actor` of ``gaussians`` (K,) from the dynamic set's ``trajectories`` (N, F, 3) and
    ``opacities`` (N, F) at the frames' ``timestamps`` (F,) seconds; ``cameras`` = (world_to_camera
    (F, 4, 4), K, width, height). With ``radar`` chains and ``radar_velocity``, the velocity of its frames
    of visibility is the radar's where a chain of it supports the actor (:func:`radar_velocity`)."""
    points, weights = trajectories[gaussians], opacities[gaussians]
    centroid, velocity, _ = opacity_track(points, weights, timestamps)
    frames = visible_frames(points, weights, *cameras, config)
    if radar is not None and config.radar_velocity and len(frames):
        measured = radar_velocity(centroid, frames, radar, config.radar_gate, config.radar_chain_frames)
        known = np.isfinite(measured[:, 0])
        velocity[frames[known], :2] = measured[known]
    heading = headings(velocity, points)
    reference = int(frames[len(frames) // 2]) if len(frames) else 0
    opaque = weights[:, reference] >= config.min_opacity  # the size of what renders there
    size = footprint_size(points[opaque if opaque.sum() >= 4 else slice(None), reference], float(heading[reference]))
    return Actor(index, np.sort(gaussians), frames, centroid, velocity, heading, size, class_guess(size),
                 radar_matches(points, weights, frames, radar_objects, config))


def discover_actors(model, scene, radar_objects=None, config: ActorConfig | None = None) -> list[Actor]:
    """The actors of a trained ``model`` of ``scene`` (every frame's time and camera), biggest first,
    ids 0, 1, ...; ``radar_objects`` is ``load_radar_objects(prepared)`` or None (no radar returns: the
    motion cues alone). Actors the spurious-actor filter (:func:`is_actor`, radar support) rejects are
    dropped; radar chains no actor took seed actors (:mod:`radar4dgs.actors.radar_cues`)."""
    from radar4dgs.io.scene import normalized_times

    config = config or ActorConfig()
    times = normalized_times(scene)
    timestamps = np.array([f.timestamp for f in scene.frames], dtype=np.float64)
    trajectories, opacities = dynamic_trajectories(model, times)
    cameras = (np.stack([scene.world_to_camera(i) for i in range(len(scene))]),
               np.asarray(scene.camera.K, dtype=np.float64), int(scene.camera.width), int(scene.camera.height))
    radar = None if radar_objects is None else radar_chains(radar_objects, timestamps, config)

    def build(groups: list[np.ndarray]) -> list[Actor]:
        return [build_actor(k, g, trajectories, opacities, timestamps, cameras, radar_objects, config, radar)
                for k, g in enumerate(groups)]

    active = np.flatnonzero(moving_mask(trajectories, opacities, config))
    labels = motion_components(trajectories[active][:, sample_indices(len(times), config.sample_frames)], config)
    groups = [active[labels == k] for k in range(int(labels.max()) + 1 if len(labels) else 0)]
    actors = build(groups)
    if len(actors) > 1:
        main = None if radar is None else [main_chain(support(a.centroid, a.frames, radar, config.radar_gate))
                                           for a in actors]
        merged = merge_groups(actors, timestamps, config, None if main is None else (main, radar))
        groups = [np.concatenate([groups[i] for i in np.flatnonzero(merged == m)]) for m in np.unique(merged)]
        actors = build(groups)
    keep = [k for k, a in enumerate(actors) if is_actor(a, config) and radar_supported(a, radar, config)]
    groups = [groups[k] for k in keep]
    if radar is not None and config.radar_seeds:
        groups += radar_seeded([actors[k] for k in keep], groups, active, radar, trajectories, opacities, config)
    actors = [a for a in build(groups) if is_actor(a, config) and radar_supported(a, radar, config)]
    actors.sort(key=lambda a: -len(a.gaussians))
    camera_positions = camera_centres(cameras[0])
    for k, actor in enumerate(actors):
        actor.id = k
        if is_car_like(actor.size) and min(config.car_size) > 0:
            actor.centroid = completed_centres(trajectories[actor.gaussians], opacities[actor.gaussians],
                                               actor.centroid, actor.heading, camera_positions,
                                               config.car_size, config.min_opacity)
    return actors
