"""Life spans of the dynamic Gaussians, shortened for fast objects."""

from __future__ import annotations

import numpy as np
import torch
from hypothesis import given, settings
from hypothesis import strategies as st

from radar4dgs.model.config import FieldConfig
from radar4dgs.model.field import DeformationField
from radar4dgs.train.model_init import image_speeds, speed_scaled_lifespans


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
