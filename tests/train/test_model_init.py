"""The field a run starts from (fresh or pre-fitted) and the life spans of the dynamic Gaussians,
shortened for fast objects."""

from __future__ import annotations

import numpy as np
import torch
from hypothesis import given, settings
from hypothesis import strategies as st

from radar4dgs.config import preset
from radar4dgs.model.config import FieldConfig, TrainConfig
from radar4dgs.model.field import DeformationField
from radar4dgs.train.data import MotionTargets
from radar4dgs.train.fit_motion import FlowSamples
from radar4dgs.train.model_init import image_speeds, new_field, speed_scaled_lifespans


@settings(max_examples=50, deadline=None)
@given(speeds=st.lists(st.floats(0.0, 500.0), min_size=1, max_size=20), reference=st.floats(0.5, 50.0))
def test_life_spans_shrink_with_speed_down_to_one_frame(speeds, reference):
    base, step = 0.05, 1 / 49
    spans = speed_scaled_lifespans(np.array(speeds), base, reference, step)
    for speed, span in zip(speeds, spans, strict=True):
        expected = base if speed <= reference else max(base * reference / speed, step)
        assert np.isclose(span, expected)


def test_image_speed_of_a_still_field_is_zero_and_of_a_moving_one_its_projection(motion_scene):
    """An untrained field moves nothing; a field that adds a sideways velocity moves a point at
    depth z by f * v * dt / z pixels in its own frame's camera."""
    from radar4dgs.io.scene import normalized_times

    scene = motion_scene
    times = normalized_times(scene)
    frame = 2
    c2w = np.linalg.inv(scene.world_to_camera(frame))
    depth = np.array([5.0, 10.0, 20.0])
    world = (np.column_stack([np.zeros(3), np.zeros(3), depth])) @ c2w[:3, :3].T + c2w[:3, 3]
    frames = np.full(3, frame)
    still = DeformationField(FieldConfig()).double()
    assert np.allclose(image_speeds(world, frames, times, still, scene), 0.0, atol=1e-9)

    class Sideways(torch.nn.Module):
        """x_t = x_c + v t along the camera's x axis (in world coordinates)."""

        def __init__(self):
            super().__init__()
            self.v = torch.nn.Parameter(torch.tensor(c2w[:3, 0] * 3.0))

        def warp(self, x, t_from, t_to):
            return x + self.v * (t_to - t_from)

    speeds = image_speeds(world, frames, times, Sideways(), scene)
    step = float(np.min(np.diff(times)))
    assert np.allclose(speeds, scene.camera.K[0, 0] * 3.0 * step / depth, rtol=1e-6)


def _translating_cloud(n: int = 400, velocity=(3.0, -1.0, 0.0)) -> MotionTargets:
    """Flow pairs of a cloud translating at ``velocity`` (m per unit of normalised time)."""
    rng = np.random.default_rng(0)
    x_i = rng.uniform(-5, 5, (n, 3))
    t_i = rng.uniform(0, 0.9, n)
    t_j = t_i + 0.1
    x_j = x_i + np.outer(t_j - t_i, velocity)
    return MotionTargets(FlowSamples(x_i, x_j, t_i, t_j), None, {})


def test_prefit_field_learns_the_flow_and_a_fresh_one_moves_nothing(one_torch_thread):
    motion = _translating_cloud()
    config = preset(TrainConfig, "tiny", optim={"field_prefit_iterations": 0})
    x = torch.as_tensor(motion.flow.x_i[:50])
    fresh = new_field(config, motion, motion.flow.x_i, torch.device("cpu"), torch.float64)
    assert torch.allclose(fresh.displacement(x, 0.2, 0.6), torch.zeros_like(x))
    config = preset(TrainConfig, "tiny", optim={"field_prefit_iterations": 200})
    fitted = new_field(config, motion, motion.flow.x_i, torch.device("cpu"), torch.float64)
    assert fitted.training
    with torch.no_grad():
        moved = fitted.displacement(x, 0.2, 0.6)
    expected = 0.4 * torch.tensor([3.0, -1.0, 0.0], dtype=torch.float64)
    # the cloud moves 1.26 m over that interval; a fitted field gets it within a few centimetres
    assert (moved - expected).norm(dim=1).median() < 0.1
    # seeded: the same run again gives the same field
    again = new_field(config, motion, motion.flow.x_i, torch.device("cpu"), torch.float64)
    pairs = zip(fitted.state_dict().values(), again.state_dict().values(), strict=True)
    assert all(torch.equal(a, b) for a, b in pairs)


def test_prefit_leaves_out_the_terms_the_run_does_not_weight(one_torch_thread):
    """ours-no-flow turns L_flow off by its weight: the pre-fit must not learn the flow either, and
    with no weighted term left the run starts from the fresh (identity) field."""
    motion = _translating_cloud()
    config = preset(TrainConfig, "tiny", optim={"field_prefit_iterations": 200}, losses={"flow_weight": 0.0})
    field = new_field(config, motion, motion.flow.x_i, torch.device("cpu"), torch.float64)
    x = torch.as_tensor(motion.flow.x_i[:50])
    assert torch.allclose(field.displacement(x, 0.2, 0.6), torch.zeros_like(x))
