"""Shared fixtures of the motion tests."""

from __future__ import annotations

import pytest


@pytest.fixture(autouse=True)
def one_torch_thread():
    """The field's matmuls are tiny; on the shared 2-core CI machine extra torch threads only spin."""
    from radar4dgs.motion.fit import torch_threads

    with torch_threads(1):
        yield
