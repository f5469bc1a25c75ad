"""Write-then-rename helpers, so that an interrupted run never leaves a half-written output.

Every temporary name carries its owner: ``.<name>.<pid>@<host>.<8 random chars><suffix>`` (e.g.
``prepared/.flow.4242@box.k2j9x_0a.tmp``). Before a helper creates a temporary it removes the
siblings of that form whose owner is gone (same host, pid not alive), so a run killed half-way
(``kill -9``, a power cut) leaves nothing behind once the next run writes there; a live run's
temporaries, and those of other hosts (a shared disk), are left alone.

A write that fails because the disk is full or the folder is read-only raises
:class:`OutputWriteError` (an OSError), whose message names the folder and says which: ``FOLDER:
disk full (...)`` or ``FOLDER: read-only (...)``; the temporary is removed and the previous output
is untouched.
"""

from __future__ import annotations

import contextlib
import errno
import io
import json
import os
import re
import shutil
import socket
import tempfile
from pathlib import Path
from typing import Any, Iterator, Mapping

import numpy as np

# mkstemp/mkdtemp create private (0600/0700) entries; outputs are meant to be shared like any file.
_FILE_MODE = 0o644
_DIR_MODE = 0o755

# This host as a temporary name carries it (letters, digits and "-" only).
HOST = re.sub(r"[^A-Za-z0-9-]", "-", socket.gethostname())[:40] or "localhost"
# ".<target>.<pid>@<host>.<mkstemp's 8 random chars><suffix>" (".tmp", ".old", or a writer's own).
TEMP_NAME = re.compile(r"^\.(?P<target>.+)\.(?P<pid>[0-9]+)@(?P<host>[A-Za-z0-9-]+)\.[a-z0-9_]{8}\.[A-Za-z0-9.]+$")
# Folders whose dead temporaries atomic_path has already removed in this process (once each).
_CLEANED: set[Path] = set()
# Why a write fails for want of room or of write access, as the one-line message says it.
_NO_ROOM = {errno.ENOSPC: "disk full", getattr(errno, "EDQUOT", errno.ENOSPC): "disk full (quota exceeded)"}
_SHORT_WRITE = re.compile(r"\d+ requested and \d+ written")
_NO_WRITE = {errno.EROFS: "read-only file system", errno.EACCES: "read-only (permission denied)",
             errno.EPERM: "read-only (operation not permitted)"}


class OutputWriteError(OSError):
    """An output could not be written: the disk is full or the folder is read-only. The message
    names the folder; the previous outputs there are untouched."""

    def __str__(self) -> str:  # the message alone, without OSError's "[Errno N]"
        return str(self.strerror)


def output_write_error(folder: str | os.PathLike, name: str, exc: OSError) -> OSError:
    """An :class:`OutputWriteError` for ``exc`` when it is a full disk or a read-only folder
    (``FOLDER: disk full (no space left writing NAME); ...``), else ``exc`` itself."""
    if isinstance(exc, OutputWriteError):
        return exc
    if exc.errno is None and _SHORT_WRITE.fullmatch(str(exc)):
        # numpy's tofile (np.save of a large array) reports a full disk as a short write, without errno.
        exc = OSError(errno.ENOSPC, f"no space left: {exc}")
    why = _NO_ROOM.get(exc.errno) or _NO_WRITE.get(exc.errno)
    if why is None:
        return exc
    what = "free some space" if exc.errno in _NO_ROOM else "make it writable or choose another output"
    return OutputWriteError(exc.errno, f"{folder}: {why}, cannot write {name} ({exc.strerror or exc}); "
                                       f"the previous outputs there are untouched; {what}")


@contextlib.contextmanager
def _named_write_errors(folder: Path, name: str) -> Iterator[None]:
    """Raise a full disk or a read-only folder met in the block as :func:`output_write_error`."""
    try:
        yield
    except OSError as exc:
        error = output_write_error(folder, name, exc)
        if error is exc:
            raise
        raise error from exc


def temp_prefix(name: str) -> str:
    """The start of a temporary name for target ``name`` owned by this process."""
    return f".{name}.{os.getpid()}@{HOST}."


def pid_alive(pid: int) -> bool:
    """Whether process ``pid`` exists on this host (a process of another user counts as alive;
    off POSIX, every pid does: nothing is removed there)."""
    if os.name != "posix" or pid <= 0:
        return True
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except PermissionError:
        return True
    except OverflowError:
        return False
    return True


def dead_temporary(name: str) -> bool:
    """Whether ``name`` is a temporary of this module whose owner (pid on this host) is gone."""
    match = TEMP_NAME.match(name)
    if match is None or match["host"] != HOST:
        return False
    pid = int(match["pid"])
    return pid != os.getpid() and not pid_alive(pid)


def remove_dead_temporaries(folder: str | os.PathLike, recursive: bool = False) -> list[Path]:
    """Delete the temporaries (files and folders) that dead runs left in ``folder`` (and its
    subfolders with ``recursive``); returns them. A missing folder has none."""
    removed: list[Path] = []
    folder = Path(folder)
    if not folder.is_dir():
        return removed
    for root, dirs, files in os.walk(folder):
        for name in [*dirs, *files]:
            if dead_temporary(name):
                path = Path(root) / name
                if path.is_dir() and not path.is_symlink():
                    shutil.rmtree(path, ignore_errors=True)
                else:
                    path.unlink(missing_ok=True)
                removed.append(path)
        # Never descend into a temporary (a live run's is its own business); stop at the top
        # unless asked.
        dirs[:] = [d for d in dirs if recursive and not TEMP_NAME.match(d)]
    return removed


@contextlib.contextmanager
def atomic_path(path: str | os.PathLike, suffix: str = ".tmp") -> Iterator[Path]:
    """Yield a temporary file path beside ``path`` for a writer that needs a file name (an
    encoder, a library's save function); on success it replaces ``path`` in one rename, on an
    exception it is deleted and ``path`` is untouched. ``suffix`` ends the temporary name (some
    writers pick the format from it)."""
    path = Path(path)
    with _named_write_errors(path.parent, path.name):
        path.parent.mkdir(parents=True, exist_ok=True)
        folder = path.parent.resolve()
        if folder not in _CLEANED:
            remove_dead_temporaries(folder)
            _CLEANED.add(folder)
        fd, name = tempfile.mkstemp(prefix=temp_prefix(path.name), suffix=suffix, dir=path.parent)
        os.close(fd)
    tmp = Path(name)
    try:
        with _named_write_errors(path.parent, path.name):
            yield tmp
            os.chmod(tmp, _FILE_MODE)
            os.replace(tmp, path)
    except BaseException:
        tmp.unlink(missing_ok=True)
        raise


def atomic_write_bytes(path: str | os.PathLike, data: bytes) -> Path:
    """Write ``data`` to ``path`` through a temporary file in the same folder and a rename."""
    with atomic_path(path) as tmp:
        tmp.write_bytes(data)
    return Path(path)


def atomic_write_text(path: str | os.PathLike, text: str) -> Path:
    return atomic_write_bytes(path, text.encode("utf-8"))


def atomic_write_json(path: str | os.PathLike, obj: Any) -> Path:
    return atomic_write_text(path, json.dumps(obj, indent=2, allow_nan=False) + "\n")


def atomic_save_npy(path: str | os.PathLike, array: np.ndarray) -> Path:
    buffer = io.BytesIO()
    np.save(buffer, np.ascontiguousarray(array), allow_pickle=False)
    return atomic_write_bytes(path, buffer.getvalue())


def atomic_save_npz(path: str | os.PathLike, arrays: Mapping[str, np.ndarray], compressed: bool = True) -> Path:
    """``arrays`` as an ``.npz`` at ``path`` (``np.savez_compressed``, or ``np.savez`` when not
    ``compressed``) through a temporary file; a mapping, so an array may be called anything."""
    buffer = io.BytesIO()
    (np.savez_compressed if compressed else np.savez)(buffer, **arrays)
    return atomic_write_bytes(path, buffer.getvalue())


def atomic_save_torch(path: str | os.PathLike, obj: Any) -> int:
    """``torch.save`` ``obj`` to ``path`` through a temporary file; returns the size in bytes.

    torch is imported here only, so that the scene tools that use this module do not load it.
    """
    import torch

    buffer = io.BytesIO()
    torch.save(obj, buffer)
    data = buffer.getvalue()
    atomic_write_bytes(path, data)
    return len(data)


@contextlib.contextmanager
def atomic_directory(path: str | os.PathLike, overwrite: bool = False) -> Iterator[Path]:
    """Yield a temporary folder beside ``path``; on success it replaces ``path`` in one rename.

    On an exception the temporary folder is deleted and ``path`` is untouched. Temporaries that
    dead runs left beside ``path`` are removed first (module doc).
    """
    path = Path(path)
    if path.exists() and not overwrite:
        raise FileExistsError(f"{path}: already exists (pass overwrite=True / --overwrite to replace it)")
    with _named_write_errors(path.parent, path.name + "/"):
        path.parent.mkdir(parents=True, exist_ok=True)
        remove_dead_temporaries(path.parent)
        tmp = Path(tempfile.mkdtemp(prefix=temp_prefix(path.name), suffix=".tmp", dir=path.parent))
        os.chmod(tmp, _DIR_MODE)
    try:
        with _named_write_errors(path.parent, path.name + "/"):
            yield tmp
            _replace_directory(tmp, path)
    except BaseException:
        shutil.rmtree(tmp, ignore_errors=True)
        raise


def _replace_directory(tmp: Path, path: Path) -> None:
    """Put folder ``tmp`` in the place of ``path`` by renames (the old one is deleted after); if the
    second rename fails, the old folder is put back."""
    if not path.exists():
        os.replace(tmp, path)
        return
    trash = Path(tempfile.mkdtemp(prefix=temp_prefix(path.name), suffix=".old", dir=path.parent))
    os.replace(path, trash / path.name)
    try:
        os.replace(tmp, path)
    except BaseException:
        os.replace(trash / path.name, path)
        shutil.rmtree(trash, ignore_errors=True)
        raise
    shutil.rmtree(trash, ignore_errors=True)
