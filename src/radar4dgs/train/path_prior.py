"""The field's path prior (``L_acc``): observed points of moving objects, carried by the field to times near
the time they were seen, should move at a constant velocity there.

Flow pairs and radar points constrain the field only at training frames and only while an object is in view.
A car about to leave the view (an oncoming car passing the ego at 5 Hz is in no later training frame) or the
times between training frames (the held-out views) are left to whatever the field's network does there: on a
hard tuning scene the field put such a car 0.17 m off in the one frame after its last flow pair, six pixels at
the car's 8 m, where a straight path would have missed by 0.03 m. :func:`acceleration_loss`
penalises the bend; constant velocity costs nothing.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import torch
from torch import Tensor

from radar4dgs.metrics.losses import acceleration_loss
from radar4dgs.model.field import DeformationField


@dataclass
class PathSamples:
    """Points of moving objects ``x`` (N, 3) seen at normalised times ``t`` (N,); ``step`` the frame interval
    (normalised time; the second difference's step) and ``reach`` how many steps either side of its time a
    point's path is checked."""

    x: np.ndarray
    t: np.ndarray
    step: float
    reach: float

    def __len__(self) -> int:
        return int(len(self.x))


def path_samples(points: list[tuple[np.ndarray, np.ndarray]], times: np.ndarray, reach: float) -> PathSamples | None:
    """The observed ``(x (N, 3), t (N,))`` point sets pooled, with the step of the scene's normalised frame
    ``times`` (F,); None without points or with fewer than two frames."""
    points = [(x, t) for x, t in points if len(x)]
    steps = np.diff(np.sort(np.asarray(times, dtype=np.float64)))
    steps = steps[steps > 0]
    if not points or not len(steps):
        return None
    return PathSamples(np.concatenate([x for x, _ in points]), np.concatenate([t for _, t in points]),
                       float(steps.min()), reach)


def observed_path_samples(flow, radar, times: np.ndarray, reach: float) -> PathSamples | None:
    """:func:`path_samples` of what the field is fitted to: the radar-supervised points (``RadarSamples``: ``x`` at
    ``t_i``) and both ends of the flow pairs (``FlowSamples``: ``x_i`` at ``t_i``, ``x_j`` at ``t_j``), pooled in that
    order (the order the measured runs drew from); either may be None or empty."""
    seen = ([(radar.x, radar.t_i)] if radar is not None else []) + \
        ([(flow.x_i, flow.t_i), (flow.x_j, flow.t_j)] if flow is not None else [])
    return path_samples(seen, times, reach)


def path_loss(field: DeformationField, samples: PathSamples, index: Tensor, generator: torch.Generator,
              dtype: torch.dtype, device: torch.device) -> Tensor:
    """``L_acc`` on the points ``index`` (B,) of ``samples``, each checked at a time drawn uniformly within
    ``reach`` steps of its own (clamped to [0, 1]); the draw uses ``generator``."""
    index = index.cpu().numpy()
    x = torch.as_tensor(samples.x[index], dtype=dtype, device=device)
    t_x = torch.as_tensor(samples.t[index], dtype=dtype, device=device)
    uniform = torch.rand(len(index), generator=generator, dtype=torch.float64)
    offset = (2.0 * uniform - 1.0) * samples.reach * samples.step
    t = (t_x + offset.to(dtype=dtype, device=device)).clamp(0.0, 1.0)
    return acceleration_loss(field, x, t_x, t, samples.step)
