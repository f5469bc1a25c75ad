"""``dynamic_in_front``: the dynamic layer is drawn ahead of static Gaussians up to that fraction of its depth
nearer, with the same image footprint and the true depth, and the setting is saved with the model."""

from __future__ import annotations

import numpy as np
import pytest
import torch

from radar4dgs.config import preset
from radar4dgs.model.config import TrainConfig
from radar4dgs.model.gaussians import GaussianSet
from radar4dgs.model.scene_model import SceneModel
from radar4dgs.model.sky import SkyEnvironment
from radar4dgs.model.view import View

pytestmark = pytest.mark.usefixtures("one_torch_thread")

K = np.array([[30.0, 0.0, 15.5], [0.0, 30.0, 11.5], [0.0, 0.0, 1.0]])
# A camera away from the origin and turned, so moving toward "the camera" is not moving toward the origin.
ANGLE = 0.3
WORLD_TO_CAMERA = np.array([[np.cos(ANGLE), 0.0, -np.sin(ANGLE), 0.4],
                            [0.0, 1.0, 0.0, -0.2],
                            [np.sin(ANGLE), 0.0, np.cos(ANGLE), 1.5],
                            [0.0, 0.0, 0.0, 1.0]])
VIEW = View(WORLD_TO_CAMERA, K, 32, 24, 0.5)
RED, BLUE = [0.9, 0.1, 0.1], [0.1, 0.1, 0.9]


def on_axis(depth: float) -> list[float]:
    """The world point ``depth`` m along the camera's optical axis."""
    return (np.linalg.inv(WORLD_TO_CAMERA) @ np.array([0.0, 0.0, depth, 1.0]))[:3].tolist()


def car_and_road(road_depth: float, fraction: float) -> SceneModel:
    """A red dynamic Gaussian 5 m ahead and a blue static one ``road_depth`` m ahead, on the axis."""
    kw = {"init_opacity": 0.9, "min_scale": 0.3, "max_scale": 0.3, "dtype": torch.float64}
    dynamic = GaussianSet.from_points([on_axis(5.0)], [RED], **kw)
    static = GaussianSet.from_points([on_axis(road_depth)], [BLUE], **kw)
    return SceneModel(static, SkyEnvironment(4, 8, dtype=torch.float64), None, dynamic, dynamic_in_front=fraction)


def centre(out: dict, key: str) -> np.ndarray:
    return out[key][12, 16].detach().numpy()


def test_the_dynamic_layer_alone_renders_the_same_image_and_depth():
    plain = car_and_road(4.8, 0.0).render(VIEW, include_static=False)
    moved = car_and_road(4.8, 0.1).render(VIEW, include_static=False)
    for key in ("rgb", "alpha", "depth", "dynamic"):
        np.testing.assert_allclose(moved[key].detach().numpy(), plain[key].detach().numpy(), atol=1e-9)
    assert centre(moved, "depth") == pytest.approx(5.0, abs=1e-6)


def test_static_gaussians_within_the_fraction_are_drawn_behind_the_mover_and_nearer_ones_in_front():
    # 4 % nearer: in front without the setting, behind with 0.1.
    assert centre(car_and_road(4.8, 0.0).render(VIEW), "dynamic") < 0.2
    assert centre(car_and_road(4.8, 0.1).render(VIEW), "dynamic") > 0.8
    assert centre(car_and_road(4.8, 0.1).render(VIEW), "rgb")[0] > 0.7  # red
    # 20 % nearer: in front either way.
    assert centre(car_and_road(4.0, 0.1).render(VIEW), "dynamic") < 0.2
    # The depth stays the blend of the true depths: with the car in front, 0.9 of 5 m and 0.1 x 0.9 of 4.8 m.
    out = car_and_road(4.8, 0.1).render(VIEW)
    weights = centre(out, "dynamic"), centre(out, "alpha") - centre(out, "dynamic")
    assert centre(out, "depth") == pytest.approx((weights[0] * 5.0 + weights[1] * 4.8) / sum(weights), rel=1e-6)


def test_the_setting_is_saved_with_the_model_checked_and_off_in_older_models():
    saved = car_and_road(4.8, 0.1).payload()
    assert SceneModel.from_payload(saved, dtype=torch.float64).dynamic_in_front == 0.1
    saved.pop("dynamic_in_front")
    assert SceneModel.from_payload(saved, dtype=torch.float64).dynamic_in_front == 0.0
    with pytest.raises(ValueError, match="dynamic_in_front"):
        preset(TrainConfig, "tiny", dynamic_in_front=1.0)
