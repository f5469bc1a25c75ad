"""`radar4dgs batch` on a local Ray cluster: the collected table, skipping finished scenes, a bad scene
failing alone, and a worker killed in the middle of training (the retry resumes from the checkpoint
and ends with the metrics of an undisturbed run, leaving no half-written file).

Tiny scenes (8 frames), 40 iterations in chunks of 10, one CPU per task: each test takes about
20-35 s on 2 cores, most of it Ray's start (about 4 s) and the workers importing torch.
"""

from __future__ import annotations

import json
import os
import shutil
import signal
import threading
import time
from pathlib import Path

import pytest

from radar4dgs.apps.batch import run_batch
from radar4dgs.apps.batch_engine import Resources
from radar4dgs.apps.batch_scene import PARTIAL, read_status
from radar4dgs.cli import main

pytest.importorskip("ray")

ITERATIONS = 40
SETTINGS = {"checkpoint_every": 10, "init": {"points_per_frame": 800, "max_static": 4000, "max_dynamic": 800}}
ARGS = ["--preset", "tiny", "--iterations", str(ITERATIONS), "--set", "checkpoint_every=10",
        "init.points_per_frame=800", "init.max_static=4000", "init.max_dynamic=800", "--no-video", "--no-lpips",
        "--quiet"]


@pytest.fixture(scope="module")
def tiny_scene(tmp_path_factory) -> Path:
    """A tiny synthetic scene (8 frames, seed 4), not prepared: the batch prepares it."""
    from radar4dgs.config import preset
    from radar4dgs.datasets.synth import SynthConfig, synthesize
    from radar4dgs.train.fit_motion import torch_threads

    root = tmp_path_factory.mktemp("batch-scene") / "scene"
    with torch_threads(1):
        synthesize(preset(SynthConfig, "tiny", seed=4, num_frames=8), root, progress=False)
    return root


def scores(run: Path) -> dict:
    """What two runs of one config must agree on: both splits' metrics and the Gaussian count."""
    metrics = json.loads((run / "metrics.json").read_text())
    return {key: metrics[key] for key in ("recon", "nvs", "num_gaussians", "per_frame")}


def assert_no_partial_files(out: Path) -> None:
    for root, dirs, files in os.walk(out):
        for name in [*dirs, *files]:
            assert not PARTIAL.match(name), f"half-written {Path(root) / name}"
            if name.endswith(".json"):
                json.loads((Path(root) / name).read_text())  # complete, parseable


def test_a_bad_scene_fails_alone_and_a_finished_scene_is_skipped(tiny_scene, tmp_path, capsys):
    bad = tmp_path / "bad"
    bad.mkdir()
    (bad / "scene.json").write_text("{not json")
    out = tmp_path / "out"
    args = ["batch", str(tiny_scene), str(bad), "--out", str(out), *ARGS]
    assert main(args) == 1
    captured = capsys.readouterr()
    assert "1 scene(s) failed: bad" in captured.err
    result = json.loads((out / "batch.json").read_text())
    good, failed = result["scenes"]
    assert (good["scene"], good["status"], good["action"]) == ("scene", "ok", "trained")
    assert failed["scene"] == "bad" and failed["status"] == "failed"
    assert "\n" not in failed["error"] and "scene.json" in failed["error"]
    assert failed["attempts"] == 1  # bad input is not retried
    assert f"[2/2] bad: FAILED: {failed['error']}" in captured.out or f"[1/2] bad: FAILED: {failed['error']}" in (
        captured.out)
    run = out / "scenes" / "scene" / "run"
    metrics = json.loads((run / "metrics.json").read_text())
    assert good["metrics"]["nvs"] == metrics["nvs"] and (run / "report.html").is_file()
    assert result["means"]["n"] == 1 and result["means"]["nvs_psnr"] == metrics["nvs"]["psnr"]
    index = (out / "index.html").read_text()
    assert 'href="scenes/scene/run/report.html"' in index and "failed" in index
    table = (out / "batch.md").read_text()
    assert "| scene | ok |" in table and f"- **bad**: {failed['error']}" in table
    assert_no_partial_files(out)

    # The same call again: the finished scene is skipped (its files untouched), the bad one fails again.
    stamp = (run / "metrics.json").stat().st_mtime_ns
    assert main(args) == 1
    rerun = json.loads((out / "batch.json").read_text())
    assert [(r["scene"], r["status"], r.get("action")) for r in rerun["scenes"]] == [
        ("scene", "ok", "skipped"), ("bad", "failed", None)]
    assert rerun["scenes"][0]["metrics"] == good["metrics"]
    assert (run / "metrics.json").stat().st_mtime_ns == stamp
    assert "[1/2] scene: skipped (finished with the same config)" in capsys.readouterr().out


class Killer(threading.Thread):
    """Kills (SIGKILL) the worker training ``scene`` once its status shows a checkpoint written
    and training going on: the process id the task reports in its status.json."""

    def __init__(self, scene_out: Path):
        super().__init__(daemon=True)
        self.scene_out, self.killed, self.stop = scene_out, None, threading.Event()

    def run(self) -> None:
        while not self.stop.is_set():
            status = read_status(self.scene_out)
            if status.get("stage") == "train" and (status.get("step") or 0) >= 10 and status.get("attempt") == 1:
                self.killed = (status["pid"], status["step"])
                os.kill(status["pid"], signal.SIGKILL)
                return
            time.sleep(0.02)


def test_a_worker_killed_while_training_resumes_and_matches_an_undisturbed_run(tiny_scene, tmp_path):
    # Two copies of one scene in one batch: "calm" runs undisturbed, "killed" loses its worker.
    calm, killed = tmp_path / "calm", tmp_path / "killed"
    shutil.copytree(tiny_scene, calm)
    shutil.copytree(tiny_scene, killed)
    out = tmp_path / "out"
    killer = Killer(out / "scenes" / "killed")
    killer.start()
    try:
        result = run_batch([calm, killed], out, "tiny", resources=Resources(cpus=1, memory_gb=0.5),
                           iterations=ITERATIONS, settings=SETTINGS, lpips=False, video=False, progress=False,
                           log=lambda line: None)
    finally:
        killer.stop.set()
        killer.join()
    assert killer.killed is not None, "the training finished before the worker could be killed"
    records = {r["scene"]: r for r in result["scenes"]}
    assert records["calm"]["status"] == "ok" and records["calm"]["attempts"] == 1
    assert records["killed"]["status"] == "ok" and records["killed"]["attempts"] == 2
    assert records["killed"]["action"] == "resumed"  # the retry continued from the checkpoint
    log = (out / "scenes" / "killed" / "task.log").read_text()
    assert "attempt 2" in log and "resuming" in log
    assert read_status(out / "scenes" / "killed")["pid"] != killer.killed[0]
    assert scores(out / "scenes" / "killed" / "run") == scores(out / "scenes" / "calm" / "run")
    assert records["killed"]["metrics"] == records["calm"]["metrics"]
    assert_no_partial_files(out)
