"""The self-contained HTML report: content, embedded PNGs, no external references, real rendering."""

from __future__ import annotations

import base64
import html
import io
import re

import numpy as np
import pytest
from _browser import chromium_or_skip, headless
from PIL import Image

from radar4dgs.evaluate.report import write_report

DATA_URI = re.compile(r'src="data:image/png;base64,([A-Za-z0-9+/=]+)"')


def metrics() -> dict:
    return {
        "recon": {"psnr": 31.234567, "ssim": 0.912345, "lpips_vgg": 0.123456, "lpips_alex": None,
                  "psnr_dyn": 27.5, "n_frames": 12},
        "nvs": {"psnr": 26.789, "ssim": 0.845678, "lpips_vgg": 0.2345, "lpips_alex": None,
                "psnr_dyn": float("nan"), "n_frames": 4},
        "mask_source": "gt/dynamic_mask",
        "lpips_available": False,
    }


def inputs(height: int = 24, width: int = 40, n_panels: int = 2) -> dict:
    rng = np.random.default_rng(0)
    per_frame = {
        "recon": [{"frame": f"{i:06d}", "psnr": 30 + rng.normal()} for i in range(16) if (i + 1) % 4],
        "nvs": [{"frame": f"{i:06d}", "psnr": 26 + rng.normal()} for i in range(16) if not (i + 1) % 4],
    }
    history = [{"step": s, "loss_rgb": 1.0 / (s + 1), "loss_depth": 0.1 / (s + 1) ** 0.5,
                "psnr": 10 + s / 10} for s in range(0, 200, 10)]
    panels = []
    for i in range(n_panels):
        panels.append({
            "name": f"frame <{i}> & co",
            "psnr": 28.5,
            "gt": rng.integers(0, 256, (height, width, 3), dtype=np.uint8),
            "render": rng.integers(0, 256, (height, width, 3), dtype=np.uint8),
            "error": np.zeros((height, width, 3), np.uint8),
            "mask": np.full((height, width), 255, np.uint8),
        })
    return {"title": "Scene <s1> & \"test\"", "metrics": metrics(), "per_frame": per_frame,
            "history": history, "panels": panels}


@pytest.fixture(scope="module")
def report(tmp_path_factory):
    path = tmp_path_factory.mktemp("report") / "out" / "report.html"
    args = inputs()
    write_report(path, **args)
    return path, args


def decode_pngs(text: str) -> list[Image.Image]:
    images = []
    for payload in DATA_URI.findall(text):
        data = base64.b64decode(payload, validate=True)
        assert data[:8] == b"\x89PNG\r\n\x1a\n"
        images.append(Image.open(io.BytesIO(data)))
    return images


def test_report_contains_the_metrics(report):
    path, _ = report
    assert path.is_file()
    assert [p.name for p in path.parent.iterdir()] == ["report.html"]  # no temporary left
    text = path.read_text(encoding="utf-8")
    assert text.startswith("<!DOCTYPE html>")
    for value in ("31.23", "0.9123", "0.1235", "27.50", "12", "26.79", "0.8457", "0.2345", "4",
                  "gt/dynamic_mask"):
        assert value in text, value
    assert "n/a" in text  # lpips_alex None and nvs psnr_dyn NaN
    assert "lpips_available: <b>no</b>" in text
    # Text is escaped, never injected.
    assert "<s1>" not in text and html.escape('Scene <s1> & "test"') in text
    assert "frame &lt;0&gt; &amp; co" in text
    assert "000003" in text  # per-frame table keeps frame names as text


def test_images_are_data_uri_pngs_of_the_right_size(report):
    path, args = report
    text = path.read_text(encoding="utf-8")
    images = decode_pngs(text)
    # 2 plots (per-frame PSNR, training curves) + 4 images in each of 2 panels.
    assert len(images) == 2 + 4 * 2
    for image in images[2:]:
        assert image.size == (40, 24)
    assert {image.mode for image in images[2:]} == {"RGB", "L"}
    # The panel images survive bit-exactly.
    first = np.asarray(images[2])
    np.testing.assert_array_equal(first, args["panels"][0]["gt"])
    for plot in images[:2]:
        assert plot.width >= 600 and plot.height >= 200
        assert len(np.unique(np.asarray(plot.convert("RGB")).reshape(-1, 3), axis=0)) > 10


def test_report_is_self_contained(report):
    path, _ = report
    text = path.read_text(encoding="utf-8")
    outside = DATA_URI.sub('src=""', text)  # base64 payloads could contain any 4 letters
    assert "http" not in outside.lower()
    for marker in ("<script", "<link", "@import", "url(", "//"):
        assert marker not in outside.lower(), marker
    # Every image is inside; the only references are to files beside the report (the run folder's).
    assert all(src == "" or "/" not in src and ":" not in src for src in re.findall(r'src="([^"]*)"', outside))
    assert all("/" not in href and ":" not in href for href in re.findall(r'href="([^"]*)"', outside))


def test_report_states_what_made_the_run_and_its_caveats(tmp_path):
    args = inputs(n_panels=1)
    caveat = "PSNR* (nvs) is computed on 0.09% of the pixels (predicted masks, 3 of 4 frames): not meaningful"
    path = write_report(tmp_path / "report.html", **args,
                        run_info={"preset": "small", "config hash": "0123456789ab", "training time": "12.7 min"},
                        caveats=[caveat], links={"resolved config": "config.json"}, video="video.mp4",
                        config={"optim": {"iterations": 1800}})
    text = path.read_text(encoding="utf-8")
    assert "<td>preset</td><td>small</td>" in text and "0123456789ab" in text and "12.7 min" in text
    assert '<a href="config.json">resolved config (config.json)</a>' in text
    assert '<video controls loop muted preload="metadata" src="video.mp4">' in text
    assert html.escape('"iterations": 1800') in text
    assert f'<p class="caveat">{html.escape(caveat)}</p>' in text
    # The run section comes first, the caveat right under the metrics it qualifies.
    assert text.index("<h2>Run</h2>") < text.index("<h2>Metrics</h2>") < text.index("<p class=\"caveat\">") \
        < text.index("<h2>Per-frame PSNR</h2>")
    with pytest.raises(ValueError, match="beside the report"):
        write_report(tmp_path / "bad.html", **args, links={"x": "https://example.org/config.json"})


def test_missing_sections_and_bad_images(tmp_path):
    path = write_report(tmp_path / "empty.html", title="empty", metrics={"recon": {}},
                        per_frame={}, history=[], panels=[])
    text = path.read_text(encoding="utf-8")
    assert "no per-frame metrics" in text and "no training history" in text
    with pytest.raises(ValueError, match=r"panel 'p' image 'render'.*uint8"):
        write_report(tmp_path / "bad.html", title="t", metrics={}, per_frame={}, history=[],
                     panels=[{"name": "p", "render": np.zeros((4, 4, 3), np.float32)}])
    with pytest.raises(ValueError, match=r"panel 'p' image 'gt'.*\(H, W, 3\)"):
        write_report(tmp_path / "bad.html", title="t", metrics={}, per_frame={}, history=[],
                     panels=[{"name": "p", "gt": np.zeros((4, 4, 2), np.uint8)}])
    assert not (tmp_path / "bad.html").exists()


def test_max_image_width_downscales(tmp_path):
    args = inputs(height=30, width=100, n_panels=1)
    path = write_report(tmp_path / "small.html", **args, max_image_width=50)
    sizes = [image.size for image in decode_pngs(path.read_text(encoding="utf-8"))[2:]]
    assert sizes == [(50, 15)] * 4


def test_report_renders_in_headless_chromium(report, tmp_path):
    # Skips without Chromium, except in CI (RADAR4DGS_REQUIRE_BROWSER=1, tests/evaluate/_browser.py);
    # the report of a real run is checked in test_report_browser.py.
    chromium = chromium_or_skip()
    path, _ = report
    shot = tmp_path / "shot.png"
    result = headless(chromium, tmp_path / "profile", f"--screenshot={shot}", "--window-size=1200,1600",
                      path.resolve().as_uri(), timeout=60)
    assert shot.is_file(), f"no screenshot (rc {result.returncode}): {result.stderr[-2000:]}"
    pixels = np.asarray(Image.open(shot).convert("RGB"))
    assert pixels.shape == (1600, 1200, 3)
    colours = np.unique(pixels.reshape(-1, 3), axis=0)
    assert len(colours) > 50, "the screenshot is (nearly) a single colour: the page did not render"
