"""The scene model's held-out window: between training frames the dynamic copies are fully visible
within a fraction of the distance to the nearest training frame; at training frames nothing changes;
the window is saved with the model, and models saved without it render as before."""

from __future__ import annotations

import math

import numpy as np
import torch

from radar4dgs.model.gaussians import GaussianSet
from radar4dgs.model.scene_model import SceneModel
from radar4dgs.model.sky import SkyEnvironment
from radar4dgs.train.model_init import with_lifespans

KEY_TIMES = (0.0, 0.1, 0.2, 0.4)  # 0.3 is a held-out frame
LIFESPAN = 0.05


def model(window_fraction: float, key_times: tuple[float, ...] | None = KEY_TIMES) -> SceneModel:
    points = np.array([[0.0, 0.0, 5.0], [1.0, 0.0, 5.0], [2.0, 0.0, 5.0]])
    static = GaussianSet.from_points(points[:1], np.full((1, 3), 0.5), dtype=torch.float64)
    dynamic = with_lifespans(GaussianSet.from_points(points, np.full((3, 3), 0.5), dtype=torch.float64),
                             np.array([0.2, 0.4, 0.1]), LIFESPAN)
    return SceneModel(static, SkyEnvironment(4, 8, dtype=torch.float64), None, dynamic,
                      key_times=key_times, window_fraction=window_fraction)


def dynamic_opacities(scene_model: SceneModel, time: float) -> np.ndarray:
    return scene_model.set_at("dynamic", time)["opacities"].detach().numpy()


def test_the_window_changes_nothing_at_training_frames_and_widens_between_them():
    for time in KEY_TIMES:
        np.testing.assert_array_equal(dynamic_opacities(model(0.25), time), dynamic_opacities(model(0.0), time))
    base = model(0.0).dynamic.activated()["opacities"].detach().numpy()
    # At 0.3 the nearest training frames lie 0.1 away: a quarter of that is flat, 0.025.
    expected = [math.exp(-0.5 * (max(abs(0.3 - tau) - 0.025, 0.0) / LIFESPAN) ** 2) for tau in (0.2, 0.4, 0.1)]
    np.testing.assert_allclose(dynamic_opacities(model(0.25), 0.3), base * expected, rtol=1e-12)
    assert (dynamic_opacities(model(0.25), 0.3) > dynamic_opacities(model(0.0), 0.3)).all()


def test_the_window_is_saved_with_the_model_and_absent_from_older_models():
    saved = model(0.25).payload()
    restored = SceneModel.from_payload(saved, dtype=torch.float64)
    assert restored.key_times == KEY_TIMES and restored.window_fraction == 0.25
    np.testing.assert_array_equal(dynamic_opacities(restored, 0.3), dynamic_opacities(model(0.25), 0.3))
    saved.pop("held_out_window")  # a model.pt written before the window existed
    older = SceneModel.from_payload(saved, dtype=torch.float64)
    assert older.key_times is None
    np.testing.assert_array_equal(dynamic_opacities(older, 0.3), dynamic_opacities(model(0.0), 0.3))
