"""`radar4dgs inspect`: the printed summary, the contact sheet and the JSON it writes."""

from __future__ import annotations

import json

# tests/io's helpers: pytest puts that folder on sys.path only for its own tests.
import sys
from pathlib import Path

import pytest

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "io"))
from _scene_helpers import FRAMES, write_valid_scene  # noqa: E402

from radar4dgs.cli import main  # noqa: E402
from radar4dgs.io.scene import read_scene  # noqa: E402


@pytest.fixture(scope="module")
def scene(tmp_path_factory):
    return read_scene(write_valid_scene(tmp_path_factory.mktemp("inspect") / "scene"))


def test_command_writes_sheet_and_json(scene, tmp_path, capsys):
    assert main(["inspect", str(scene.root), "--sheet", str(tmp_path / "s.png"),
                 "--json", str(tmp_path / "s.json")]) == 0
    out = capsys.readouterr().out
    assert "frames     6 over 0.50 s" in out and "median 8" in out
    assert (tmp_path / "s.png").stat().st_size > 0
    assert json.loads((tmp_path / "s.json").read_text())["frames"] == FRAMES


def test_a_folder_that_is_not_a_scene_is_one_line(tmp_path, capsys):
    assert main(["inspect", str(tmp_path / "nothing")]) == 1
    err = capsys.readouterr().err.strip().splitlines()
    assert err == [f"radar4dgs inspect: {tmp_path / 'nothing'}: not a scene folder (no such directory)"]
