"""One live process per prepared or run folder: an OS file lock (``filelock``, ``flock`` on POSIX).

``folder_lock(FOLDER)`` holds ``.<name>.lock`` beside ``FOLDER`` (beside, so that a command that
replaces or deletes the whole folder, ``train --force``, keeps its lock) and writes who holds it
(pid, host, start time, command) to ``.<name>.lock.owner`` for the message a second process gets:
``FOLDER is in use by pid N since TIME``. The kernel drops the lock when its process dies however it
dies, so a lock left by a dead run (``kill -9``) is simply taken over; the stale owner file is
overwritten. The lock file itself stays (deleting a lock file is what breaks mutual exclusion).

The lock is re-entrant within one process (``train`` runs ``eval`` on the run it holds). A caller
that would rather queue than fail (a benchmark preparing a scene another benchmark is preparing)
passes ``wait`` seconds.
"""

from __future__ import annotations

import contextlib
import json
import math
import os
import sys
import time
from pathlib import Path
from typing import Callable, Iterator

from filelock import FileLock, Timeout

from radar4dgs.io.atomic import HOST, atomic_write_json

# Locks this process holds: lock file -> [FileLock, depth].
_HELD: dict[Path, list] = {}


class FolderInUseError(RuntimeError):
    """Another live process holds the folder's lock; the message says which and since when."""


def lock_paths(folder: str | os.PathLike) -> tuple[Path, Path]:
    """The lock file and its owner file for ``folder`` (both beside it)."""
    folder = Path(os.path.abspath(folder))
    return folder.parent / f".{folder.name}.lock", folder.parent / f".{folder.name}.lock.owner"


def lock_owner(folder: str | os.PathLike) -> dict | None:
    """What the owner file of ``folder``'s lock says (pid, host, since, command), None if unreadable."""
    try:
        owner = json.loads(lock_paths(folder)[1].read_text(encoding="utf-8"))
    except (OSError, ValueError):
        return None
    return owner if isinstance(owner, dict) else None


def in_use_message(folder: str | os.PathLike) -> str:
    owner = lock_owner(folder)
    if owner is None or "pid" not in owner:
        return f"{folder} is in use by another process (lock {lock_paths(folder)[0]})"
    host = owner.get("host")
    where = f" on {host}" if host and host != HOST else ""
    command = f" ({owner['command']})" if owner.get("command") else ""
    return f"{folder} is in use by pid {owner['pid']}{where} since {owner.get('since', '?')}{command}"


def _stderr(line: str) -> None:
    print(line, file=sys.stderr, flush=True)


def _owner_alive(owner: dict | None) -> bool:
    """Whether ``owner`` names a live process (one on another host is taken as alive)."""
    if owner is None or not isinstance(owner.get("pid"), int):
        return False
    if owner.get("host") not in (None, HOST):
        return True
    try:
        os.kill(owner["pid"], 0)
    except ProcessLookupError:
        return False
    except PermissionError:
        return True  # alive, another user's
    return True


def _wait_for_live_owner(folder: str | os.PathLike, seconds: float = 1.0) -> None:
    """Give the holder of a lock just taken time to write its owner file, so the message names it
    (and not the stale owner of a dead run, or nobody): the holder writes it right after locking."""
    deadline = time.monotonic() + seconds
    while not _owner_alive(lock_owner(folder)) and time.monotonic() < deadline:
        time.sleep(0.05)


@contextlib.contextmanager
def folder_lock(folder: str | os.PathLike, command: str | None = None, wait: float = 0.0,
                log: Callable[[str], None] | None = None) -> Iterator[Path]:
    """Hold ``folder``'s lock for the ``with`` block, or raise :class:`FolderInUseError` when
    another live process holds it: at once (``wait`` 0), or after waiting ``wait`` seconds for it
    (``math.inf``: until it is free), saying once through ``log`` (default: stderr) whom it waits
    for. ``command`` (default: this process's command line) goes into the message others get.
    Yields the lock file."""
    lock_file, owner_file = lock_paths(folder)
    held = _HELD.get(lock_file)
    if held is not None:
        held[1] += 1
        try:
            yield lock_file
        finally:
            held[1] -= 1
        return
    lock_file.parent.mkdir(parents=True, exist_ok=True)
    lock = FileLock(lock_file, timeout=0)
    try:
        lock.acquire()
    except Timeout:
        _wait_for_live_owner(folder)
        if wait <= 0:
            raise FolderInUseError(in_use_message(folder)) from None
        (log or _stderr)(f"waiting: {in_use_message(folder)}")
        try:
            # filelock polls (every 50 ms by default); -1 is its "for ever".
            lock.acquire(timeout=-1 if math.isinf(wait) else wait)
        except Timeout:
            _wait_for_live_owner(folder)
            raise FolderInUseError(f"{in_use_message(folder)} (waited {wait:g} s)") from None
    try:
        if command is None:
            command = " ".join([Path(sys.argv[0]).name, *sys.argv[1:]]) if sys.argv and sys.argv[0] else ""
        atomic_write_json(owner_file, {"pid": os.getpid(), "host": HOST,
                                       "since": time.strftime("%Y-%m-%d %H:%M:%S %z"), "command": command})
        _HELD[lock_file] = [lock, 1]
        yield lock_file
    finally:
        _HELD.pop(lock_file, None)
        with contextlib.suppress(OSError):
            owner_file.unlink()
        lock.release()
