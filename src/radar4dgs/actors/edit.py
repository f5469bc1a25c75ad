"""Editing actors at render time: remove, move or re-time an actor by changing ITS Gaussians (opacity
zero, a rigid offset, a remapped time), not the picture.

Command-line forms (``radar4dgs render``), each flag repeatable:

``--remove-actors all|ID[,ID...]``
    Opacity zero for the actors' Gaussians (``all``: every dynamic Gaussian, assigned to an actor or
    not, so only the static layer and the sky remain).
``--move-actor ID:DX,DY``
    Offset the actor by DX metres laterally (+ = to the actor's left) and DY metres longitudinally
    (+ = forward), in the actor's own frame at each time: its heading (``actors.json``) turns the
    offset with it.
``--retime-actor ID:SCALE`` or ``ID:+SECONDS`` (``-SECONDS``)
    The actor's Gaussians are evaluated at another time: ``t * SCALE`` (normalised time; 2 = twice as
    fast, 0.5 = half speed, from the first frame) or ``t - SECONDS / duration`` (+ = the actor is
    SECONDS later). Remapped times are clamped to the trained span [0, 1]: before its start and after
    its end the actor stands at its first or last trained pose.
"""

from __future__ import annotations

import math

import numpy as np

from radar4dgs.actors.spec import ActorEdits
from radar4dgs.model.scene_model import SceneModel


class EditedSceneModel(SceneModel):
    """A :class:`SceneModel` sharing another's Gaussians and field (and its sky unless given one), whose
    :meth:`gaussians_at` applies actor edits to the dynamic Gaussians; renders, masks and depth follow
    unchanged."""

    def __init__(self, model: SceneModel, removed, moved, retimed, frame_times: np.ndarray, duration: float,
                 sky=None):
        super().__init__(model.static, model.sky if sky is None else sky, model.field, model.dynamic,
                         model.offsets, model.baseline, model.actor_motion, model.key_times, model.window_fraction,
                         model.own_time_means, model.dynamic_in_front)
        self.removed = removed  # (K,) long tensor of dynamic indices, or None
        self.moved = moved  # [(indices, heading (F,), (lateral, longitudinal))]
        self.retimed = retimed  # {actor id: (indices, kind, value)}
        self.frame_times = np.asarray(frame_times, dtype=np.float64)
        self.duration = float(duration)

    def remapped_time(self, kind: str, value: float, time: float) -> float:
        """The time (normalised, clamped to [0, 1]) an actor retimed by (kind, value) is shown at ``time``."""
        t = time * value if kind == "scale" else time - value / max(self.duration, 1e-9)
        return float(min(max(t, 0.0), 1.0))

    def gaussians_at(self, time: float, include_static: bool = True, include_dynamic: bool = True,
                     detach_static: bool = False, cull: bool = False):
        import torch

        g = super().gaussians_at(time, include_static, include_dynamic, detach_static, cull)
        if not include_dynamic or self.dynamic is None or len(self.dynamic) == 0:
            return g
        start = len(self.static) if include_static else 0
        means, opacities = g["means"].clone(), g["opacities"].clone()
        own_time = {}
        for indices, kind, value in self.retimed.values():
            own = self.remapped_time(kind, value, time)
            moved = self.set_at("dynamic", own, cull)
            means[start + indices] = moved["means"][indices]
            opacities[start + indices] = moved["opacities"][indices]
            own_time[id(indices)] = own
        for indices, heading, (lateral, longitudinal), key in self.moved:
            h = float(np.interp(own_time.get(key, time), self.frame_times, heading))
            offset = lateral * np.array([-math.sin(h), math.cos(h), 0.0]) + \
                longitudinal * np.array([math.cos(h), math.sin(h), 0.0])
            means[start + indices] = means[start + indices] + torch.as_tensor(offset, dtype=means.dtype,
                                                                              device=means.device)
        if self.removed is not None:
            opacities[start + self.removed] = 0.0
        return {**g, "means": means, "opacities": opacities}


def edited_model(model: SceneModel, actors, edits: ActorEdits, frame_times: np.ndarray,
                 duration: float = 1.0, sky=None) -> SceneModel:
    """``model`` with ``edits`` applied to ``actors`` (the :class:`~radar4dgs.actors.discover.Actor`
    list of its run), or ``model`` itself when there are none. ``frame_times`` (F,) normalised times
    of the actors' per-frame headings; ``duration`` the scene's length (s) for ``+SECONDS`` shifts;
    ``sky`` a sky map to render with instead of the model's (:func:`~radar4dgs.actors.background.background_sky`)."""
    import torch

    if edits.empty:
        return model
    device = next(iter(model.dynamic.params.values())).device if model.dynamic is not None else "cpu"
    by_id = {a.id: a for a in actors}

    def indices(actor_id: int):
        return torch.as_tensor(np.asarray(by_id[actor_id].gaussians, dtype=np.int64), device=device)

    removed = None
    if edits.remove_all and model.dynamic is not None:
        removed = torch.arange(len(model.dynamic), device=device)
    elif edits.remove:
        removed = torch.cat([indices(i) for i in edits.remove])
    retimed = {i: (indices(i), kind, value) for i, (kind, value) in edits.retime.items()}
    moved = []
    for i, offset in edits.move.items():
        members = retimed[i][0] if i in retimed else indices(i)
        heading = np.unwrap(np.asarray(by_id[i].heading, dtype=np.float64))
        moved.append((members, heading, offset, id(members)))
    return EditedSceneModel(model, removed, moved, retimed, frame_times, duration, sky).eval()
