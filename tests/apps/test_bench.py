"""`radar4dgs bench`: refusals, resuming a grid, parallel jobs, one real cell."""

from __future__ import annotations

import csv
import io
import json

import pytest
from _bench_helpers import fake_metrics, make_scene

from radar4dgs.apps.bench import BenchCommand, run_bench
from radar4dgs.apps.bench_spec import BenchScene
from radar4dgs.cli import main


def test_unknown_method_is_refused_listing_the_methods(tmp_path, capsys):
    assert main(["bench", "--synth-seeds", "1", "--methods", "ours", "nope", "--out", str(tmp_path)]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "invalid choice 'nope' for argument '--methods'" in err
    assert BenchCommand(synth_seeds=(1,), methods=("ours", "nope"), out=tmp_path).run() == 2
    err = capsys.readouterr().err
    assert "unknown method(s) ['nope']" in err and "'ours-gt-masks'" in err
    assert list(tmp_path.iterdir()) == []  # refused before synthesizing anything


def test_a_scene_without_prepared_folder_is_refused_by_name(tmp_path, capsys):
    good, bad = make_scene(tmp_path / "good"), make_scene(tmp_path / "bad", prepared=False)
    assert BenchCommand(scenes=(good, bad), methods=("static",), out=tmp_path / "out").run() == 2
    err = capsys.readouterr().err
    assert f"{bad}: has no prepared folder ({bad / 'prepared'} or {tmp_path / 'prepared'})" in err
    assert f"radar4dgs prepare {bad}" in err
    assert not (tmp_path / "out").exists()


class FakeTraining:
    """Stands in for train_run and evaluate_run: records the calls, writes the files a real run
    would (model.pt, metrics.json), and fails training of the cells named in ``fail``."""

    def __init__(self):
        self.calls: list[tuple] = []
        self.fail: set[str] = set()

    def train_run(self, scene, prepared, out, config, resume=False, progress=True):
        self.calls.append(("train", out.parent.name, out.name, resume, config.optim.iterations, config.threads))
        if f"{out.parent.name}/{out.name}" in self.fail:
            raise RuntimeError("loss is nan")
        out.mkdir(parents=True, exist_ok=True)
        (out / "model.pt").write_bytes(b"model")

    def evaluate_run(self, run_dir, device=None, lpips=True, video=True, report=True, progress=True):
        assert (video, report) == (False, False)
        self.calls.append(("eval", run_dir.parent.name, run_dir.name))
        value = {"ours": 22.0, "static": 18.0}[run_dir.name] + (1.0 if run_dir.parent.name == "b" else 0.0)
        metrics = fake_metrics((30.0, 0.9, None, value + 5), (25.0, 0.8, None, value))
        (run_dir / "metrics.json").write_text(json.dumps(metrics))
        return metrics


@pytest.fixture
def fake_training(monkeypatch):
    import radar4dgs.evaluate.reconstruction as reconstruction
    import radar4dgs.train.trainer as trainer

    fake = FakeTraining()
    monkeypatch.setattr(trainer, "train_run", fake.train_run)
    monkeypatch.setattr(reconstruction, "evaluate_run", fake.evaluate_run)
    return fake


def test_the_grid_resumes_each_cell_from_what_its_folder_holds(tmp_path, fake_training, capsys):
    from radar4dgs.config import save_config
    from radar4dgs.train.variants import variant_config

    scenes = (make_scene(tmp_path / "a"), make_scene(tmp_path / "b"))
    out = tmp_path / "out"
    runs = out / "runs"
    # a/ours finished before; a/static was trained, not evaluated; b/ours was killed after a
    # checkpoint (with 4 threads then: it resumes with this bench's 1, a runtime field).
    (runs / "a" / "ours").mkdir(parents=True)
    (runs / "a" / "ours" / "metrics.json").write_text(
        json.dumps(fake_metrics((31, 0.9, None, 26), (26, 0.8, None, 21))))
    (runs / "a" / "static").mkdir(parents=True)
    (runs / "a" / "static" / "model.pt").write_bytes(b"model")
    (runs / "b" / "ours" / "checkpoints").mkdir(parents=True)
    (runs / "b" / "ours" / "checkpoints" / "last.pt").write_bytes(b"checkpoint")
    save_config(variant_config("tiny", "ours", threads=4, optim={"iterations": 7}), runs / "b" / "ours" / "config.json")
    fake_training.fail = {"b/static"}
    command = BenchCommand(scenes=scenes, methods=("ours", "static"), out=out, preset="tiny", iterations=7,
                           threads=1, lpips=False, quiet=True)

    assert command.run() == 1
    assert fake_training.calls == [
        ("eval", "a", "static"),
        ("train", "b", "ours", True, 7, 1), ("eval", "b", "ours"),
        ("train", "b", "static", False, 7, 1)]
    captured = capsys.readouterr()
    assert "[1/4] a/ours: skipped" in captured.out and "novel-view PSNR* 21.00 dB" in captured.out
    assert "[4/4] b/static: FAILED after" in captured.out and "RuntimeError: loss is nan" in captured.out
    assert "1 cell(s) failed: b/static" in captured.err
    result = json.loads((out / "bench.json").read_text())
    assert [(c["scene"], c["method"], c["status"], c.get("action")) for c in result["cells"]] == [
        ("a", "ours", "ok", "skipped"), ("a", "static", "ok", "evaluated"),
        ("b", "ours", "ok", "resumed"), ("b", "static", "failed", None)]
    assert result["cells"][3]["error"] == "RuntimeError: loss is nan"
    assert result["failed"] == 1 and result["config"]["iterations"] == 7
    means = {row["method"]: row for row in result["means"]}
    assert means["ours"]["n"] == 2 and means["ours"]["nvs_psnr_dyn"] == pytest.approx((21.0 + 23.0) / 2)
    assert means["static"]["n"] == 1 and means["static"]["nvs_psnr_dyn"] == 18.0
    table = (out / "table.md").read_text()
    assert "| ours | **30.50** | **0.900** | – | **27.00** | **25.50** | **0.800** | – | **22.00** | 2 |" in table
    assert (out / "ablation.png").is_file() and (out / "table.csv").is_file()

    # The rerun trains only the failed cell; the others keep their metrics and their seconds.
    fake_training.calls.clear()
    fake_training.fail = set()
    assert command.run() == 0
    assert fake_training.calls == [("train", "b", "static", False, 7, 1), ("eval", "b", "static")]
    rerun = json.loads((out / "bench.json").read_text())
    assert [c["action"] for c in rerun["cells"]] == ["skipped", "skipped", "skipped", "trained"]
    assert [c["seconds"] for c in rerun["cells"][:3]] == [c["seconds"] for c in result["cells"][:3]]
    assert {row["method"]: row["n"] for row in rerun["means"]} == {"ours": 2, "static": 2}


def test_a_cell_trained_with_other_settings_is_not_reused(tmp_path, fake_training):
    from radar4dgs.config import save_config
    from radar4dgs.train.variants import variant_config

    run = tmp_path / "out" / "runs" / "a" / "static"
    run.mkdir(parents=True)
    (run / "metrics.json").write_text(json.dumps(fake_metrics((31, 0.9, None, 26), (26, 0.8, None, 21))))
    save_config(variant_config("tiny", "static", threads=1, optim={"iterations": 5}), run / "config.json")
    result = run_bench([BenchScene("a", make_scene(tmp_path / "a"), tmp_path / "a" / "prepared")], ["static"],
                       tmp_path / "out", "tiny", iterations=20, threads=2, progress=False, log=lambda line: None)
    (cell,) = result["cells"]
    assert cell["status"] == "failed" and "optim.iterations: 5 != 20" in cell["error"]
    assert "pass --force to retrain it" in cell["error"]
    assert fake_training.calls == []
    # --force: the cell is deleted and trained again with the bench's config.
    (run / "run.json").write_text("{}")
    result = run_bench([BenchScene("a", tmp_path / "a", tmp_path / "a" / "prepared")], ["static"],
                       tmp_path / "out", "tiny", iterations=20, threads=2, progress=False, log=lambda line: None,
                       force=True)
    (cell,) = result["cells"]
    assert cell["status"] == "ok" and cell["action"] == "trained"
    assert fake_training.calls == [("train", "a", "static", False, 20, 2), ("eval", "a", "static")]
    assert not (run / "config.json").exists()  # the old run is gone (the fake trainer writes none)


def test_a_synthetic_scene_of_another_preset_is_refused_then_made_again_with_force(tmp_path, fake_training,
                                                                                 monkeypatch):
    import radar4dgs.apps.prepare as prepare
    import radar4dgs.datasets.synth as synth
    from radar4dgs.apps.bench_spec import BenchError, resolve_scenes

    made = []

    def fake_synthesize(config, out, overwrite=False, progress=True, preset=None):
        made.append((config.seed, preset))
        out.mkdir(parents=True, exist_ok=True)
        from radar4dgs.datasets.synth.generate import config_record

        (out / "scene.json").write_text(json.dumps({"source": {"dataset": "synthetic", "seed": config.seed,
                                                               "preset": preset},
                                                    "synthetic": {"config": config_record(config)}}))
        return out

    monkeypatch.setattr(synth, "synthesize", fake_synthesize)
    monkeypatch.setattr(prepare, "run_prepare", lambda *args, **kwargs: {})
    out = tmp_path / "out"
    resolve_scenes((), (1,), "tiny", out, log=lambda line: None)
    assert made == [(1, "tiny")]
    resolve_scenes((), (1,), "tiny", out, log=lambda line: None)  # the same preset: reused
    assert made == [(1, "tiny")]
    (out / "runs" / "seed1" / "ours").mkdir(parents=True)
    with pytest.raises(BenchError, match=r"was made with preset 'tiny', seed 1, not preset 'small', seed 1; "
                                         r"pass --force"):
        resolve_scenes((), (1,), "small", out, log=lambda line: None)
    resolve_scenes((), (1,), "small", out, log=lambda line: None, force=True)
    assert made == [(1, "tiny"), (1, "small")]
    assert not (out / "runs" / "seed1").exists()  # its cells were trained on the old scene


def pool_runner(spec):
    """A picklable stand-in for run_cell (the worker processes import it from this module)."""
    if spec.method == "static":
        raise ValueError(f"no {spec.scene}")
    return {"action": "trained", "metrics": fake_metrics((30.0, 0.9, 0.1, 25.0), (len(spec.scene), 0.8, 0.2, 20.0))}


def test_parallel_jobs_record_results_and_failures_in_grid_order(tmp_path):
    scenes = [BenchScene(label, tmp_path / label, tmp_path / label / "prepared") for label in ("a", "bb")]
    lines = []
    result = run_bench(scenes, ["ours", "static"], tmp_path / "out", "tiny", jobs=2, runner=pool_runner,
                       log=lines.append)
    assert result["config"]["threads_per_job"] >= 1
    assert [(c["scene"], c["method"], c["status"]) for c in result["cells"]] == [
        ("a", "ours", "ok"), ("a", "static", "failed"), ("bb", "ours", "ok"), ("bb", "static", "failed")]
    assert result["cells"][3]["error"] == "ValueError: no bb"
    assert result["means"][0]["nvs_psnr"] == pytest.approx(1.5) and result["means"][1]["n"] == 0
    assert sum("FAILED" in line for line in lines) == 2


def test_one_real_cell_end_to_end(tiny_trained_run, tmp_path, capsys):
    scene, out = tiny_trained_run / "scene", tmp_path / "bench"
    args = ["bench", "--scenes", str(scene), "--methods", "static", "--out", str(out), "--preset", "tiny",
            "--iterations", "20", "--jobs", "1", "--threads", "1", "--no-lpips", "--quiet"]
    assert main(args) == 0
    assert "[1/1] scene/static: trained in" in capsys.readouterr().out
    metrics = json.loads((out / "runs" / "scene" / "static" / "metrics.json").read_text())
    assert metrics["method"] == "static" and metrics["nvs"]["lpips_vgg"] is None
    nvs_psnr_dyn, recon_psnr = metrics["nvs"]["psnr_dyn"], metrics["recon"]["psnr"]
    assert 5.0 < recon_psnr < 60.0 and nvs_psnr_dyn is not None
    (mean,) = [r for r in csv.DictReader(io.StringIO((out / "table.csv").read_text())) if r["scene"] == "mean"]
    assert float(mean["nvs_psnr_dyn"]) == nvs_psnr_dyn and float(mean["recon_psnr"]) == recon_psnr
    row = next(line for line in (out / "table.md").read_text().splitlines() if line.startswith("| static |"))
    assert f"**{nvs_psnr_dyn:.2f}** | 1 |" in row and f"**{recon_psnr:.2f}**" in row
    assert (out / "ablation.png").read_bytes()[:4] == b"\x89PNG"
    cell = json.loads((out / "bench.json").read_text())["cells"][0]
    assert cell["metrics"]["nvs"]["psnr_dyn"] == nvs_psnr_dyn and cell["action"] == "trained"
    # Rerun: the finished cell is reused as it is.
    stamp = (out / "runs" / "scene" / "static" / "metrics.json").stat().st_mtime_ns
    assert main(args) == 0
    assert "[1/1] scene/static: skipped" in capsys.readouterr().out
    assert (out / "runs" / "scene" / "static" / "metrics.json").stat().st_mtime_ns == stamp


def test_a_threads_setting_is_the_cells_thread_count(tmp_path, fake_training, monkeypatch):
    # The default (CPUs / jobs) used to override `--set threads=N`: parallel benchmarks oversubscribed.
    import radar4dgs.apps.bench as bench

    monkeypatch.setattr(bench, "default_threads", lambda jobs: 7)
    scene = make_scene(tmp_path / "a")
    result = run_bench([BenchScene("a", scene, scene / "prepared")], ["static"], tmp_path / "out", "tiny",
                       iterations=5, progress=False, log=lambda line: None, settings={"threads": 1})
    assert [call[5] for call in fake_training.calls if call[0] == "train"] == [1]
    assert result["config"]["threads_per_job"] == 1
    run_bench([BenchScene("a", scene, scene / "prepared")], ["static"], tmp_path / "out2", "tiny",
              iterations=5, progress=False, log=lambda line: None)
    assert [call[5] for call in fake_training.calls if call[0] == "train"] == [1, 7]
