"""Atomic writes (issue 26): temporaries name their owner; those of dead runs are removed, those
of live runs and of other hosts are kept."""

from __future__ import annotations

import errno
import os
from pathlib import Path

import numpy as np
import pytest

from radar4dgs.io import atomic
from radar4dgs.io.atomic import (
    HOST,
    TEMP_NAME,
    OutputWriteError,
    atomic_directory,
    atomic_path,
    atomic_save_npz,
    atomic_save_torch,
    dead_temporary,
    output_write_error,
    pid_alive,
    remove_dead_temporaries,
)


def dead_pid() -> int:
    """A pid no process has: above the kernel's maximum."""
    try:
        return int(Path("/proc/sys/kernel/pid_max").read_text()) + 1
    except OSError:
        return 2 ** 22 + 1


def temporaries(folder: Path, target: str) -> dict[str, Path]:
    """A dead run's folder and file, a live run's (this process), and a dead pid on another host."""
    made = {"dead": folder / f".{target}.{dead_pid()}@{HOST}.ab12cd_9.tmp",
            "dead_file": folder / f".{target}.{dead_pid()}@{HOST}.zz99aa00.tmp.mp4",
            "old": folder / f".{target}.{dead_pid()}@{HOST}.qq11ww22.old",
            "live": folder / f".{target}.{os.getpid()}@{HOST}.k3j4h5g6.tmp",
            "other_host": folder / f".{target}.{dead_pid()}@not-{HOST}.m1n2b3v4.tmp",
            "legacy": folder / f".{target}.p0o9i8u7.tmp",  # no owner: never guessed at
            "user": folder / f".{target}.notes"}
    folder.mkdir(parents=True, exist_ok=True)
    for key, path in made.items():
        if key in ("dead_file", "user"):
            path.write_bytes(b"half")
        else:
            path.mkdir()
            (path / "frame.npy").write_bytes(b"half")
    return made


def test_temporary_names_carry_the_owner(tmp_path):
    with atomic_path(tmp_path / "a.json") as tmp:
        match = TEMP_NAME.match(tmp.name)
        assert match and int(match["pid"]) == os.getpid() and match["host"] == HOST
        assert match["target"] == "a.json"
        tmp.write_text("{}")
    with atomic_directory(tmp_path / "flow") as tmp:
        assert TEMP_NAME.match(tmp.name)["target"] == "flow"
    assert sorted(p.name for p in tmp_path.iterdir()) == ["a.json", "flow"]


def test_pid_alive():
    assert pid_alive(os.getpid()) and not pid_alive(dead_pid())
    assert not dead_temporary(f".x.{os.getpid()}@{HOST}.abcdefgh.tmp")
    assert dead_temporary(f".x.{dead_pid()}@{HOST}.abcdefgh.tmp")


def test_a_stage_removes_only_dead_runs_temporaries(tmp_path):
    made = temporaries(tmp_path / "prepared", "flow")
    with atomic_directory(tmp_path / "prepared" / "flow", overwrite=True) as out:
        (out / "0.npy").write_bytes(b"x")
    left = {key for key, path in made.items() if path.exists()}
    assert left == {"live", "other_host", "legacy", "user"}
    assert (tmp_path / "prepared" / "flow" / "0.npy").is_file()


def test_a_checkpoint_write_removes_dead_temporaries(tmp_path, monkeypatch):
    monkeypatch.setattr(atomic, "_CLEANED", set())
    made = temporaries(tmp_path / "run" / "checkpoints", "last.pt")
    atomic_save_torch(tmp_path / "run" / "checkpoints" / "last.pt", {"step": 3})
    assert {key for key, path in made.items() if path.exists()} == {"live", "other_host", "legacy", "user"}


def test_remove_dead_temporaries_recursive(tmp_path):
    top = temporaries(tmp_path, "renders")
    deep = temporaries(tmp_path / "renders" / "test", "000.png")
    assert remove_dead_temporaries(tmp_path / "renders") == []  # no temporaries at its top
    removed = remove_dead_temporaries(tmp_path, recursive=True)
    expected = [made[key] for made in (top, deep) for key in ("dead", "dead_file", "old")]
    assert sorted(removed) == sorted(expected)
    assert all(path.exists() for made in (top, deep) for key, path in made.items()
               if key not in ("dead", "dead_file", "old"))
    assert remove_dead_temporaries(tmp_path / "missing") == []


def test_a_failed_write_leaves_nothing(tmp_path):
    with pytest.raises(RuntimeError), atomic_directory(tmp_path / "depth"):
        raise RuntimeError("killed")
    assert list(tmp_path.iterdir()) == []


@pytest.mark.parametrize("compressed", [True, False])
def test_an_npz_round_trips_and_leaves_no_temporary(tmp_path, compressed):
    # "path" and "compressed" as array names: the arrays are a mapping, not keyword arguments.
    arrays = {"path": np.arange(6, dtype=np.float32).reshape(2, 3), "compressed": np.bool_(True), "index": np.int64(4)}
    written = atomic_save_npz(tmp_path / "pair.npz", arrays, compressed=compressed)
    with np.load(written, allow_pickle=False) as data:
        assert sorted(data.files) == sorted(arrays)
        for key, value in arrays.items():
            assert data[key].dtype == np.asarray(value).dtype and np.array_equal(data[key], value)
    assert [p.name for p in tmp_path.iterdir()] == ["pair.npz"]


def test_a_compressed_npz_is_smaller(tmp_path):
    zeros = {"zeros": np.zeros((200, 200))}
    compressed = atomic_save_npz(tmp_path / "compressed.npz", zeros).stat().st_size
    assert compressed * 10 < atomic_save_npz(tmp_path / "plain.npz", zeros, compressed=False).stat().st_size


def test_numpys_short_write_inside_an_atomic_folder_is_a_full_disk_named_by_the_folder(tmp_path):
    # np.save of a large array reports a full disk as "N requested and M written", with no errno.
    target = tmp_path / "prepared" / "depth"
    with pytest.raises(OutputWriteError) as caught, atomic_directory(target):
        raise OSError("57600 requested and 8160 written")
    assert caught.value.errno == errno.ENOSPC
    assert str(caught.value).startswith(f"{target.parent}: disk full, cannot write depth/ (no space left: 57600 "
                                        "requested and 8160 written); the previous outputs there are untouched")
    assert not target.exists()
    other = OSError("something else")
    assert output_write_error(tmp_path, "x", other) is other
