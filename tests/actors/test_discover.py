"""Actor discovery against the generator's moving objects (oracle dynamic set, tests/actors/conftest.py)
and its pieces on closed-form trajectories."""

from __future__ import annotations

import numpy as np

from radar4dgs.actors.config import ActorConfig
from radar4dgs.actors.discover import discover_actors, headings, motion_components, moving_mask
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
