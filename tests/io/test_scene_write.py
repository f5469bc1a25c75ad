"""The scene writer is atomic: an error or a missing ``finish()`` leaves nothing behind, and an
existing scene is never overwritten by default."""

from __future__ import annotations

import numpy as np
import pytest

from radar4dgs.io.scene_types import Frame
from radar4dgs.io.scene_write import SceneWriter


def test_writer_leaves_nothing_on_error(tmp_path):
    out = tmp_path / "broken"
    with pytest.raises(ZeroDivisionError):
        with SceneWriter(out) as writer:
            writer.add_frame(Frame("a", 0.0, np.eye(4), 0.0, np.eye(4)), np.zeros((2, 2, 3), np.uint8),
                             np.zeros((0, 4)))
            raise ZeroDivisionError
    assert list(tmp_path.iterdir()) == []


def test_writer_refuses_to_overwrite(valid_scene):
    with pytest.raises(FileExistsError, match="already exists"):
        with SceneWriter(valid_scene):
            pass


def test_writer_without_finish_is_an_error(tmp_path):
    with pytest.raises(RuntimeError, match="without finish"):
        with SceneWriter(tmp_path / "unfinished"):
            pass
    assert list(tmp_path.iterdir()) == []
