"""The VGPT deformation field: an invertible, time-conditioned map ``D_t: R^3 -> R^3``.

Canonical dynamic Gaussians ``x_c`` are moved to time ``t`` by ``x_t = D_t(x_c)``; an observed point
of time ``t_i`` goes back to the canonical space by the exact inverse ``x_c = D_t_i^-1(x_t_i)``, and
``warp(x, t_i, t_j) = D_t_j(D_t_i^-1(x))`` carries a point from one time to another.

Construction (OmniMotion, Wang et al. ICCV 2023, after Real-NVP, Dinh et al. ICLR 2017): a stack of
affine coupling layers. Layer ``l`` changes ONE coordinate ``k = l mod 3`` as

    y_k = x_k * exp(s) + b,    (s, b) = MLP(gamma(x_a, x_b), tau(t))

where ``a, b`` are the other two coordinates (left unchanged, so the inverse sees the same
conditioning) and ``tau(t)`` is the time code. The inverse is ``x_k = (y_k - b) * exp(-s)``, run
from the last layer to the first: exact, not iterative, so the round trip is limited only by
rounding. ``s = m * tanh(raw / m)`` bounds the log-scale to (-m, m): an unbounded ``exp`` lets a
few bad steps make the layer nearly singular and the inverse explode.

Time code: deterministic Fourier features of t, ``[t, sin(2^k pi t), cos(2^k pi t)]`` for
k < ``time_frequencies``. We prefer them to a learned per-frame latent because (1) test frames
(every 4th, held out) and any novel time need a code, and Fourier features are defined for every
t in [0, 1] while per-frame latents would need ad-hoc interpolation; (2) they add no parameters
per frame, so the model does not grow with the sequence and cannot memorise a frame; (3) the
linear ``t`` term lets constant-velocity motion, the common case in driving, be represented
exactly by the MLP's linear part, and keeping only low frequencies (default: one, period 2)
makes the code interpolate well between training frames (see ``FieldConfig.time_frequencies``).

Coordinates are normalised by a stored affine map of the dynamic region (``centre``, per-axis
``scale`` buffers) to about [-1, 1]^3 before the couplings and mapped back after, so the same
network sizes work for a 10 m and a 100 m scene. The last linear layer of every coupling is zero,
so an untrained field is the identity and does not move points.
"""

from __future__ import annotations

import math
from typing import Any

import torch
from torch import Tensor, nn

from radar4dgs.model.config import FieldConfig


def fourier_features(values: Tensor, frequencies: int) -> Tensor:
    """``[v, sin(2^k pi v), cos(2^k pi v)]`` for k < ``frequencies``, per column.

    Args:
        values: (N, C).
    Returns:
        (N, C * (1 + 2 * frequencies)), same dtype and device.
    """
    if frequencies <= 0:
        return values
    scales = math.pi * (2.0 ** torch.arange(frequencies, dtype=values.dtype, device=values.device))
    angles = (values[..., None] * scales).flatten(-2)  # (N, C * F)
    return torch.cat([values, torch.sin(angles), torch.cos(angles)], dim=-1)


def time_code(t: Tensor | float, n: int, frequencies: int, dtype: torch.dtype, device: torch.device) -> Tensor:
    """The time code of ``n`` points.

    Args:
        t: a Python float, a 0-d tensor, or (n,) per-point times in [0, 1].
    Returns:
        (n, 1 + 2 * frequencies).
    """
    t = torch.as_tensor(t, dtype=dtype, device=device)
    if t.ndim == 0:
        t = t.expand(n)
    elif t.shape != (n,):
        raise ValueError(f"times must be a scalar or have shape ({n},), got {tuple(t.shape)}")
    return fourier_features(t[:, None], frequencies)


class CouplingLayer(nn.Module):
    """Changes coordinate ``axis`` affinely, conditioned on the other two and the time code."""

    def __init__(self, axis: int, time_dim: int, config: FieldConfig):
        super().__init__()
        self.axis = axis
        self.others = [a for a in range(3) if a != axis]
        self.space_frequencies = config.space_frequencies
        self.max_log_scale = config.max_log_scale
        width = 2 * (1 + 2 * config.space_frequencies) + time_dim
        layers: list[nn.Module] = []
        for _ in range(config.hidden_layers):
            layers += [nn.Linear(width, config.hidden), nn.ReLU()]
            width = config.hidden
        self.last = nn.Linear(width, 2)
        self.mlp = nn.Sequential(*layers, self.last)
        # Zero last layer: s = 0, b = 0, the layer is the identity until trained.
        nn.init.zeros_(self.last.weight)
        nn.init.zeros_(self.last.bias)

    def scale_shift(self, x: Tensor, code: Tensor) -> tuple[Tensor, Tensor]:
        """(N,) log-scale s in (-m, m) and (N,) shift b, from the unchanged coordinates of ``x`` (N, 3)
        and the time code (N, T)."""
        condition = fourier_features(x[:, self.others], self.space_frequencies)
        raw = self.mlp(torch.cat([condition, code], dim=-1))
        m = self.max_log_scale
        s = m * torch.tanh(raw[:, 0] / m) if m > 0 else torch.zeros_like(raw[:, 0])
        return s, raw[:, 1]

    def _replace_axis(self, x: Tensor, value: Tensor) -> Tensor:
        # Out-of-place so autograd keeps the input intact.
        columns = [x[:, a] for a in range(3)]
        columns[self.axis] = value
        return torch.stack(columns, dim=1)

    def forward(self, x: Tensor, code: Tensor) -> Tensor:
        s, b = self.scale_shift(x, code)
        return self._replace_axis(x, x[:, self.axis] * torch.exp(s) + b)

    def inverse(self, y: Tensor, code: Tensor) -> Tensor:
        s, b = self.scale_shift(y, code)  # the conditioning coordinates are unchanged by forward
        return self._replace_axis(y, (y[:, self.axis] - b) * torch.exp(-s))


class DeformationField(nn.Module):
    """``D_t``: canonical space -> world at time t, with its exact inverse.

    Points are (N, 3) world coordinates (metres); times are a scalar or (N,) values in [0, 1]
    (``t = (timestamp - t_first) / (t_last - t_first)``, see ``radar4dgs.io.scene.normalized_times``).
    All methods are differentiable and work in the module's dtype (float32 or float64: call
    ``field.double()``); inputs of another dtype are refused rather than silently cast.
    """

    def __init__(self, config: FieldConfig | None = None):
        super().__init__()
        self.config = config or FieldConfig()
        time_dim = 1 + 2 * self.config.time_frequencies
        self.layers = nn.ModuleList(CouplingLayer(i % 3, time_dim, self.config)
                                    for i in range(self.config.num_layers))
        # Normalisation of the dynamic region: x_n = (x - centre) / scale. Buffers, so they follow
        # .to(dtype/device) and are saved in the state dict.
        self.register_buffer("centre", torch.zeros(3))
        self.register_buffer("scale", torch.ones(3))

    # ---- normalisation
    def set_normalization(self, centre: Tensor | Any, scale: Tensor | Any) -> None:
        """Store the affine normalisation: ``centre`` (3,), ``scale`` (3,) or scalar, metres."""
        centre = torch.as_tensor(centre, dtype=self.centre.dtype, device=self.centre.device).reshape(3)
        scale = torch.as_tensor(scale, dtype=self.scale.dtype, device=self.scale.device).expand(3).clone()
        if not torch.all(scale > 0):
            raise ValueError(f"normalisation scale must be positive, got {scale.tolist()}")
        self.centre.copy_(centre)
        self.scale.copy_(scale)

    def fit_normalization(self, points: Tensor | Any) -> None:
        """Set the normalisation to the bounding box of (N, 3) ``points`` (the dynamic region),
        grown by ``normalization_margin`` and with half-extents at least ``normalization_min_scale``."""
        centre, scale = normalization_from_points(points, self.config.normalization_margin,
                                                  self.config.normalization_min_scale)
        self.set_normalization(centre, scale)

    def _check(self, x: Tensor) -> None:
        if x.ndim != 2 or x.shape[1] != 3:
            raise ValueError(f"points must have shape (N, 3), got {tuple(x.shape)}")
        if x.dtype != self.centre.dtype:
            raise TypeError(f"points are {x.dtype} but the field is {self.centre.dtype}; "
                            f"convert one of them (field.to(dtype))")

    # ---- maps
    def forward(self, x: Tensor, t: Tensor | float) -> Tensor:
        """``D_t(x)``: (N, 3) canonical points -> (N, 3) points at time(s) ``t``."""
        self._check(x)
        code = time_code(t, x.shape[0], self.config.time_frequencies, x.dtype, x.device)
        y = (x - self.centre) / self.scale
        for layer in self.layers:
            y = layer(y, code)
        return y * self.scale + self.centre

    def inverse(self, y: Tensor, t: Tensor | float) -> Tensor:
        """``D_t^-1(y)``: (N, 3) points at time(s) ``t`` -> (N, 3) canonical points (exact)."""
        self._check(y)
        code = time_code(t, y.shape[0], self.config.time_frequencies, y.dtype, y.device)
        x = (y - self.centre) / self.scale
        for layer in reversed(self.layers):
            x = layer.inverse(x, code)
        return x * self.scale + self.centre

    def warp(self, x: Tensor, t_from: Tensor | float, t_to: Tensor | float) -> Tensor:
        """``D_t_to(D_t_from^-1(x))``: (N, 3) points at ``t_from`` -> the same material points at ``t_to``."""
        return self.forward(self.inverse(x, t_from), t_to)

    def displacement(self, x: Tensor, t_from: Tensor | float, t_to: Tensor | float) -> Tensor:
        """(N, 3) predicted displacement ``warp(x, t_from, t_to) - x`` (metres)."""
        return self.warp(x, t_from, t_to) - x


def normalization_from_points(points: Tensor | Any, margin: float = 0.1,
                              min_scale: float = 1.0) -> tuple[Tensor, Tensor]:
    """Centre (3,) and per-axis half-extent (3,) of the bounding box of (N, 3) ``points``.

    Non-finite rows are ignored; with no finite point the result is (0, min_scale).
    """
    points = torch.as_tensor(points, dtype=torch.float64).reshape(-1, 3)
    points = points[torch.isfinite(points).all(dim=1)]
    if len(points) == 0:
        return torch.zeros(3, dtype=torch.float64), torch.full((3,), float(min_scale), dtype=torch.float64)
    low, high = points.min(dim=0).values, points.max(dim=0).values
    centre = (low + high) / 2
    scale = torch.clamp((high - low) / 2 * (1 + margin), min=min_scale)
    return centre, scale


def randomize_(field: DeformationField, last_std: float = 0.1,
               generator: torch.Generator | None = None) -> DeformationField:
    """Give ``field`` random weights, for tests and benchmarks of invertibility away from the
    identity: hidden layers get PyTorch's default (Kaiming-uniform) initialisation, the zero last
    layers N(0, ``last_std``^2), so each layer moves its coordinate by about ``last_std``
    normalised units (a few metres in a driving scene). Returns ``field``."""
    with torch.no_grad():
        for layer in field.layers:
            for module in layer.mlp:
                if isinstance(module, nn.Linear):
                    bound = 1.0 / math.sqrt(module.in_features)
                    for parameter in (module.weight, module.bias):
                        noise = torch.rand(parameter.shape, generator=generator, dtype=torch.float64)
                        value = (2 * noise - 1) * bound
                        if module is layer.last:
                            value = torch.randn(parameter.shape, generator=generator,
                                                dtype=torch.float64) * last_std
                        parameter.copy_(value.to(parameter.dtype))
    return field
