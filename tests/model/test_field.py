"""The invertible deformation field: identity at initialisation, exact inverse under random weights
in float32 and float64, per-point times, gradients, normalisation."""

from __future__ import annotations

import pytest
import torch
from hypothesis import given, settings
from hypothesis import strategies as st

from radar4dgs.config import preset
from radar4dgs.model.field import DeformationField, FieldConfig, fourier_features, normalization_from_points, randomize_

# The field's matmuls are tiny; on the shared 2-core CI machine extra torch threads only spin.
pytestmark = pytest.mark.usefixtures("one_torch_thread")


def random_field(name: str = "small", seed: int = 0, dtype=torch.float32, last_std: float = 0.1) -> DeformationField:
    field = DeformationField(preset(FieldConfig, name))
    randomize_(field, last_std, torch.Generator().manual_seed(seed))
    return field.to(dtype)


def test_untrained_field_is_the_identity():
    field = DeformationField(preset(FieldConfig, "small"))
    field.set_normalization([10.0, -3.0, 1.0], [25.0, 8.0, 2.0])
    x = torch.randn(500, 3) * 20
    assert torch.allclose(field(x, 0.7), x, atol=1e-5)
    assert torch.allclose(field.inverse(x, torch.rand(500)), x, atol=1e-5)
    assert torch.allclose(field.warp(x, 0.1, 0.9), x, atol=1e-5)


@pytest.mark.parametrize("name", ["tiny", "small", "paper"])
def test_round_trip_float32_random_weights(name):
    field = random_field(name, seed=3)
    generator = torch.Generator().manual_seed(1)
    n = 5000 if name == "paper" else 20000
    x = torch.rand(n, 3, generator=generator) * 2 - 1
    t = torch.rand(n, generator=generator)
    y = field(x, t)
    assert (y - x).norm(dim=1).mean() > 0.1  # the random field really moves points
    assert (field.inverse(y, t) - x).abs().max() <= 1e-5
    assert (field(field.inverse(x, t), t) - x).abs().max() <= 1e-5


def test_round_trip_float64_and_dtype_checks():
    field = random_field("small", seed=5, dtype=torch.float64)
    x = torch.rand(1000, 3, dtype=torch.float64) * 2 - 1
    assert (field.inverse(field(x, 0.4), 0.4) - x).abs().max() <= 1e-12
    with pytest.raises(TypeError, match="float32 but the field is torch.float64"):
        field(x.float(), 0.4)
    with pytest.raises(ValueError, match=r"shape \(N, 3\)"):
        field(x[:, :2], 0.4)
    with pytest.raises(ValueError, match="times must be a scalar"):
        field(x, torch.zeros(7, dtype=torch.float64))


@settings(max_examples=20, deadline=None)
@given(seed=st.integers(0, 10_000), t=st.floats(0.0, 1.0), spread=st.floats(0.1, 1.0))
def test_round_trip_with_world_normalisation(seed, t, spread):
    field = random_field("small", seed=seed)
    field.set_normalization([30.0, -2.0, 0.5], [40.0, 12.0, 2.0])
    generator = torch.Generator().manual_seed(seed)
    x = (torch.rand(256, 3, generator=generator) * 2 - 1) * spread * torch.tensor([40.0, 12.0, 2.0]) \
        + torch.tensor([30.0, -2.0, 0.5])
    back = field.inverse(field(x, t), t)
    # Relative to the normalisation scale, the same 1e-5 bound as in normalised units.
    assert ((back - x) / field.scale).abs().max() <= 1e-5


def test_scalar_and_per_point_times_agree():
    field = random_field("tiny", seed=2)
    x = torch.rand(64, 3) * 2 - 1
    per_point = field(x, torch.full((64,), 0.25))
    assert torch.allclose(field(x, 0.25), per_point)
    assert torch.allclose(field(x, torch.tensor(0.25)), per_point)
    times = torch.linspace(0, 1, 64)
    rows = torch.stack([field(x[k:k + 1], float(times[k]))[0] for k in range(64)])
    assert torch.allclose(field(x, times), rows, atol=1e-6)


def test_warp_composes_and_is_identity_at_equal_times():
    field = random_field("small", seed=7, dtype=torch.float64)
    x = torch.rand(100, 3, dtype=torch.float64) * 2 - 1
    assert torch.allclose(field.warp(x, 0.3, 0.3), x, atol=1e-12)
    via = field.warp(field.warp(x, 0.1, 0.5), 0.5, 0.8)
    assert torch.allclose(via, field.warp(x, 0.1, 0.8), atol=1e-12)
    assert torch.allclose(field.displacement(x, 0.1, 0.8), field.warp(x, 0.1, 0.8) - x)


def test_gradients_flow_to_parameters_and_inputs():
    field = random_field("tiny", seed=1, dtype=torch.float64)
    x = (torch.rand(20, 3, dtype=torch.float64) * 2 - 1).requires_grad_(True)
    t = torch.rand(20, dtype=torch.float64)
    field.warp(x, t, 1 - t).pow(2).sum().backward()
    assert x.grad is not None and torch.isfinite(x.grad).all()
    assert all(p.grad is not None for p in field.parameters())
    # Finite-difference check of the inverse's input Jacobian (exactness of autograd through it).
    x0 = x.detach()[:3].clone().requires_grad_(True)
    assert torch.autograd.gradcheck(lambda z: field.inverse(z, 0.6), (x0,))


def test_untrained_field_has_gradients_despite_zero_last_layer():
    field = DeformationField(preset(FieldConfig, "tiny"))
    x = torch.rand(50, 3)
    (field.warp(x, 0.0, 1.0) - x - 1).pow(2).sum().backward()
    assert any(float(p.grad.abs().sum()) > 0 for p in field.parameters() if p.grad is not None)


def test_normalisation_from_points_and_state_dict():
    points = torch.tensor([[0.0, 0.0, 0.0], [10.0, 4.0, 0.2], [float("nan"), 0, 0]])
    centre, scale = normalization_from_points(points, margin=0.1, min_scale=1.0)
    assert torch.allclose(centre, torch.tensor([5.0, 2.0, 0.1], dtype=torch.float64))
    assert torch.allclose(scale, torch.tensor([5.5, 2.2, 1.0], dtype=torch.float64))
    field = random_field("tiny", seed=4)
    field.fit_normalization(points)
    copy = DeformationField(preset(FieldConfig, "tiny"))
    copy.load_state_dict(field.state_dict())
    x = torch.rand(10, 3) * 10
    assert torch.equal(copy(x, 0.5), field(x, 0.5))
    with pytest.raises(ValueError, match="positive"):
        field.set_normalization([0, 0, 0], [1.0, 0.0, 1.0])


def test_fourier_features_layout():
    values = torch.tensor([[0.5]])
    features = fourier_features(values, 2)
    expected = torch.tensor([[0.5, 1.0, 0.0, 0.0, -1.0]])  # [v, sin(pi v), sin(2 pi v), cos(pi v), cos(2 pi v)]
    assert torch.allclose(features, expected, atol=1e-6)
