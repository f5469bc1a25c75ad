"""The field's path prior L_acc: closed forms of the second difference, the samples it is drawn from, the
times it checks, its place in the trainer's motion terms, and a fit that carries a car leaving the view on
straight."""

from __future__ import annotations

import numpy as np
import pytest
import torch
from hypothesis import given, settings
from hypothesis import strategies as st

from radar4dgs.config import preset
from radar4dgs.metrics.losses import acceleration_loss, acceleration_residual
from radar4dgs.model.config import TrainConfig
from radar4dgs.train.config import FitConfig, MotionConfig
from radar4dgs.train.data import MotionTargets
from radar4dgs.train.fit_motion import FlowSamples, fit_field, run_fit
from radar4dgs.train.model_init import prefit_field
from radar4dgs.train.objective import loss_weights, motion_losses
from radar4dgs.train.path_prior import path_loss, path_samples

pytestmark = pytest.mark.usefixtures("one_torch_thread")

vectors = st.lists(st.floats(-30, 30), min_size=3, max_size=3).map(np.array)


class PolynomialMotion:
    """A stand-in field: the canonical point ``c`` is at ``c + v t + b t^3`` at time t (exactly invertible)."""

    def __init__(self, v, b):
        self.v, self.b = torch.as_tensor(v, dtype=torch.float64), torch.as_tensor(b, dtype=torch.float64)

    def offset(self, t):
        t = torch.as_tensor(t, dtype=torch.float64).reshape(-1, 1)
        return self.v * t + self.b * t ** 3

    def forward(self, c, t):
        return c + self.offset(t)

    def inverse(self, x, t):
        return x - self.offset(t)


@settings(max_examples=30, deadline=None)
@given(v=vectors, a=vectors, t=st.floats(-1, 1), h=st.floats(0.01, 0.5))
def test_the_second_difference_is_zero_at_constant_velocity_and_a_h2_at_constant_acceleration(v, a, t, h):
    def path(s):
        return torch.as_tensor(v * s + 0.5 * a * s ** 2)[None]
    constant = acceleration_residual(*(torch.as_tensor(v * s)[None] for s in (t - h, t, t + h)))
    assert float(constant) == pytest.approx(0.0, abs=1e-9 * (1 + np.abs(v).sum()))
    accelerating = acceleration_residual(path(t - h), path(t), path(t + h))
    assert float(accelerating) == pytest.approx(float((a ** 2).sum()) * h ** 4, rel=1e-6, abs=1e-9)


def test_the_loss_of_a_cubic_path_is_its_closed_form_at_each_point_time():
    # p(t) = v t + b t^3: p(t+h) - 2 p(t) + p(t-h) = 6 b t h^2, whatever time the point was seen at.
    field = PolynomialMotion([3.0, -1.0, 0.5], [2.0, 0.0, -1.0])
    x = torch.tensor([[0.0, 0.0, 0.0], [5.0, 1.0, -2.0]], dtype=torch.float64)
    t_x, t, h = torch.tensor([0.2, 0.9]), torch.tensor([0.3, 0.6], dtype=torch.float64), 0.05
    per_point = acceleration_loss(field, x, t_x, t, h, reduction="none")
    expected = (6.0 * t * h ** 2) ** 2 * torch.tensor([4.0, 0.0, 1.0], dtype=torch.float64).sum()
    torch.testing.assert_close(per_point, expected)
    assert float(acceleration_loss(field, x, t_x, t, h)) == pytest.approx(float(expected.mean()))


def test_samples_pool_the_point_sets_and_step_by_the_shortest_frame_interval():
    times = np.array([0.0, 0.25, 0.5, 0.6, 1.0])
    a, b = (np.ones((2, 3)), np.array([0.0, 0.25])), (np.zeros((3, 3)), np.array([0.5, 0.5, 0.6]))
    samples = path_samples([a, b, (np.zeros((0, 3)), np.zeros(0))], times, reach=2.0)
    assert len(samples) == 5 and samples.step == pytest.approx(0.1) and samples.reach == 2.0
    np.testing.assert_array_equal(samples.t, [0.0, 0.25, 0.5, 0.5, 0.6])
    assert path_samples([], times, 2.0) is None
    assert path_samples([a], np.array([0.3]), 2.0) is None


@pytest.mark.parametrize("reach", [0.0, 3.0])
def test_points_are_checked_within_reach_steps_of_the_time_they_were_seen(reach):
    # Cubic motion: the loss at check time t is (6 |b| t h^2)^2, so it brackets the drawn times.
    field = PolynomialMotion([0.0, 0.0, 0.0], [1.0, 0.0, 0.0])
    samples = path_samples([(np.zeros((400, 3)), np.full(400, 0.5))], np.linspace(0, 1, 11), reach)
    h = samples.step
    generator = torch.Generator().manual_seed(0)
    mean_loss = path_loss(field, samples, torch.arange(400), generator, torch.float64, torch.device("cpu"))
    lowest, highest = (6.0 * (0.5 - reach * h) * h ** 2) ** 2, (6.0 * (0.5 + reach * h) * h ** 2) ** 2
    assert lowest - 1e-12 <= float(mean_loss) <= highest + 1e-12
    if reach == 0.0:
        assert float(mean_loss) == pytest.approx((6.0 * 0.5 * h ** 2) ** 2)
    else:  # uniform draws over +-3 steps: the mean of t^2 is 0.25 + (3h)^2 / 3
        assert float(mean_loss) == pytest.approx(36.0 * h ** 4 * (0.25 + (3 * h) ** 2 / 3.0), rel=0.05)


def car_leaving_the_view(seed_points: int = 0):
    """A 4 m car at constant velocity, seen in the first 11 of 21 frames: flow pairs of consecutive frames,
    and where it truly is at any time."""
    rng = np.random.default_rng(seed_points)
    body = rng.uniform([-2.0, -1.0, 0.0], [2.0, 1.0, 1.5], (300, 3))
    times = np.linspace(0.0, 1.0, 21)

    def at(t):
        return body + np.array([0.0, 10.0, 0.0]) + np.array([20.0, 1.0, 0.0]) * t

    seen = times[:11]
    flow = FlowSamples(np.concatenate([at(t) for t in seen[:-1]]), np.concatenate([at(t) for t in seen[1:]]),
                       np.repeat(seen[:-1], len(body)), np.repeat(seen[1:], len(body)))
    return flow, times, at


def extrapolation_error(field, at, t_from: float, t_to: float) -> float:
    with torch.no_grad():
        moved = field.warp(torch.as_tensor(at(t_from), dtype=torch.float32), t_from, t_to).double().numpy()
    return float(np.linalg.norm(moved - at(t_to), axis=1).mean())


def test_a_fit_with_the_prior_carries_a_car_leaving_the_view_on_straight():
    flow, times, at = car_leaving_the_view()
    path = path_samples([(flow.x_i, flow.t_i), (flow.x_j, flow.t_j)], times, reach=2.0)
    field_config = preset(MotionConfig, "tiny").field
    errors = {}
    for weight in (0.0, 1.0):
        fit = FitConfig(iterations=300, batch_size=256, seed=0, acceleration_weight=weight)
        field, history = fit_field(flow, None, field_config, fit, path=path)
        errors[weight] = (extrapolation_error(field, at, times[10], times[11]),
                          extrapolation_error(field, at, times[4], times[5]))
        assert ("acceleration" in history[-1]) == (weight > 0)
    # One frame after the last flow pair (1 m of motion): measured 0.27 m without the prior, 0.12 with it;
    # inside the seen frames both fit to about 4 cm.
    assert errors[1.0][0] < 0.6 * errors[0.0][0]
    assert errors[1.0][1] < 0.08 and errors[0.0][1] < 0.08


def test_the_trainer_draws_the_term_after_the_others_and_weighs_it():
    flow, times, _ = car_leaving_the_view()
    path = path_samples([(flow.x_i, flow.t_i)], times, reach=2.0)
    config = preset(TrainConfig, "tiny", losses={"acceleration_weight": 0.7, "radar_weight": 0.0},
                    optim={"field_prefit_iterations": 20})
    assert loss_weights(config)["acceleration"] == 0.7
    field = prefit_field(config, MotionTargets(flow, None, {}, path=path), torch.device("cpu"), torch.float32)
    terms = {}
    for with_path in (False, True):
        motion = MotionTargets(flow, None, {}, path=path if with_path else None)
        generator = torch.Generator().manual_seed(3)
        terms[with_path] = {k: v.detach() for k, v in motion_losses(field, motion, 64, generator, torch.device("cpu"),
                                                                 torch.float32).items()}
    assert set(terms[False]) == {"flow"} and set(terms[True]) == {"flow", "acceleration"}
    assert float(terms[True]["flow"]) == float(terms[False]["flow"])  # the flow draws are unchanged
    assert float(terms[True]["acceleration"]) >= 0.0


def test_the_standalone_fit_takes_the_prior_from_its_config(motion_scene, motion_prepared):
    config = preset(MotionConfig, "tiny", flow={"depth_source": "oracle", "mask_source": "oracle"},
                    fit={"radar_source": "oracle", "iterations": 20, "acceleration_weight": 0.5})
    _, result = run_fit(motion_scene, motion_prepared, config, evaluate=False)
    assert all("acceleration" in row for row in result["history"])
    last, fit = result["history"][-1], config.fit
    assert last["total"] == pytest.approx(last["flow"] + fit.radar_weight * last.get("radar", 0.0)
                                          + fit.velocity_weight * last.get("velocity", 0.0)
                                          + 0.5 * last["acceleration"], rel=1e-5)
