"""Radar cues of actor discovery: chains of radar tracks on closed-form paths, and discovery on the oracle
run (tests/actors/conftest.py) with radar objects placed on the generator's moving objects."""

from __future__ import annotations

from types import SimpleNamespace

import numpy as np
import pytest

import radar4dgs.actors.discover as discover
from radar4dgs.actors.config import ActorConfig
from radar4dgs.actors.groundtruth import scene_movers, score_actors
from radar4dgs.actors.radar_cues import distinct_objects, radar_chains, support
from radar4dgs.io.scene import normalized_times


def _object(track: int, xy, velocity) -> SimpleNamespace:
    """A radar object as ``load_radar_objects`` gives it (the fields discovery reads)."""
    return SimpleNamespace(track=track, centroid=np.array([*xy, 0.5]), velocity=np.array([*velocity, 0.0]),
                           num_returns=5, points=np.arange(5))


def test_tracks_of_one_car_chain_and_clutter_supports_nothing():
    t = np.arange(12) * 0.1
    frames: list[list] = [[] for _ in t]
    for f in range(12):
        x = 10 * t[f]
        # One car at 10 m/s: track 1 until 0.4 s, lost for two scans, track 2 from 0.7 s; a near car seen as
        # two clusters 1 m apart (tracks 3 and 4); a car one lane over (3.5 m) at the same speed (track 5).
        if f <= 4:
            frames[f].append(_object(1, (x, 0.0), (10, 0)))
        if f >= 7:
            frames[f].append(_object(2, (x + 0.3, 0.2), (10, 0)))
        frames[f] += [_object(3, (x, 10.0), (10, 0)), _object(4, (x + 1.0, 10.0), (10, 0)),
                      _object(5, (x, 3.5), (10, 0))]
    frames[3].append(_object(9, (40.0, -7.0), (20, 0)))  # clutter: one scan
    chains = radar_chains(frames, t, ActorConfig())
    by_track = {o.track: int(chains.chain[f][np.linalg.norm(chains.centroids[f] - o.centroid[:2], axis=1).argmin()])
                for f in range(12) for o in frames[f] if o.track != 9}
    assert by_track[1] == by_track[2] and by_track[3] == by_track[4]
    assert len({by_track[1], by_track[3], by_track[5]}) == 3 and len(chains.frames) == 3
    assert len(chains.chain[3]) == 4  # the clutter object is not among the confirmed ones
    assert distinct_objects(by_track[1], by_track[5], chains)
    # A piece of Gaussians 1 m behind the first car is supported by its chain where radar saw it.
    centroid = np.stack([10 * t - 1.0, 0 * t, 0 * t], axis=1)
    supported = support(centroid, np.arange(12), chains, ActorConfig().radar_gate)
    assert (supported[[0, 1, 2, 3, 4, 7, 8, 9, 10, 11]] == by_track[1]).all() and (supported[[5, 6]] == -1).all()


def _radar_on_movers(scene, skip: int | None = None) -> list[list[SimpleNamespace]]:
    """Per frame, one radar object per generator mover (track = its id) at its box centre."""
    frames: list[list[SimpleNamespace]] = [[] for _ in range(len(scene))]
    for mover in scene_movers(scene):
        if mover.id == skip:
            continue
        for f in range(len(scene)):
            frames[f].append(_object(mover.id, mover.centre[f, :2], mover.velocity[f, :2]))
    return frames


@pytest.fixture
def oracle_paths(oracle, monkeypatch):
    """The oracle's dynamic trajectories (N, F, 3) and opacities (N, F), served to discovery through
    ``dynamic_trajectories`` so that a test may change them."""
    paths = [np.array(a) for a in discover.dynamic_trajectories(oracle.run.model, normalized_times(oracle.run.scene))]
    monkeypatch.setattr(discover, "dynamic_trajectories", lambda model, times: paths)
    return paths


def test_a_moving_group_the_radar_never_saw_is_dropped(oracle, oracle_paths):
    scene = oracle.run.scene
    trajectories, opacities = oracle_paths
    # A ghost: a copy of the first mover's Gaussians 12 m to the side of it (on no lane, where no radar
    # return is), moving with it: a group of dynamic Gaussians that is no object.
    first = oracle.members[min(oracle.members)]
    ghost = trajectories[first] + np.array([0.0, 12.0, 0.0])
    oracle_paths[0] = np.concatenate([trajectories, ghost])
    oracle_paths[1] = np.concatenate([opacities, opacities[first]])
    movers = scene_movers(scene)
    without = discover.discover_actors(oracle.run.model, scene, None)
    assert len(without) == 4 and score_actors(without, movers)["spurious"] == 1
    found = discover.discover_actors(oracle.run.model, scene, _radar_on_movers(scene))
    score = score_actors(found, movers)
    assert len(found) == 3 and score["spurious"] == 0 and score["recall"] == 1.0
    assert all(a.gaussians.max() < len(trajectories) for a in found)  # none of the ghost's Gaussians


def test_a_weak_mover_on_a_radar_track_is_found(oracle, oracle_paths):
    scene = oracle.run.scene
    trajectories, _ = oracle_paths
    # The field barely learnt one car: each of its Gaussians drifts its own way (up to 1.5 m over the
    # sequence), so no two stay within the link distance and the motion graph leaves them all alone.
    movers = scene_movers(scene)
    weak_id = max(m.id for m in movers if len(m.visible) >= 5)  # a mover the benchmark counts
    weak = oracle.members[weak_id]
    rng = np.random.default_rng(0)
    drift = rng.uniform(-1, 1, (len(weak), 1, 3)) * np.array([1.5, 1.5, 0.0])
    trajectories[weak] += drift * np.linspace(0, 1, trajectories.shape[1])[None, :, None]
    config = ActorConfig(attach_distance=0.0)
    blind = discover.discover_actors(oracle.run.model, scene, _radar_on_movers(scene, skip=weak_id),
                                     ActorConfig(attach_distance=0.0))
    blind_score = score_actors(blind, movers)
    assert len(blind) == 2 and blind_score["recall"] == 0.5
    # The miss is named: the weak car among the counted movers nothing matched.
    assert weak_id in {m["mover"] for m in blind_score["missed"]}
    found = discover.discover_actors(oracle.run.model, scene, _radar_on_movers(scene), config)
    score = score_actors(found, movers)
    assert len(found) == 3 and score["recall"] == 1.0 and score["spurious"] == 0 and score["missed"] == []
    seeded = next(a for a in found if set(a.gaussians) <= set(weak))
    # Every one of the car's Gaussians stays within the radar gate (3 m) of its box centre: all found.
    assert len(seeded.gaussians) == len(weak)
    # Its centroid: the box centre plus the mean drift (tens of cm), well inside the benchmark's gates.
    assert score["centroid_error_median"] < 0.5
    # Its velocity where the radar saw it is the radar's (here the generator's own), not its drifting
    # Gaussians'.
    mover = next(m for m in movers if m.id == weak_id)
    assert np.allclose(seeded.velocity[seeded.frames, :2], mover.velocity[seeded.frames, :2], atol=1e-9)
    drifting = discover.discover_actors(oracle.run.model, scene, _radar_on_movers(scene),
                                        ActorConfig(attach_distance=0.0, radar_velocity=False))
    slow = next(a for a in drifting if set(a.gaussians) <= set(weak))
    assert np.abs(slow.velocity[slow.frames, :2] - mover.velocity[slow.frames, :2]).max() > 0.01



def test_radar_chains_split_and_merge_pieces():
    from radar4dgs.actors.discover import Actor, headings, merge_groups

    t = np.arange(21) * 0.1
    every = np.arange(21)

    def piece(x: np.ndarray, y: float) -> Actor:
        centroid = np.stack([x, np.full_like(x, y), np.zeros_like(x)], axis=1)
        velocity = np.gradient(centroid, t, axis=0)
        return Actor(0, np.arange(3), every, centroid, velocity, headings(velocity, np.zeros((1, 21, 3))),
                     (4.0, 1.8, 1.5), "car")

    # Two cars 1 m apart across (a junction: one turning in beside the other) at the same speed: one body
    # by their motion. The radar sees two objects (tracks 1 and 2, 2.8 m apart: two chains).
    pieces = [piece(10 * t, 0.0), piece(10 * t, 1.0)]
    frames = [[_object(1, (10 * s - 0.4, -0.9), (10, 0)), _object(2, (10 * s + 0.4, 1.8), (10, 0))] for s in t]
    chains = radar_chains(frames, t, ActorConfig())
    main = [int(chains.chain[0][0]), int(chains.chain[0][1])]
    assert len(set(merge_groups(pieces, t, ActorConfig()))) == 1
    assert len(set(merge_groups(pieces, t, ActorConfig(), (main, chains)))) == 2
    # The front and the rear of one long bus, 9 m apart (beyond the 5 m merge distance): two bodies by
    # their motion, one object for the radar.
    bus = [piece(10 * t + 4.5, 0.0), piece(10 * t - 4.5, 0.0)]
    one = radar_chains([[_object(7, (10 * s, 0.0), (10, 0))] for s in t], t, ActorConfig())
    assert len(set(merge_groups(bus, t, ActorConfig()))) == 2
    chain = int(one.chain[0][0])
    assert len(set(merge_groups(bus, t, ActorConfig(), ([chain, chain], one)))) == 1
