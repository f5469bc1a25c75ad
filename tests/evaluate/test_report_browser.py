"""The HTML report of a real (tiny) trained run, opened in headless Chromium: the page states what
made the run and its metrics, every picture decodes, the video beside it loads, no error is raised.

CI runs this (``.ci/run`` installs Debian's chromium and sets RADAR4DGS_REQUIRE_BROWSER=1, so a
missing browser fails there instead of skipping); elsewhere it skips without a browser.
"""

from __future__ import annotations

import html
import json
import re
import shutil

import pytest
from _browser import chromium_or_skip, headless

pytestmark = pytest.mark.usefixtures("one_torch_thread")

# Injected into a copy of the report (the report itself has no script): errors of the page and of
# its resources (images, video) are recorded; once the page and the video's metadata have loaded,
# a <pre id="probe"> with every image's natural size, the video's state and the errors is added to
# the DOM, which --dump-dom prints.
ERRORS_SCRIPT = """<script>
window.__errors = [];
window.addEventListener("error", function (e) {
  window.__errors.push(e.message || ("failed to load " + ((e.target && (e.target.currentSrc || e.target.src)) || "?")
                                     ).slice(0, 200));
}, true);
</script>"""
PROBE_SCRIPT = """<script>
window.addEventListener("load", function () {
  var video = document.querySelector("video"), done = false;
  function finish() {
    if (done) return;
    done = true;
    var images = Array.prototype.map.call(document.images, function (img) {
      return [img.alt, img.complete ? img.naturalWidth : -1, img.complete ? img.naturalHeight : -1];
    });
    var probe = document.createElement("pre");
    probe.id = "probe";
    probe.textContent = JSON.stringify({
      images: images, errors: window.__errors,
      video: video ? {readyState: video.readyState, width: video.videoWidth, height: video.videoHeight,
                      duration: video.duration, error: video.error ? video.error.code : null} : null});
    document.body.appendChild(probe);
  }
  if (video && video.readyState < 1 && !video.error) {
    video.addEventListener("loadedmetadata", finish);
    video.addEventListener("error", finish);
    setTimeout(finish, 5000);
  } else {
    finish();
  }
});
</script>"""


@pytest.fixture(scope="module")
def evaluated_run(tiny_trained_run, tmp_path_factory):
    """A copy of the tiny trained run, evaluated with its video and report, and its metrics."""
    from radar4dgs.evaluate.reconstruction import evaluate_run, write_provenance
    from radar4dgs.train.fit_motion import torch_threads

    run_dir = tmp_path_factory.mktemp("browser") / "run"
    shutil.copytree(tiny_trained_run / "run", run_dir)
    write_provenance(run_dir, preset="tiny", method="ours", command="radar4dgs train (test fixture)")
    with torch_threads(1):
        metrics = evaluate_run(run_dir, lpips=False, video=True, report=True, progress=False)
    return run_dir, metrics


def test_the_report_of_a_trained_run_renders_in_headless_chromium(evaluated_run, tmp_path):
    chromium = chromium_or_skip()
    run_dir, metrics = evaluated_run
    report = (run_dir / "report.html").read_text(encoding="utf-8")
    assert "<script" not in report  # self-contained and static: the probe below is added to a copy
    # The copy sits beside the report, so its relative links (video, config, metrics) resolve alike.
    probe_page = run_dir / "report_probe.html"
    probe_page.write_text(report.replace("<head>", "<head>\n" + ERRORS_SCRIPT, 1)
                          .replace("</body>", PROBE_SCRIPT + "\n</body>", 1), encoding="utf-8")
    result = headless(chromium, tmp_path / "profile", "--dump-dom", "--virtual-time-budget=15000",
                      "--autoplay-policy=no-user-gesture-required", probe_page.resolve().as_uri())
    dom = result.stdout
    assert result.returncode == 0 and "</html>" in dom, f"no DOM (rc {result.returncode}): {result.stderr[-2000:]}"

    # What made the run, as the run table shows it.
    run_table = re.search(r'<table class="run">(.*?)</table>', dom, re.S)
    assert run_table, "no run table in the rendered page"
    rows = dict(re.findall(r"<tr><td>(.*?)</td><td>(.*?)</td></tr>", run_table.group(1)))
    assert rows["preset"] == "tiny" and rows["method"] == "ours" and rows["iterations"] == "20"
    assert rows["config hash"] == metrics["run"]["config_hash"]
    assert rows["PSNR* masks"].startswith("gt (recon ")
    assert rows["training time"].endswith(" s") and rows["evaluation time"].endswith(" s")
    # The metrics, as metrics.json has them.
    table = re.search(r'<table class="metrics">(.*?)</table>', dom, re.S)
    assert table, "no metrics table in the rendered page"
    for split, label in (("recon", "reconstruction (train views)"), ("nvs", "novel views (test views)")):
        row = re.search(rf"<tr><td>{re.escape(label)}</td>(.*?)</tr>", table.group(1), re.S)
        assert row, f"no {split} row"
        cells = [html.unescape(c) for c in re.findall(r"<td[^>]*>(.*?)</td>", row.group(1))]
        assert cells[0] == f"{metrics[split]['psnr']:.2f}" and cells[1] == f"{metrics[split]['ssim']:.4f}"
        assert cells[4].startswith(f"{metrics[split]['psnr_dyn']:.2f}")
        assert cells[5] == str(metrics[split]["n_frames"])
    assert json.loads((run_dir / "metrics.json").read_text())["nvs"]["psnr"] == metrics["nvs"]["psnr"]
    for name in ("config.json", "metrics.json", "video.mp4"):
        assert f'href="{name}"' in dom and (run_dir / name).is_file()

    # Every picture decoded, the video's metadata loaded, and nothing raised an error.
    probe = re.search(r'<pre id="probe">(.*?)</pre>', dom, re.S)
    assert probe, f"the page never finished loading: {result.stderr[-2000:]}"
    state = json.loads(html.unescape(probe.group(1)))
    assert state["errors"] == []
    images = state["images"]
    assert len(images) == report.count("<img ") >= 2 + 6 * metrics["nvs"]["n_frames"]
    broken = [alt for alt, width, height in images if width <= 0 or height <= 0]
    assert not broken, f"images that did not decode: {broken}"
    assert {alt for alt, _, _ in images} >= {"per-frame PSNR", "training curves", "gt", "render", "depth"}
    video = state["video"]
    assert video is not None and video["error"] is None, video
    assert video["readyState"] >= 1 and video["width"] > 0 and video["height"] > 0, video
