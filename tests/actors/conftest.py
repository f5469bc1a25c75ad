"""An oracle run for the actor tests: the session's tiny trained run (calm synthetic scene, seed 4, 8
frames; tests/conftest.py) with its dynamic set replaced by Gaussians sampled on the generator's moving
cars, moved by the generator's own motion (constant velocity: PVG's vibration with a period far longer
than the sequence is ``mu + v t`` to 1e-7). Discovery and edits are then tested against exact ground
truth in a fraction of a second, without training."""

from __future__ import annotations

import shutil

import numpy as np
import pytest

# Points sampled on each box (body, cabin, wheels) of a moving car.
POINTS_PER_BOX = 150
# PVG period (normalised time) making its sine linear over [0, 1]: sin(x) = x (1 - x^2 / 6 ...),
# 2 pi / 1e4 -> relative error 7e-8.
LINEAR_PERIOD = 1e4


def box_surface_points(centre, half, rng: np.random.Generator, count: int) -> np.ndarray:
    """(count, 3) points uniform on the faces of an axis-aligned box (body frame)."""
    centre, half = np.asarray(centre, float), np.asarray(half, float)
    points = rng.uniform(-1, 1, (count, 3))
    axis = rng.integers(0, 3, count)
    points[np.arange(count), axis] = rng.choice([-1.0, 1.0], count)
    return centre + points * half


def oracle_model(scene, base_model, seed: int = 0):
    """(model, {mover id: (K,) dynamic indices}): ``base_model``'s static set and sky with a dynamic set
    on ``scene``'s moving objects."""
    import torch

    from radar4dgs.model.config import BaselineConfig
    from radar4dgs.model.gaussians import GaussianSet
    from radar4dgs.model.scene_model import SceneModel

    rng = np.random.default_rng(seed)
    duration = scene.frames[-1].timestamp - scene.frames[0].timestamp
    means, velocity, colours, members = [], [], [], {}
    for entry in scene.extra["synthetic"]["objects"]:
        if entry.get("kind") != "moving":
            continue
        pose = np.asarray(entry["poses"][0])
        local = np.concatenate([box_surface_points(b["center"], b["half_size"], rng, POINTS_PER_BOX)
                                for b in entry["boxes"]])
        start = sum(len(m) for m in means)
        means.append(local @ pose[:3, :3].T + pose[:3, 3])
        velocity.append(np.tile(np.asarray(entry["velocity"]) * duration, (len(local), 1)))
        colours.append(np.tile(entry["color"], (len(local), 1)))
        members[entry["id"]] = np.arange(start, start + len(local))
    n = sum(len(m) for m in means)
    as_tensor = lambda a: torch.as_tensor(np.concatenate(a), dtype=torch.float32)  # noqa: E731
    dynamic = GaussianSet({"means": as_tensor(means), "quats": torch.tensor([[1.0, 0, 0, 0]]).repeat(n, 1),
                           "log_scales": torch.full((n, 3), float(np.log(0.12))),
                           "opacity_logits": torch.full((n,), 4.0), "colors": as_tensor(colours),
                           "velocity": as_tensor(velocity), "tau": torch.zeros(n)})
    model = SceneModel(base_model.static, base_model.sky, None, dynamic, None, BaselineConfig(pvg_period=LINEAR_PERIOD))
    return model.eval(), members


@pytest.fixture(scope="session")
def oracle(tiny_trained_run, tmp_path_factory):
    """A run folder ``root`` holding the oracle model (run.json and config.json of the tiny run), the
    loaded ``run``, and ``members``: generator mover id -> dynamic indices."""
    from types import SimpleNamespace

    import torch

    from radar4dgs.model.run import load_run

    trained = tiny_trained_run / "run"
    root = tmp_path_factory.mktemp("oracle-run")
    for name in ("run.json", "config.json"):
        shutil.copy(trained / name, root / name)
    base = load_run(trained, "cpu")
    model, members = oracle_model(base.scene, base.model)
    torch.save({"model": model.payload()}, root / "model.pt")
    run = load_run(root, "cpu")
    return SimpleNamespace(root=root, run=run, members=members)
