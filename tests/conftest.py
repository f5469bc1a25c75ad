"""Fixtures shared across test packages: one tiny trained run for every test of what comes after
training (eval, render, export, viewer), built once per session."""

from __future__ import annotations

from pathlib import Path

import pytest

TINY_RUN_FRAMES = 8


@pytest.fixture
def one_torch_thread():
    """Tiny models on the shared 2-core CI machine: extra torch threads only spin."""
    from radar4dgs.train.fit_motion import torch_threads

    with torch_threads(1):
        yield


@pytest.fixture(scope="session")
def tiny_trained_run(tmp_path_factory) -> Path:
    """A folder with ``scene/`` (tiny synthetic, 8 frames, seed 4, prepared in ``scene/prepared``)
    and ``run/`` (20 training iterations; not evaluated). Tests may add files to the run folder but
    must not change what is there."""
    from radar4dgs.apps.prepare import PrepareConfig, run_prepare
    from radar4dgs.config import preset
    from radar4dgs.datasets.synth import SynthConfig, synthesize
    from radar4dgs.model.config import TrainConfig
    from radar4dgs.train.fit_motion import torch_threads
    from radar4dgs.train.trainer import train_run

    root = tmp_path_factory.mktemp("tiny-run")
    scene = root / "scene"
    with torch_threads(1):
        synthesize(preset(SynthConfig, "tiny", seed=4, num_frames=TINY_RUN_FRAMES), scene, progress=False)
        run_prepare(scene, None, preset(PrepareConfig, "tiny"), progress=False)
        config = preset(TrainConfig, "tiny", threads=1, optim={"iterations": 20},
                        init={"points_per_frame": 800, "max_static": 4000, "max_dynamic": 800})
        train_run(scene, scene / "prepared", root / "run", config, progress=False)
    return root


@pytest.fixture(scope="session")
def motion_scene(tmp_path_factory):
    """A tiny synthetic scene (seed 2) for the motion tests: flow, association, fit, command."""
    from radar4dgs.config import preset
    from radar4dgs.datasets.synth import SynthConfig, synthesize
    from radar4dgs.io.scene import read_scene

    root = tmp_path_factory.mktemp("motion") / "scene"
    synthesize(preset(SynthConfig, "tiny", seed=2), root, overwrite=True, progress=False)
    return read_scene(root)


@pytest.fixture(scope="session")
def motion_prepared(motion_scene, tmp_path_factory):
    """``motion_scene``'s prepared flow, from ground-truth depth and masks (the flow stage alone)."""
    from radar4dgs.config import preset
    from radar4dgs.motion.config import FlowConfig
    from radar4dgs.motion.flow import prepare_flow

    folder = tmp_path_factory.mktemp("prepared")
    prepare_flow(motion_scene, folder, preset(FlowConfig, "tiny", depth_source="oracle", mask_source="oracle"))
    return folder
