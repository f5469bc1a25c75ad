"""Switching discovered actors from the deformation field to rigid motions of their own
(``TrainConfig.rigid_actors_at``; :mod:`radar4dgs.model.actor_motion`).

At the switch the dynamic Gaussians are grouped into actors (:func:`radar4dgs.actors.discover.discover_actors`,
as ``radar4dgs actors`` does after training). For each actor the field's positions of its Gaussians
at every key time give the initial rigid motion: a weighted 2-D Procrustes fit (yaw about z) and the
weighted centroid's displacement, weighted by the Gaussians' opacities at the reference time and at
the key time (a Gaussian outside its life span is flung anywhere by the field and must not count).
The reference time is the key where the actor's opacity mass is largest; its Gaussians' means become
their positions then.
"""

from __future__ import annotations

import numpy as np
import torch
from torch import Tensor, nn

from radar4dgs.model.actor_motion import ActorMotion
from radar4dgs.model.scene_model import SceneModel


def procrustes_yaw(reference: np.ndarray, moved: np.ndarray, weights: np.ndarray) -> float:
    """Yaw (radians about z) of the best rotation taking the (n, 2) ``reference`` offsets to the
    (n, 2) ``moved`` ones (both about their own weighted centroids), weighted by (n,) ``weights``.
    Closed form of the 2-D weighted Kabsch problem (scipy's Rotation.align_vectors is 3-D and
    would need the z offsets dropped anyway)."""
    cross = np.sum(weights * (reference[:, 0] * moved[:, 1] - reference[:, 1] * moved[:, 0]))
    dot = np.sum(weights * (reference[:, 0] * moved[:, 0] + reference[:, 1] * moved[:, 1]))
    return float(np.arctan2(cross, dot))


def fit_rigid_track(positions: np.ndarray, opacities: np.ndarray) -> tuple[int, np.ndarray, np.ndarray, np.ndarray]:
    """The rigid motion of one actor from its Gaussians' (n, K, 3) field ``positions`` and (n, K)
    ``opacities`` at K key times: the reference key, the pivot (3,) (weighted centroid there), and per
    key the yaw (K,) and shift (K, 3) such that ``Rz(yaw_k) (x_ref - pivot) + pivot + shift_k`` is the
    weighted least-squares fit of the key's positions."""
    reference = int(np.argmax(opacities.sum(axis=0)))
    w_ref = opacities[:, reference] + 1e-9
    pivot = np.average(positions[:, reference], axis=0, weights=w_ref)
    keys = positions.shape[1]
    yaw, shift = np.zeros(keys), np.zeros((keys, 3))
    for k in range(keys):
        weights = w_ref * opacities[:, k]
        if weights.sum() < 1e-6 * w_ref.sum():
            weights = w_ref  # the actor is not there at this key: its Gaussians' field positions alone
        src_centre = np.average(positions[:, reference], axis=0, weights=weights)
        dst_centre = np.average(positions[:, k], axis=0, weights=weights)
        yaw[k] = procrustes_yaw(positions[:, reference, :2] - src_centre[:2], positions[:, k, :2] - dst_centre[:2],
                                weights)
        c, s = np.cos(yaw[k]), np.sin(yaw[k])
        offset = src_centre - pivot
        turned = np.array([c * offset[0] - s * offset[1], s * offset[0] + c * offset[1], offset[2]])
        shift[k] = dst_centre - pivot - turned
    return reference, pivot, yaw, shift


@torch.no_grad()
def rigid_actor_motion(model: SceneModel, groups: list[np.ndarray], key_times: np.ndarray
                       ) -> tuple[ActorMotion, Tensor, Tensor]:
    """The initial :class:`ActorMotion` of ``groups`` (one (k,) index array into the dynamic set per
    actor) at (K,) normalised ``key_times``, the (N,) actor index of every dynamic Gaussian (-1 for
    none) and the (N, 3) means they start from (reference-time positions for the actors', the
    canonical ones for the rest)."""
    dynamic = model.dynamic
    means = dynamic.params["means"].detach()
    positions, opacities = [], []
    for t in key_times:
        g = model.set_at("dynamic", float(t))
        positions.append(g["means"].double().cpu().numpy())
        opacities.append(g["opacities"].double().cpu().numpy())
    positions, opacities = np.stack(positions, axis=1), np.stack(opacities, axis=1)
    actor = torch.full((len(dynamic),), -1.0, dtype=means.dtype, device=means.device)
    start = means.clone()
    pivots, yaws, shifts = [], [], []
    for a, members in enumerate(groups):
        reference, pivot, yaw, shift = fit_rigid_track(positions[members], opacities[members])
        index = torch.as_tensor(members, dtype=torch.long, device=means.device)
        actor[index] = float(a)
        start[index] = torch.as_tensor(positions[members, reference], dtype=means.dtype, device=means.device)
        pivots.append(pivot)
        yaws.append(yaw)
        shifts.append(shift)
    kw = {"dtype": means.dtype, "device": means.device}
    motion = ActorMotion(torch.as_tensor(np.asarray(key_times), **kw), torch.as_tensor(np.array(pivots), **kw),
                         torch.as_tensor(np.array(yaws), **kw), torch.as_tensor(np.array(shifts), **kw))
    return motion, actor, start


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
