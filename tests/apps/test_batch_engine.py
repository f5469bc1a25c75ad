"""The batch engine's pure parts (no Ray started): resources, one-line errors, the progress lines,
what a killed atomic write leaves, the per-preset resources; and no hand-made process pool in src/."""

from __future__ import annotations

import re
import time
from pathlib import Path

import pytest

from radar4dgs.apps.batch import PRESET_RESOURCES, ProgressView, scene_overrides, task_resources
from radar4dgs.apps.batch_engine import Resources, check_resources, elapsed_text, one_line, run_inline
from radar4dgs.apps.batch_scene import BatchError, remove_partial_files
from radar4dgs.apps.batch_table import index_html, markdown, payload

SRC = Path(__file__).resolve().parents[2] / "src"


def test_no_hand_made_process_pool_in_the_package():
    pattern = re.compile(r"\b(ProcessPoolExecutor|multiprocessing)\b")
    offenders = [f"{path.relative_to(SRC)}:{number}" for path in sorted(SRC.rglob("*.py"))
                 for number, line in enumerate(path.read_text(encoding="utf-8").splitlines(), 1)
                 if pattern.search(line)]
    assert offenders == []


def test_resources_as_ray_options_and_checked_against_the_cluster():
    assert Resources(2, 0.5, 1.5).options() == {"num_cpus": 2, "num_gpus": 0.5, "memory": int(1.5 * 1024**3)}
    assert Resources(1).options() == {"num_cpus": 1, "num_gpus": 0.0}
    have = {"CPU": 2.0, "memory": 8 * 1024**3}
    assert check_resources(Resources(2, 0, 4), have, local=True) == []
    problems = check_resources(Resources(4, 1, 16), have, local=True)
    assert problems == ["4 CPU per task, this machine has 2 (--cpus)", "1 GPU per task, this machine has 0 (--gpus)",
                        "16 GiB of memory per task, the cluster has 8.0 GiB (--memory-gb)"]


def test_preset_resources_and_the_overrides_they_imply():
    assert task_resources("tiny") == PRESET_RESOURCES["tiny"] == Resources(1, 0, 1)
    assert task_resources("paper", gpus=0.25) == Resources(4, 0.25, 12)
    with pytest.raises(BatchError, match="--cpus > 0"):
        task_resources("small", cpus=0)
    assert scene_overrides({}, Resources(2), 30) == {"threads": 2, "device": "cpu", "optim": {"iterations": 30}}
    assert scene_overrides({"device": "cuda:1"}, Resources(2), None)["device"] == "cuda:1"
    assert scene_overrides({"threads": 1}, Resources(1, 0.5), None) == {"threads": 1, "device": "cuda"}


def test_failures_are_one_line():
    class Wrapped(Exception):
        def __init__(self, cause):
            super().__init__("a long\ntraceback")
            self.cause = cause

    assert one_line(ValueError("scene.json: bad\nmore")) == "ValueError: scene.json: bad"
    assert one_line(Wrapped(RuntimeError("loss is nan"))) == "RuntimeError: loss is nan"
    seen = []
    run_inline(lambda item: 1 / item, [1, 0], on_done=lambda i, result, error: seen.append((i, result, error)))
    assert seen == [(0, 1.0, None), (1, None, "ZeroDivisionError: division by zero")]


def test_progress_lines_say_stage_iteration_eta_and_attempt():
    now = time.time()
    assert ProgressView.describe("a", {"stage": "train", "step": 20, "total": 40, "eta_s": 75, "updated": now,
                                       "attempt": 1}) == "a: train 20/40 it, ETA 1m15s"
    assert ProgressView.describe("b", {"stage": "train", "step": None, "total": 40, "attempt": 2}) == (
        "b: train ?/40 it (attempt 2, resumed)")
    assert ProgressView.describe("c", {"stage": "failed", "error": "ValueError: x"}) == "c: failed: ValueError: x"
    assert elapsed_text(3725) == "1h02m" and elapsed_text(None) == "?"


def test_what_a_killed_atomic_write_leaves_is_removed(tmp_path):
    from radar4dgs.io.atomic import atomic_path

    (tmp_path / "run" / "checkpoints").mkdir(parents=True)
    (tmp_path / "run" / "config.json").write_text("{}")
    (tmp_path / "run" / ".hidden").write_text("kept")
    with pytest.raises(KeyboardInterrupt), atomic_path(tmp_path / "x.json") as tmp:
        kept = tmp.name
        raise KeyboardInterrupt
    partial = [tmp_path / "run" / "checkpoints" / ".last.pt.ab12cd_9.tmp", tmp_path / "run" / ".video.mp4.zz99aa00.mp4"]
    for path in partial:
        path.write_bytes(b"half")
    (tmp_path / "run" / ".renders.k3j4h5g6.tmp").mkdir()
    assert re.match(r"^\..+\.[a-z0-9_]{8}\.[A-Za-z0-9]+$", kept)  # the atomic helpers' naming
    removed = remove_partial_files(tmp_path)
    assert sorted(removed) == sorted([*partial, tmp_path / "run" / ".renders.k3j4h5g6.tmp"])
    assert (tmp_path / "run" / "config.json").is_file() and (tmp_path / "run" / ".hidden").is_file()


def test_the_collected_table_links_reports_and_lists_failures():
    config = {"preset": "tiny", "method": "ours", "iterations": 40}
    ok = {"scene": "a", "status": "ok", "action": "trained", "seconds": 12.0, "attempts": 2,
          "metrics": {"recon": {"psnr": 30.0}, "nvs": {"psnr": 25.0, "ssim": 0.9, "lpips_vgg": None,
                                                        "psnr_dyn": 20.0}}}
    bad = {"scene": "b<", "status": "failed", "error": "SceneError: b/scene.json: not JSON", "seconds": None}
    result = payload(config, ["a", "b<", "c"], {"a": ok, "b<": bad})
    assert result["failed"] == 1 and result["missing"] == ["c"] and result["means"]["nvs_psnr"] == 25.0
    md = markdown(result)
    assert "| a | ok | 30.00 | 25.00 | 0.900 | – | 20.00 | 12s | 2 | [report](scenes/a/run/report.html) |" in md
    assert "- **b<**: SceneError: b/scene.json: not JSON" in md and "Not finished: c" in md
    page = index_html(result)
    assert '<a href="scenes/a/run/report.html">a</a>' in page and "b&lt;" in page
