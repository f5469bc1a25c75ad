"""Rigid motion per actor: the dynamic Gaussians of one discovered actor moved as one body.

One deformation field has to give every moving object its motion at once; when a fast car passes
slow neighbours its smoothness blurs them together (the standalone fit of the hard set's seed 211,
fitted to exact flow, is 1.5 m off on pixels moving > 30 px a frame). A car is rigid, so once the
actors are known (:mod:`radar4dgs.actors.discover`) each can have a motion of its own, as box-based
methods give each box a pose: a yaw about the world's z axis and a translation per key time,

    x_i(t) = Rz(yaw_a(t)) (c_i - p_a) + p_a + shift_a(t),

with ``c_i`` the Gaussian's position at the actor's reference time, ``p_a`` the actor's pivot (its
centroid then), and yaw and shift interpolated linearly between the key times (the training frames'
times, so a held-out frame between two of them gets the interpolated pose; beyond the first or last
key they extrapolate). The Gaussians' rotations
turn with the yaw. Gaussians of no actor keep the field.
"""

from __future__ import annotations

from typing import Any, Mapping

import torch
from torch import Tensor, nn

# Speed (m/s) below which an actor's path direction counts less in ActorMotion.heading_mismatch: a walking
# pedestrian's few centimetres a frame give it no reliable direction; a cyclist or a car has one.
HEADING_MIN_SPEED = 3.0


def yaw_quaternions(yaw: Tensor) -> Tensor:
    """(N, 4) wxyz unit quaternions of rotations by (N,) ``yaw`` radians about z."""
    half = 0.5 * yaw
    zero = torch.zeros_like(half)
    return torch.stack([torch.cos(half), zero, zero, torch.sin(half)], dim=-1)


def quaternion_product(a: Tensor, b: Tensor) -> Tensor:
    """(N, 4) Hamilton products ``a * b`` of (N, 4) wxyz quaternions (rotation ``b`` first)."""
    aw, ax, ay, az = a.unbind(-1)
    bw, bx, by, bz = b.unbind(-1)
    return torch.stack([aw * bw - ax * bx - ay * by - az * bz,
                        aw * bx + ax * bw + ay * bz - az * by,
                        aw * by - ax * bz + ay * bw + az * bx,
                        aw * bz + ax * by - ay * bx + az * bw], dim=-1)


def interpolation_weights(key_times: Tensor, time: float) -> tuple[int, int, float]:
    """The two key indices around normalised ``time`` and the weight of the second; before the first
    key and after the last the first or last two keys extrapolate linearly (a held-out first or last
    frame of a moving car), so the weight leaves [0, 1] there. ``key_times`` (K,) increasing."""
    k = int(key_times.numel())
    if k == 1:
        return 0, 0, 0.0
    upper = int(torch.searchsorted(key_times, torch.tensor(float(time), dtype=key_times.dtype,
                                                           device=key_times.device)).clamp(1, k - 1))
    lower = upper - 1
    span = float(key_times[upper] - key_times[lower])
    return lower, upper, (float(time) - float(key_times[lower])) / max(span, 1e-12)


class ActorMotion(nn.Module):
    """Rigid motions of A actors at K key times: ``yaw`` (A, K) radians and ``shift`` (A, K, 3)
    metres (learned), about ``pivots`` (A, 3) (fixed), at ``key_times`` (K,) normalised times."""

    def __init__(self, key_times: Tensor, pivots: Tensor, yaw: Tensor, shift: Tensor):
        super().__init__()
        a, k = yaw.shape
        if key_times.shape != (k,) or pivots.shape != (a, 3) or shift.shape != (a, k, 3):
            raise ValueError(f"inconsistent shapes: key_times {tuple(key_times.shape)}, pivots "
                             f"{tuple(pivots.shape)}, yaw {tuple(yaw.shape)}, shift {tuple(shift.shape)}")
        self.register_buffer("key_times", key_times.detach().clone())
        self.register_buffer("pivots", pivots.detach().clone())
        self.yaw = nn.Parameter(yaw.detach().clone())
        self.shift = nn.Parameter(shift.detach().clone())

    def __len__(self) -> int:
        return int(self.yaw.shape[0])

    def pose_at(self, time: float) -> tuple[Tensor, Tensor]:
        """Every actor's (A,) yaw and (A, 3) shift at normalised ``time``."""
        lower, upper, w = interpolation_weights(self.key_times, time)
        yaw = (1.0 - w) * self.yaw[:, lower] + w * self.yaw[:, upper]
        shift = (1.0 - w) * self.shift[:, lower] + w * self.shift[:, upper]
        return yaw, shift

    def forward(self, means: Tensor, quats: Tensor, actor: Tensor, time: float) -> tuple[Tensor, Tensor]:
        """(N, 3) ``means`` (positions at each actor's reference time) and (N, 4) unit ``quats`` of
        Gaussians of (N,) ``actor`` indices in [0, A), moved to normalised ``time``."""
        yaw, shift = self.pose_at(time)
        yaw_i, pivot_i = yaw[actor], self.pivots[actor]
        cos, sin = torch.cos(yaw_i), torch.sin(yaw_i)
        local = means - pivot_i
        turned = torch.stack([cos * local[:, 0] - sin * local[:, 1], sin * local[:, 0] + cos * local[:, 1],
                              local[:, 2]], dim=-1)
        return turned + pivot_i + shift[actor], quaternion_product(yaw_quaternions(yaw_i), quats)

    def acceleration(self) -> Tensor:
        """Mean squared change of velocity between consecutive key intervals, shift (metres) and yaw
        (radians), each velocity taken over the mean key spacing: the departure from constant
        velocity per key, which a per-key pose fitted to its own image alone does not pay for; 0
        with fewer than 3 keys."""
        if self.key_times.numel() < 3:
            return self.shift.sum() * 0.0
        spacing = (self.key_times[1:] - self.key_times[:-1]).clamp_min(1e-9)
        step = spacing / spacing.mean()
        shift_rate = (self.shift[:, 1:] - self.shift[:, :-1]) / step[None, :, None]
        yaw_rate = (self.yaw[:, 1:] - self.yaw[:, :-1]) / step[None]
        return ((shift_rate[:, 1:] - shift_rate[:, :-1]) ** 2).sum(-1).mean() + \
            ((yaw_rate[:, 1:] - yaw_rate[:, :-1]) ** 2).mean()

    def heading_mismatch(self, unit_seconds: float, min_speed: float = HEADING_MIN_SPEED) -> Tensor:
        """Weighted mean squared difference (rad²) between each actor's turn and the turn of its path: the
        yaw change from the middle of one key interval to the middle of the next, ``(yaw[k+1] - yaw[k-1]) / 2``,
        against the change in direction of its pivot's travel over the two intervals (a road vehicle points
        where it goes; changes, not directions, so a constant sideslip of its centroid costs nothing). Pairs
        of intervals travelled slower than ``min_speed`` m/s count in proportion to their slower speed (a
        still body's path has no direction); ``unit_seconds``: seconds per unit of normalised time. The
        path is held fixed here (detached): the images place a body far better than they turn it. 0 with
        fewer than 3 keys."""
        if self.key_times.numel() < 3:
            return self.yaw.sum() * 0.0
        step = (self.shift[:, 1:, :2] - self.shift[:, :-1, :2]).detach()
        direction = torch.atan2(step[..., 1], step[..., 0])
        path_turn = direction[:, 1:] - direction[:, :-1]
        path_turn = torch.atan2(torch.sin(path_turn), torch.cos(path_turn))
        seconds = (self.key_times[1:] - self.key_times[:-1]).clamp_min(1e-9) * unit_seconds
        speed = step.norm(dim=-1) / seconds
        weight = (torch.minimum(speed[:, 1:], speed[:, :-1]) / max(min_speed, 1e-9)).clamp(max=1.0)
        yaw_turn = 0.5 * (self.yaw[:, 2:] - self.yaw[:, :-2])
        return (weight * (yaw_turn - path_turn) ** 2).sum() / weight.sum().clamp_min(1.0)

    def param_groups(self, lr: float) -> list[dict[str, Any]]:
        return [{"params": [self.yaw, self.shift], "lr": lr, "name": "actors"}]

    def state(self) -> dict[str, Tensor]:
        return {"key_times": self.key_times.cpu(), "pivots": self.pivots.cpu(), "yaw": self.yaw.detach().cpu(),
                "shift": self.shift.detach().cpu()}

    @classmethod
    def from_state(cls, state: Mapping[str, Tensor], device: torch.device | str = "cpu",
                   dtype: torch.dtype = torch.float32) -> "ActorMotion":
        return cls(*(state[k].to(device=device, dtype=dtype) for k in ("key_times", "pivots", "yaw", "shift")))
