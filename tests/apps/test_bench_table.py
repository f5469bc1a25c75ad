"""The bench's table from hand-computed metrics: means, bold best values, csv rows, the plot."""

from __future__ import annotations

import csv
import io

import pytest
from _bench_helpers import fake_metrics

from radar4dgs.apps.bench_table import COLUMN_NAMES, csv_table, markdown_table, plot_ablation, scene_rows, summarize


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
    assert all(pvg[name] is None for name in COLUMN_NAMES)


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
