"""RUN/actors.json: round trip, staleness, the issue's JSON shape."""

from __future__ import annotations

import json
import os

import numpy as np

from radar4dgs.actors.store import ACTORS_FILE, is_current, read_actors, run_actors


def test_actors_json_round_trips_and_has_the_issue_shape(oracle):
    actors = run_actors(oracle.run, recompute=True)
    path = oracle.root / ACTORS_FILE
    document = json.loads(path.read_text())
    assert len(document["actors"]) == 3
    for record in document["actors"]:
        assert isinstance(record["id"], int) and isinstance(record["n_gaussians"], int)
        for frame in record["frames"]:
            assert isinstance(frame["name"], str) and len(frame["centroid_world"]) == 3
            assert len(frame["velocity_world"]) == 3
    back = read_actors(path)
    for a, b in zip(actors, back, strict=True):
        assert a.id == b.id and np.array_equal(a.gaussians, b.gaussians) and np.array_equal(a.frames, b.frames)
        assert np.allclose(a.centroid, b.centroid, atol=1e-4) and np.allclose(a.heading, b.heading, atol=1e-5)


def test_a_changed_model_makes_actors_json_stale(oracle):
    run_actors(oracle.run)
    assert is_current(oracle.root)
    model = oracle.root / "model.pt"
    stat = model.stat()
    os.utime(model, ns=(stat.st_atime_ns, stat.st_mtime_ns + 10**9))
    try:
        assert not is_current(oracle.root)
    finally:
        os.utime(model, ns=(stat.st_atime_ns, stat.st_mtime_ns))
