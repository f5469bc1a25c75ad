"""Robustness sweep: the whole pipeline, `tiny` preset, on scenes outside the generator's defaults.

    python benchmarks/robustness.py [--variants base nomovers ...] [--work /tmp/radar4dgs-robustness]
                                    [--out benchmarks/results/robustness.json] [--timeout 1500]

Each variant is synthetic seed 3 with some options changed (see VARIANTS), taken through the commands a
user runs: `synth`, `prepare`, `frontend-eval`, `train`, `eval`. A variant passes when every command exits
0, prints no Python warning (RuntimeWarning and the like: they hide NaNs) and the metrics are finite. The
JSON records, per variant, the first failing command (if any), the warnings seen, and recon / novel-view
PSNR and PSNR*. A variant whose run folder already holds metrics.json is reused (marked "reused": its
warnings were not seen by this sweep), so an interrupted sweep continues. Numbers are a smoke test of the
`tiny` preset (200 iterations), not of reconstruction quality.
"""

from __future__ import annotations

import argparse
import json
import math
import re
import subprocess
import sys
import time
from pathlib import Path

from radar4dgs.io.atomic import atomic_write_json

RESULTS = Path(__file__).parent / "results"
# Options of `radar4dgs synth` per variant, on top of `--preset tiny --seed 3`.
VARIANTS: dict[str, list[str]] = {
    "base": ["--traffic", "rush"],
    "nomovers": ["--scene.moving-cars", "0", "0", "--scene.crossing-probability", "0"],
    "egostill": ["--traffic", "realistic", "--scene.ego-speed", "0", "0"],
    "short": ["--traffic", "rush", "--scene.num-frames", "8"],
    "fps2": ["--traffic", "rush", "--scene.fps", "2"],
    "fps30": ["--traffic", "realistic", "--scene.fps", "30"],
    "oddsize": ["--traffic", "rush", "--scene.width", "171", "--scene.height", "97"],
    "aspect43": ["--traffic", "rush", "--scene.width", "200", "--scene.height", "150"],
    "wide": ["--traffic", "rush", "--scene.hfov-deg", "110"],
    "egofast": ["--traffic", "rush", "--scene.ego-speed", "28", "32"],
    "sparseradar": ["--traffic", "rush", "--scene.radar.max-points", "60"],
    "narrowradar": ["--traffic", "rush", "--scene.radar.azimuth-fov-deg", "50"],
}
# Python's own warning lines ("path:line: RuntimeWarning: ..."), not the pipeline's "warning: ..." notes.
PYTHON_WARNING = re.compile(r"\b\w*Warning: ")


def variant_commands(scene: Path, synth_options: list[str]) -> list[list[str]]:
    """The five commands of one variant, in order, each run with this script's interpreter."""
    run = scene / "run"
    cli = [sys.executable, "-m", "radar4dgs.cli"]
    return [[*cli, "synth", str(scene), "--preset", "tiny", "--seed", "3", *synth_options],
            [*cli, "prepare", str(scene), "--preset", "tiny", "--quiet"],
            [*cli, "frontend-eval", str(scene)],
            [*cli, "train", str(scene), "--out", str(run), "--preset", "tiny", "--quiet"],
            [*cli, "eval", str(run)]]


def run_variant(name: str, work: Path, timeout: float) -> dict:
    """Run (or reuse) one variant; its status, warnings, wall time and metrics."""
    scene = work / name
    metrics_path = scene / "run" / "metrics.json"
    result: dict = {"synth_options": VARIANTS[name], "failed_at": None, "python_warnings": [],
                    "reused": metrics_path.is_file()}
    if not result["reused"]:
        start = time.perf_counter()
        for command in variant_commands(scene, VARIANTS[name]):
            try:
                done = subprocess.run(command, capture_output=True, text=True, timeout=timeout)
            except subprocess.TimeoutExpired:
                result["failed_at"] = f"radar4dgs {command[3]} (timed out after {timeout:g} s)"
                return result
            output = done.stdout + done.stderr
            result["python_warnings"] += [line for line in output.splitlines() if PYTHON_WARNING.search(line)]
            if done.returncode != 0:
                result["failed_at"] = f"radar4dgs {command[3]} (exit {done.returncode}): {output.strip()[-300:]}"
                return result
        result["seconds"] = round(time.perf_counter() - start, 1)
    metrics = json.loads(metrics_path.read_text())
    finite = True
    for split in ("recon", "nvs"):
        for key in ("psnr", "psnr_dyn"):
            value = metrics[split].get(key)
            finite = finite and (value is None or math.isfinite(value))
            result[f"{split}_{key}"] = None if value is None else round(value, 2)
    result["ok"] = finite and not result["python_warnings"]
    return result


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--variants", nargs="+", choices=sorted(VARIANTS), default=list(VARIANTS))
    parser.add_argument("--work", type=Path, default=Path("/tmp/radar4dgs-robustness"))
    parser.add_argument("--out", type=Path, default=RESULTS / "robustness.json")
    parser.add_argument("--timeout", type=float, default=1500.0, help="seconds per command")
    args = parser.parse_args()
    args.work.mkdir(parents=True, exist_ok=True)
    results = {}
    for name in args.variants:
        results[name] = run_variant(name, args.work, args.timeout)
        status = "OK" if results[name].get("ok") else f"FAILED {results[name]['failed_at'] or 'warnings/NaN'}"
        print(f"{name:12s} {status}  recon {results[name].get('recon_psnr')} / {results[name].get('recon_psnr_dyn')}"
              f"  novel {results[name].get('nvs_psnr')} / {results[name].get('nvs_psnr_dyn')} dB (PSNR / PSNR*)",
              flush=True)
        atomic_write_json(args.out, {"what": "tiny pipelines on scenes outside the generator's defaults "
                                             "(benchmarks/robustness.py)", "variants": results})
    print(f"wrote {args.out}")


if __name__ == "__main__":
    main()
