"""Fixtures of the command tests that read the session's tiny trained run (see tests/conftest.py)."""

from __future__ import annotations

import pytest


@pytest.fixture(scope="module")
def trained(tiny_trained_run):
    """The shared tiny run folder (tests add files under it, never change what is there)."""
    return tiny_trained_run / "run"


@pytest.fixture(scope="module")
def model(trained):
    """The shared tiny run's model, loaded once per module."""
    from radar4dgs.model.scene_model import load_model

    return load_model(trained / "model.pt")
