"""Training logs: TensorBoard event files in RUN/tb with gsplat's tags (on by default,
``--no-tensorboard`` off), evaluation added to them, history.json at every log step, and a
logging failure that does not stop training."""

from __future__ import annotations

import json
import shutil

import numpy as np
import pytest

from radar4dgs.cli import main
from radar4dgs.config import preset
from radar4dgs.model.config import TrainConfig
from radar4dgs.model.run import LOSS_TERMS
from radar4dgs.model.run_log import TB_DIR, TensorBoard, peak_memory_gib, train_scalars
from radar4dgs.train.trainer import train_run

pytestmark = pytest.mark.usefixtures("one_torch_thread")


def events(tb_dir):
    """(scalar tags -> [(step, value)], image tags) of every event file in ``tb_dir``."""
    from tensorboard.backend.event_processing.event_accumulator import EventAccumulator

    accumulator = EventAccumulator(str(tb_dir), size_guidance={"scalars": 0, "images": 0})
    accumulator.Reload()
    tags = accumulator.Tags()
    scalars = {tag: [(e.step, e.value) for e in accumulator.Scalars(tag)] for tag in tags["scalars"]}
    return scalars, set(tags["images"])


def small_config(**overrides) -> TrainConfig:
    values = {"threads": 1, "log_every": 2, "checkpoint_every": 2, "optim": {"iterations": 6},
              "init": {"points_per_frame": 600, "max_static": 3000, "max_dynamic": 600},
              "losses": {"motion_batch": 64, "radar_points_per_frame": 100}}
    values.update(overrides)
    return preset(TrainConfig, "tiny", **values)


def test_a_trained_run_holds_tensorboard_events_with_the_loss_terms(tiny_trained_run):
    run = tiny_trained_run / "run"
    files = list((run / TB_DIR).glob("events.out.tfevents.*"))
    assert files, f"no event file in {run / TB_DIR}"
    scalars, _ = events(run / TB_DIR)
    history = json.loads((run / "history.json").read_text())["history"]
    logged = [h for h in history if "total" in h]
    # gsplat's tags: the total, one per loss term, the Gaussian count, PSNR, peak memory.
    for tag in ("train/loss", "train/num_GS", "train/psnr", "train/mem", "train/l1", "train/ssim"):
        assert tag in scalars, tag
    terms = [term for term in LOSS_TERMS if term in logged[0]]
    assert {"l1", "ssim", "flow", "radar"} <= set(terms)
    for term in terms:
        assert [step for step, _ in scalars[f"train/{term}"]] == [h["step"] for h in logged]
    assert [step for step, _ in scalars["train/loss"]] == [h["step"] for h in logged]
    np.testing.assert_allclose([v for _, v in scalars["train/loss"]], [h["total"] for h in logged], rtol=1e-6)
    np.testing.assert_allclose([v for _, v in scalars["train/num_GS"]], [h["num_gaussians"] for h in logged])
    assert all(v > 0 for _, v in scalars["train/mem"])


def test_history_is_written_at_every_log_step_and_resume_appends_to_tensorboard(tiny_trained_run, tmp_path):
    scene, out = tiny_trained_run / "scene", tmp_path / "run"
    config = small_config()
    # Killed after 3 iterations: history.json already holds the log steps 0 and 2.
    train_run(scene, scene / "prepared", out, config, progress=False, stop_after=3)
    assert not (out / "model.pt").exists()
    history = json.loads((out / "history.json").read_text())
    assert [h["step"] for h in history["history"] if "total" in h] == [0, 2]
    assert "train_seconds_last_call" not in history
    scalars, _ = events(out / TB_DIR)
    assert [step for step, _ in scalars["train/loss"]] == [0, 2]
    # Resumed: a second event file in the same folder; TensorBoard reads the steps of both calls.
    train_run(scene, scene / "prepared", out, config, progress=False, resume=True)
    history = json.loads((out / "history.json").read_text())
    assert [h["step"] for h in history["history"] if "total" in h] == [0, 2, 4, 5]
    assert history["train_seconds_last_call"] > 0
    assert len(list((out / TB_DIR).glob("events.out.tfevents.*"))) == 2
    scalars, _ = events(out / TB_DIR)
    assert [step for step, _ in scalars["train/loss"]] == [0, 2, 4, 5]
    assert [step for step, _ in scalars["train/l1"]] == [0, 2, 4, 5]


def test_no_tensorboard_writes_no_tb_folder(tiny_trained_run, tmp_path):
    scene, out = tiny_trained_run / "scene", tmp_path / "run"
    code = main(["train", str(scene), "--out", str(out), "--preset", "tiny", "--no-tensorboard", "--no-eval",
                 "--quiet", "--config.threads", "1", "--config.optim.iterations", "2",
                 "--config.init.points-per-frame", "600", "--config.init.max-static", "3000"])
    assert code == 0
    assert (out / "model.pt").is_file() and (out / "history.json").is_file()
    assert not (out / TB_DIR).exists()


def test_evaluation_adds_its_metrics_and_test_frames(tiny_trained_run, tmp_path):
    from radar4dgs.evaluate.reconstruction import TB_IMAGES, evaluate_run

    run = tmp_path / "run"
    shutil.copytree(tiny_trained_run / "run", run)
    # Other tests may have evaluated the shared run already: only this evaluation's events count.
    before, _ = events(run / TB_DIR)
    metrics = evaluate_run(run, lpips=False, video=False, report=False, progress=False)
    assert metrics["lpips_convention"]["lpips_vgg"]["normalize"] is False
    assert metrics["lpips_convention"]["lpips_alex"]["normalize"] is True
    on_disk = json.loads((run / "metrics.json").read_text())
    assert on_disk["lpips_convention"] == metrics["lpips_convention"]
    scalars, images = events(run / TB_DIR)
    assert "train/loss" in scalars  # training's events are still there
    step = json.loads((run / "config.json").read_text())["config"]["optim"]["iterations"]
    for tag, value in (("val/psnr", metrics["nvs"]["psnr"]), ("recon/ssim", metrics["recon"]["ssim"])):
        assert scalars[tag][:-1] == before.get(tag, [])
        assert scalars[tag][-1] == (step, pytest.approx(value, rel=1e-6))
    assert "val/lpips_vgg" not in scalars  # null without backbone weights: not logged
    assert scalars["val/num_GS"][0][1] == metrics["num_gaussians"]
    assert 0 < len(images) <= TB_IMAGES and all(tag.startswith("val/gt_render/") for tag in images)


def test_a_logging_failure_does_not_stop_anything(tmp_path, monkeypatch):
    from torch.utils.tensorboard import SummaryWriter

    lines = []
    tb = TensorBoard(tmp_path / "tb", log=lines.append)
    assert tb.enabled

    def broken(*args, **kwargs):
        raise OSError("disk full")

    monkeypatch.setattr(SummaryWriter, "add_scalar", broken)
    tb.scalars({"train/loss": 1.0}, 0)
    assert not tb.enabled and len(lines) == 1 and "disk full" in lines[0]
    tb.scalars({"train/loss": 1.0}, 1)  # off now: nothing raised, nothing reported again
    tb.images({"val/x": np.zeros((4, 4, 3), np.uint8)}, 1)
    tb.close()
    assert len(lines) == 1
    assert not TensorBoard(tmp_path / "off", enabled=False).enabled and not (tmp_path / "off").exists()


def test_training_goes_on_when_tensorboard_cannot_start(tiny_trained_run, tmp_path, monkeypatch, capsys):
    import torch.utils.tensorboard

    def refuse(*args, **kwargs):
        raise RuntimeError("no tensorboard here")

    monkeypatch.setattr(torch.utils.tensorboard, "SummaryWriter", refuse)
    scene, out = tiny_trained_run / "scene", tmp_path / "run"
    state = train_run(scene, scene / "prepared", out, small_config(optim={"iterations": 2}), progress=False)
    assert state.step == 2 and (out / "model.pt").is_file()
    printed = capsys.readouterr().out
    assert "TensorBoard logging off" in printed and "no tensorboard here" in printed


def test_train_scalars_and_memory():
    record = {"step": 3, "stage": 1, "total": 0.5, "psnr": 20.0, "num_gaussians": 7, "l1": 0.1, "flow": 0.2}
    values = train_scalars(record, LOSS_TERMS, 1.5)
    assert values == {"train/loss": 0.5, "train/psnr": 20.0, "train/num_GS": 7, "train/stage": 1,
                      "train/mem": 1.5, "train/l1": 0.1, "train/flow": 0.2}
    import torch

    assert peak_memory_gib(torch.device("cpu")) > 0
