"""Where the dynamic Gaussians' means live, and which of them a render moves.

``own_time_means``: a mean is the Gaussian's position at its life peak, so at that time it is drawn
exactly there whatever the field is; at other times it moves by the field's warp. A render moves only
the dynamic Gaussians the rasterizer can draw, and that changes neither the image nor any gradient."""

from __future__ import annotations

import numpy as np
import pytest
import torch
from hypothesis import given, settings
from hypothesis import strategies as st

import radar4dgs.model.scene_model as scene_model_module
from radar4dgs.model.config import FieldConfig, TrainConfig
from radar4dgs.model.field import DeformationField, randomize_
from radar4dgs.model.gaussians import GaussianSet
from radar4dgs.model.scene_model import SceneModel
from radar4dgs.model.sky import SkyEnvironment
from radar4dgs.model.view import View
from radar4dgs.train.model_init import with_lifespans

WIDTH, HEIGHT, FOCAL = 40, 30, 30.0


def random_field(seed: int) -> DeformationField:
    """A field far from the identity (metres of motion), float64."""
    field = DeformationField(FieldConfig(num_layers=3, hidden=16)).double()
    field.set_normalization(torch.zeros(3), torch.full((3,), 4.0))
    return randomize_(field, last_std=0.2, generator=torch.Generator().manual_seed(seed))


def scene(own_time: bool, seed: int = 0, n: int = 60) -> SceneModel:
    """Dynamic Gaussians 4-8 m in front of an identity camera, life peaks spread over [0, 1]."""
    rng = np.random.default_rng(seed)
    points = np.column_stack([rng.uniform(-2, 2, n), rng.uniform(-1.5, 1.5, n), rng.uniform(4, 8, n)])
    kw = {"init_opacity": 0.7, "min_scale": 0.15, "max_scale": 0.3, "dtype": torch.float64}
    static = GaussianSet.from_points(np.array([[0.0, 0.0, 12.0]]), np.full((1, 3), 0.5), **kw)
    dynamic = with_lifespans(GaussianSet.from_points(points, rng.uniform(0, 1, (n, 3)), **kw),
                             rng.uniform(0, 1, n), 0.05)
    return SceneModel(static, SkyEnvironment(4, 8, dtype=torch.float64), random_field(seed), dynamic,
                      own_time_means=own_time)


@settings(max_examples=15, deadline=None)
@given(seed=st.integers(0, 10_000), time=st.floats(0.0, 1.0))
def test_own_time_means_are_drawn_at_their_life_peak_whatever_the_field(seed, time):
    model = scene(own_time=True, seed=seed)
    stored = model.dynamic.params["means"].detach()
    tau = model.dynamic.params["tau"].detach()
    with torch.no_grad():
        # Each Gaussian alone at its own peak: the field's warp from tau to tau is the identity.
        at_peaks = torch.stack([model.set_at("dynamic", float(t))["means"][i] for i, t in enumerate(tau[:8])])
        np.testing.assert_allclose(at_peaks.numpy(), stored[:8].numpy(), atol=1e-9)
        # At any other time they move by the warp D_t(D_tau^-1(x)); the canonical model moves them by D_t(x).
        warped = model.field(model.field.inverse(stored, tau), time)
        np.testing.assert_allclose(model.set_at("dynamic", time)["means"].numpy(), warped.numpy(), atol=1e-9)
        canonical = scene(own_time=False, seed=seed)
        np.testing.assert_allclose(canonical.set_at("dynamic", time)["means"].numpy(),
                                   canonical.field(stored, time).numpy(), atol=1e-12)
    assert float((warped - stored).norm(dim=1).max()) > 0.05  # the field really moves them


def render_and_gradients(model: SceneModel, time: float) -> tuple[np.ndarray, dict[str, np.ndarray]]:
    K = np.array([[FOCAL, 0, (WIDTH - 1) / 2], [0, FOCAL, (HEIGHT - 1) / 2], [0, 0, 1]])
    model.zero_grad(set_to_none=True)
    out = model.render(View(np.eye(4), K, WIDTH, HEIGHT, time))
    (out["rgb"].square().sum() + out["depth"].sum()).backward()
    named = [(f"field.{k}", v) for k, v in model.field.named_parameters()]
    named += [(f"dynamic.{k}", v) for k, v in model.dynamic.params.items()]
    grads = {k: np.zeros(tuple(v.shape)) if v.grad is None else v.grad.numpy() for k, v in named}
    return out["rgb"].detach().numpy(), grads


@pytest.mark.parametrize("own_time", [False, True])
def test_moving_only_the_drawable_gaussians_changes_no_pixel_and_no_gradient(monkeypatch, own_time):
    model = scene(own_time, n=200)
    visible = model.set_at("dynamic", 0.5)["opacities"].detach()
    assert 0.2 < float((visible >= scene_model_module.FIELD_CULL_OPACITY).double().mean()) < 0.8
    culled_rgb, culled_grads = render_and_gradients(model, 0.5)
    monkeypatch.setattr(scene_model_module, "FIELD_CULL_OPACITY", 0.0)  # every Gaussian through the field
    full_rgb, full_grads = render_and_gradients(model, 0.5)
    np.testing.assert_allclose(culled_rgb, full_rgb, atol=1e-12)
    assert np.abs(full_grads["field.layers.0.last.weight"]).max() > 0  # the image does reach the field
    for name, grad in full_grads.items():
        np.testing.assert_allclose(culled_grads[name], grad, atol=1e-10, err_msg=name)


def test_positions_asked_for_outside_a_render_are_moved_for_every_gaussian():
    """Actor discovery and export read every Gaussian's position, drawn or not."""
    model = scene(own_time=False)
    with torch.no_grad():
        moved = model.set_at("dynamic", 0.0)["means"]
        np.testing.assert_allclose(moved.numpy(), model.field(model.dynamic.params["means"], 0.0).numpy(), atol=1e-12)


def test_own_time_means_are_saved_with_the_model_and_absent_from_older_models():
    payload = scene(own_time=True).payload()
    assert SceneModel.from_payload(payload, dtype=torch.float64).own_time_means is True
    payload.pop("own_time_means")  # a model.pt written before the option existed
    assert SceneModel.from_payload(payload, dtype=torch.float64).own_time_means is False


def test_own_time_means_need_a_life_peak():
    with pytest.raises(ValueError, match="dynamic_lifespan > 0"):
        TrainConfig(dynamic_positions="own-time", dynamic_lifespan=0.0)
