import math

import numpy as np
import pytest
import torch
from hypothesis import given, settings
from hypothesis import strategies as st
from scipy.spatial.transform import Rotation

from radar4dgs.model.actor_motion import ActorMotion, interpolation_weights, quaternion_product, yaw_quaternions

angles = st.floats(-math.pi, math.pi)


@settings(max_examples=30, deadline=None)
@given(yaw=angles, rotvec=st.lists(st.floats(-2, 2), min_size=3, max_size=3))
def test_yaw_turns_a_rotation_as_scipy_composes_them(yaw, rotvec):
    inner = Rotation.from_rotvec(rotvec)
    quat = torch.tensor(np.roll(inner.as_quat(), 1)[None])  # scipy is xyzw, ours wxyz
    product = quaternion_product(yaw_quaternions(torch.tensor([yaw], dtype=torch.float64)), quat)[0].numpy()
    expected = (Rotation.from_euler("z", yaw) * inner).as_matrix()
    np.testing.assert_allclose(Rotation.from_quat(np.roll(product, -1)).as_matrix(), expected, atol=1e-9)


def test_interpolation_weights_are_linear_and_extrapolate_beyond_the_keys():
    keys = torch.tensor([0.0, 0.25, 1.0])
    assert interpolation_weights(keys, 0.125) == (0, 1, pytest.approx(0.5))
    assert interpolation_weights(keys, 0.625) == (1, 2, pytest.approx(0.5))
    assert interpolation_weights(keys, -0.25) == (0, 1, pytest.approx(-1.0))
    assert interpolation_weights(keys, 1.75) == (1, 2, pytest.approx(2.0))
    assert interpolation_weights(torch.tensor([0.3]), 0.9) == (0, 0, 0.0)


def test_a_body_turns_about_its_pivot_and_shifts_with_its_key_poses():
    keys = torch.tensor([0.0, 1.0], dtype=torch.float64)
    pivots = torch.tensor([[10.0, 5.0, 0.0], [0.0, 0.0, 0.0]], dtype=torch.float64)
    yaw = torch.tensor([[0.0, math.pi / 2], [0.0, 0.0]], dtype=torch.float64)
    shift = torch.zeros(2, 2, 3, dtype=torch.float64)
    shift[0, 1] = torch.tensor([4.0, 0.0, 1.0])
    shift[1, :, 1] = torch.tensor([0.0, 2.0])
    motion = ActorMotion(keys, pivots, yaw, shift)
    means = torch.tensor([[12.0, 5.0, 1.0], [1.0, 1.0, 1.0]], dtype=torch.float64)
    quats = torch.tensor([[1.0, 0, 0, 0]] * 2, dtype=torch.float64)
    actor = torch.tensor([0, 1])
    at_start, _ = motion(means, quats, actor, 0.0)
    torch.testing.assert_close(at_start, means)
    at_end, turned = motion(means, quats, actor, 1.0)
    # (12, 5) is 2 m ahead of the pivot: a quarter turn puts it 2 m to its left, then 4 m on.
    torch.testing.assert_close(at_end, torch.tensor([[14.0, 7.0, 2.0], [1.0, 3.0, 1.0]], dtype=torch.float64))
    torch.testing.assert_close(turned[0], yaw_quaternions(torch.tensor([math.pi / 2], dtype=torch.float64))[0])
    halfway, _ = motion(means, quats, actor, 0.5)
    c = math.cos(math.pi / 4)
    torch.testing.assert_close(halfway[0], torch.tensor([10 + 2 * c + 2, 5 + 2 * c, 1.5], dtype=torch.float64))


def test_state_round_trip_and_shape_checks():
    motion = ActorMotion(torch.linspace(0, 1, 4), torch.randn(3, 3), torch.randn(3, 4), torch.randn(3, 4, 3))
    again = ActorMotion.from_state(motion.state())
    for name in ("key_times", "pivots", "yaw", "shift"):
        torch.testing.assert_close(getattr(again, name), getattr(motion, name))
    with pytest.raises(ValueError, match="inconsistent shapes"):
        ActorMotion(torch.linspace(0, 1, 4), torch.randn(3, 3), torch.randn(3, 5), torch.randn(3, 4, 3))


def test_acceleration_is_zero_at_constant_velocity_and_counts_a_jolt():
    keys = torch.tensor([0.0, 0.1, 0.3, 0.4])  # uneven spacing: a held-out frame between 0.1 and 0.3
    shift = torch.zeros(1, 4, 3)
    shift[0, :, 0] = 5.0 * keys  # constant velocity
    yaw = (0.2 * keys)[None]
    motion = ActorMotion(keys, torch.zeros(1, 3), yaw, shift)
    assert float(motion.acceleration().detach()) == pytest.approx(0.0, abs=1e-10)
    with torch.no_grad():
        motion.shift[0, 3, 0] += 0.3  # the last key 0.3 m further: its interval's rate (per mean step) jumps
    spacing_mean = float((keys[1:] - keys[:-1]).mean())
    jump = 0.3 / (0.1 / spacing_mean)
    assert float(motion.acceleration().detach()) == pytest.approx(jump ** 2 / 2, rel=1e-5)  # mean over 2 changes
    assert ActorMotion(keys[:2], torch.zeros(1, 3), yaw[:, :2], shift[:, :2]).acceleration() == 0.0


def arc_motion(radius: float, speed: float, keys: int, sideslip: float, duration: float, yaw_turns: bool
               ) -> tuple[ActorMotion, float]:
    """One body driving a circle of ``radius`` m at ``speed`` m/s for ``duration`` s, sampled at ``keys`` even keys,
    its yaw following the path (plus a constant ``sideslip``) or held at 0; and the path's turn a key."""
    times = torch.linspace(0.0, 1.0, keys, dtype=torch.float64)
    angle = speed * duration * times / radius
    shift = torch.stack([radius * torch.sin(angle), radius * (1 - torch.cos(angle)), torch.zeros_like(angle)], -1)
    yaw = (angle + sideslip) if yaw_turns else torch.zeros_like(angle)
    return ActorMotion(times, torch.zeros(1, 3, dtype=torch.float64), yaw[None], shift[None]), float(angle[1])


@settings(max_examples=25, deadline=None)
@given(radius=st.floats(8.0, 200.0), speed=st.floats(4.0, 25.0), sideslip=st.floats(-0.2, 0.2),
       keys=st.integers(3, 12))
def test_heading_mismatch_is_zero_for_a_body_turning_with_its_path_and_its_turn_squared_when_it_does_not(
        radius, speed, sideslip, keys):
    duration = min(2.0, 0.9 * math.pi * radius / speed)  # less than half the circle
    turning, _ = arc_motion(radius, speed, keys, sideslip, duration, yaw_turns=True)
    assert float(turning.heading_mismatch(duration).detach()) == pytest.approx(0.0, abs=1e-12)
    held, turn = arc_motion(radius, speed, keys, 0.0, duration, yaw_turns=False)
    # Chords of a circle turn by the arc's angle a key, which the held yaw never does.
    assert float(held.heading_mismatch(duration).detach()) == pytest.approx(turn ** 2, rel=1e-9)


def test_heading_mismatch_ignores_a_still_body_and_pulls_only_the_yaw():
    still = ActorMotion(torch.linspace(0, 1, 5), torch.zeros(1, 3), torch.tensor([[0.0, 0.5, -0.3, 1.0, 0.2]]),
                        torch.zeros(1, 5, 3))
    assert float(still.heading_mismatch(10.0).detach()) == 0.0
    held, turn = arc_motion(20.0, 10.0, 6, 0.0, 2.0, yaw_turns=False)
    # At half the minimum speed the pairs count half, but they are all there is: the same mean.
    slow, _ = arc_motion(20.0, 10.0, 6, 0.0, 2.0, yaw_turns=False)
    assert float(slow.heading_mismatch(2.0, min_speed=20.0).detach()) == pytest.approx(turn ** 2, rel=1e-9)
    held.heading_mismatch(2.0).backward()
    assert held.shift.grad is None or float(held.shift.grad.abs().max()) == 0.0
    assert float(held.yaw.grad.abs().max()) > 0.0
    assert ActorMotion(torch.tensor([0.0, 1.0]), torch.zeros(1, 3), torch.zeros(1, 2),
                       torch.zeros(1, 2, 3)).heading_mismatch(1.0) == 0.0
