"""Fixtures of the scene tests: one valid scene per test module, and a throwaway copy per test."""

from __future__ import annotations

import shutil
from pathlib import Path

import pytest

# pytest puts this folder on sys.path (rootdir-relative "prepend" imports), as for the other helpers.
from _scene_helpers import write_valid_scene


@pytest.fixture(scope="module")
def valid_scene(tmp_path_factory) -> Path:
    return write_valid_scene(tmp_path_factory.mktemp("scenes") / "valid")


@pytest.fixture
def scene_copy(valid_scene, tmp_path) -> Path:
    return Path(shutil.copytree(valid_scene, tmp_path / "copy"))
