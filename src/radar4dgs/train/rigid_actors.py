"""Switching discovered actors from the deformation field to rigid motions of their own
(``TrainConfig.rigid_actors_at``; :mod:`radar4dgs.model.actor_motion`).

At the switch the dynamic Gaussians are grouped into actors (:func:`radar4dgs.actors.discover.discover_actors`,
as ``radar4dgs actors`` does after training). For each actor the field's positions of its Gaussians
at the key times give the initial rigid motion (:func:`fit_rigid_track`: weighted 2-D Procrustes
steps from key to key), and its Gaussians' means become their positions at the actor's reference
time. Optionally (:func:`attach_free`) the Gaussians the discovery left to the field join the actor whose
fitted body covers them in their own frame.
"""

from __future__ import annotations

from pathlib import Path
from typing import NamedTuple

import numpy as np
import torch
from torch import Tensor, nn

from radar4dgs.actors.config import ActorConfig
from radar4dgs.actors.discover import discover_actors, dynamic_trajectories
from radar4dgs.depth.geometry import project
from radar4dgs.io.scene import normalized_times
from radar4dgs.model.actor_motion import ActorMotion
from radar4dgs.model.pose_refine import camera_centres
from radar4dgs.model.scene_model import SceneModel
from radar4dgs.radar.objects import optional_radar_objects
from radar4dgs.train.optimizers import adam


def procrustes_yaw(reference: np.ndarray, moved: np.ndarray, weights: np.ndarray) -> float:
    """Yaw (radians about z) of the best rotation taking the (n, 2) ``reference`` offsets to the
    (n, 2) ``moved`` ones (both about their own weighted centroids), weighted by (n,) ``weights``.
    Closed form of the 2-D weighted Kabsch problem (scipy's Rotation.align_vectors is 3-D and
    would need the z offsets dropped anyway)."""
    cross = np.sum(weights * (reference[:, 0] * moved[:, 1] - reference[:, 1] * moved[:, 0]))
    dot = np.sum(weights * (reference[:, 0] * moved[:, 0] + reference[:, 1] * moved[:, 1]))
    return float(np.arctan2(cross, dot))


def rigid_step(before: np.ndarray, after: np.ndarray, weights: np.ndarray,
               pivot: np.ndarray) -> tuple[float, np.ndarray]:
    """The rigid step ``after ≈ Rz(yaw) (before - pivot) + pivot + shift`` of (n, 3) points,
    weighted least squares: (yaw, shift (3,))."""
    src, dst = np.average(before, axis=0, weights=weights), np.average(after, axis=0, weights=weights)
    yaw = procrustes_yaw(before[:, :2] - src[:2], after[:, :2] - dst[:2], weights)
    return yaw, dst - pivot - turn_about_z(src - pivot, yaw)


def turn_about_z(offset: np.ndarray, yaw: float) -> np.ndarray:
    """(..., 3) offsets turned by ``yaw`` radians about z (a float, or an array broadcast with ``offset[..., 0]``)."""
    c, s = np.cos(yaw), np.sin(yaw)
    return np.stack([c * offset[..., 0] - s * offset[..., 1], s * offset[..., 0] + c * offset[..., 1],
                     offset[..., 2]], axis=-1)


def reference_positions(points: np.ndarray, pivot: np.ndarray, yaw: np.ndarray, shift: np.ndarray) -> np.ndarray:
    """(..., 3) world ``points``, each seen at its own key, brought back to the actor's reference time: the inverse
    of ``T_k(c) = Rz(yaw_k) (c - pivot) + pivot + shift_k`` with that key's ``yaw`` (...) and ``shift`` (..., 3) and
    the ``pivot`` ((3,) or (..., 3))."""
    return turn_about_z(points - pivot - shift, -yaw) + pivot


# An actor is born at a key when the Gaussians whose opacity peaks there hold at least this share of the
# opacity mass of its largest such key (a few stray copies elsewhere do not count).
BORN_SHARE = 0.1


def born_span(opacities: np.ndarray) -> tuple[int, int]:
    """The first and last of K keys an actor's Gaussians were born at, from their (n, K) opacities: keys
    where the Gaussians peaking there hold at least :data:`BORN_SHARE` of the largest such mass."""
    own = np.argmax(opacities, axis=1)
    mass = np.bincount(own, weights=opacities[np.arange(len(own)), own], minlength=opacities.shape[1])
    born = np.flatnonzero(mass >= BORN_SHARE * mass.max())
    return int(born[0]), int(born[-1])


def extrapolate_ends(yaw: np.ndarray, shift: np.ndarray, times: np.ndarray, first: int, last: int
                     ) -> tuple[np.ndarray, np.ndarray]:
    """(K,) ``yaw`` and (K, 3) ``shift`` with the keys before ``first`` and after ``last`` replaced by
    constant-velocity extrapolation from the keys ``first``, ``first + 1`` (``last - 1``, ``last``), yaw
    held, at the keys' (K,) normalised ``times``; unchanged when ``first == last`` (no velocity)."""
    yaw, shift = yaw.copy(), shift.copy()
    if last <= first:
        return yaw, shift
    for end, inner, keys in ((first, first + 1, range(first)), (last, last - 1, range(last + 1, len(times)))):
        velocity = (shift[inner] - shift[end]) / (times[inner] - times[end])
        for k in keys:
            shift[k] = shift[end] + velocity * (times[k] - times[end])
            yaw[k] = yaw[end]
    return yaw, shift


def fit_rigid_track(positions: np.ndarray, opacities: np.ndarray, times: np.ndarray | None = None,
                    flat: bool = False) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """The rigid motion of one actor from its Gaussians' (n, K, 3) field ``positions`` and (n, K)
    ``opacities`` (life span included) at K key times: the pivot (3,) (the weighted centroid at the
    key where the actor's opacity mass is largest, the reference), per key the yaw (K,) and shift
    (K, 3) of ``T_k(c) = Rz(yaw_k) (c - pivot) + pivot + shift_k`` (identity at the reference), and
    each Gaussian's (n, 3) position ``c`` at the reference time.

    Each dynamic Gaussian is one frame's copy of its object and renders only near that frame: the
    field's position of a copy far from its own time means little. So the motion is chained from
    key to key, each step fitted on the Gaussians that render at both (opacity products as
    weights), and each Gaussian's reference position is its position at its own key (where its
    opacity peaks) brought back by that key's motion. With the keys' (K,) normalised ``times``, the keys
    outside the actor's :func:`born_span` follow :func:`extrapolate_ends` instead of the field. ``flat``: the path
    keeps the reference key's height (shift z 0 at every key); each copy stays where the field put it at its own key."""
    keys = positions.shape[1]
    reference = int(np.argmax(opacities.sum(axis=0)))
    pivot = np.average(positions[:, reference], axis=0, weights=opacities[:, reference] + 1e-9)
    yaw, shift = np.zeros(keys), np.zeros((keys, 3))
    order = [(k, k - 1) for k in range(reference + 1, keys)] + [(k, k + 1) for k in range(reference - 1, -1, -1)]
    for k, known in order:
        weights = opacities[:, k] * opacities[:, known]
        if weights.sum() < 1e-6:
            weights = opacities[:, k] + opacities[:, known] + 1e-9  # nobody renders at both: the field alone
        step_yaw, step_shift = rigid_step(positions[:, known], positions[:, k], weights, pivot)
        yaw[k] = yaw[known] + step_yaw
        shift[k] = turn_about_z(shift[known], step_yaw) + step_shift
    if flat:
        # A road user's height hardly changes over a clip; the field's vertical drift (metres over a crossing
        # car's path on the strict tuning seeds) would carry each copy up or down away from its own frame.
        shift[:, 2] = 0.0
    if times is not None:
        yaw, shift = extrapolate_ends(yaw, shift, np.asarray(times, dtype=np.float64), *born_span(opacities))
    own = np.argmax(opacities, axis=1)
    canonical = reference_positions(positions[np.arange(len(own)), own], pivot, yaw[own], shift[own])
    return pivot, yaw, shift, canonical


class RadarPaths(NamedTuple):
    """What :func:`radar_corrected_shift` needs of every actor: per actor the (K, 2) velocities and (K,) their
    stds (:func:`radar_key_velocities`), and per key the (K, 3) camera centre and the time (K,) in seconds."""

    velocities: list[tuple[np.ndarray, np.ndarray]]
    centres: np.ndarray
    seconds: np.ndarray


# Trusting an actor's radar object at a frame: at least this many returns, and a velocity standard deviation
# (the larger axis of its covariance) of at most this (m/s). Fewer returns fit some velocity by chance.
RADAR_PATH_MIN_RETURNS = 3
RADAR_PATH_MAX_STD = 1.0
# Standard deviations (m) of the field's pivot path across the line of sight (the images place it there to a few
# centimetres at 40 m) and along it (the depth maps, metres on a far car), weighting the radar path's fusion.
ACROSS_SIGHT_STD = 0.1
ALONG_SIGHT_STD = 3.0


def radar_key_velocities(actor_radar: dict[int, list[dict]], radar_objects: list[list], key_frames: np.ndarray
                         ) -> tuple[np.ndarray, np.ndarray]:
    """Per key (frame indices (K,)): the planar world velocity (K, 2) of the trusted radar object an actor holds
    there (``actor_radar``: :attr:`radar4dgs.actors.discover.Actor.radar`; of several, the one with most returns)
    and its standard deviation (K,) in m/s; NaN where it holds none."""
    velocity, std = np.full((len(key_frames), 2), np.nan), np.full(len(key_frames), np.nan)
    for k, frame in enumerate(key_frames):
        tracks = {hit["track"] for hit in actor_radar.get(int(frame), [])}
        held = [o for o in radar_objects[int(frame)] if o.track in tracks and o.num_returns >= RADAR_PATH_MIN_RETURNS]
        if not held:
            continue
        best = max(held, key=lambda o: o.num_returns)
        sigma = float(np.sqrt(max(np.linalg.eigvalsh(np.asarray(best.velocity_covariance))[-1], 0.0)))
        if sigma <= RADAR_PATH_MAX_STD:
            velocity[k], std[k] = best.velocity[:2], max(sigma, 0.05)
    return velocity, std


def radar_corrected_shift(pivot: np.ndarray, shift: np.ndarray, centres: np.ndarray, velocity: np.ndarray,
                          velocity_std: np.ndarray, seconds: np.ndarray) -> np.ndarray:
    """(K, 3) ``shift`` with the pivot's planar path ``pivot + shift`` moved to fit the radar's velocities: least
    squares over per-key planar corrections, keeping each key's position across the line of sight from the
    camera ``centres`` (K, 3) (std :data:`ACROSS_SIGHT_STD`), loosely along it (:data:`ALONG_SIGHT_STD`), and
    each step between keys whose (K, 2) ``velocity`` (NaN where none; std (K,) m/s) is known matching their mean
    velocity times the (K,) ``seconds`` between them. The images fix where a far car is seen, not how far away:
    along the line of sight the radar's Doppler says how it moves. Unchanged without two such keys in a row."""
    keys = len(shift)
    path = pivot[:2] + shift[:, :2]
    known = np.isfinite(velocity[:, 0])
    steps = [k for k in range(keys - 1) if known[k] and known[k + 1]]
    if not steps:
        return shift.copy()
    sight = path - centres[:, :2]
    sight /= np.maximum(np.linalg.norm(sight, axis=1, keepdims=True), 1e-9)
    across = np.stack([-sight[:, 1], sight[:, 0]], axis=1)
    rows, rhs = [], []
    for k in range(keys):  # each key's correction d_k (2 unknowns at 2k, 2k+1)
        for direction, std in ((across[k], ACROSS_SIGHT_STD), (sight[k], ALONG_SIGHT_STD)):
            row = np.zeros(2 * keys)
            row[2 * k:2 * k + 2] = direction / std
            rows.append(row)
            rhs.append(0.0)
    for k in steps:
        dt = seconds[k + 1] - seconds[k]
        std = dt * 0.5 * np.hypot(velocity_std[k], velocity_std[k + 1])
        moved = 0.5 * (velocity[k] + velocity[k + 1]) * dt - (path[k + 1] - path[k])
        for axis in range(2):
            row = np.zeros(2 * keys)
            row[2 * (k + 1) + axis], row[2 * k + axis] = 1.0 / std, -1.0 / std
            rows.append(row)
            rhs.append(moved[axis] / std)
    correction = np.linalg.lstsq(np.array(rows), np.array(rhs), rcond=None)[0].reshape(keys, 2)
    out = shift.copy()
    out[:, :2] += correction
    return out


# Points nearer the camera plane than this (m) are left out of image-space comparisons: their projections run far
# outside the image and say nothing about where an actor is seen.
IN_FRONT_M = 0.5

# A free copy joins a body whose projection lies within the attach radius of it only when its depth is within this
# share of that body point's: a car 15 m ahead overlaps a far one in the image, while one far car's copies from
# different frames lie metres apart along the line of sight (the depth maps' error at 40-60 m).
ATTACH_DEPTH_SHARE = 0.2


def body_attachments(points: np.ndarray, keys: np.ndarray, bodies: list[np.ndarray], world_to_camera: np.ndarray,
                     K: np.ndarray, radius: float) -> np.ndarray:
    """(M,) index of the body each of M free Gaussians joins, -1 for none.

    Each free Gaussian is seen at its own key ``keys`` (M,), at (M, 3) world ``points`` there; body ``a`` is
    (K, n_a, 3): its members at every key. A Gaussian joins the body with a member projecting within ``radius``
    px of it in that key's camera (``world_to_camera`` (K, 4, 4), intrinsics ``K``) at a depth within
    :data:`ATTACH_DEPTH_SHARE` of its own; of several, the nearest in the image. Compared in the image, not in 3-D,
    because the depth maps place one frame's copy of a far car metres off another's along the line of sight."""
    from scipy.spatial import cKDTree

    joins = np.full(len(points), -1, dtype=np.int64)
    if not bodies or not len(points):
        return joins
    labels = np.concatenate([np.full(b.shape[1], a) for a, b in enumerate(bodies)])
    for k in np.unique(keys):
        free = np.flatnonzero(keys == k)
        body = np.concatenate([b[k] for b in bodies])
        cam = world_to_camera[k]
        uv_b, z_b = project(K, body @ cam[:3, :3].T + cam[:3, 3])
        uv_f, z_f = project(K, points[free] @ cam[:3, :3].T + cam[:3, 3])
        front = z_b > IN_FRONT_M
        if not front.any():
            continue
        uv_b, z_b, label = uv_b[front], z_b[front], labels[front]
        near = cKDTree(uv_b).query_ball_point(np.where(np.isfinite(uv_f), uv_f, -1e9), r=radius)
        for i, candidates in enumerate(near):
            if z_f[i] <= IN_FRONT_M or not candidates:
                continue
            c = np.asarray(candidates)
            c = c[np.abs(z_b[c] - z_f[i]) <= ATTACH_DEPTH_SHARE * z_b[c]]
            if len(c):
                joins[free[i]] = label[c[np.argmin(np.linalg.norm(uv_b[c] - uv_f[i], axis=1))]]
    return joins


@torch.no_grad()
def rigid_actor_motion(model: SceneModel, groups: list[np.ndarray], key_times: np.ndarray,
                       extrapolate: bool = False, radar_paths: RadarPaths | None = None,
                       attach: tuple[np.ndarray, np.ndarray, float] | None = None, flat: bool = False
                       ) -> tuple[ActorMotion, Tensor, Tensor]:
    """The initial :class:`ActorMotion` of ``groups`` (one (k,) index array into the dynamic set per
    actor) at (K,) normalised ``key_times``, the (N,) actor index of every dynamic Gaussian (-1 for
    none) and the (N, 3) means they start from (reference-time positions for the actors', the
    canonical ones for the rest); ``extrapolate``: each actor's path outside the keys it was born at
    goes on at constant velocity (:func:`fit_rigid_track`); ``radar_paths``: each actor's path is then
    moved along the line of sight to its radar velocities (:func:`radar_corrected_shift`); ``attach`` = (the keys'
    (K, 4, 4) world-to-camera, intrinsics (3, 3), radius px): the Gaussians of no group join the actor whose fitted
    body covers them at their own key (:func:`body_attachments`); ``flat``: as :func:`fit_rigid_track`."""
    dynamic = model.dynamic
    means = dynamic.params["means"].detach()
    positions, opacities = dynamic_trajectories(model, key_times)
    actor = torch.full((len(dynamic),), -1.0, dtype=means.dtype, device=means.device)
    start = means.clone()
    pivots, yaws, shifts = [], [], []
    for a, members in enumerate(groups):
        pivot, yaw, shift, canonical = fit_rigid_track(positions[members], opacities[members],
                                                       np.asarray(key_times) if extrapolate else None, flat)
        if radar_paths is not None:
            velocity, std = radar_paths.velocities[a]
            shift = radar_corrected_shift(pivot, shift, radar_paths.centres, velocity, std, radar_paths.seconds)
            if extrapolate:
                yaw, shift = extrapolate_ends(yaw, shift, np.asarray(key_times, dtype=np.float64),
                                              *born_span(opacities[members]))
        index = torch.as_tensor(members, dtype=torch.long, device=means.device)
        actor[index] = float(a)
        start[index] = torch.as_tensor(canonical, dtype=means.dtype, device=means.device)
        pivots.append(pivot)
        yaws.append(yaw)
        shifts.append(shift)
    if attach is not None and groups:
        attach_free(positions, opacities, groups, actor, start, np.array(pivots), np.array(yaws), np.array(shifts),
                    *attach)
    kw = {"dtype": means.dtype, "device": means.device}
    motion = ActorMotion(torch.as_tensor(np.asarray(key_times), **kw), torch.as_tensor(np.array(pivots), **kw),
                         torch.as_tensor(np.array(yaws), **kw), torch.as_tensor(np.array(shifts), **kw))
    return motion, actor, start


def attach_free(positions: np.ndarray, opacities: np.ndarray, groups: list[np.ndarray], actor: Tensor, start: Tensor,
                pivots: np.ndarray, yaws: np.ndarray, shifts: np.ndarray, world_to_camera: np.ndarray, K: np.ndarray,
                radius: float) -> None:
    """Give the Gaussians of no group that render (opacity at least ActorConfig.min_opacity at some key) to the
    actor whose body covers them at their own key (:func:`body_attachments`), in place: (N,) ``actor`` and their
    (N, 3) reference-time ``start``. The field moves a far, fast car's copies apart away from their own frames, so
    the discovery links few of them; each copy is right at its own frame, where the images place it. Bodies are the
    groups' members at every key under the fitted motions: ``pivots`` (A, 3), ``yaws`` (A, K), ``shifts`` (A, K, 3),
    from (N, K, 3) ``positions`` and (N, K) ``opacities`` at the keys."""
    rendering = opacities.max(axis=1) >= ActorConfig().min_opacity
    free = np.flatnonzero((actor.cpu().numpy() < 0) & rendering)
    if not len(free):
        return
    own = np.argmax(opacities[free], axis=1)
    points = positions[free, own]
    bodies = []
    for a, members in enumerate(groups):
        c = start[torch.as_tensor(members[rendering[members]], dtype=torch.long)].double().cpu().numpy()
        offsets = np.broadcast_to(c - pivots[a], (yaws.shape[1],) + c.shape)
        bodies.append(turn_about_z(offsets, yaws[a][:, None]) + pivots[a] + shifts[a][:, None])
    joins = body_attachments(points, own, bodies, world_to_camera, K, radius)
    joined = np.flatnonzero(joins >= 0)
    a, k = joins[joined], own[joined]
    index = torch.as_tensor(free[joined], dtype=torch.long, device=actor.device)
    actor[index] = torch.as_tensor(a, dtype=actor.dtype, device=actor.device)
    start[index] = torch.as_tensor(reference_positions(points[joined], pivots[a], yaws[a, k], shifts[a, k]),
                                   dtype=start.dtype, device=start.device)


def rigid_members(model: SceneModel, motion: ActorMotion, actor: Tensor, start: Tensor,
                  optimizer: torch.optim.Optimizer) -> None:
    """Install ``motion`` in ``model``: the dynamic set gets the (N,) ``actor`` parameter and the
    actors' Gaussians their reference-time ``start`` means (their Adam moments of the means zeroed:
    the old ones were steps of another parametrisation)."""
    dynamic = model.dynamic
    rigid = actor >= 0
    old = dynamic.params["means"]
    new = nn.Parameter(start.clone())
    for group in optimizer.param_groups:
        if group["params"][0] is old:
            state = optimizer.state.pop(old, {})
            for key in ("exp_avg", "exp_avg_sq"):
                if key in state:
                    state[key] = state[key].clone()
                    state[key][rigid] = 0.0
            group["params"] = [new]
            if state:
                optimizer.state[new] = state
    dynamic.params["means"] = new
    dynamic.params["actor"] = nn.Parameter(actor.clone(), requires_grad=False)
    model.actor_motion = motion


def actor_image_motion(centroids: np.ndarray, frames: np.ndarray, world_to_camera: np.ndarray,
                       K: np.ndarray) -> float:
    """90th percentile (px) of how far an actor's centroid moves in the image from a visible frame to
    the next one (consecutive frames only; a frame with the centroid less than :data:`IN_FRONT_M` in front
    of the camera is skipped), each frame seen by its own camera; 0 when no pair is left.

    Args:
        centroids: (F, 3) world centroid per frame. frames: (V,) visible frame indices, ascending.
        world_to_camera: (F, 4, 4). K: (3, 3).
    """
    frames = np.asarray(frames, dtype=np.int64)
    pairs = frames[:-1][np.diff(frames) == 1]
    if len(pairs) == 0:
        return 0.0
    both = np.concatenate([pairs, pairs + 1])
    cam = np.einsum("fij,fj->fi", world_to_camera[both, :3, :3], centroids[both]) + world_to_camera[both, :3, 3]
    uv, z = project(np.asarray(K, dtype=np.float64), cam)
    n = len(pairs)
    keep = (z[:n] > IN_FRONT_M) & (z[n:] > IN_FRONT_M)
    if not keep.any():
        return 0.0
    return float(np.percentile(np.linalg.norm(uv[n:] - uv[:n], axis=1)[keep], 90))


def start_rigid_actors(model: SceneModel, scene, prepared: Path, key_frames: np.ndarray,
                       optimizers: dict[str, torch.optim.Optimizer], lr: float, min_motion: float = 0.0,
                       extrapolate: bool = False, radar_path: bool = False, attach: float = 0.0,
                       flat: bool = False) -> str:
    """Discover ``model``'s actors in ``scene`` (with the radar objects of ``prepared`` when it has them) and, for those
    moving at least ``min_motion`` x the image width a frame in the image (:func:`actor_image_motion`), move each
    rigidly from now on: the motion installed in ``model`` at the normalised times of the (K,) frames ``key_frames``
    and its Adam (rate ``lr``) added to ``optimizers`` as "actors"; ``extrapolate`` as :func:`rigid_actor_motion`;
    ``radar_path`` (with radar objects): each actor's path is fitted to the velocities of the radar objects it holds
    (:func:`radar_corrected_shift`); ``attach`` > 0: the Gaussians left to the field join an actor covering them in
    their own frame within that fraction of the image width (:func:`attach_free`); ``flat``: as
    :func:`fit_rigid_track`. Returns the line to log."""
    # Without (current) radar objects the motion graph alone groups the Gaussians.
    radar_objects, why = optional_radar_objects(prepared, len(scene))
    without = "" if radar_objects is not None else f" (without radar objects: {why})"
    actors = discover_actors(model, scene, radar_objects)
    if not actors:
        return f"rigid actors: no actor found; the field keeps every dynamic Gaussian{without}"
    found = len(actors)
    if min_motion > 0:
        poses = np.stack([scene.world_to_camera(i) for i in range(len(scene))])
        threshold = min_motion * scene.camera.width
        actors = [a for a in actors if actor_image_motion(a.centroid, a.frames, poses, scene.camera.K) >= threshold]
        if not actors:
            return (f"rigid actors: none of {found} actors moves {threshold:.1f} px a frame in the image; the "
                    f"field keeps every dynamic Gaussian{without}")
    paths, bodies = None, None
    frames = np.asarray(key_frames)
    key_times = normalized_times(scene)[frames]
    if attach > 0 or (radar_path and radar_objects is not None):
        cameras = np.stack([scene.world_to_camera(int(f)) for f in frames])
    if attach > 0:
        bodies = (cameras, np.asarray(scene.camera.K, dtype=np.float64), attach * scene.camera.width)
    if radar_path and radar_objects is not None:
        stamps = np.array([scene.frames[f].timestamp for f in frames], dtype=np.float64)
        paths = RadarPaths([radar_key_velocities(a.radar, radar_objects, frames) for a in actors],
                           camera_centres(cameras), stamps)
    groups = [a.gaussians for a in actors]
    motion, actor, start = rigid_actor_motion(model, groups, key_times, extrapolate, paths, bodies, flat)
    rigid_members(model, motion, actor, start, optimizers["dynamic"])
    optimizers["actors"] = adam(motion.param_groups(lr))
    joined = int((actor >= 0).sum()) - sum(len(g) for g in groups)
    return (f"rigid actors: {len(actors)} of {found} actors, {int((actor >= 0).sum())} of {len(actor)} dynamic "
            f"Gaussians move rigidly{f' ({joined} joined in their own frame)' if bodies else ''}{without}")
