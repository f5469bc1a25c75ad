"""The baselines' motion models, inside the same trainer as the full method (issue 10).

Written here: they are the compared papers' models (Deformable-GS, PVG, AD-GS), re-implemented in
the form this trainer needs, not libraries.

- ``deformable`` (Deformable-GS, Yang et al. 2024): one MLP ``f(gamma(x), gamma(t)) -> dx`` moves
  every Gaussian; not invertible, no flow or radar supervision, no static/dynamic split.
- ``pvg`` (Periodic Vibration Gaussians, Chen et al. 2023): every Gaussian vibrates around its mean,
  ``mu(t) = mu + v * l / (2 pi) * sin(2 pi (t - tau) / l)``, and is visible around its life peak,
  ``o(t) = o * exp(-0.5 ((t - tau) / beta)^2)``; static parts learn ``v -> 0`` and a long ``beta``.
- ``bspline`` (AD-GS style, Xu et al. 2025): the Gaussians of the masked (dynamic) pixels move on
  per-Gaussian uniform cubic B-spline trajectories ``mu(t) = mu + sum_k B_k(t) c_k`` and are
  visible around the frame they were seen in (as PVG's life span), since each frame's points of a
  moving car start where that frame saw it. AD-GS's trigonometric local term is left out.

Per-Gaussian motion parameters live in the :class:`~radar4dgs.model.gaussians.GaussianSet` beside
the appearance, so densification clones, splits and prunes them with their Gaussian.
"""

from __future__ import annotations

import math

import numpy as np
import torch
from torch import Tensor, nn

from radar4dgs.model.config import BaselineConfig

# --------------------------------------------------------------------------------------------
# PVG


def pvg_means(means: Tensor, velocity: Tensor, tau: Tensor, time: float, period: float) -> Tensor:
    """(N, 3) vibrating positions ``mu + v l / (2 pi) sin(2 pi (t - tau) / l)``; ``means`` and
    ``velocity`` (N, 3), ``tau`` (N,). Near the life peak the Gaussian moves at velocity ``v``."""
    phase = 2.0 * math.pi * (time - tau) / period
    return means + velocity * (period / (2.0 * math.pi)) * torch.sin(phase)[:, None]


def temporal_visibility(tau: Tensor, log_lifespan: Tensor, time: float, flat: float = 0.0) -> Tensor:
    """(N,) ``exp(-0.5 (max(0, |t - tau| - flat) / beta)^2)`` with ``beta = exp(log_lifespan)``: fully
    visible within ``flat`` (normalised time) of the life peak ``tau``, Gaussian beyond."""
    return torch.exp(-0.5 * (((time - tau).abs() - flat).clamp_min(0.0) / torch.exp(log_lifespan)) ** 2)


# --------------------------------------------------------------------------------------------
# B-spline trajectories


def bspline_weights(time: float, count: int, dtype: torch.dtype = torch.float32,
                    device: torch.device | str = "cpu") -> Tensor:
    """(count,) weights of a uniform cubic B-spline with ``count`` control points spread over
    t in [0, 1] (the curve is defined on ``count - 3`` spans); they are >= 0 and sum to 1."""
    spans = count - 3
    x = min(max(float(time), 0.0), 1.0) * spans
    span = min(int(math.floor(x)), spans - 1)
    u = x - span
    local = torch.tensor([(1 - u) ** 3, 3 * u ** 3 - 6 * u ** 2 + 4, -3 * u ** 3 + 3 * u ** 2 + 3 * u + 1, u ** 3],
                         dtype=dtype, device=device) / 6.0
    weights = torch.zeros(count, dtype=dtype, device=device)
    weights[span:span + 4] = local
    return weights


def bspline_means(means: Tensor, control: Tensor, time: float) -> Tensor:
    """(N, 3) ``mu + sum_k B_k(t) c_k`` for ``control`` (N, K, 3) offsets."""
    weights = bspline_weights(time, control.shape[1], control.dtype, control.device)
    return means + torch.einsum("k,nkc->nc", weights, control)


# --------------------------------------------------------------------------------------------
# Deformable-GS offsets


def fourier_features(x: Tensor, frequencies: int) -> Tensor:
    """(..., D * (1 + 2F)) ``[x, sin(2^k pi x), cos(2^k pi x)]`` for k < F."""
    if frequencies <= 0:
        return x
    scales = (2.0 ** torch.arange(frequencies, dtype=x.dtype, device=x.device)) * math.pi
    angles = x[..., None] * scales
    return torch.cat([x, torch.sin(angles).flatten(-2), torch.cos(angles).flatten(-2)], dim=-1)


class OffsetField(nn.Module):
    """``dx = MLP(gamma(normalise(x)), gamma(t))`` (metres): Deformable-GS's time-conditioned offsets
    of every Gaussian. The last layer starts at zero, so an untrained field moves nothing."""

    def __init__(self, config: BaselineConfig, centre: np.ndarray | None = None, scale: float = 1.0):
        super().__init__()
        self.space_frequencies = config.offset_space_frequencies
        self.time_frequencies = config.offset_time_frequencies
        inputs = 3 * (1 + 2 * self.space_frequencies) + (1 + 2 * self.time_frequencies)
        layers: list[nn.Module] = []
        width = inputs
        for _ in range(config.offset_layers):
            layers += [nn.Linear(width, config.offset_hidden), nn.ReLU()]
            width = config.offset_hidden
        last = nn.Linear(width, 3)
        nn.init.zeros_(last.weight)
        nn.init.zeros_(last.bias)
        self.mlp = nn.Sequential(*layers, last)
        # The scene's region maps to about [-1, 1]^3, so the Fourier frequencies mean the same in any
        # scene. Offsets come out in metres, as Deformable-GS's: scaling them by the region's size
        # (~100 m with the far background) made every weight step move the near scene by metres.
        self.register_buffer("centre", torch.as_tensor(np.zeros(3) if centre is None else centre,
                                                       dtype=torch.float32).reshape(3))
        self.register_buffer("scale", torch.tensor(float(scale), dtype=torch.float32))

    def forward(self, means: Tensor, time: float) -> Tensor:
        """(N, 3) offsets of (N, 3) world ``means`` at normalised ``time``."""
        x = (means - self.centre) / self.scale
        t = torch.full((means.shape[0], 1), float(time), dtype=means.dtype, device=means.device)
        features = torch.cat([fourier_features(x, self.space_frequencies),
                              fourier_features(t, self.time_frequencies)], dim=-1)
        return self.mlp(features)
