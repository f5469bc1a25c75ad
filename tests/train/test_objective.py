"""The image terms of one iteration: the log-depth term on the dynamic-mask pixels (``losses.dynamic_depth_weight``)
against a hand-computed value, and the way its gradient moves a dynamic Gaussian drawn too deep; the static
Gaussians drawn over a mover; the moving pixels' extra L1 weight (``losses.dynamic_l1_weight``) and its widened mask."""

from __future__ import annotations

import numpy as np
import pytest
import torch
from hypothesis import given, settings
from hypothesis import strategies as st
from scipy import ndimage

from radar4dgs.config import preset
from radar4dgs.model.config import TrainConfig
from radar4dgs.model.gaussians import GaussianSet
from radar4dgs.model.scene_model import SceneModel
from radar4dgs.model.sky import SkyEnvironment
from radar4dgs.model.view import View
from radar4dgs.train.data import FrameTargets
from radar4dgs.train.objective import dilate, image_losses, loss_weights

pytestmark = pytest.mark.usefixtures("one_torch_thread")

WIDTH, HEIGHT, FOCAL, TRUE_DEPTH = 32, 24, 30.0, 5.0


def car_too_deep(depth: float) -> tuple[SceneModel, FrameTargets]:
    """One dynamic Gaussian on the camera axis at ``depth`` (identity pose, no field); the target says
    the masked centre of the image is ``TRUE_DEPTH`` away."""
    kw = {"init_opacity": 0.9, "min_scale": 0.4, "max_scale": 0.4}
    dynamic = GaussianSet.from_points([[0.0, 0.0, depth]], [[0.9, 0.1, 0.1]], **kw)
    static = GaussianSet.from_points([[0.0, 0.0, 30.0]], [[0.3, 0.3, 0.3]], **kw)
    model = SceneModel(static, SkyEnvironment(8, 16), None, dynamic, None)
    K = np.array([[FOCAL, 0, (WIDTH - 1) / 2], [0, FOCAL, (HEIGHT - 1) / 2], [0, 0, 1]])
    mask = torch.zeros(HEIGHT, WIDTH, dtype=torch.bool)
    mask[8:16, 12:20] = True
    targets = FrameTargets(0, "000000", View(np.eye(4), K, WIDTH, HEIGHT, 0.5), torch.full((HEIGHT, WIDTH, 3), 0.5),
                           torch.full((HEIGHT, WIDTH), TRUE_DEPTH), torch.zeros(HEIGHT, WIDTH, dtype=torch.bool), mask,
                           None)
    return model, targets


def rendered_terms(config: TrainConfig, model: SceneModel, target: FrameTargets, stage: int,
                   ignore_dynamic: bool) -> tuple[dict, dict]:
    """The render of ``target``'s view and its image terms."""
    render = model.render(target.view)
    return render, image_losses(render, target, config, stage, ignore_dynamic=ignore_dynamic)


def test_the_term_is_the_mean_log_depth_error_on_the_mask_and_only_where_the_movers_train():
    config = preset(TrainConfig, "tiny", losses={"dynamic_depth_weight": 0.5})
    model, target = car_too_deep(6.0)
    render, losses = rendered_terms(config, model, target, 2, ignore_dynamic=False)
    on = target.dynamic & (render["alpha"] > 0.05)
    expected = (render["depth"][on].log() - np.log(TRUE_DEPTH)).abs().mean()
    value = float(losses["dynamic_depth"].detach())
    assert value == pytest.approx(float(expected.detach()), rel=1e-6)
    assert value > 0.05  # the Gaussian is 20 % deep: log 1.2 = 0.18 where it covers
    assert loss_weights(config)["dynamic_depth"] == 0.5
    # Stage 1 ignores the dynamic pixels; with the default weight 0 the term is not computed at all.
    assert "dynamic_depth" not in image_losses(render, target, config, 1, ignore_dynamic=True)
    assert "dynamic_depth" not in image_losses(render, target, preset(TrainConfig, "tiny"), 2, ignore_dynamic=False)


def test_its_gradient_pulls_a_dynamic_gaussian_drawn_too_deep_toward_the_camera_and_one_too_near_away():
    config = preset(TrainConfig, "tiny", losses={"dynamic_depth_weight": 1.0})
    for depth, sign in ((6.0, 1.0), (4.0, -1.0)):
        model, target = car_too_deep(depth)
        image_losses(model.render(target.view), target, config, 2, ignore_dynamic=False)["dynamic_depth"].backward()
        dz = float(model.dynamic.params["means"].grad[0, 2])
        # Gradient descent moves z by -dz: toward TRUE_DEPTH from either side.
        assert sign * dz > 0
        assert model.static.params["means"].grad is None or float(model.static.params["means"].grad.abs().sum()) < 1e-3


def road_over_car(static_depth: float) -> tuple[SceneModel, FrameTargets]:
    """:func:`car_too_deep`'s car at its true depth, and a static Gaussian at ``static_depth`` on the
    same axis, drawn over it where nearer."""
    model, target = car_too_deep(TRUE_DEPTH)
    kw = {"init_opacity": 0.5, "min_scale": 0.4, "max_scale": 0.4}
    model.static = GaussianSet.from_points([[0.0, 0.0, static_depth]], [[0.3, 0.3, 0.3]], **kw)
    return model, target


def test_static_gaussians_drawn_over_a_mover_from_in_front_lose_opacity_and_the_mover_is_untouched():
    config = preset(TrainConfig, "tiny", losses={"over_movers_weight": 0.2})
    model, target = road_over_car(3.0)
    _, losses = rendered_terms(config, model, target, 3, ignore_dynamic=True)
    assert float(losses["over_movers"].detach()) > 1e-3
    assert loss_weights(config)["over_movers"] == 0.2
    losses["over_movers"].backward()
    # Gradient descent lowers the static Gaussian's opacity logit; the dynamic one takes nothing from the term.
    assert float(model.static.params["opacity_logits"].grad[0]) > 0
    grad = model.dynamic.params["opacity_logits"].grad
    assert grad is None or float(grad.abs().sum()) == 0.0
    # Behind the car, the term is 0; with the static set frozen (stage 2) or the weight 0 (the default), absent.
    assert float(rendered_terms(config, *road_over_car(30.0), 3, ignore_dynamic=True)[1]["over_movers"].detach()) == 0.0
    model, target = road_over_car(3.0)
    frozen = model.render(target.view, detach_static=True)
    assert "over_movers" not in image_losses(frozen, target, config, 2, ignore_dynamic=False)
    assert "over_movers" not in rendered_terms(preset(TrainConfig, "tiny"), model, target, 3, ignore_dynamic=True)[1]


def test_dynamic_l1_weight_counts_each_mask_pixel_one_plus_w_times_and_only_where_the_movers_train():
    model, target = car_too_deep(6.0)
    render = model.render(target.view)
    error = (render["rgb"] - target.image).abs().detach()
    weight = 4.0
    expected = (error.sum() + weight * error[target.dynamic].sum()) / error.numel()
    config = preset(TrainConfig, "tiny", losses={"dynamic_l1_weight": weight})
    weighted = float(image_losses(render, target, config, 2, ignore_dynamic=False)["l1"].detach())
    assert weighted == pytest.approx(float(expected), rel=1e-6)
    off = preset(TrainConfig, "tiny", losses={"dynamic_l1_weight": 0.0})
    plain = float(image_losses(render, target, off, 2, ignore_dynamic=False)["l1"].detach())
    assert plain == pytest.approx(float(error.mean()), rel=1e-6)
    # The baselines keep their own plain L1 whatever the weight.
    pvg = preset(TrainConfig, "tiny", method="pvg", losses={"dynamic_l1_weight": weight})
    baseline = float(image_losses(render, target, pvg, 2, ignore_dynamic=False)["l1"].detach())
    assert baseline == pytest.approx(plain, rel=1e-6)
    assert weighted > plain * 1.5  # the red car on grey: most of the error is on the mask
    # Stage 1 scores the mask pixels against the render itself: the weight changes nothing there.
    stage1 = image_losses(render, target, config, 1, ignore_dynamic=True)["l1"]
    unweighted = image_losses(render, target, off, 1, ignore_dynamic=True)["l1"]
    assert float(stage1.detach()) == pytest.approx(float(unweighted.detach()), rel=1e-6)


@settings(max_examples=40, deadline=None)
@given(seed=st.integers(0, 10_000), radius=st.integers(-4, 4), density=st.floats(0.0, 1.0))
def test_dilate_is_scipys_square_maximum_filter_and_a_negative_radius_its_minimum_filter(seed, radius, density):
    mask = np.random.default_rng(seed).random((13, 17)) < density
    size = 2 * abs(radius) + 1
    if radius >= 0:
        expected = ndimage.maximum_filter(mask, size=size, mode="constant", cval=False)
    else:  # outside the image counts as mask, so a car cut by the frame's edge is not narrowed there
        expected = ndimage.minimum_filter(mask, size=size, mode="constant", cval=True)
    assert np.array_equal(dilate(torch.from_numpy(mask), radius).numpy() > 0.5, expected)


def test_dynamic_l1_dilation_weighs_the_ring_around_the_mask_as_much_as_the_mask():
    model, target = car_too_deep(6.0)
    render = model.render(target.view)
    error = (render["rgb"] - target.image).abs().detach()
    weight, radius = 4.0, 2
    widened = torch.zeros_like(target.dynamic)
    widened[8 - radius:16 + radius, 12 - radius:20 + radius] = True  # the 8 x 8 car's mask, 2 px wider each side
    expected = (error.sum() + weight * error[widened].sum()) / error.numel()
    config = preset(TrainConfig, "tiny", losses={"dynamic_l1_weight": weight, "dynamic_l1_dilation": radius})
    widened_l1 = float(image_losses(render, target, config, 2, ignore_dynamic=False)["l1"].detach())
    assert widened_l1 == pytest.approx(float(expected), rel=1e-6)
    narrow = preset(TrainConfig, "tiny", losses={"dynamic_l1_weight": weight})
    assert widened_l1 > float(image_losses(render, target, narrow, 2, ignore_dynamic=False)["l1"].detach())

