"""Actor discovery against the generator's moving objects (oracle dynamic set, tests/actors/conftest.py)
and its pieces on closed-form trajectories."""

from __future__ import annotations

import numpy as np

from radar4dgs.actors.config import ActorConfig
from radar4dgs.actors.discover import (
    Actor,
    discover_actors,
    headings,
    is_actor,
    merge_groups,
    motion_components,
    moving_mask,
    opacity_track,
)
from radar4dgs.actors.groundtruth import scene_movers, score_actors


def test_actors_are_the_generators_moving_objects(oracle):
    actors = discover_actors(oracle.run.model, oracle.run.scene)
    # Exactly the three moving cars, each with exactly its own Gaussians.
    assert sorted(tuple(a.gaussians) for a in actors) == sorted(tuple(m) for m in oracle.members.values())
    score = score_actors(actors, scene_movers(oracle.run.scene))
    assert score["recall"] == 1.0 and score["spurious"] == 0 and score["matched"] == 3
    # The centroid of points on the boxes' faces is the box centre to within sampling noise (measured
    # 0.066 m median, 150 points per box); the velocity is the generator's (measured 1e-5 m/s).
    assert score["centroid_error_median"] < 0.15
    assert score["velocity_error_median"] < 1e-3
    assert all(a.category == "car" for a in actors)
    by_id = {m.id: m for m in scene_movers(oracle.run.scene)}
    fastest = max(actors, key=lambda a: a.mean_speed)
    assert abs(fastest.mean_speed - np.linalg.norm(by_id[4].velocity[0, :2])) < 1e-3


def _two_bodies(times: np.ndarray) -> np.ndarray:
    """(40, T, 3): a 2 m row of 20 points driving +x at 10 m/s, and one driving -x past it 3 m away."""
    row = np.stack([np.linspace(0, 2, 20), np.zeros(20), np.zeros(20)], axis=1)
    a = row[:, None, :] + np.stack([10 * times, 0 * times, 0 * times], axis=1)[None]
    b = row[:, None, :] + np.stack([20 - 10 * times, 0 * times + 3, 0 * times], axis=1)[None]
    return np.concatenate([a, b])


def test_bodies_that_pass_each_other_stay_apart():
    times = np.linspace(0, 2, 9)
    trajectories = _two_bodies(times)
    labels = motion_components(trajectories, ActorConfig(link_distance=0.8, min_gaussians=5))
    assert len(set(labels[:20])) == 1 and len(set(labels[20:])) == 1 and labels[0] != labels[20]
    # At 1 s the two rows are 3 m apart side by side: a per-frame radius graph would merge them at any
    # link distance above 3 m; the max over time keeps them apart up to ~half their closing motion.
    assert len(set(motion_components(trajectories, ActorConfig(link_distance=3.5, min_gaussians=5)))) == 2


def test_still_or_faint_gaussians_take_no_part():
    times = np.linspace(0, 1, 5)
    trajectories = np.concatenate([_two_bodies(times), np.zeros((3, 5, 3))])
    opacities = np.ones(trajectories.shape[:2])
    opacities[0] = 0.01
    mask = moving_mask(trajectories, opacities, ActorConfig())
    assert not mask[0] and mask[1:40].all() and not mask[40:].any()


def test_heading_follows_the_velocity_and_holds_when_slow():
    velocity = np.array([[0, 5, 0], [0, 5, 0], [0.1, 0, 0], [-5, 0, 0]], dtype=float)
    assert np.allclose(headings(velocity, np.zeros((2, 4, 3))), [np.pi / 2, np.pi / 2, np.pi / 2, np.pi])


def _actor(x: np.ndarray, y: float, frames: np.ndarray, timestamps: np.ndarray) -> Actor:
    """A hand-made actor whose centroid follows (x (F,), y) over the frames, seen in ``frames``."""
    centroid = np.stack([x, np.full_like(x, y), np.zeros_like(x)], axis=1)
    velocity = np.gradient(centroid, timestamps, axis=0)
    heading = headings(velocity, np.zeros((1, len(x), 3)))
    return Actor(0, np.arange(3), np.asarray(frames), centroid, velocity, heading, (4.0, 1.8, 1.5), "car")


def test_pieces_of_one_body_merge_and_cars_side_by_side_stay_apart():
    t = np.linspace(0, 2, 21)
    config = ActorConfig()
    every = np.arange(21)
    pieces = [_actor(10 * t + 1.5, 0.0, every, t),  # front half of a car at 10 m/s
              _actor(10 * t - 1.5, 0.3, every, t),  # its rear half, 3 m behind
              _actor(10 * t, 3.0, every, t),  # a car beside it, one lane (3 m) over, same speed
              _actor(10 * t, -3.5, every, t),  # one on the other side, 3.5 m
              _actor(30 - 10 * t, 0.0, every, t)]  # an oncoming car passing through the first one's place
    groups = merge_groups(pieces, t, config)
    assert groups[0] == groups[1] and len(set(groups)) == 4
    # A piece seen in the first 0.8 s only and one from 1.3 s on, along the same path: a hand-over.
    assert len(set(merge_groups([_actor(10 * t, 0.0, np.arange(0, 9), t),
                                 _actor(10 * t, 0.2, np.arange(13, 21), t)], t, config))) == 1
    # The same after a 1.1 s gap, or on the next lane, is another car.
    late = [_actor(10 * t, 0.0, np.arange(0, 5), t), _actor(10 * t, 0.0, np.arange(16, 21), t),
            _actor(10 * t, 3.0, np.arange(6, 21), t)]
    assert len(set(merge_groups(late, t, config))) == 3


def test_short_lived_or_still_actors_are_dropped():
    t = np.linspace(0, 2, 21)
    config = ActorConfig()
    assert is_actor(_actor(10 * t, 0.0, np.arange(21), t), config)
    assert is_actor(_actor(1.4 * t, 0.0, np.arange(21), t), config)  # a walker: 2.8 m
    assert not is_actor(_actor(10 * t, 0.0, np.array([4, 5]), t), config)  # two frames: a blob
    assert not is_actor(_actor(0.2 * t, 0.0, np.arange(21), t), config)  # 0.4 m in 2 s: residue


def test_tracks_follow_the_gaussians_that_render():
    t = np.array([0.0, 0.1, 0.2])
    # Two Gaussians at 10 m/s along x; the second is transparent (outside its life span) at the last
    # frame, where the field has flung it 50 m sideways.
    points = np.zeros((2, 3, 3))
    points[:, :, 0] = 10 * t
    points[1, :, 0] += 1.0
    points[1, 2, 1] = 50.0
    weights = np.array([[1.0, 1.0, 1.0], [1.0, 1.0, 0.0]])
    centroid, velocity, mass = opacity_track(points, weights, t)
    assert np.allclose(centroid[:2, 0], 10 * t[:2] + 0.5) and np.allclose(centroid[2], [2.0, 0.0, 0.0])
    assert np.allclose(velocity[2], [10.0, 0.0, 0.0]) and np.allclose(mass, [2, 2, 1])
