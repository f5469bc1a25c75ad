"""`radar4dgs eval RUN` on a tiny trained run: metrics against recomputation, outputs, determinism."""

from __future__ import annotations

import json
import shutil

import numpy as np
import pytest
import torch
from PIL import Image

from radar4dgs.cli import main
from radar4dgs.evaluate.alignment import exposure_aligned
from radar4dgs.evaluate.observability import seen_summary, unseen_close_share
from radar4dgs.evaluate.reconstruction import evaluate_run, format_metrics, load_run

pytestmark = pytest.mark.usefixtures("one_torch_thread")


@pytest.fixture(scope="module")
def trained(tiny_trained_run):
    return tiny_trained_run


def _psnr(a: np.ndarray, b: np.ndarray, mask: np.ndarray | None = None) -> float:
    diff = (a.astype(np.float64) - b.astype(np.float64)) / 255.0
    if mask is not None:
        diff = diff[mask]
    return float(10 * np.log10(1.0 / np.mean(diff ** 2)))


def test_metrics_match_a_recomputation_from_the_saved_renders(trained):
    run_dir = trained / "run"
    metrics = evaluate_run(run_dir, progress=False)
    on_disk = json.loads((run_dir / "metrics.json").read_text())
    assert on_disk["recon"] == pytest.approx(metrics["recon"])
    run = load_run(run_dir)
    scene = run.scene
    assert metrics["recon"]["n_frames"] == len(scene.train_indices) == 6
    assert metrics["nvs"]["n_frames"] == len(scene.test_indices) == 2
    assert metrics["mask_source"] == "gt"
    assert metrics["lpips_available"] is False and metrics["nvs"]["lpips_vgg"] is None
    for split, indices in (("recon", scene.train_indices), ("nvs", scene.test_indices)):
        recomputed, dyn = [], []
        for i in indices:
            name = scene.frames[i].name
            with Image.open(run_dir / "renders" / split / f"{name}.png") as image:
                render = np.asarray(image.convert("RGB"))
            gt = scene.load_image(i)
            recomputed.append(_psnr(render, gt))
            mask = scene.load_optional("gt/dynamic_mask", i)
            if mask.any():
                dyn.append(_psnr(render, gt, mask))
            assert (run_dir / "renders" / split / f"{name}_depth.png").is_file()
            assert (run_dir / "renders" / split / f"{name}_dynamic.png").is_file()
        # The PNGs are rounded to 8 bits: PSNR agrees to a few hundredths of a dB.
        assert metrics[split]["psnr"] == pytest.approx(np.mean(recomputed), abs=0.05)
        if dyn:
            assert metrics[split]["psnr_dyn"] == pytest.approx(np.mean(dyn), abs=0.1)
        assert 0.0 < metrics[split]["ssim"] <= 1.0
    exposure = []
    for i in scene.test_indices:
        with Image.open(run_dir / "renders" / "nvs" / f"{scene.frames[i].name}.png") as image:
            render = torch.as_tensor(np.asarray(image.convert("RGB")) / 255.0)
        gt = scene.load_image(i)
        exposure.append(_psnr(np.round(exposure_aligned(render, torch.as_tensor(gt / 255.0)).numpy() * 255), gt))
    assert metrics["nvs_exposure_aligned"]["n_frames"] == 2
    assert metrics["nvs_exposure_aligned"]["psnr"] == pytest.approx(np.mean(exposure), abs=0.1)
    # Test frames of a synthetic scene say how close the training frames around them saw their movers.
    for entry in metrics["per_frame"]["nvs"]:
        assert entry["unseen_close_share"] == unseen_close_share(scene, entry["index"], scene.train_indices)
    assert not any("unseen_close_share" in entry for entry in metrics["per_frame"]["recon"])
    assert metrics["nvs_seen"] == seen_summary(metrics["per_frame"]["nvs"])
    assert metrics["nvs_seen"]["n_frames"] + len(metrics["nvs_seen"]["unseen_frames"]) == 2
    assert (run_dir / "video.mp4").stat().st_size > 1000
    html = (run_dir / "report.html").read_text()
    assert "data:image/png;base64," in html
    assert "novel views, exposure aligned" in html
    assert f"<td>{metrics['nvs_exposure_aligned']['psnr']:.2f}</td>" in html
    table = format_metrics(metrics)
    assert "PSNR*" in table and f"{metrics['nvs']['psnr']:.2f}" in table
    assert f"exposure aligned (a colour transform fitted per test frame, cross-fitted halves): PSNR " \
           f"{metrics['nvs_exposure_aligned']['psnr']:.2f}" in table


def test_evaluation_is_deterministic_and_cli_reloads_the_saved_config(trained, capsys):
    run_dir = trained / "run"
    first = evaluate_run(run_dir, video=False, report=False, progress=False)
    assert main(["eval", str(run_dir), "--no-video", "--no-report"]) == 0
    assert "recon" in capsys.readouterr().out
    second = json.loads((run_dir / "metrics.json").read_text())
    for split in ("recon", "nvs"):
        assert second[split]["psnr"] == first[split]["psnr"]
        assert second[split]["psnr_dyn"] == first[split]["psnr_dyn"]


def test_predicted_masks_are_used_without_ground_truth(trained, tmp_path):
    # A copy of the scene without gt/: PSNR* falls back to the prepared masks, and says so.
    scene = tmp_path / "scene"
    shutil.copytree(trained / "scene", scene, ignore=shutil.ignore_patterns("gt"))
    run_dir = tmp_path / "run"
    shutil.copytree(trained / "run", run_dir)
    run_file = json.loads((run_dir / "run.json").read_text())
    run_file["scene"] = str(scene)
    (run_dir / "run.json").write_text(json.dumps(run_file))
    metrics = evaluate_run(run_dir, video=False, report=False, progress=False)
    assert metrics["mask_source"] == "predicted"
    assert any("predicted dynamic masks" in c for c in metrics["psnr_dyn_caveats"])


def test_psnr_star_on_near_empty_masks_is_flagged(trained, tmp_path, capsys):
    # Predicted masks with one pixel per frame (0.01 % of the image): PSNR* is computed, and flagged
    # in metrics.json, in the printed table and in the report, which also says what made the run.
    from radar4dgs.evaluate.reconstruction import write_provenance
    from radar4dgs.io.scene import read_scene

    scene = tmp_path / "scene"
    shutil.copytree(trained / "scene", scene, ignore=shutil.ignore_patterns("gt", "prepared"))
    prepared = tmp_path / "prepared"
    shutil.copytree(trained / "scene" / "prepared", prepared)
    width, height = read_scene(scene).camera.width, read_scene(scene).camera.height
    for mask in (prepared / "masks").glob("*.png"):
        pixels = np.zeros((height, width), np.uint8)
        pixels[height // 2, width // 2] = 255
        Image.fromarray(pixels).save(mask)
    run_dir = tmp_path / "run"
    shutil.copytree(trained / "run", run_dir)
    (run_dir / "run.json").write_text(json.dumps({"scene": str(scene), "prepared": str(prepared)}))
    write_provenance(run_dir, preset="tiny", method="ours", command="radar4dgs train (test)")
    assert main(["eval", str(run_dir), "--no-video"]) == 0
    printed = capsys.readouterr().out
    metrics = json.loads((run_dir / "metrics.json").read_text())
    assert metrics["mask_source"] == "predicted"
    assert metrics["mask_coverage"]["nvs"] == pytest.approx(1 / (width * height))
    assert metrics["nvs"]["psnr_dyn"] is not None
    flagged = [c for c in metrics["psnr_dyn_caveats"] if "not meaningful" in c]
    share = f"{1 / (width * height):.2%} of the pixels"
    assert len(flagged) == 2 and share in flagged[0]
    assert f"caveat: PSNR* (recon) is computed on {share}" in printed
    assert metrics["run"]["preset"] == "tiny" and len(metrics["run"]["config_hash"]) == 12
    assert metrics["run"]["train_seconds"] > 0 and metrics["run"]["iterations"] == 20
    report = (run_dir / "report.html").read_text()
    assert "<td>preset</td><td>tiny</td>" in report and metrics["run"]["config_hash"] in report
    assert "<td>training time</td>" in report and '<a href="config.json">' in report
    assert "not meaningful" in report and f"predicted (recon {share}" in report
    assert "<video" not in report  # --no-video: no video to link


def test_psnr_star_is_flagged_when_the_trained_masks_miss_the_moving_pixels(trained, tmp_path, capsys):
    # The run trained on predicted masks (the tiny preset's mask_source); here they are empty, so
    # they find none of the ground-truth dynamic pixels: PSNR* (on the gt masks) is flagged in
    # metrics.json, in the printed table and in the report.
    from radar4dgs.io.scene import read_scene

    scene = read_scene(trained / "scene")
    prepared = tmp_path / "prepared"
    shutil.copytree(trained / "scene" / "prepared", prepared)
    for mask in (prepared / "masks").glob("*.png"):
        Image.fromarray(np.zeros((scene.camera.height, scene.camera.width), np.uint8)).save(mask)
    run_dir = tmp_path / "run"
    shutil.copytree(trained / "run", run_dir, ignore=shutil.ignore_patterns("renders", "*.mp4", "report.html"))
    (run_dir / "run.json").write_text(json.dumps({"scene": str(trained / "scene"), "prepared": str(prepared)}))
    assert main(["eval", str(run_dir), "--no-video", "--no-lpips"]) == 0
    printed = capsys.readouterr().out
    metrics = json.loads((run_dir / "metrics.json").read_text())
    assert metrics["mask_source"] == "gt" and metrics["run"]["iterations"] == 20
    assert metrics["predicted_mask_recall"] == {"recon": 0.0, "nvs": 0.0}
    assert metrics["psnr_dyn_flagged"] == {"recon": True, "nvs": True}
    flagged = [c for c in metrics["psnr_dyn_caveats"] if "find only 0.0% of the ground-truth dynamic pixels" in c]
    assert [c.split(":")[0] for c in flagged] == ["PSNR* (recon)", "PSNR* (nvs)"]
    assert "caveat: PSNR* (nvs): the predicted dynamic masks the run trained on" in printed
    report = (run_dir / "report.html").read_text()
    assert "find only 0.0% of the ground-truth dynamic pixels" in report
    assert "<td>predicted masks&#x27; recall of the gt dynamic pixels</td><td>recon 0.0%, nvs 0.0%</td>" in report
    assert report.count("(flagged: see the caveats)") == 2

    # With the masks it was trained on (which find the moving cars), nothing is flagged.
    (run_dir / "run.json").write_text(json.dumps({"scene": str(trained / "scene"),
                                                  "prepared": str(trained / "scene" / "prepared")}))
    metrics = evaluate_run(run_dir, lpips=False, video=False, report=False, progress=False)
    assert all(value > 0.5 for value in metrics["predicted_mask_recall"].values())
    assert metrics["psnr_dyn_flagged"] == {"recon": False, "nvs": False}
    assert not any("find only" in c for c in metrics["psnr_dyn_caveats"])


def test_missing_model_is_named(tmp_path):
    (tmp_path / "run").mkdir()
    with pytest.raises(FileNotFoundError, match="run.json"):
        evaluate_run(tmp_path / "run", progress=False)


def test_report_plots_only_loss_terms():
    from radar4dgs.evaluate.reconstruction import loss_curves

    history = [{"step": 0, "stage": 1, "frame": "000001", "width": 160, "total": 1.0, "l1": 0.5, "psnr": 20.0,
                "num_gaussians": 5000},
               {"step": 9, "densify": "static", "cloned": 3, "num_gaussians": 5003}]
    assert loss_curves(history) == [{"step": 0, "psnr": 20.0, "total": 1.0, "l1": 0.5}]
