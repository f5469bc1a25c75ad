"""The supervision terms of the deformation field (DESIGN.md stage 6, and a velocity term), as
functions the trainer and the standalone fit call.

- ``L_flow = mean_n |D_tj(D_ti^-1(x_i)) - x_j|^2``: pseudo scene flow pairs (x_i at t_i, x_j at
  t_j) must be carried onto each other. Squared Euclidean norm (m^2) per pair.
- ``L_rad = mean_n |F . (x - A) / |x - A| - v_r dt|``: F = D_tj(D_ti^-1(x)) - x, the predicted
  displacement of the point x of time t_i over dt = (timestamp_j - timestamp_i) seconds (a world
  vector: the world frame is the same at every time, so "the frame of time i" is just the start
  point x of the displacement); A the radar centre (world) at time i; v_r the compensated radial
  velocity of the associated radar point (m/s, positive receding). Absolute value (m) per point.
- ``L_vel = mean_n huber(r_n)``, ``r = sqrt(e^T (S dt^2 + s0^2 I)^-1 e)``, ``e = F_xy - v_xy dt``: the
  full planar velocity ``v`` of a radar object (covariance ``S``, m^2/s^2) carried over dt must match
  the displacement F of the object's points (an addition to the paper, issue 21: where optical flow
  is missing or rejected, Doppler alone cannot see motion across the line of sight). ``r`` is a
  Mahalanobis distance (in standard deviations, dimensionless); ``s0`` (m) floors the uncertainty,
  for what the velocity does not model (a turning car's ``omega x r dt``, the field's smoothness).
  Huber, so a wrongly tracked object pulls with a bounded force. F_z is left free (``v_z = 0`` is
  an assumption of the radar fit, not a measurement).

Reduction: the paper writes sums; we return means over the (valid) points by default, so the loss
weights do not depend on how many points or Gaussians a batch holds (``reduction="sum"`` gives the
paper's form). Each function has a pure residual form (tensors in, per-point residuals out) for
hand-checkable tests, and a field form that evaluates the field.

Also the per-pixel terms of the trainer's image supervision: :func:`inverse_depth_l1` against the
radar-scaled depth, :func:`binary_cross_entropy` of a rendered probability (opacity, dynamic
share) against a mask, and :func:`static_over_movers`, the static Gaussians drawn over moving objects.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Literal

import torch
import torch.nn.functional as F
from torch import Tensor

from radar4dgs.model.field import DeformationField

Reduction = Literal["mean", "sum", "none"]


def _reduce(values: Tensor, weight: Tensor | None, reduction: Reduction) -> Tensor:
    if weight is not None:
        values = values * weight
    if reduction == "none":
        return values
    if reduction == "sum":
        return values.sum()
    if reduction == "mean":
        if values.numel() == 0:
            return values.sum()  # 0, still attached to the graph
        denominator = weight.sum().clamp_min(1e-12) if weight is not None else values.numel()
        return values.sum() / denominator
    raise ValueError(f"unknown reduction {reduction!r}; choose 'mean', 'sum' or 'none'")


def flow_residual(predicted_j: Tensor, x_j: Tensor) -> Tensor:
    """(N,) squared distances ``|predicted_j - x_j|^2`` between (N, 3) warped points and targets."""
    return ((predicted_j - x_j) ** 2).sum(dim=-1)


def radar_residual(displacement: Tensor, x: Tensor, centre: Tensor, v_r: Tensor, dt: Tensor | float) -> Tensor:
    """(N,) ``|F . (x - A) / |x - A| - v_r dt|``.

    Args:
        displacement: (N, 3) predicted displacement F over dt (m).
        x: (N, 3) the points at time i (world); centre: (3,) or (N, 3) radar centre A (world).
        v_r: (N,) compensated radial velocity (m/s); dt: scalar or (N,) seconds.
    """
    direction = x - centre
    direction = direction / direction.norm(dim=-1, keepdim=True).clamp_min(1e-9)
    return ((displacement * direction).sum(dim=-1) - v_r * dt).abs()


def huber_of_squared(squared: Tensor, delta: float) -> Tensor:
    """(N,) Huber of ``r = sqrt(squared)``: ``r^2 / 2`` for ``r <= delta``, ``delta (r - delta / 2)``
    beyond. Takes ``r^2`` so the quadratic branch needs no square root (whose gradient at 0 is NaN)."""
    root = squared.clamp_min(delta * delta).sqrt()  # only used where squared > delta^2
    return torch.where(squared <= delta * delta, 0.5 * squared, delta * (root - 0.5 * delta))


def velocity_squared_residual(displacement: Tensor, velocity: Tensor, covariance: Tensor, dt: Tensor | float,
                              position_std: float) -> Tensor:
    """(N,) ``r^2 = e^T (S dt^2 + s0^2 I)^-1 e`` with ``e = F_xy - v_xy dt`` (module doc).

    Args:
        displacement: (N, 3) predicted displacement F over dt (m); its z is not used.
        velocity: (N, 2) or (N, 3) object velocity (world, m/s); only x, y are used.
        covariance: (N, 2, 2) covariance S of the planar velocity (m^2/s^2).
        dt: scalar or (N,) seconds; position_std: s0 (m), > 0.
    """
    dt = torch.as_tensor(dt, dtype=displacement.dtype, device=displacement.device).expand(len(displacement))
    e = displacement[:, :2] - velocity[:, :2] * dt[:, None]  # (N, 2)
    c = covariance * (dt * dt)[:, None, None]  # (N, 2, 2) position covariance of v dt
    a, b = c[:, 0, 0] + position_std ** 2, c[:, 0, 1]
    b2, d = c[:, 1, 0], c[:, 1, 1] + position_std ** 2
    # Closed-form inverse of the 2x2 C = [[a, b], [b2, d]] (S symmetric: b = b2).
    det = (a * d - b * b2).clamp_min(1e-30)
    return (d * e[:, 0] ** 2 - (b + b2) * e[:, 0] * e[:, 1] + a * e[:, 1] ** 2) / det


def velocity_residual(displacement: Tensor, velocity: Tensor, covariance: Tensor, dt: Tensor | float,
                      position_std: float) -> Tensor:
    """(N,) Mahalanobis planar distance ``r`` (standard deviations); arguments as
    :func:`velocity_squared_residual`."""
    return velocity_squared_residual(displacement, velocity, covariance, dt, position_std).sqrt()


def flow_loss(field: DeformationField, x_i: Tensor, x_j: Tensor, t_i: Tensor | float, t_j: Tensor | float,
              weight: Tensor | None = None, reduction: Reduction = "mean") -> Tensor:
    """``L_flow`` for (N, 3) point pairs ``x_i`` (time ``t_i``) -> ``x_j`` (time ``t_j``); times
    scalar or (N,) in [0, 1]; optional (N,) ``weight``. Mean (default) is the weighted mean."""
    return _reduce(flow_residual(field.warp(x_i, t_i, t_j), x_j), weight, reduction)


def acceleration_residual(before: Tensor, at: Tensor, after: Tensor) -> Tensor:
    """(N,) squared second differences ``|after - 2 at + before|^2`` of (N, 3) positions one step apart."""
    return ((after - 2.0 * at + before) ** 2).sum(dim=-1)


def acceleration_loss(field: DeformationField, x: Tensor, t_x: Tensor | float, t: Tensor | float,
                      step: float, weight: Tensor | None = None, reduction: Reduction = "mean") -> Tensor:
    """``L_acc`` (m^2): the squared second difference of the field's paths of (N, 3) points ``x`` (seen at
    ``t_x``) around time(s) ``t``, ``|D_{t+h}(c) - 2 D_t(c) + D_{t-h}(c)|^2`` with ``c = D_{t_x}^-1(x)`` and
    ``h = step`` (normalised time). Zero for constant velocity, so where no flow or radar reaches (a car
    about to leave the view, the times between training frames) the field carries on straight."""
    canonical = field.inverse(x, t_x)
    t = torch.as_tensor(t, dtype=x.dtype, device=x.device)
    path = [field.forward(canonical, t + offset) for offset in (-step, 0.0, step)]
    return _reduce(acceleration_residual(*path), weight, reduction)


def radar_loss(field: DeformationField, x: Tensor, t_i: Tensor | float, t_j: Tensor | float,
               dt: Tensor | float, centre: Tensor, v_r: Tensor, weight: Tensor | None = None,
               reduction: Reduction = "mean") -> Tensor:
    """``L_rad`` for (N, 3) points ``x`` at time ``t_i``, displaced to ``t_j``.

    Args:
        dt: seconds between the two times (scalar or (N,)); centre: (3,) or (N, 3) radar centre
        at time i; v_r: (N,) associated compensated radial velocity, NaN = unmatched (excluded,
        as if its weight were 0).
    """
    matched = torch.isfinite(v_r)
    if not bool(matched.all()):
        def per_point(value, ndim):  # select matched rows of per-point inputs, keep shared ones
            return value[matched] if torch.is_tensor(value) and value.ndim == ndim else value
        x, centre, v_r = x[matched], per_point(centre, 2), v_r[matched]
        t_i, t_j, dt, weight = (per_point(v, 1) for v in (t_i, t_j, dt, weight))
    residual = radar_residual(field.displacement(x, t_i, t_j), x, centre, v_r, dt)
    return _reduce(residual, weight, reduction)


def velocity_loss(field: DeformationField, x: Tensor, t_i: Tensor | float, t_j: Tensor | float,
                  dt: Tensor | float, velocity: Tensor, covariance: Tensor, position_std: float = 0.05,
                  huber: float = 1.0, weight: Tensor | None = None, reduction: Reduction = "mean") -> Tensor:
    """``L_vel`` for (N, 3) points ``x`` at time ``t_i`` displaced to ``t_j`` over ``dt`` seconds.

    Args:
        velocity: (N, 2) or (N, 3) their object's world velocity (m/s); covariance: (N, 2, 2) its
        planar covariance; position_std: s0 (m); huber: the Huber threshold on ``r`` (standard
        deviations); weight: optional (N,).
    """
    squared = velocity_squared_residual(field.displacement(x, t_i, t_j), velocity, covariance, dt, position_std)
    return _reduce(huber_of_squared(squared, huber), weight, reduction)


def binary_cross_entropy(probability: Tensor, target: Tensor) -> Tensor:
    """Mean BCE of probabilities (clamped away from 0 and 1) against a bool/float target."""
    return F.binary_cross_entropy(probability.clamp(1e-4, 1 - 1e-4), target.to(probability.dtype))


def _transformed_depth_l1(rendered: Tensor, alpha: Tensor, target: Tensor, valid: Tensor,
                          transform: Callable[[Tensor], Tensor]) -> Tensor:
    """Mean ``|transform(d_rendered) - transform(d_target)|`` over ``valid`` pixels with finite
    positive target depth and some rendered opacity; 0 when there is none. All (H, W)."""
    valid = valid & torch.isfinite(target) & (target > 0) & (alpha > 0.05)
    if not bool(valid.any()):
        return rendered.sum() * 0.0
    return (transform(rendered[valid].clamp_min(0.1)) - transform(target[valid])).abs().mean()


def inverse_depth_l1(rendered: Tensor, alpha: Tensor, target: Tensor, valid: Tensor) -> Tensor:
    """Mean ``|1 / d_rendered - 1 / d_target|`` (see :func:`_transformed_depth_l1`). All (H, W)."""
    return _transformed_depth_l1(rendered, alpha, target, valid, torch.reciprocal)


def log_depth_l1(rendered: Tensor, alpha: Tensor, target: Tensor, valid: Tensor) -> Tensor:
    """Mean ``|log d_rendered - log d_target|`` (see :func:`_transformed_depth_l1`): scale-free, so a
    far object drawn 20 % too deep costs as much as a near one, where the inverse depth's cost
    falls with the distance (and its gradient in depth with the distance squared). All (H, W)."""
    return _transformed_depth_l1(rendered, alpha, target, valid, torch.log)


# Where a Gaussian's footprint is probed: its projected centre and one standard deviation along
# each image axis (the rasterizer's radii are about 3 sigma).
_FOOTPRINT_PROBES = ((0.0, 0.0), (1.0, 0.0), (-1.0, 0.0), (0.0, 1.0), (0.0, -1.0))


def movers_covered(means2d: Tensor, radii: Tensor, depths: Tensor, mask: Tensor, surface_depth: Tensor,
                   margin: float) -> Tensor:
    """(N,) ``a_g``, not differentiated: an estimate of the pixels of each Gaussian's 2-sigma box that lie
    on ``mask`` where the Gaussian is nearer than ``surface_depth * (1 - margin)``, from five probes (its
    centre and +-1 sigma along u and v): the probes that hit, a fifth of the box each, at most the
    mask's pixel count (a Gaussian larger than the mover covers at most the mover).

    means2d (N, 2) px, radii (N, 2) or (N,) px (0 = culled), depths (N,) camera z (m), mask (H, W)
    bool, surface_depth (H, W) m (NaN = unknown: never hit)."""
    height, width = mask.shape
    radii = radii if radii.dim() == 2 else radii[:, None].expand(-1, 2)
    sigma = radii.to(means2d.dtype) / 3.0
    centres, near = means2d.detach(), depths.detach()
    drawn = radii.max(dim=1).values > 0
    hits = torch.zeros(len(near), dtype=means2d.dtype, device=means2d.device)
    for du, dv in _FOOTPRINT_PROBES:
        u = torch.floor(centres[:, 0] + du * sigma[:, 0]).long()
        v = torch.floor(centres[:, 1] + dv * sigma[:, 1]).long()
        inside = drawn & (u >= 0) & (u < width) & (v >= 0) & (v < height)
        u, v = u.clamp(0, width - 1), v.clamp(0, height - 1)
        hit = inside & mask[v, u] & (near < surface_depth[v, u] * (1.0 - margin))  # NaN surface compares False
        hits = hits + hit.to(hits.dtype)
    return (hits / len(_FOOTPRINT_PROBES) * 4.0 * sigma[:, 0] * sigma[:, 1]).clamp(max=float(mask.sum()))


def static_over_movers(means2d: Tensor, radii: Tensor, depths: Tensor, opacities: Tensor, mask: Tensor,
                       surface_depth: Tensor, margin: float) -> Tensor:
    """``sum_g opacity_g * a_g / (H W)``: the moving-object pixels that static Gaussians are drawn over
    from in front, ``a_g`` from :func:`movers_covered` (same arguments); ``opacities`` (N,), the
    rasterized ones, is the only input differentiated. Returns a scalar (0 with gradient when nothing is hit).

    Why: stage 1 leaves the moving pixels out of the image loss and stage 2 freezes the static set, so
    until stage 3 (never, with TrainConfig.static_outside_masks) nothing keeps a road Gaussian just in
    front of a car from spreading its footprint over the car's lower part; sorted first, it hides the
    car (issue 21: a fifth to a third of the composite on the cars' lower third in trained runs)."""
    height, width = mask.shape
    return (opacities * movers_covered(means2d, radii, depths, mask, surface_depth, margin)).sum() / (height * width)
