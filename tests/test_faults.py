"""Faults (issue 26), as an operator meets them, on the tiny 8-frame scene of the shared run:
`prepare` and `train` killed (SIGKILL) at several points then run again give what an
undisturbed run gives (prepared arrays byte for byte; the same model, metrics within 0.1 dB) and
leave no temporary behind; two commands on one folder at once: one runs, the other refuses in one
line; a full disk or a read-only folder: one line naming the folder, the previous outputs kept."""

from __future__ import annotations

import errno
import json
import os
import shutil
import signal
import subprocess
import sys
import time
from pathlib import Path
from typing import Callable

import pytest
import torch

from radar4dgs.cli import main
from radar4dgs.io.atomic import TEMP_NAME

ENV = {**os.environ, "OMP_NUM_THREADS": "1", "MKL_NUM_THREADS": "1"}
TRAIN = ["--preset", "tiny", "--quiet", "--no-eval", "--no-tensorboard", "--config.threads", "1",
         "--config.optim.iterations", "20", "--config.checkpoint-every", "5", "--config.init.points-per-frame", "800",
         "--config.init.max-static", "4000", "--config.init.max-dynamic", "800"]
EVAL = ["--no-video", "--no-report", "--no-lpips"]


def command(*argv: str) -> list[str]:
    return [sys.executable, "-m", "radar4dgs.cli", *map(str, argv)]


def run(*argv: str) -> subprocess.CompletedProcess:
    return subprocess.run(command(*argv), env=ENV, capture_output=True, text=True, timeout=300)


def kill_when(argv: list[str], condition: Callable[[], bool]) -> bool:
    """Run ``radar4dgs argv``; SIGKILL it as soon as ``condition()`` holds. True when it was
    killed, False when it ended first (it must then have succeeded)."""
    process = subprocess.Popen(command(*argv), env=ENV, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True)
    while process.poll() is None:
        if condition():
            process.send_signal(signal.SIGKILL)
            process.wait(timeout=60)
            return True
        time.sleep(0.005)
    assert process.returncode == 0, process.stderr.read()
    return False


def temporaries(folder: Path) -> list[Path]:
    return [Path(root) / name for root, dirs, files in os.walk(folder) for name in [*dirs, *files]
            if TEMP_NAME.match(name)]


def arrays(prepared: Path) -> dict[str, bytes]:
    """Every array and mask of a prepared folder (JSON summaries may hold timings)."""
    return {str(p.relative_to(prepared)): p.read_bytes() for p in sorted(prepared.rglob("*"))
            if p.suffix in (".npy", ".npz", ".png")}


def fresh_scene(source: Path, target: Path) -> Path:
    shutil.copytree(source, target, ignore=shutil.ignore_patterns("prepared", ".prepared.lock*"))
    return target


@pytest.fixture(scope="module")
def reference(tiny_trained_run, tmp_path_factory):
    """Undisturbed runs, through the command line: a prepared copy of the tiny scene, and a run
    trained (20 iterations) on the shared scene's prepared folder and evaluated."""
    root = tmp_path_factory.mktemp("faults")
    scene = fresh_scene(tiny_trained_run / "scene", root / "scene")
    done = run("prepare", scene, "--preset", "tiny", "--quiet")
    assert done.returncode == 0, done.stderr
    shared = tiny_trained_run / "scene"
    # Training and evaluation in this process (one thread: as in a subprocess), to save imports.
    assert main(["train", str(shared), "--out", str(root / "run"), *TRAIN]) == 0
    assert main(["eval", str(root / "run"), *EVAL]) == 0
    return {"scene": scene, "prepared": scene / "prepared", "shared": shared, "run": root / "run"}


def psnrs(run_dir: Path) -> dict[str, float]:
    metrics = json.loads((run_dir / "metrics.json").read_text())
    out = {}
    for split, values in metrics.items():
        if isinstance(values, dict):
            out.update({f"{split}.{k}": v for k, v in values.items() if k.startswith("psnr") and v is not None})
    return out


def same_model(a: Path, b: Path) -> bool:
    pa = torch.load(a / "model.pt", map_location="cpu", weights_only=True)["model"]
    pb = torch.load(b / "model.pt", map_location="cpu", weights_only=True)["model"]
    same = all(torch.equal(pa["static"][k], pb["static"][k]) for k in pa["static"])
    return same and torch.equal(pa["sky"], pb["sky"])


def test_prepare_killed_anywhere_then_rerun_gives_the_undisturbed_outputs(reference, tiny_trained_run, tmp_path):
    scene = fresh_scene(tiny_trained_run / "scene", tmp_path / "scene")
    prepared = scene / "prepared"
    argv = ["prepare", scene, "--preset", "tiny", "--quiet"]

    def in_stage(name: str) -> Callable[[], bool]:  # its temporary folder exists, or it is done
        return lambda: (prepared / name / "stage.json").is_file() or any(
            p.name.startswith(f".{name}.") for p in (prepared.iterdir() if prepared.is_dir() else ()))

    killed, left = [], []
    for stage in ("radar", "depth", "masks", "object_depth", "flow"):
        killed.append(kill_when(argv, in_stage(stage)))
        left += temporaries(scene)
    assert sum(killed) >= 3, killed
    assert left, "no kill caught a stage half-written"
    done = run(*argv)
    assert done.returncode == 0, done.stderr
    assert temporaries(scene) == []
    assert arrays(prepared) == arrays(reference["prepared"]) and len(arrays(prepared)) > 20


def test_train_killed_anywhere_then_resumed_matches_the_undisturbed_run(reference, tmp_path, capsys):
    out = tmp_path / "run"
    last = out / "checkpoints" / "last.pt"
    argv = ["train", reference["shared"], "--out", out, *TRAIN]

    def checkpoint_after(step: int) -> Callable[[], bool]:
        seen = {"mtime": None}

        def written() -> bool:  # read the checkpoint only when it changed (the poll shares the cores)
            try:
                mtime = last.stat().st_mtime_ns
                if mtime == seen["mtime"]:
                    return False
                seen["mtime"] = mtime
                return torch.load(last, map_location="cpu", weights_only=True)["step"] >= step
            except Exception:  # not there yet, or being replaced
                return False
        return written

    def half_written() -> bool:  # a checkpoint temporary exists
        return last.parent.is_dir() and any(TEMP_NAME.match(p.name) for p in last.parent.iterdir())

    assert kill_when(argv, checkpoint_after(5))  # after the first checkpoint
    resume = ["train", out, "--resume", "--quiet", "--no-eval", "--no-tensorboard"]
    after_second = checkpoint_after(10)
    assert kill_when(resume, lambda: half_written() or after_second())  # mid-write, or just after
    capsys.readouterr()
    assert main(list(map(str, resume))) == 0  # from the last complete checkpoint to the end
    assert f"resuming {out} at iteration" in capsys.readouterr().out
    assert same_model(out, reference["run"])
    assert main(["eval", str(out), *EVAL]) == 0
    assert temporaries(out) == []
    ours, theirs = psnrs(out), psnrs(reference["run"])
    assert ours.keys() == theirs.keys() and ours
    assert all(abs(ours[k] - theirs[k]) <= 0.1 for k in ours), (ours, theirs)


def concurrently(argv: list[str]) -> list[subprocess.CompletedProcess]:
    processes = [subprocess.Popen(command(*argv), env=ENV, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
                 for _ in range(2)]
    return [subprocess.CompletedProcess(p.args, p.wait(timeout=300), *p.communicate()) for p in processes]


def check_one_refused(results: list[subprocess.CompletedProcess], name: str, folder: Path) -> None:
    codes = sorted(r.returncode for r in results)
    assert codes == [0, 1], [r.stderr for r in results]
    refused = next(r for r in results if r.returncode == 1).stderr
    # The loser waits for the winner's owner file, so even two commands started together name it.
    assert refused.count("\n") == 1 and refused.startswith(f"radar4dgs {name}: {folder} is in use by pid "), refused
    assert " since " in refused, refused


def test_two_prepares_on_one_folder_one_runs_the_other_refuses(reference, tiny_trained_run, tmp_path):
    scene = fresh_scene(tiny_trained_run / "scene", tmp_path / "scene")
    check_one_refused(concurrently(["prepare", scene, "--preset", "tiny", "--quiet"]), "prepare", scene / "prepared")
    assert arrays(scene / "prepared") == arrays(reference["prepared"])


def test_two_trainings_on_one_folder_one_runs_the_other_refuses(reference, tmp_path):
    out = tmp_path / "run"
    check_one_refused(concurrently(["train", reference["shared"], "--out", out, *TRAIN]), "train", out)
    assert same_model(out, reference["run"]) and temporaries(out) == []


# ---- a full disk, a read-only folder


def refuse_writes(monkeypatch, code: int, folder: Path) -> None:
    """Every new file or folder inside ``folder`` fails with ``code`` (ENOSPC: the disk is full;
    EROFS: a read-only file system), as the OS says it (writes elsewhere, such as the lock's owner
    file beside the folder, go through)."""
    import tempfile

    def failing(create):
        def create_or_fail(*args, **kwargs):
            where = Path(kwargs.get("dir") or tempfile.gettempdir()).resolve()
            if where == folder.resolve() or folder.resolve() in where.parents:
                raise OSError(code, os.strerror(code))
            return create(*args, **kwargs)
        return create_or_fail

    monkeypatch.setattr(tempfile, "mkstemp", failing(tempfile.mkstemp))
    monkeypatch.setattr(tempfile, "mkdtemp", failing(tempfile.mkdtemp))


def test_a_write_that_fills_the_disk_keeps_the_previous_file(tmp_path, monkeypatch):
    from radar4dgs.io.atomic import OutputWriteError, atomic_write_bytes

    target = tmp_path / "out" / "metrics.json"
    atomic_write_bytes(target, b"complete")

    def full(self, data):
        with open(self, "wb") as f:
            f.write(data[:3])  # part of it fits
        raise OSError(errno.ENOSPC, os.strerror(errno.ENOSPC), str(self))

    monkeypatch.setattr(Path, "write_bytes", full)
    with pytest.raises(OutputWriteError) as caught:
        atomic_write_bytes(target, b"the new, longer content")
    assert str(caught.value).startswith(f"{target.parent}: disk full, cannot write metrics.json (No space left "
                                        f"on device); the previous outputs there are untouched; free some space")
    assert caught.value.errno == errno.ENOSPC
    monkeypatch.undo()
    assert target.read_bytes() == b"complete" and temporaries(tmp_path) == []


@pytest.mark.parametrize("code, says", [(errno.ENOSPC, "disk full"), (errno.EROFS, "read-only file system")])
def test_prepare_on_a_full_or_read_only_disk_says_so_and_keeps_the_outputs(reference, tmp_path, monkeypatch,
                                                                           capsys, code, says):
    scene = tmp_path / "scene"
    shutil.copytree(reference["scene"], scene)
    before = arrays(scene / "prepared")
    refuse_writes(monkeypatch, code, scene / "prepared")
    capsys.readouterr()
    assert main(["prepare", str(scene), "--preset", "tiny", "--quiet", "--force"]) == 1
    err = capsys.readouterr().err
    assert err.count("\n") == 1, err
    assert err.startswith(f"radar4dgs prepare: {scene / 'prepared'}: {says}, cannot write "), err
    assert "the previous outputs there are untouched" in err
    assert arrays(scene / "prepared") == before and temporaries(scene) == []


@pytest.mark.parametrize("code, says", [(errno.ENOSPC, "disk full"), (errno.EROFS, "read-only file system")])
def test_train_and_eval_on_a_full_or_read_only_disk_say_so_and_keep_the_run(reference, tmp_path, monkeypatch, capsys,
                                                                            code, says):
    out = tmp_path / "run"
    shutil.copytree(reference["run"], out)
    files = {p: p.read_bytes() for p in out.rglob("*") if p.is_file()}
    refuse_writes(monkeypatch, code, out)
    capsys.readouterr()
    assert main(["eval", str(out), *EVAL]) == 1
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and err.startswith(f"radar4dgs eval: {out}"), err
    assert f": {says}, cannot write " in err
    assert main(["train", str(out), "--resume", "--quiet", "--no-eval", "--no-tensorboard"]) == 1
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and f": {says}, cannot write " in err, err
    assert {p: p.read_bytes() for p in out.rglob("*") if p.is_file()} == files


@pytest.mark.skipif(os.name != "posix" or os.geteuid() == 0, reason="root writes into read-only folders")
def test_a_read_only_run_folder_is_named(reference, tmp_path, capsys):
    out = tmp_path / "run"
    shutil.copytree(reference["run"], out)
    files = {p: p.read_bytes() for p in out.rglob("*") if p.is_file()}
    folders = [out, *(p for p in out.rglob("*") if p.is_dir())]
    for folder in folders:
        folder.chmod(0o555)
    try:
        assert main(["eval", str(out), *EVAL]) == 1
        err = capsys.readouterr().err
        assert err.count("\n") == 1 and "read-only (permission denied), cannot write" in err, err
    finally:
        for folder in folders:
            folder.chmod(0o755)
    assert {p: p.read_bytes() for p in out.rglob("*") if p.is_file()} == files
