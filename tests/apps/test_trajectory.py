"""Re-rendering camera paths: recorded, lane shift, height, bullet time, custom files, upsampling."""

from __future__ import annotations

import json
import re

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from scipy.spatial.transform import Rotation

from radar4dgs.apps.trajectory import (
    CameraPose,
    build_trajectory,
    interpolate_trajectory,
    parse_trajectory,
    write_custom_trajectory,
)

# Front camera as the scene format has it: OpenCV camera (x right, y down, z forward) in the ego
# frame (x forward, y left, z up), 1.5 m up.
CAM_TO_EGO = np.array([[0.0, 0.0, 1.0, 1.0],
                       [-1.0, 0.0, 0.0, 0.0],
                       [0.0, -1.0, 0.0, 1.5],
                       [0.0, 0.0, 0.0, 1.0]])


def ego_to_world(x: float, y: float, yaw: float) -> np.ndarray:
    m = np.eye(4)
    m[:3, :3] = Rotation.from_euler("z", yaw).as_matrix()
    m[:3, 3] = (x, y, 0.0)
    return m


def recorded(n: int = 6) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(world_to_cameras (n, 4, 4), times (n,), ego yaws (n,)) of a car driving a left curve."""
    yaws = np.linspace(0.0, 0.6, n)
    w2c = np.stack([np.linalg.inv(ego_to_world(3.0 * i, 0.2 * i * i, yaw) @ CAM_TO_EGO)
                    for i, yaw in enumerate(yaws)])
    return w2c, np.linspace(0.0, 1.0, n), yaws


def centres(poses) -> np.ndarray:
    return np.stack([p.center for p in poses])


def rotations(poses) -> np.ndarray:
    return np.stack([p.world_to_camera[:3, :3] for p in poses])


def test_recorded_is_identity():
    w2c, times, _ = recorded()
    poses = build_trajectory("recorded", w2c, times)
    assert len(poses) == len(w2c)
    for pose, m, t in zip(poses, w2c, times, strict=True):
        assert isinstance(pose, CameraPose)
        assert pose.world_to_camera.dtype == np.float64 and pose.world_to_camera.shape == (4, 4)
        np.testing.assert_array_equal(pose.world_to_camera, m)
        assert pose.time == t
    # The result does not alias the input.
    poses[0].world_to_camera[0, 0] = 7.0
    assert w2c[0, 0, 0] != 7.0


def test_lane_shift_moves_left_by_exactly_m_and_keeps_orientation():
    w2c, times, yaws = recorded()
    base = build_trajectory("recorded", w2c, times)
    shifted = build_trajectory("lane-shift:2", w2c, times)
    # Ego +y (left) in world coordinates for each frame.
    left = np.stack([-np.sin(yaws), np.cos(yaws), np.zeros_like(yaws)], axis=1)
    np.testing.assert_allclose(centres(shifted) - centres(base), 2.0 * left, atol=1e-12)
    np.testing.assert_array_equal(rotations(shifted), rotations(base))
    assert [p.time for p in shifted] == list(times)

    right = build_trajectory("lane-shift:-1.5", w2c, times)
    np.testing.assert_allclose(centres(right) - centres(base), -1.5 * left, atol=1e-12)


def test_lane_shift_positive_is_world_plus_y_for_the_first_frame():
    # The world frame is the first frame's ego frame: left is +y there.
    w2c = np.linalg.inv(CAM_TO_EGO)[None]
    pose = build_trajectory("lane-shift:2", w2c, np.zeros(1))[0]
    np.testing.assert_allclose(pose.center, [1.0, 2.0, 1.5], atol=1e-12)


def test_lane_shift_of_a_tilted_camera_stays_horizontal():
    tilt = np.eye(4)
    tilt[:3, :3] = Rotation.from_euler("xz", [0.3, -0.2]).as_matrix()  # roll and pitch, camera axes
    w2c = np.linalg.inv(ego_to_world(5.0, 1.0, 0.4) @ CAM_TO_EGO @ tilt)[None]
    before = build_trajectory("recorded", w2c, np.zeros(1))[0].center
    after = build_trajectory("lane-shift:3", w2c, np.zeros(1))[0].center
    assert after[2] == pytest.approx(before[2], abs=1e-12)
    assert np.linalg.norm(after - before) == pytest.approx(3.0, abs=1e-12)


def test_height_moves_up_along_world_z():
    w2c, times, _ = recorded()
    base = build_trajectory("recorded", w2c, times)
    up = build_trajectory("height:1.25", w2c, times)
    np.testing.assert_allclose(centres(up) - centres(base), [[0.0, 0.0, 1.25]] * len(w2c), atol=1e-12)
    np.testing.assert_array_equal(rotations(up), rotations(base))
    assert [p.time for p in up] == list(times)
    down = build_trajectory("height:-0.5", w2c, times, up=(0.0, 0.0, 2.0))  # up is normalised
    np.testing.assert_allclose(centres(down)[:, 2] - centres(base)[:, 2], -0.5, atol=1e-12)


def test_stop_time_freezes_time_and_follows_the_recorded_path():
    w2c, times, _ = recorded(5)
    for spec, frozen in (("stop-time:2", times[2]), ("stop-time:1", times[1]),
                         ("stop-time:0.5", 0.5), ("stop-time:1.0", 1.0), ("stop-time:0", 0.0)):
        poses = build_trajectory(spec, w2c, times)
        assert [p.time for p in poses] == [frozen] * 5, spec
        for pose, m in zip(poses, w2c, strict=True):
            np.testing.assert_array_equal(pose.world_to_camera, m)
    with pytest.raises(ValueError, match=re.escape("'stop-time:5'") + ".*out of range for 5 frames"):
        build_trajectory("stop-time:5", w2c, times)


def test_custom_json_round_trip(tmp_path):
    w2c, times, _ = recorded(4)
    original = build_trajectory("lane-shift:1", w2c, times)
    path = write_custom_trajectory(tmp_path / "path.json", original)
    back = build_trajectory(f"custom:{path}", w2c[:1], times[:1])  # recorded cameras ignored
    assert len(back) == len(original)
    for a, b in zip(back, original, strict=True):
        np.testing.assert_array_equal(a.world_to_camera, b.world_to_camera)
        assert a.time == b.time


def test_custom_json_camera_to_world_form(tmp_path):
    c2w = ego_to_world(2.0, -1.0, 0.3) @ CAM_TO_EGO
    path = tmp_path / "c2w.json"
    path.write_text(json.dumps([{"camera_to_world": c2w.tolist(), "time": 0.25},
                                {"world_to_camera": np.eye(4).tolist(), "time": 1}]))
    spec = parse_trajectory(f"custom:{path}")
    assert spec.kind == "custom" and spec.path == path
    poses = build_trajectory(spec, np.eye(4)[None], np.zeros(1))
    np.testing.assert_allclose(poses[0].world_to_camera, np.linalg.inv(c2w), atol=1e-12)
    np.testing.assert_allclose(poses[0].center, c2w[:3, 3], atol=1e-12)
    assert poses[0].time == 0.25 and poses[1].time == 1.0


@pytest.mark.parametrize("content, message", [
    ("not json", "cannot read the custom trajectory as JSON"),
    ("[]", "non-empty JSON list"),
    ('[{"world_to_camera": [[1,0,0,0],[0,1,0,0],[0,0,1,0],[0,0,0,1]]}]', "missing 'time'"),
    ('[{"time": 0.1}]', "exactly one of"),
    ('[{"world_to_camera": [[2,0,0,0],[0,1,0,0],[0,0,1,0],[0,0,0,1]], "time": 0}]', "not a rotation"),
    ('[{"world_to_camera": [[1,0,0],[0,1,0],[0,0,1]], "time": 0}]', "expected a 4x4 matrix"),
    ('[{"world_to_camera": [[1,0,0,0],[0,1,0,0],[0,0,1,0],[0,0,0,1]], "time": 1.5}]', r"\[0, 1\]"),
    ('[{"world_to_camera": [[1,0,0,0],[0,1,0,0],[0,0,1,0],[0,0,0,1]], "time": 0, "fov": 1}]',
     "unknown keys"),
])
def test_bad_custom_files_name_the_spec_and_the_problem(tmp_path, content, message):
    path = tmp_path / "bad.json"
    path.write_text(content)
    spec = f"custom:{path}"
    with pytest.raises(ValueError, match=re.escape(repr(spec)) + ".*" + message):
        parse_trajectory(spec)


@pytest.mark.parametrize("spec", ["", "sideways", "lane-shift", "lane-shift:", "lane-shift:abc",
                                  "height:nan", "height:inf", "stop-time:1.5", "stop-time:-1",
                                  "stop-time:soon", "recorded:3", "custom:/no/such/file.json",
                                  "lane_shift:2"])
def test_bad_specs_raise_naming_the_spec(spec):
    with pytest.raises(ValueError, match=re.escape(repr(spec))):
        parse_trajectory(spec)
    w2c, times, _ = recorded(2)
    with pytest.raises(ValueError, match=re.escape(repr(spec))):
        build_trajectory(spec, w2c, times)


def test_bad_recorded_inputs():
    w2c, times, _ = recorded(3)
    with pytest.raises(ValueError, match=r"times must have shape \(3,\)"):
        build_trajectory("recorded", w2c, times[:2])
    with pytest.raises(ValueError, match=r"\(N, 4, 4\)"):
        build_trajectory("recorded", w2c[:, :3], times)
    with pytest.raises(ValueError, match=r"normalised to \[0, 1\]"):
        build_trajectory("recorded", w2c, times * 10)
    scaled = w2c.copy()
    scaled[1, :3, :3] *= 2
    with pytest.raises(ValueError, match=r"world_to_cameras\[1\].*not a rotation"):
        build_trajectory("recorded", scaled, times)


def test_interpolate_upsamples_with_slerp_and_lerp():
    w2c, times, yaws = recorded(4)
    base = build_trajectory("recorded", w2c, times)
    dense = build_trajectory("recorded", w2c, times, interpolate=3)
    assert len(dense) == (4 - 1) * 3 + 1
    assert interpolate_trajectory(base, 3)[4].time == dense[4].time
    for j, key in enumerate(base):  # keyframes kept exactly
        np.testing.assert_array_equal(dense[3 * j].world_to_camera, key.world_to_camera)
        assert dense[3 * j].time == key.time
    # One third of the way between frames 0 and 1: centre and time lerped, yaw slerped.
    c0, c1 = base[0].center, base[1].center
    np.testing.assert_allclose(dense[1].center, c0 + (c1 - c0) / 3, atol=1e-12)
    assert dense[1].time == pytest.approx(times[0] + (times[1] - times[0]) / 3)
    relative = dense[1].camera_to_world[:3, :3] @ np.linalg.inv(CAM_TO_EGO[:3, :3])
    yaw = Rotation.from_matrix(relative).as_euler("zyx")[0]
    assert yaw == pytest.approx(yaws[0] + (yaws[1] - yaws[0]) / 3, abs=1e-12)
    for pose in dense:
        R = pose.world_to_camera[:3, :3]
        np.testing.assert_allclose(R @ R.T, np.eye(3), atol=1e-12)
    # Bullet time stays frozen between keyframes.
    assert {p.time for p in build_trajectory("stop-time:0.3", w2c, times, interpolate=4)} == {0.3}
    with pytest.raises(ValueError, match="integer >= 1"):
        interpolate_trajectory(base, 0)
    assert len(interpolate_trajectory(base[:1], 5)) == 1


@st.composite
def camera_poses(draw):
    n = draw(st.integers(1, 5))
    seed = draw(st.integers(0, 2**32 - 1))
    rng = np.random.default_rng(seed)
    w2c = np.tile(np.eye(4), (n, 1, 1))
    w2c[:, :3, :3] = Rotation.random(n, random_state=seed).as_matrix()
    w2c[:, :3, 3] = rng.uniform(-100, 100, (n, 3))
    return w2c


@settings(max_examples=60, deadline=None)
@given(w2c=camera_poses(), m=st.floats(-20.0, 20.0, allow_nan=False))
def test_lane_shift_distance_is_abs_m_for_random_poses(w2c, m):
    times = np.linspace(0.0, 1.0, len(w2c))
    base = build_trajectory("recorded", w2c, times)
    shifted = build_trajectory(f"lane-shift:{m!r}", w2c, times)
    distance = np.linalg.norm(centres(shifted) - centres(base), axis=1)
    np.testing.assert_allclose(distance, abs(m), atol=1e-9)
    np.testing.assert_array_equal(rotations(shifted), rotations(base))
    # Height is kept whenever the camera's x axis is not (nearly) vertical.
    horizontal = np.linalg.norm(w2c[:, 0, :2], axis=1) > 1e-3
    np.testing.assert_allclose(centres(shifted)[horizontal, 2], centres(base)[horizontal, 2], atol=1e-9)
    # The shift is towards the camera's left (-x): it is never on the right side.
    right = w2c[:, 0, :3]
    assert np.all(np.einsum("ni,ni->n", centres(shifted) - centres(base), right) * np.sign(m)
                  <= 1e-9)
