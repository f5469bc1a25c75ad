import math
from types import SimpleNamespace

import numpy as np
import pytest
import torch
from hypothesis import given, settings
from hypothesis import strategies as st

from radar4dgs.model.config import BaselineConfig
from radar4dgs.model.gaussians import GaussianSet
from radar4dgs.model.scene_model import SceneModel
from radar4dgs.model.sky import SkyEnvironment
from radar4dgs.train.optimizers import adam
from radar4dgs.train.rigid_actors import (
    actor_image_motion,
    body_attachments,
    born_span,
    extrapolate_ends,
    fit_rigid_track,
    procrustes_yaw,
    radar_corrected_shift,
    radar_key_velocities,
    rigid_actor_motion,
    rigid_members,
    start_rigid_actors,
)


def turn(points: np.ndarray, yaw: float) -> np.ndarray:
    c, s = math.cos(yaw), math.sin(yaw)
    return np.stack([c * points[..., 0] - s * points[..., 1], s * points[..., 0] + c * points[..., 1],
                     points[..., 2]], axis=-1)


@settings(max_examples=25, deadline=None)
@given(yaw=st.floats(-3.0, 3.0))
def test_procrustes_yaw_is_the_rotation_between_two_point_sets(yaw):
    points = np.random.default_rng(0).normal(size=(20, 3))
    found = procrustes_yaw(points[:, :2], turn(points, yaw)[:, :2], np.ones(20))
    assert abs(math.remainder(found - yaw, 2 * math.pi)) < 1e-9


@settings(max_examples=20, deadline=None)
@given(seed=st.integers(0, 1000), keys=st.integers(2, 7))
def test_a_rigid_track_is_recovered_from_copies_that_live_around_their_own_key(seed, keys):
    """One copy of a body per key (as each training frame adds one), each rendering at its key and the
    next ones only; the field's positions of a copy elsewhere are junk and must not count."""
    rng = np.random.default_rng(seed)
    body = rng.uniform([-2, -1, 0], [2, 1, 1.5], (30, 3)) + [20, 3, 0]
    yaws, shifts = rng.uniform(-0.5, 0.5, keys), rng.uniform(-5, 5, (keys, 3))
    centre = body.mean(axis=0)
    truth = np.stack([turn(body - centre, yaws[k]) + centre + shifts[k] for k in range(keys)], axis=1)
    positions = np.concatenate([truth] * keys)  # copy j: rows 30 j .. 30 j + 29
    opacities = np.zeros((30 * keys, keys))
    for j in range(keys):
        rows = slice(30 * j, 30 * (j + 1))
        alive = [k for k in range(keys) if abs(k - j) <= 1]
        opacities[rows, alive] = [1.0 if k == j else 0.3 for k in alive]
        dead = [k for k in range(keys) if k not in alive]
        positions[rows, dead] = rng.uniform(-100, 100, (30, len(dead), 3))
    pivot, yaw, shift, canonical = fit_rigid_track(positions, opacities)
    for k in range(keys):
        moved = turn(canonical - pivot, yaw[k]) + pivot + shift[k]
        np.testing.assert_allclose(moved, np.concatenate([truth[:, k]] * keys), atol=1e-7)


@settings(max_examples=20, deadline=None)
@given(seed=st.integers(0, 1000), climb=st.floats(0.05, 1.0))
def test_a_flat_path_keeps_its_height_and_every_copy_where_the_field_put_it_at_its_own_key(seed, climb):
    """A car driving on level ground whose copies the field lifts by ``climb`` metres a key: held flat, the path's
    step carries a copy to the next key at the car's true height, and each copy stays put at its own key."""
    rng = np.random.default_rng(seed)
    keys, body = 6, rng.uniform([-2, -1, 0], [2, 1, 1.5], (30, 3)) + [20, 3, 0]
    truth = np.stack([body + [4.0 * k, 0.0, 0.0] for k in range(keys)], axis=1)
    field = truth + np.array([0.0, 0.0, climb])[None, None] * np.arange(keys)[None, :, None]
    opacities = np.zeros((30 * keys, keys))
    for j in range(keys):
        opacities[30 * j:30 * (j + 1), j] = 1.0
        opacities[30 * j:30 * (j + 1), [k for k in (j - 1, j + 1) if 0 <= k < keys]] = 0.3
    positions = np.concatenate([field] * keys)
    pivot, yaw, shift, canonical = fit_rigid_track(positions, opacities, flat=True)
    assert np.all(shift[:, 2] == 0.0)
    for j in range(keys):
        rows = slice(30 * j, 30 * (j + 1))
        at_own = turn(canonical[rows] - pivot, yaw[j]) + pivot + shift[j]
        np.testing.assert_allclose(at_own, field[:, j], atol=1e-7)
        if j + 1 < keys:
            carried = turn(canonical[rows] - pivot, yaw[j + 1]) + pivot + shift[j + 1]
            np.testing.assert_allclose(carried - at_own, truth[:, j + 1] - truth[:, j], atol=1e-7)
    # Not flat, the path climbs with the field.
    _, _, climbing, _ = fit_rigid_track(positions, opacities)
    np.testing.assert_allclose(np.diff(climbing[:, 2]), climb, atol=1e-7)


def test_the_born_span_ignores_a_few_stray_copies():
    # Copies peaking at keys 0..6: masses 0.5 (stray), 0, 10, 20, 30, 20, 1 (below a tenth of 30).
    peaks = [0.5, 0.0, 10.0, 20.0, 30.0, 20.0, 1.0]
    opacities = np.zeros((7, 7))
    opacities[np.arange(7), np.arange(7)] = peaks
    opacities[1] = 0.0  # a copy that never renders peaks at key 0 by argmax, with no mass
    assert born_span(opacities) == (2, 5)


@settings(max_examples=25, deadline=None)
@given(seed=st.integers(0, 1000), first=st.integers(0, 3), length=st.integers(1, 4))
def test_the_ends_go_on_at_the_velocity_of_the_first_and_last_born_keys(seed, first, length):
    rng = np.random.default_rng(seed)
    times = np.cumsum(rng.uniform(0.5, 2.0, 10))
    yaw, shift = rng.uniform(-1, 1, 10), rng.uniform(-9, 9, (10, 3))
    last = min(first + length, 9)
    new_yaw, new_shift = extrapolate_ends(yaw, shift, times, first, last)
    inside = slice(first, last + 1)
    np.testing.assert_array_equal(new_shift[inside], shift[inside])
    np.testing.assert_array_equal(new_yaw[inside], yaw[inside])
    head = (shift[first + 1] - shift[first]) / (times[first + 1] - times[first])
    tail = (shift[last] - shift[last - 1]) / (times[last] - times[last - 1])
    for k in range(first):
        np.testing.assert_allclose(new_shift[k], shift[first] + head * (times[k] - times[first]), atol=1e-9)
        assert new_yaw[k] == yaw[first]
    for k in range(last + 1, 10):
        np.testing.assert_allclose(new_shift[k], shift[last] + tail * (times[k] - times[last]), atol=1e-9)
        assert new_yaw[k] == yaw[last]
    # One born key: no velocity to go on with, nothing changes.
    same_yaw, same_shift = extrapolate_ends(yaw, shift, times, 4, 4)
    assert np.array_equal(same_yaw, yaw) and np.array_equal(same_shift, shift)


def test_a_car_entering_late_keeps_its_speed_before_it_is_seen():
    """A body crossing at 3 m per key, born at keys 3-6 only; before key 3 the field moved its copies
    anywhere (far outside their life spans). With the keys' times, the path before key 3 is the
    body's own constant velocity, not the junk."""
    rng = np.random.default_rng(1)
    keys, body = 8, rng.uniform([-2, -1, 0], [2, 1, 1.5], (30, 3)) + [40, 0, 0]
    truth = np.stack([body + [0.0, 3.0 * k, 0.0] for k in range(keys)], axis=1)
    positions = np.concatenate([truth] * 4)  # copies born at keys 3, 4, 5, 6
    opacities = np.zeros((120, keys))
    for j, born in enumerate(range(3, 7)):
        rows = slice(30 * j, 30 * (j + 1))
        opacities[rows, born] = 1.0
        opacities[rows, [born - 1, born + 1]] = 0.3
        positions[rows, :born - 1] = rng.uniform(-100, 100, (30, born - 1, 3))
    times = np.arange(keys, dtype=np.float64)
    pivot, yaw, shift, canonical = fit_rigid_track(positions, opacities, times)
    for k in range(keys):
        moved = turn(canonical - pivot, yaw[k]) + pivot + shift[k]
        np.testing.assert_allclose(moved[:30], truth[:, k], atol=1e-6)
    # Without the times the junk decides the first keys.
    _, _, junk, _ = fit_rigid_track(positions, opacities)
    assert np.abs(junk[0] - shift[0]).max() > 1.0


def pvg_model(velocity: np.ndarray, n: int = 40) -> tuple[SceneModel, np.ndarray]:
    """A model whose dynamic set is two bodies of ``n`` Gaussians moving at constant velocities
    (PVG with a period far longer than the sequence: linear to 1e-7), and their index groups."""
    rng = np.random.default_rng(0)
    means = np.concatenate([rng.normal(size=(n, 3)) + [10, 0, 1], rng.normal(size=(n, 3)) + [20, 5, 1]])
    speeds = np.repeat(velocity, n, axis=0)
    kw = {"dtype": torch.float64}
    dynamic = GaussianSet({"means": torch.tensor(means, **kw), "quats": torch.tensor([[1.0, 0, 0, 0]] * 2 * n, **kw),
                           "log_scales": torch.full((2 * n, 3), -2.0, **kw),
                           "opacity_logits": torch.full((2 * n,), 4.0, **kw), "colors": torch.zeros(2 * n, 3, **kw),
                           "velocity": torch.tensor(speeds, **kw), "tau": torch.zeros(2 * n, **kw)})
    static = GaussianSet({k: v[:1].clone() for k, v in dynamic.params.items() if k not in ("velocity", "tau")})
    model = SceneModel(static, SkyEnvironment(4, 8, dtype=torch.float64), None, dynamic,
                       baseline=BaselineConfig(pvg_period=1e4))
    return model, [np.arange(n), np.arange(n, 2 * n)]


def test_switching_to_rigid_actors_keeps_every_position_between_and_beyond_the_keys():
    model, groups = pvg_model(np.array([[8.0, 0.0, 0.0], [-3.0, 4.0, 0.0]]))
    times = np.linspace(0.0, 1.0, 11)
    before = [model.set_at("dynamic", t)["means"].detach().clone() for t in times]
    optimizer = adam(model.dynamic.param_groups({"means": 0.01, "colors": 0.01}), eps=1e-15)
    motion, actor, start = rigid_actor_motion(model, groups, times[1:-1:2])  # keys: every other frame, not the ends
    rigid_members(model, motion, actor, start, optimizer)
    assert model.dynamic.has("actor") and (model.dynamic.params["actor"] >= 0).all()
    assert optimizer.param_groups[0]["params"][0] is model.dynamic.params["means"]
    np.testing.assert_allclose(motion.yaw.detach().numpy(), 0.0, atol=1e-9)
    for t, expected in zip(times, before, strict=True):
        torch.testing.assert_close(model.set_at("dynamic", t)["means"], expected, atol=1e-6, rtol=0)
    payload = SceneModel.from_payload(model.payload(), dtype=torch.float64)
    torch.testing.assert_close(payload.set_at("dynamic", 0.3)["means"], model.set_at("dynamic", 0.3)["means"])


K_TEST = np.array([[100.0, 0.0, 50.0], [0.0, 100.0, 50.0], [0.0, 0.0, 1.0]])


def sliding_centroids(frames: int, step_m: float, depth: float = 10.0) -> np.ndarray:
    """(F, 3) a centroid ``depth`` m in front of an identity camera, moving ``step_m`` m along x a frame."""
    return np.stack([np.arange(frames) * step_m, np.zeros(frames), np.full(frames, depth)], axis=1)


def test_actor_image_motion_is_the_projected_step_between_consecutive_frames():
    poses = np.repeat(np.eye(4)[None], 8, axis=0)
    centroids = sliding_centroids(8, 0.5)  # f * 0.5 m / 10 m = 5 px a frame
    assert actor_image_motion(centroids, np.array([0, 1, 2, 3, 6, 7]), poses, K_TEST) == pytest.approx(5.0)
    centroids[3, 0] += 4.0  # frame 3 alone 40 px off: the steps 2->3 and 3->4 are 45 and 35 px
    steps = np.array([5.0, 5.0, 45.0, 35.0, 5.0, 5.0, 5.0])
    assert actor_image_motion(centroids, np.arange(8), poses, K_TEST) == pytest.approx(np.percentile(steps, 90))
    assert actor_image_motion(centroids, np.array([0, 2, 4]), poses, K_TEST) == 0.0  # no consecutive pair
    behind = sliding_centroids(8, 0.5, depth=-10.0)
    assert actor_image_motion(behind, np.arange(8), poses, K_TEST) == 0.0


def test_only_actors_moving_far_enough_in_the_image_become_rigid(monkeypatch):
    import types

    import radar4dgs.train.rigid_actors as rigid_module

    model, groups = pvg_model(np.array([[8.0, 0.0, 0.0], [-3.0, 4.0, 0.0]]))
    frames = 6
    actors = [types.SimpleNamespace(gaussians=members, centroid=sliding_centroids(frames, step),
                                    frames=np.arange(frames))
              for members, step in zip(groups, (1.0, 0.0), strict=True)]
    monkeypatch.setattr(rigid_module, "discover_actors", lambda *args, **kwargs: actors)

    class Scene:  # 100 px wide; the fast actor moves 10 px a frame, the other not at all
        camera = types.SimpleNamespace(K=K_TEST, width=100)
        frames = [types.SimpleNamespace(timestamp=0.2 * i) for i in range(6)]

        def __len__(self):
            return frames

        def world_to_camera(self, index):
            return np.eye(4)

    optimizers = {"dynamic": adam(model.dynamic.param_groups({"means": 0.01, "colors": 0.01}), eps=1e-15)}
    line = start_rigid_actors(model, Scene(), None, np.arange(1, 6), optimizers, 0.002, min_motion=0.05)
    assert line.startswith("rigid actors: 1 of 2 actors")
    actor = model.dynamic.params["actor"].long()
    assert (actor[groups[0]] == 0).all() and (actor[groups[1]] == -1).all() and "actors" in optimizers
    model, groups = pvg_model(np.array([[8.0, 0.0, 0.0], [-3.0, 4.0, 0.0]]))
    optimizers = {"dynamic": adam(model.dynamic.param_groups({"means": 0.01, "colors": 0.01}), eps=1e-15)}
    line = start_rigid_actors(model, Scene(), None, np.arange(1, 6), optimizers, 0.002, min_motion=0.2)
    assert "none of 2 actors moves 20.0 px" in line and model.actor_motion is None and "actors" not in optimizers


def crossing_car(keys: int, speed: float, slide: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray,
                                                                      np.ndarray]:
    """A car crossing 50 m ahead of a camera driving along x at 10 m/s, keys 0.2 s apart: its true planar path
    (K, 2), the camera centres (K, 3), the times (K,), and a path slid along the line of sight by ``slide`` (K,) m
    as (pivot (3,), shift (K, 3))."""
    seconds = 0.2 * np.arange(keys)
    centres = np.stack([10.0 * seconds, np.zeros(keys), np.full(keys, 1.5)], axis=1)
    truth = np.stack([50.0 + 10.0 * seconds, -10.0 + speed * seconds], axis=1)
    sight = truth - centres[:, :2]
    sight /= np.linalg.norm(sight, axis=1, keepdims=True)
    path = truth + slide[:, None] * sight
    pivot = np.array([*path[0], 0.7])
    shift = np.concatenate([path - path[0], np.zeros((keys, 1))], axis=1)
    return truth, centres, seconds, pivot, shift


@settings(max_examples=25, deadline=None)
@given(seed=st.integers(0, 10_000), keys=st.integers(4, 12), speed=st.floats(5.0, 20.0))
def test_the_radar_velocity_puts_back_a_path_slid_along_the_line_of_sight(seed, keys, speed):
    slide = np.random.default_rng(seed).normal(0.0, 2.0, keys)
    slide -= slide.mean()  # the depth prior keeps the mean; the steps come from the radar
    truth, centres, seconds, pivot, shift = crossing_car(keys, speed, slide)
    velocity = np.tile([10.0, speed], (keys, 1))  # the true velocity, every key
    fixed = radar_corrected_shift(pivot, shift, centres, velocity, np.full(keys, 0.1), seconds)
    path = pivot[:2] + fixed[:, :2]
    before = np.abs(np.diff(pivot[:2] + shift[:, :2], axis=0) - np.diff(truth, axis=0)).max()
    after = np.abs(np.diff(path, axis=0) - np.diff(truth, axis=0)).max()
    assert after < 0.05 + 0.02 * before
    np.testing.assert_allclose(fixed[:, 2], shift[:, 2])
    # Without two known keys in a row nothing moves.
    alone = velocity.copy()
    alone[1::2] = np.nan
    np.testing.assert_array_equal(radar_corrected_shift(pivot, shift, centres, alone, np.full(keys, 0.1), seconds),
                                  shift)


def test_radar_key_velocities_trust_held_objects_with_returns_and_a_tight_velocity():
    def radar_object(track, returns, std):
        return SimpleNamespace(track=track, num_returns=returns, velocity=np.array([3.0 + track, 1.0, 0.0]),
                               velocity_covariance=np.diag([std ** 2, (std / 2) ** 2]))

    objects = [[radar_object(1, 8, 0.3), radar_object(2, 20, 0.2)],  # holds 1 only
               [radar_object(1, 2, 0.1)],                            # too few returns
               [radar_object(1, 9, 1.5)],                            # too loose
               [radar_object(1, 5, 0.01), radar_object(3, 12, 0.2)]]  # holds both: the one with more returns
    held = {0: [{"track": 1}], 1: [{"track": 1}], 2: [{"track": 1}], 3: [{"track": 1}, {"track": 3}]}
    velocity, std = radar_key_velocities(held, objects, np.array([0, 1, 2, 3]))
    np.testing.assert_allclose(velocity[[0, 3]], [[4.0, 1.0], [6.0, 1.0]])
    assert np.isnan(velocity[[1, 2]]).all() and np.isnan(std[[1, 2]]).all()
    np.testing.assert_allclose(std[[0, 3]], [0.3, 0.2])


def test_a_free_copy_joins_the_body_covering_it_in_its_own_frame_at_its_own_depth():
    # Camera at the origin looking along +z (K_TEST: 100 px focal, so 1 px is 0.1 m at 10 m); two keys.
    cameras = np.stack([np.eye(4), np.eye(4)])
    near = np.array([[0.0, 0.0, 10.0], [0.5, 0.0, 10.0]])  # body 0: 10 m ahead, 0 and 5 px right of centre
    far = np.array([[0.0, 0.0, 40.0]])  # body 1: behind it on the same line of sight
    bodies = [np.stack([near, near + [0.0, 9.0, 0.0]]), np.stack([far, far])]  # body 0 moves 90 px down at key 1
    points = np.array([[0.01, 0.0, 10.5],   # 0.1 px from body 0, 5 % deeper: body 0
                       [0.0, 0.0, 42.0],    # on both bodies in the image; depth says body 1
                       [0.0, 0.0, 20.0],    # on both in the image, at neither's depth
                       [0.25, 0.0, 10.0],   # 2.5 px from both of body 0's points, radius 2: none
                       [0.42, 0.0, 10.0],   # 0.8 px from body 0's second point
                       [0.0, 0.0, 10.0]])   # seen at key 1, where body 0 has moved away: none
    keys = np.array([0, 0, 0, 0, 0, 1])
    joins = body_attachments(points, keys, bodies, cameras, K_TEST, radius=2.0)
    np.testing.assert_array_equal(joins, [0, 1, -1, -1, 0, -1])
    assert (body_attachments(points, keys, [], cameras, K_TEST, 2.0) == -1).all()


def test_free_copies_of_a_moving_body_join_its_actor_and_keep_their_positions():
    model, groups = pvg_model(np.array([[8.0, 0.0, 0.0], [-3.0, 4.0, 0.0]]), n=200)
    times = np.linspace(0.0, 1.0, 11)
    keys = times[1:-1:2]
    before = [model.set_at("dynamic", t)["means"].detach().clone() for t in times]
    # A camera at the origin looking along +x (world y to the left, z up), the same at every key.
    look_along_x = np.array([[0.0, -1.0, 0.0, 0.0], [0.0, 0.0, -1.0, 0.0], [1.0, 0.0, 0.0, 0.0], [0.0, 0.0, 0.0, 1.0]])
    cameras = np.repeat(look_along_x[None], len(keys), axis=0)
    half = groups[0][:100]  # the discovery linked half of the first body; its other half is left to the field
    optimizer = adam(model.dynamic.param_groups({"means": 0.01, "colors": 0.01}), eps=1e-15)
    motion, actor, start = rigid_actor_motion(model, [half, groups[1]], keys, attach=(cameras, K_TEST, 20.0))
    np.testing.assert_array_equal(actor.numpy()[groups[0]], 0)
    np.testing.assert_array_equal(actor.numpy()[groups[1]], 1)
    motion_without, actor_without, _ = rigid_actor_motion(model, [half, groups[1]], keys)
    assert (actor_without.numpy()[groups[0][100:]] == -1).all()
    rigid_members(model, motion, actor, start, optimizer)
    for t, expected in zip(times, before, strict=True):
        torch.testing.assert_close(model.set_at("dynamic", t)["means"], expected, atol=1e-6, rtol=0)
