"""L_flow, L_rad and L_vel against hand-computed cases (a field that is a known translation, two points)."""

from __future__ import annotations

import math

import pytest
import torch

from radar4dgs.metrics.losses import (
    binary_cross_entropy,
    flow_loss,
    flow_residual,
    huber_of_squared,
    inverse_depth_l1,
    log_depth_l1,
    radar_loss,
    radar_residual,
    static_over_movers,
    velocity_loss,
    velocity_residual,
)
from radar4dgs.model.field import DeformationField, FieldConfig
from radar4dgs.train.fit_motion import torch_threads

# Tiny tensors: on the shared 2-core CI machine extra torch threads only spin.
pytestmark = pytest.mark.usefixtures("one_torch_thread")


class Translation(DeformationField):
    """D_t(x) = x + t * v: a known motion with a closed-form warp, warp(x, ti, tj) = x + (tj - ti) v."""

    def __init__(self, velocity):
        super().__init__(FieldConfig(num_layers=1, hidden=4, hidden_layers=1, time_frequencies=0,
                                     space_frequencies=0))
        self.register_buffer("velocity", torch.as_tensor(velocity, dtype=torch.float64))

    def forward(self, x, t):
        t = torch.as_tensor(t, dtype=x.dtype)
        return x + (t[..., None] if t.ndim else t) * self.velocity

    def inverse(self, y, t):
        t = torch.as_tensor(t, dtype=y.dtype)
        return y - (t[..., None] if t.ndim else t) * self.velocity


def test_flow_loss_hand_computed_translation():
    field = Translation([2.0, 0.0, 0.0]).double()
    x_i = torch.tensor([[0.0, 0.0, 0.0], [1.0, 1.0, 1.0]], dtype=torch.float64)
    # warp over t 0.25 -> 0.75 moves by 0.5 * (2, 0, 0) = (1, 0, 0).
    x_j = torch.tensor([[1.0, 0.0, 0.0], [2.0, 3.0, 1.0]], dtype=torch.float64)
    # residuals: |(1,0,0)-(1,0,0)|^2 = 0 and |(2,1,1)-(2,3,1)|^2 = 4
    assert flow_loss(field, x_i, x_j, 0.25, 0.75).item() == pytest.approx(2.0)
    assert flow_loss(field, x_i, x_j, 0.25, 0.75, reduction="sum").item() == pytest.approx(4.0)
    assert flow_loss(field, x_i, x_j, 0.25, 0.75, reduction="none").tolist() == pytest.approx([0.0, 4.0])
    weight = torch.tensor([1.0, 3.0], dtype=torch.float64)
    assert flow_loss(field, x_i, x_j, 0.25, 0.75, weight=weight).item() == pytest.approx(12.0 / 4.0)
    # per-point times: second point warped 0 -> 1 moves by (2, 0, 0): |(3,1,1)-(2,3,1)|^2 = 5
    times_i = torch.tensor([0.25, 0.0], dtype=torch.float64)
    times_j = torch.tensor([0.75, 1.0], dtype=torch.float64)
    assert flow_loss(field, x_i, x_j, times_i, times_j, reduction="none").tolist() == pytest.approx([0.0, 5.0])


def test_radar_loss_hand_computed_translation():
    # Radar at A = (0, 0, 0); velocity (10, 0, 0) m/s over a scene of 2 s, so t 0.0 -> 0.05 is
    # dt = 0.1 s and a displacement F = (1, 0, 0) m.
    field = Translation([20.0, 0.0, 0.0]).double()
    x = torch.tensor([[10.0, 0.0, 0.0], [3.0, 4.0, 0.0]], dtype=torch.float64)
    centre = torch.zeros(3, dtype=torch.float64)
    v_r = torch.tensor([10.0, 5.0], dtype=torch.float64)
    # point 1: direction (1,0,0), F.u = 1, v_r dt = 1 -> 0
    # point 2: direction (0.6,0.8,0), F.u = 0.6, v_r dt = 0.5 -> 0.1
    loss = radar_loss(field, x, 0.0, 0.05, 0.1, centre, v_r, reduction="none")
    assert loss.tolist() == pytest.approx([0.0, 0.1])
    assert radar_loss(field, x, 0.0, 0.05, 0.1, centre, v_r).item() == pytest.approx(0.05)
    # Unmatched points (NaN velocity) are excluded, not counted as zero.
    v_r_nan = torch.tensor([float("nan"), 5.0], dtype=torch.float64)
    assert radar_loss(field, x, 0.0, 0.05, 0.1, centre, v_r_nan).item() == pytest.approx(0.1)
    # Per-point centres: radar at (3, 0, 0) sees point 2 straight across (u = (0,1,0)): F.u = 0 -> |0 - 0.5|
    centres = torch.tensor([[0.0, 0.0, 0.0], [3.0, 0.0, 0.0]], dtype=torch.float64)
    assert radar_loss(field, x, 0.0, 0.05, 0.1, centres, v_r, reduction="none").tolist() == pytest.approx([0.0, 0.5])


def test_residuals_directly():
    assert flow_residual(torch.tensor([[1.0, 2.0, 2.0]]), torch.zeros(1, 3)).item() == pytest.approx(9.0)
    displacement = torch.tensor([[0.0, 1.0, 0.0]])
    x = torch.tensor([[0.0, 2.0, 0.0]])
    # receding at 1 m/s for 0.5 s = 0.5 m; predicted 1 m along the line of sight -> 0.5
    assert radar_residual(displacement, x, torch.zeros(3), torch.tensor([1.0]), 0.5).item() == pytest.approx(0.5)
    # approaching (negative v_r) with a displacement away from the radar: |1 - (-0.5)| = 1.5
    assert radar_residual(displacement, x, torch.zeros(3), torch.tensor([-1.0]), 0.5).item() == pytest.approx(1.5)


def test_velocity_residual_closed_forms():
    # Isotropic: S = 0, s0 = 0.1 m; v dt = (2, 0) * 0.5 = (1, 0); F = (1.3, 0.4, 5): e = (0.3, 0.4),
    # |e| = 0.5 m = 5 sigma. F_z = 5 m is free (not part of the residual).
    F = torch.tensor([[1.3, 0.4, 5.0]], dtype=torch.float64)
    v = torch.tensor([[2.0, 0.0, 0.0]], dtype=torch.float64)
    zero = torch.zeros(1, 2, 2, dtype=torch.float64)
    assert velocity_residual(F, v, zero, 0.5, 0.1).item() == pytest.approx(5.0)
    assert velocity_residual(F, v[:, :2], zero, torch.tensor([0.5], dtype=torch.float64), 0.1).item() \
        == pytest.approx(5.0)
    # Anisotropic: S = diag(4, 1) (m/s)^2, dt = 0.5 s -> S dt^2 = diag(1, 0.25) m^2; s0 -> 0;
    # e = (1, 0.5): r^2 = 1 / 1 + 0.25 / 0.25 = 2.
    S = torch.tensor([[[4.0, 0.0], [0.0, 1.0]]], dtype=torch.float64)
    F = torch.tensor([[1.0, 0.5, 0.0]], dtype=torch.float64)
    assert velocity_residual(F, torch.zeros(1, 2, dtype=torch.float64), S, 0.5, 1e-9).item() \
        == pytest.approx(math.sqrt(2.0))
    # A correlated covariance: the same error is cheap along the long axis of the ellipse and dear
    # across it. S = R diag(9, 0.01) R^T with R a 45 deg rotation, dt = 1, s0 = 0.
    R = torch.tensor([[1.0, -1.0], [1.0, 1.0]], dtype=torch.float64) / math.sqrt(2.0)
    S = (R @ torch.diag(torch.tensor([9.0, 0.01], dtype=torch.float64)) @ R.T)[None]
    along = torch.tensor([[3.0 / math.sqrt(2.0), 3.0 / math.sqrt(2.0), 0.0]], dtype=torch.float64)  # |e| 3, 1 sigma
    across = torch.tensor([[-0.1 / math.sqrt(2.0), 0.1 / math.sqrt(2.0), 0.0]], dtype=torch.float64)  # 0.1, 1 sigma
    zero_v = torch.zeros(1, 2, dtype=torch.float64)
    assert velocity_residual(along, zero_v, S, 1.0, 1e-9).item() == pytest.approx(1.0)
    assert velocity_residual(across, zero_v, S, 1.0, 1e-9).item() == pytest.approx(1.0)
    assert velocity_residual(3 * across, zero_v, S, 1.0, 1e-9).item() == pytest.approx(3.0)


def test_huber_of_squared_and_velocity_loss():
    squared = torch.tensor([0.0, 0.25, 4.0, 9.0], dtype=torch.float64, requires_grad=True)
    # delta 1: r = 0, 0.5 -> r^2 / 2 = 0, 0.125; r = 2, 3 -> r - 0.5 = 1.5, 2.5
    value = huber_of_squared(squared, 1.0)
    assert value.tolist() == pytest.approx([0.0, 0.125, 1.5, 2.5])
    value.sum().backward()
    assert torch.isfinite(squared.grad).all()  # no NaN from sqrt at r = 0
    # Translation (2, 0, 0) per unit t over t 0.25 -> 0.75: F = (1, 0, 0). Over dt = 1 s an object
    # velocity (1, 0) explains it (r = 0); (0, 0) leaves e = (1, 0), r = 1 / 0.5 = 2 -> Huber 1.5.
    field = Translation([2.0, 0.0, 0.0]).double()
    x = torch.zeros(2, 3, dtype=torch.float64)
    velocity = torch.tensor([[1.0, 0.0], [0.0, 0.0]], dtype=torch.float64)
    covariance = torch.zeros(2, 2, 2, dtype=torch.float64)
    per_point = velocity_loss(field, x, 0.25, 0.75, 1.0, velocity, covariance, position_std=0.5, huber=1.0,
                              reduction="none")
    assert per_point.tolist() == pytest.approx([0.0, 1.5])
    assert velocity_loss(field, x, 0.25, 0.75, 1.0, velocity, covariance, 0.5, 1.0).item() == pytest.approx(0.75)
    # A large velocity covariance makes the same error cheap: S dt^2 = 3.75 + s0^2 0.25 -> r = 0.5.
    loose = torch.eye(2, dtype=torch.float64).expand(2, 2, 2) * 3.75
    assert velocity_loss(field, x, 0.25, 0.75, 1.0, velocity, loose, 0.5, 1.0, reduction="none").tolist() \
        == pytest.approx([0.0, 0.125])


def test_losses_train_a_real_field_towards_a_translation():
    torch.manual_seed(0)
    field = DeformationField(FieldConfig(num_layers=3, hidden=16, hidden_layers=1, time_frequencies=1,
                                         space_frequencies=0))
    field.set_normalization([0.0, 0.0, 0.0], [5.0, 5.0, 5.0])
    optimizer = torch.optim.Adam(field.parameters(), lr=1e-2)
    x = torch.rand(256, 3) * 4 - 2
    velocity = torch.tensor([1.0, 0.5, 0.0])
    first = None
    with torch_threads(1):  # tiny matmuls: one thread is fastest on a busy machine
        for _ in range(100):
            loss = flow_loss(field, x, x + 0.5 * velocity, 0.0, 0.5)
            first = first if first is not None else float(loss.detach())
            optimizer.zero_grad()
            loss.backward()
            optimizer.step()
    assert float(loss.detach()) < 0.05 * first
    # radar loss gradient points the right way: a field predicting no motion is pushed along u
    field2 = DeformationField(FieldConfig(num_layers=3, hidden=8, hidden_layers=1))
    x2 = torch.tensor([[5.0, 0.0, 0.0]])
    loss = radar_loss(field2, x2, 0.0, 1.0, 1.0, torch.zeros(3), torch.tensor([1.0]))
    assert loss.item() == pytest.approx(1.0, abs=1e-6)
    loss.backward()
    assert all(torch.isfinite(p.grad).all() for p in field2.parameters() if p.grad is not None)


def test_empty_inputs_give_zero_with_graph():
    field = DeformationField(FieldConfig(num_layers=3, hidden=8, hidden_layers=1))
    empty = torch.zeros(0, 3)
    assert flow_loss(field, empty, empty, 0.0, 1.0).item() == 0.0
    nan = torch.tensor([math.nan])
    assert radar_loss(field, torch.ones(1, 3), 0.0, 1.0, 0.1, torch.zeros(3), nan).item() == 0.0


def test_image_losses_against_closed_forms():
    rendered = torch.tensor([[2.0, 4.0], [10.0, 1.0]])
    target = torch.tensor([[4.0, 4.0], [float("nan"), 2.0]])
    alpha = torch.tensor([[1.0, 1.0], [1.0, 0.0]])
    valid = torch.ones(2, 2, dtype=torch.bool)
    # Pixel (0, 0): |1/2 - 1/4| = 0.25; (0, 1): 0; (1, 0) NaN target; (1, 1) transparent.
    assert float(inverse_depth_l1(rendered, alpha, target, valid)) == pytest.approx(0.125)
    assert float(inverse_depth_l1(rendered, alpha, target, torch.zeros_like(valid))) == 0.0
    # The same pixels in log depth: |log 2 - log 4| and 0.
    assert float(log_depth_l1(rendered, alpha, target, valid)) == pytest.approx(math.log(2.0) / 2)
    # Scale-free: 20 % too deep costs the same at 5 m and at 40 m; the inverse depth's cost falls 8x.
    near, far = torch.full((1, 1), 5.0), torch.full((1, 1), 40.0)
    one, every = torch.ones(1, 1), torch.ones(1, 1, dtype=torch.bool)
    assert float(log_depth_l1(near * 1.2, one, near, every)) == pytest.approx(float(log_depth_l1(far * 1.2, one, far,
                                                                                                 every)))
    assert float(inverse_depth_l1(near * 1.2, one, near, every)) == pytest.approx(
        8 * float(inverse_depth_l1(far * 1.2, one, far, every)))
    p = torch.tensor([0.9, 0.2])
    expected = -(math.log(0.9) + math.log(0.8)) / 2
    assert float(binary_cross_entropy(p, torch.tensor([True, False]))) == pytest.approx(expected, rel=1e-6)


def _one_gaussian(depth: float, sigma_px: float = 1.0, opacity: float = 0.4):
    """One Gaussian projected at pixel (10, 10)'s centre, ``sigma_px`` wide, ``depth`` m away."""
    means2d = torch.tensor([[10.5, 10.5]], dtype=torch.float64)
    radii = torch.tensor([[3 * sigma_px, 3 * sigma_px]], dtype=torch.float64)
    return means2d, radii, torch.tensor([depth], dtype=torch.float64), torch.tensor([opacity], dtype=torch.float64,
                                                                                   requires_grad=True)


def test_static_over_movers_is_opacity_times_the_covered_box_in_front_of_the_mover_and_nothing_else():
    mask = torch.zeros(32, 40, dtype=torch.bool)
    mask[5:16, 5:16] = True
    surface = torch.full((32, 40), 10.0, dtype=torch.float64)
    means2d, radii, depths, opacity = _one_gaussian(4.0)
    value = static_over_movers(means2d, radii, depths, opacity, mask, surface, margin=0.05)
    # Every probe on the mask: the whole 2-sigma box, 4 px^2, at opacity 0.4, over 32 x 40 pixels.
    assert float(value.detach()) == pytest.approx(0.4 * 4.0 / (32 * 40))
    value.backward()
    assert float(opacity.grad) == pytest.approx(4.0 / (32 * 40))
    # Within the margin (9.6 m is not 5 % nearer than 10 m), behind it, culled, on an unknown or unmasked surface: 0.
    for depth, rad, surf, m in ((9.6, 3.0, 10.0, mask), (12.0, 3.0, 10.0, mask), (4.0, 0.0, 10.0, mask),
                                (4.0, 3.0, float("nan"), mask), (4.0, 3.0, 10.0, ~mask)):
        means2d, radii, depths, opacity = _one_gaussian(depth)
        zero = static_over_movers(means2d, radii * rad / 3.0, depths, opacity, m,
                                  torch.full((32, 40), surf, dtype=torch.float64), margin=0.05)
        assert float(zero.detach()) == 0.0
    # 9.4 m is: the margin is relative.
    means2d, radii, depths, opacity = _one_gaussian(9.4)
    assert float(static_over_movers(means2d, radii, depths, opacity, mask, surface, margin=0.05).detach()) > 0


def test_static_over_movers_counts_the_probes_on_the_mask_and_caps_a_large_gaussian_at_the_mask():
    surface = torch.full((32, 40), 10.0, dtype=torch.float64)
    # Only the centre column of pixel 10 and the +sigma probe (pixel 14) are masked: 2 of 5 probes.
    mask = torch.zeros(32, 40, dtype=torch.bool)
    mask[10, 10] = mask[10, 14] = True
    means2d, radii, depths, opacity = _one_gaussian(4.0, sigma_px=4.0)
    value = static_over_movers(means2d, radii, depths, opacity, mask, surface, margin=0.0)
    # The box is 8 x 8 = 64 px^2; 2 of 5 probes hit -> 25.6 px, capped at the mask's 2 pixels.
    assert float(value.detach()) == pytest.approx(0.4 * 2.0 / (32 * 40))
    mask[:, :] = True
    value = static_over_movers(means2d, radii, depths, opacity, mask, surface, margin=0.0)
    assert float(value.detach()) == pytest.approx(0.4 * 64.0 / (32 * 40))
