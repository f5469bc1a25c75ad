"""Folder locks (issue 26): a folder another live process holds is refused in one line; a dead
process's lock is taken over; prepare, train and eval take it."""

from __future__ import annotations

import json
import math
import os
import re
import signal
import subprocess
import sys
import textwrap
import threading
import time
from pathlib import Path

import pytest

from radar4dgs.cli import main
from radar4dgs.io.atomic import HOST
from radar4dgs.io.locks import FolderInUseError, folder_lock, lock_owner, lock_paths

HOLDER = textwrap.dedent("""
    import sys, time
    from radar4dgs.io.locks import folder_lock
    with folder_lock(sys.argv[1], command="holder"):
        print("held", flush=True)
        sys.stdin.read()  # until the test closes stdin (or kills this process)
""")


class Holder:
    """A child process holding ``folder``'s lock until :meth:`release` or :meth:`kill`."""

    def __init__(self, folder: Path):
        self.process = subprocess.Popen([sys.executable, "-c", HOLDER, str(folder)], stdin=subprocess.PIPE,
                                        stdout=subprocess.PIPE, text=True)
        assert self.process.stdout.readline().strip() == "held"

    def release(self) -> None:
        self.process.stdin.close()
        assert self.process.wait(timeout=60) == 0

    def kill(self) -> None:
        self.process.send_signal(signal.SIGKILL)
        self.process.wait(timeout=60)
        self.process.stdin.close()


@pytest.fixture
def holder():
    holders = []

    def start(folder: Path) -> Holder:
        holders.append(Holder(folder))
        return holders[-1]

    yield start
    for h in holders:
        if h.process.poll() is None:
            h.kill()


IN_USE = r"{folder} is in use by pid {pid} since \d{{4}}-\d\d-\d\d \d\d:\d\d:\d\d [+-]\d{{4}} \(holder\)"


def test_a_held_folder_is_refused_then_free_after_release(tmp_path, holder):
    run = tmp_path / "run"
    h = holder(run)
    with pytest.raises(FolderInUseError, match=IN_USE.format(folder=re.escape(str(run)), pid=h.process.pid)):
        with folder_lock(run):
            pass
    h.release()
    assert not lock_paths(run)[1].exists()  # the owner file goes with the lock
    with folder_lock(run):
        assert lock_owner(run)["pid"] == os.getpid() and lock_owner(run)["host"] == HOST
    assert not run.exists()  # the lock lives beside the folder, it creates nothing in it


def test_a_waiting_caller_gets_the_folder_when_its_holder_ends(tmp_path, holder):
    run = tmp_path / "run"
    h = holder(run)
    said = []
    releaser = threading.Timer(0.5, h.release)
    releaser.start()
    started = time.monotonic()
    with folder_lock(run, wait=math.inf, log=said.append):
        assert lock_owner(run)["pid"] == os.getpid()
    releaser.join()
    assert time.monotonic() - started >= 0.5
    assert len(said) == 1 and re.fullmatch("waiting: " + IN_USE.format(folder=re.escape(str(run)),
                                                                          pid=h.process.pid), said[0]), said


def test_a_wait_that_runs_out_is_refused_saying_how_long(tmp_path, holder):
    run = tmp_path / "run"
    h = holder(run)
    started = time.monotonic()
    with pytest.raises(FolderInUseError, match=IN_USE.format(folder=re.escape(str(run)), pid=h.process.pid)
                       + re.escape(" (waited 0.3 s)")):
        with folder_lock(run, wait=0.3, log=lambda line: None):
            pass
    assert time.monotonic() - started >= 0.3
    assert lock_owner(run)["pid"] == h.process.pid  # the holder keeps it


def test_a_dead_processs_lock_is_taken_over(tmp_path, holder):
    run = tmp_path / "run"
    h = holder(run)
    h.kill()  # kill -9: the owner file stays, the kernel drops the lock
    assert lock_owner(run)["pid"] == h.process.pid
    with folder_lock(run, command="second"):
        assert lock_owner(run) == {**lock_owner(run), "pid": os.getpid(), "command": "second"}


def test_a_stale_owner_file_is_overwritten(tmp_path):
    lock_file, owner_file = lock_paths(tmp_path / "prepared")
    lock_file.write_text("")
    owner_file.write_text(json.dumps({"pid": 2 ** 22 + 1, "host": HOST, "since": "then"}))
    with folder_lock(tmp_path / "prepared"):
        assert lock_owner(tmp_path / "prepared")["pid"] == os.getpid()


def test_the_lock_is_reentrant_in_one_process(tmp_path):
    with folder_lock(tmp_path / "run"), folder_lock(tmp_path / "run"):
        pass
    with folder_lock(tmp_path / "run"):  # released by the outer block
        pass


@pytest.mark.parametrize("command", ["prepare", "train", "eval"])
def test_commands_refuse_a_folder_in_use(command, valid_scene, tmp_path, holder, capsys):
    folder = tmp_path / ("prepared" if command == "prepare" else "run")
    argv = {"prepare": ["prepare", str(valid_scene), "--out", str(folder), "--quiet"],
            "train": ["train", str(valid_scene), "--out", str(folder), "--quiet"],
            "eval": ["eval", str(folder)]}[command]
    h = holder(folder)
    capsys.readouterr()
    assert main(argv) == 1
    err = capsys.readouterr().err
    assert err.count("\n") == 1
    assert re.fullmatch(f"radar4dgs {command}: " + IN_USE.format(folder=re.escape(str(folder)), pid=h.process.pid),
                        err.strip())
    h.release()
    if command == "prepare":
        return  # running the stages is the prepare tests' business
    # Free again: the command gets past the lock (and stops at the missing prepared scene / run).
    assert main(argv) == 1
    assert "in use" not in capsys.readouterr().err


def test_train_removes_what_dead_runs_left(tmp_path, capsys):
    run = tmp_path / "run"
    dead = run / "checkpoints" / f".last.pt.{2 ** 22 + 1}@{HOST}.ab12cd_9.tmp"
    live = run / "checkpoints" / f".last.pt.{os.getpid()}@{HOST}.k3j4h5g6.tmp"
    dead.parent.mkdir(parents=True)
    dead.write_bytes(b"half")
    live.write_bytes(b"half")
    assert main(["train", str(tmp_path / "no-scene"), "--out", str(run), "--quiet"]) == 1
    assert not dead.exists() and live.exists()


def test_a_lock_just_taken_is_named_by_its_new_owner_not_a_stale_one(tmp_path):
    """The holder writes its owner file right after it locks; a command refused in between waits
    for it instead of naming a dead run's stale owner (or nobody)."""
    import threading

    from filelock import FileLock

    from radar4dgs.io.atomic import atomic_write_json

    folder = tmp_path / "run"
    lock_file, owner_file = lock_paths(folder)
    dead = subprocess.Popen([sys.executable, "-c", "pass"])
    dead.wait()
    atomic_write_json(owner_file, {"pid": dead.pid, "host": HOST, "since": "long ago", "command": "dead"})
    raw = FileLock(lock_file, timeout=0)
    raw.acquire()
    try:
        late = threading.Timer(0.3, atomic_write_json, (owner_file, {"pid": os.getpid(), "host": HOST,
                                                                    "since": "now", "command": "live"}))
        late.start()
        with pytest.raises(FolderInUseError, match=rf"is in use by pid {os.getpid()} since now \(live\)"):
            with folder_lock(folder):
                pass
        late.join()
    finally:
        raw.release()
