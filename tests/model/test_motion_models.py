"""The baselines' motion models against closed forms: B-spline partition of unity and linear
reproduction, PVG's vibration (position and velocity at the life peak), temporal visibility, the
Deformable-GS offset MLP, and densification carrying the motion parameters with their Gaussians."""

from __future__ import annotations

import math

import numpy as np
import torch
from hypothesis import given, settings
from hypothesis import strategies as st

from radar4dgs.model.config import DensifyConfig
from radar4dgs.model.gaussians import GaussianSet
from radar4dgs.model.motion_models import (
    BaselineConfig,
    OffsetField,
    bspline_means,
    bspline_weights,
    fourier_features,
    pvg_means,
    temporal_visibility,
)
from radar4dgs.train.densify import GradientStats, densify_and_prune


@settings(max_examples=60, deadline=None)
@given(t=st.floats(0.0, 1.0), count=st.integers(4, 16))
def test_bspline_weights_are_a_partition_of_unity_that_reproduces_lines(t, count):
    w = bspline_weights(t, count, torch.float64)
    assert (w >= -1e-12).all()
    assert abs(float(w.sum()) - 1.0) < 1e-12
    # A uniform cubic B-spline through control points c_k = k is the line 1 + t (count - 3).
    assert abs(float(w @ torch.arange(count, dtype=torch.float64)) - (1.0 + t * (count - 3))) < 1e-9


def test_bspline_means_with_constant_control_points_is_a_translation():
    means = torch.randn(5, 3, dtype=torch.float64)
    control = torch.tensor([1.0, -2.0, 0.5], dtype=torch.float64).expand(5, 8, 3).clone()
    for t in (0.0, 0.37, 1.0):
        torch.testing.assert_close(bspline_means(means, control, t), means + control[:, 0])


def test_pvg_position_and_velocity_at_the_life_peak():
    means = torch.tensor([[1.0, 2.0, 3.0]], dtype=torch.float64)
    velocity = torch.tensor([[4.0, -1.0, 0.0]], dtype=torch.float64)
    tau = torch.tensor([0.3], dtype=torch.float64)
    period = 0.2
    torch.testing.assert_close(pvg_means(means, velocity, tau, 0.3, period), means)
    h = 1e-6
    derivative = (pvg_means(means, velocity, tau, 0.3 + h, period)
                  - pvg_means(means, velocity, tau, 0.3 - h, period)) / (2 * h)
    torch.testing.assert_close(derivative, velocity, rtol=1e-6, atol=1e-6)
    # Never further from the mean than |v| l / (2 pi).
    far = max(float((pvg_means(means, velocity, tau, t, period) - means).norm()) for t in np.linspace(0, 1, 101))
    assert far <= float(velocity.norm()) * period / (2 * math.pi) + 1e-12


def test_temporal_visibility_closed_form():
    tau = torch.tensor([0.5, 0.5])
    log_lifespan = torch.log(torch.tensor([0.1, 0.2]))
    torch.testing.assert_close(temporal_visibility(tau, log_lifespan, 0.5), torch.ones(2))
    torch.testing.assert_close(temporal_visibility(tau, log_lifespan, 0.6),
                               torch.tensor([math.exp(-0.5), math.exp(-0.125)]))


@settings(max_examples=40, deadline=None)
@given(gap=st.floats(0.0, 0.5), flat=st.floats(0.0, 0.3), beta=st.floats(0.01, 0.3))
def test_a_flat_top_window_is_the_gaussian_shifted_by_its_flat_part(gap, flat, beta):
    tau = torch.tensor([0.5], dtype=torch.float64)
    log_lifespan = torch.tensor([math.log(beta)], dtype=torch.float64)
    expected = math.exp(-0.5 * (max(gap - flat, 0.0) / beta) ** 2)  # 1 within the flat part
    for time in (0.5 - gap, 0.5 + gap):
        assert abs(float(temporal_visibility(tau, log_lifespan, time, flat)[0]) - expected) < 1e-9
    assert torch.equal(temporal_visibility(tau, log_lifespan, 0.3, 0.0), temporal_visibility(tau, log_lifespan, 0.3))


def test_offset_field_starts_at_zero_and_learns():
    torch.manual_seed(0)
    field = OffsetField(BaselineConfig(offset_hidden=16, offset_layers=2), centre=np.array([10.0, 0, 0]), scale=20.0)
    x = torch.randn(64, 3) * 10
    assert field(x, 0.4).abs().max() == 0
    target = torch.tensor([0.5, 0.0, -0.25])
    optimizer = torch.optim.Adam(field.parameters(), lr=1e-3)
    for _ in range(200):
        loss = ((field(x, 0.4) - target) ** 2).mean()
        optimizer.zero_grad()
        loss.backward()
        optimizer.step()
    assert float(loss.detach()) < 1e-3
    assert fourier_features(torch.zeros(7, 3), 4).shape == (7, 27)


def test_densification_carries_motion_parameters_with_their_gaussians():
    n = 6
    params = {"means": torch.randn(n, 3), "quats": torch.tensor([[1.0, 0, 0, 0]]).repeat(n, 1),
              "log_scales": torch.full((n, 3), math.log(0.01)), "opacity_logits": torch.zeros(n),
              "colors": torch.zeros(n, 3), "velocity": torch.arange(n * 3, dtype=torch.float32).reshape(n, 3),
              "tau": torch.linspace(0, 1, n), "log_lifespan": torch.zeros(n), "control": torch.randn(n, 8, 3)}
    params["log_scales"][3:] = math.log(5.0)  # large: split; small: clone
    params["opacity_logits"][1] = -20.0  # transparent: pruned
    gaussians = GaussianSet(params)
    optimizer = torch.optim.Adam(gaussians.param_groups({name: 1e-3 for name in gaussians.names}), eps=1e-15)
    stats = GradientStats(n)
    grad = torch.zeros(n, 2)
    grad[[0, 3]] = 1.0  # Gaussian 0 is cloned, Gaussian 3 split in two
    stats.add(grad, torch.ones(n, dtype=torch.bool), 100, 100)
    counts = densify_and_prune(gaussians, optimizer, stats, extent=10.0,
                               config=DensifyConfig(grad_threshold=1e-3, clone_max_scale=0.1, prune_scale=100.0),
                               generator=torch.Generator().manual_seed(0))
    assert counts == {"cloned": 1, "split": 1, "pruned": 1}
    p = gaussians.params
    # Kept rows 0, 2, 4, 5, then the clone of 0, then the two children of 3 (split parent gone,
    # transparent 1 pruned): every motion parameter follows its row.
    rows = [0, 2, 4, 5, 0, 3, 3]
    for name in ("velocity", "tau", "log_lifespan", "control", "colors"):
        torch.testing.assert_close(p[name].detach(), params[name][rows])
    assert [g["params"][0] for g in optimizer.param_groups] == [p[name] for name in gaussians.names]
