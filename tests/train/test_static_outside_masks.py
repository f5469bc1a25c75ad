"""Stage 3 with ``static_outside_masks``: no dynamic-mask pixel gives a static Gaussian an image gradient."""

from __future__ import annotations

import numpy as np
import pytest
import torch
from _prepared import prepared_tiny_scene

from radar4dgs.config import preset
from radar4dgs.model.config import TrainConfig
from radar4dgs.model.gaussians import GaussianSet
from radar4dgs.model.scene_model import SceneModel
from radar4dgs.model.sky import SkyEnvironment
from radar4dgs.model.view import View
from radar4dgs.train.data import FrameTargets
from radar4dgs.train.objective import image_losses, image_phase
from radar4dgs.train.trainer import Trainer, train_run

pytestmark = pytest.mark.usefixtures("one_torch_thread")

WIDTH, HEIGHT, FOCAL = 48, 32, 40.0
# The dynamic mask covers the left half; SSIM's window (11 px) never reaches from column 6 past 23.
MASK_COLUMNS = 24


def pixel_point(u: float, depth: float = 5.0) -> list[float]:
    """The camera-frame point (identity pose) that projects to column ``u`` of the middle row."""
    return [(u - (WIDTH - 1) / 2) * depth / FOCAL, 0.0, depth]


def two_layer_scene() -> SceneModel:
    """Static Gaussians at columns 6 (inside the mask) and 40 (outside), a dynamic one at 12."""
    kw = {"init_opacity": 0.8, "min_scale": 0.05, "max_scale": 0.05}
    static = GaussianSet.from_points([pixel_point(6), pixel_point(40)], [[0.2, 0.3, 0.4], [0.6, 0.5, 0.4]], **kw)
    dynamic = GaussianSet.from_points([pixel_point(12, 4.0)], [[0.9, 0.1, 0.1]], **kw)
    return SceneModel(static, SkyEnvironment(8, 16), None, dynamic, None)


def frame_targets() -> FrameTargets:
    """A flat grey target (a car the layers under-explain, as far as the static layer knows), 5 m deep."""
    K = np.array([[FOCAL, 0, (WIDTH - 1) / 2], [0, FOCAL, (HEIGHT - 1) / 2], [0, 0, 1]])
    view = View(np.eye(4), K, WIDTH, HEIGHT, 0.5)
    dynamic = torch.zeros(HEIGHT, WIDTH, dtype=torch.bool)
    dynamic[:, :MASK_COLUMNS] = True
    return FrameTargets(0, "000000", view, torch.full((HEIGHT, WIDTH, 3), 0.7), torch.full((HEIGHT, WIDTH), 5.0),
                        torch.zeros(HEIGHT, WIDTH, dtype=torch.bool), dynamic, None)


def image_gradients(model: SceneModel, config: TrainConfig, step: int, target: FrameTargets):
    """Gradients of the image terms (L1 + SSIM + depth) of one stage-3 iteration with respect to the
    static and dynamic colours (None: that set was not differentiated)."""
    for p in list(model.static.parameters()) + list(model.dynamic.parameters()):
        p.grad = None
    ignore, detach = image_phase(config, 3, step)
    render = model.render(target.view, detach_static=detach)
    losses = image_losses(render, target, config, 3, ignore_dynamic=ignore)
    (losses["l1"] + losses["ssim"] + losses["depth"]).backward()
    return model.static.params["colors"].grad, model.dynamic.params["colors"].grad


def masked_l1_reference(model: SceneModel, target: FrameTargets) -> torch.Tensor:
    """The naive reference: d/d(static colours) of the L1 over the pixels outside the mask only."""
    model.static.params["colors"].grad = None
    rgb = model.render(target.view)["rgb"]
    outside = ~target.dynamic[..., None]
    ((rgb - target.image).abs() * outside).sum().div(rgb.numel()).backward()
    return model.static.params["colors"].grad


def test_phases_by_stage_and_step():
    on = preset(TrainConfig, "tiny", static_outside_masks=True)
    off = preset(TrainConfig, "tiny", static_outside_masks=False)
    assert [image_phase(on, s, 0) for s in (1, 2)] == [(True, False), (False, True)]
    assert [image_phase(on, 3, step) for step in (40, 41, 42, 43)] == [(False, True), (True, False)] * 2
    assert {image_phase(off, 3, step) for step in range(4)} == {(False, False)}
    baseline = preset(TrainConfig, "tiny", method="pvg", static_outside_masks=True)
    assert {image_phase(baseline, stage, 1) for stage in (1, 2, 3)} == {(False, False)}


def test_static_gaussian_inside_the_mask_gets_no_image_gradient():
    target = frame_targets()
    model = two_layer_scene()
    on = preset(TrainConfig, "tiny", static_outside_masks=True)
    # Odd iteration: the mask's pixels are ignored. The static Gaussian inside gets exactly nothing; the
    # one outside gets the L1 gradient of the pixels outside the mask (the naive reference) plus SSIM's.
    # (Zero up to float32 rounding in SSIM's closed-form gradient: 1e-8 against 6e-3 outside.)
    static_grad, dynamic_grad = image_gradients(model, on, 1, target)
    assert float(static_grad[0].abs().max()) < 1e-7 and float(static_grad[1].abs().max()) > 1e-3
    assert float(dynamic_grad.abs().max()) < 1e-7  # the dynamic Gaussian lies inside the mask too
    l1_static = image_gradients_l1(model, on, 1, target)
    torch.testing.assert_close(l1_static, masked_l1_reference(model, target), rtol=1e-5, atol=1e-9)
    assert float(l1_static[1].abs().sum()) > 0
    # Even iteration: the static set is frozen; the dynamic Gaussian learns from the mask's pixels.
    static_grad, dynamic_grad = image_gradients(model, on, 2, target)
    assert static_grad is None and float(dynamic_grad.abs().sum()) > 0
    # Without the rule the static Gaussian inside the mask learns the under-explained pixels (bakes them in).
    off = preset(TrainConfig, "tiny", static_outside_masks=False)
    static_grad, _ = image_gradients(model, off, 1, target)
    assert float(static_grad[0].abs().sum()) > 0


def image_gradients_l1(model: SceneModel, config: TrainConfig, step: int, target: FrameTargets) -> torch.Tensor:
    """d L1 / d(static colours) of one stage-3 iteration."""
    model.static.params["colors"].grad = None
    ignore, detach = image_phase(config, 3, step)
    render = model.render(target.view, detach_static=detach)
    image_losses(render, target, config, 3, ignore_dynamic=ignore)["l1"].backward()
    return model.static.params["colors"].grad


@pytest.fixture(scope="module")
def prepared(tmp_path_factory):
    return prepared_tiny_scene(tmp_path_factory.mktemp("static_outside"), seed=2)


@pytest.mark.parametrize("rule", [True, False])
def test_trainer_alternates_in_stage_3(prepared, tmp_path, monkeypatch, rule):
    """Every stage-3 iteration either ignores the mask's pixels or freezes (and does not step) the static set."""
    import radar4dgs.train.trainer as trainer

    scene, prep = prepared
    seen: list[tuple[int, bool, bool, bool]] = []
    real_losses, real_densify = trainer.image_losses, Trainer._densify
    ignored: list[bool] = []

    def losses(*args, ignore_dynamic, **kwargs):
        ignored.append(ignore_dynamic)
        return real_losses(*args, ignore_dynamic=ignore_dynamic, **kwargs)

    def densify(self, state, render, stage, trainable, generator):
        frozen = state.model.static.params["colors"].grad is None
        seen.append((stage, ignored[-1], frozen, "static" in trainable))
        return real_densify(self, state, render, stage, trainable, generator)

    monkeypatch.setattr(trainer, "image_losses", losses)
    monkeypatch.setattr(Trainer, "_densify", densify)
    config = preset(TrainConfig, "tiny", static_outside_masks=rule, threads=1, optim={"iterations": 12},
                    init={"points_per_frame": 300, "max_static": 1500, "max_dynamic": 300},
                    losses={"motion_batch": 32, "radar_points_per_frame": 50})
    train_run(scene, prep, tmp_path / "run", config, progress=False, tensorboard=False)
    stage3 = [s[1:] for s in seen if s[0] == 3]
    assert len(stage3) == 12 - round(config.optim.stage3_start * 12)
    if rule:
        assert set(stage3) == {(True, False, True), (False, True, False)}
        assert all(a != b for a, b in zip(stage3[:-1], stage3[1:], strict=True))  # alternating
    else:
        assert set(stage3) == {(False, False, True)}


def test_runs_saved_before_the_option_count_as_training_static_on_every_pixel():
    import dataclasses

    from radar4dgs.config import to_dict
    from radar4dgs.train.run_config import run_config_difference

    config = preset(TrainConfig, "tiny", static_outside_masks=True)
    saved = to_dict(config)
    del saved["static_outside_masks"]
    assert any("static_outside_masks" in line for line in run_config_difference(saved, config))
    assert not run_config_difference(saved, dataclasses.replace(config, static_outside_masks=False))
