"""`radar4dgs bench`: the table from hand-computed metrics, refusals, resuming a grid, one real cell."""

from __future__ import annotations

import csv
import io
import json
from pathlib import Path

import pytest

from radar4dgs.cli import main
from radar4dgs.apps import bench
from radar4dgs.apps.bench import (BenchCommand, BenchError, BenchScene, check_scene, csv_table, dotted,
                                      markdown_table, parse_overrides,
                                      plot_ablation, run_bench, scene_labels, scene_rows, summarize)

KEYS = ("psnr", "ssim", "lpips_vgg", "psnr_dyn")


def fake_metrics(recon: tuple, nvs: tuple) -> dict:
    """A metrics.json summary from (psnr, ssim, lpips_vgg, psnr_dyn) per split."""
    def split(values):
        return {**dict(zip(KEYS, values)), "lpips_alex": None, "n_frames": 6, "n_frames_dyn": 5}

    return {"recon": split(recon), "nvs": split(nvs), "method": "x", "num_gaussians": 10, "mask_source": "gt"}


def ok(scene: str, method: str, recon: tuple, nvs: tuple) -> dict:
    return {"scene": scene, "method": method, "status": "ok", "action": "trained", "seconds": 1.0,
            "metrics": fake_metrics(recon, nvs)}


# ours on a and b (b has no dynamic pixel among its test views), static on a only (b failed),
# pvg never finished; LPIPS exists for the training views only.
CELLS = [
    ok("a", "ours", (30.0, 0.90, 0.20, 25.0), (26.0, 0.80, None, 20.0)),
    ok("a", "static", (33.0, 0.95, 0.12, 21.0), (25.5, 0.83, None, 17.5)),
    ok("b", "ours", (32.0, 0.94, 0.10, 27.0), (24.0, 0.84, None, None)),
    {"scene": "b", "method": "static", "status": "failed", "seconds": 2.0, "error": "RuntimeError: boom"},
]
METHODS = ["ours", "static", "pvg"]


def test_summarize_averages_the_finished_scenes_per_method():
    rows = summarize(CELLS, METHODS)
    assert [(r["method"], r["n"], r["scenes"]) for r in rows] == [
        ("ours", 2, ["a", "b"]), ("static", 1, ["a"]), ("pvg", 0, [])]
    ours, static, pvg = rows
    assert ours["recon_psnr"] == pytest.approx(31.0)
    assert ours["recon_ssim"] == pytest.approx(0.92)
    assert ours["recon_lpips"] == pytest.approx(0.15)
    assert ours["recon_psnr_dyn"] == pytest.approx(26.0)
    assert ours["nvs_psnr"] == pytest.approx(25.0)
    assert ours["nvs_ssim"] == pytest.approx(0.82)
    assert ours["nvs_lpips"] is None
    assert ours["nvs_psnr_dyn"] == pytest.approx(20.0)  # scene b has none: the mean of a alone
    assert static["recon_psnr"] == 33.0 and static["nvs_psnr_dyn"] == 17.5
    assert all(pvg[name] is None for name in bench.COLUMN_NAMES)


def test_markdown_table_bolds_the_best_of_each_column():
    rows = summarize(CELLS, METHODS)
    text = markdown_table(rows, {m: f"{m} description" for m in METHODS}, "small", 1800)
    lines = text.splitlines()
    assert lines[0] == ("| Method | Recon. PSNR ↑ | Recon. SSIM ↑ | Recon. LPIPS ↓ | Recon. PSNR* ↑ | NVS PSNR ↑ "
                        "| NVS SSIM ↑ | NVS LPIPS ↓ | NVS PSNR* ↑ | n |")
    assert lines[2] == "| ours | 31.00 | 0.920 | 0.150 | **26.00** | 25.00 | 0.820 | – | **20.00** | 2 |"
    assert lines[3] == "| static | **33.00** | **0.950** | **0.120** | 21.00 | **25.50** | **0.830** | – | 17.50 | 1 |"
    assert lines[4] == "| pvg | – | – | – | – | – | – | – | – | 0 |"
    assert "preset `small`, 1800 training iterations" in text
    assert "- **static**: static description" in lines


def test_values_equal_as_printed_are_bolded_alike():
    rows = [{"method": "a", "n": 1, "nvs_psnr": 25.001}, {"method": "b", "n": 1, "nvs_psnr": 24.999},
            {"method": "c", "n": 1, "nvs_psnr": 24.9}]
    lines = markdown_table(rows).splitlines()
    assert "| **25.00** |" in lines[2] and "| **25.00** |" in lines[3] and "| 24.90 |" in lines[4]


def test_csv_has_the_mean_rows_then_one_row_per_finished_cell():
    rows = summarize(CELLS, METHODS)
    table = list(csv.DictReader(io.StringIO(csv_table(rows, scene_rows(CELLS, METHODS)))))
    assert [(r["scene"], r["method"], r["n"]) for r in table] == [
        ("mean", "ours", "2"), ("mean", "static", "1"), ("mean", "pvg", "0"),
        ("a", "ours", "1"), ("b", "ours", "1"), ("a", "static", "1")]
    assert float(table[0]["recon_psnr"]) == pytest.approx(31.0)
    assert table[0]["nvs_lpips"] == "" and table[2]["recon_psnr"] == ""
    assert float(table[4]["recon_ssim"]) == 0.94 and table[4]["nvs_psnr_dyn"] == ""
    assert float(table[5]["nvs_psnr_dyn"]) == 17.5


def test_plot_is_written(tmp_path):
    rows = summarize(CELLS, METHODS)
    path = plot_ablation(rows, scene_rows(CELLS, METHODS), tmp_path / "ablation.png")
    assert path.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    assert [p.name for p in tmp_path.iterdir()] == ["ablation.png"]  # no temporary file left


def test_scene_labels_are_names_unless_they_clash(tmp_path):
    paths = [tmp_path / "x" / "seed1" / "scene", tmp_path / "x" / "seed2" / "scene", tmp_path / "y" / "drive"]
    assert scene_labels(paths) == ["seed1-scene", "seed2-scene", "drive"]
    assert scene_labels([tmp_path / "a" / "seed3"], reserved=["seed3"]) == ["a-seed3"]
    with pytest.raises(BenchError, match="more than once"):
        scene_labels([tmp_path / "s", tmp_path / "t" / ".." / "s"])


def test_unknown_method_is_refused_listing_the_methods(tmp_path, capsys):
    with pytest.raises(SystemExit):
        main(["bench", "--synth-seeds", "1", "--methods", "ours", "nope", "--out", str(tmp_path)])
    assert "nope" in capsys.readouterr().err
    assert BenchCommand(synth_seeds=(1,), methods=("ours", "nope"), out=tmp_path).run() == 2
    err = capsys.readouterr().err
    assert "unknown method(s) ['nope']" in err and "'ours-gt-masks'" in err
    assert list(tmp_path.iterdir()) == []  # refused before synthesizing anything


def make_scene(root: Path, prepared: bool = True) -> Path:
    """A folder that passes the bench's checks (the fake runners never read it)."""
    root.mkdir(parents=True)
    (root / "scene.json").write_text("{}")
    if prepared:
        (root / "prepared" / "depth").mkdir(parents=True)
    return root


def test_a_scene_without_prepared_folder_is_refused_by_name(tmp_path, capsys):
    good, bad = make_scene(tmp_path / "good"), make_scene(tmp_path / "bad", prepared=False)
    assert BenchCommand(scenes=(good, bad), methods=("static",), out=tmp_path / "out").run() == 2
    err = capsys.readouterr().err
    assert f"{bad}: has no prepared folder ({bad / 'prepared'} or {tmp_path / 'prepared'})" in err
    assert f"radar4dgs prepare {bad}" in err
    assert not (tmp_path / "out").exists()


def test_the_demo_layout_prepared_beside_the_scene_is_found(tmp_path):
    scene = make_scene(tmp_path / "demo" / "scene", prepared=False)
    (tmp_path / "demo" / "prepared" / "depth").mkdir(parents=True)
    assert check_scene(scene) == tmp_path / "demo" / "prepared"


def test_set_overrides_parse_to_nested_fields():
    assert parse_overrides(["densify.max_gaussians=40000", "optim.dropout=0.2", "mask_source=gt",
                            "init.source=\"lidar\""]) == {
        "densify": {"max_gaussians": 40000}, "optim": {"dropout": 0.2}, "mask_source": "gt",
        "init": {"source": "lidar"}}
    assert dotted({"densify": {"max_gaussians": 40000}, "seed": 1}) == [("densify.max_gaussians", 40000), ("seed", 1)]
    with pytest.raises(BenchError, match="KEY=VALUE"):
        parse_overrides(["densify.max_gaussians"])


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
    (runs / "a" / "ours" / "metrics.json").write_text(json.dumps(fake_metrics((31, 0.9, None, 26), (26, 0.8, None, 21))))
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
    assert fake_training.calls == []


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
