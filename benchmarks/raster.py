"""Benchmark of radar4dgs.render.rasterize: forward + backward time and peak memory.

Scene: a driving-like random scene seen by one forward camera (fx = image width, ~53 deg
horizontal field of view): Gaussians spread through the view frustum at depths 3-60 m, scales
log-uniform in 0.05-0.5 m, opacities uniform in 0.1-1, random rotations, RGB colours. The loss is
the sum of colour and alpha against random weights, as training would do.

Each (resolution, N) configuration runs in its own subprocess so that its peak memory (VmHWM from
/proc/self/status, or psutil when installed) is clean. Prints a table and writes JSON.

    python benchmarks/raster.py                        # CPU, torch backend, 2 threads
    python benchmarks/raster.py --device cuda          # gsplat and torch backends on CUDA
    python benchmarks/raster.py --sizes 320x180 --counts 20000 --runs 7
    python benchmarks/raster.py --threads 1 --out /tmp/raster_1t.json   # single-thread CPU time

Next to the wall time, the table reports the process CPU time (user + system, all threads) of
forward + backward: on a shared machine the wall time depends on what else runs, the CPU time
of one thread much less so (with more threads it also counts OpenMP spin-waiting).
"""

from __future__ import annotations

import argparse
import json
import math
import os
import platform
import resource
import statistics
import subprocess
import sys
import time
from pathlib import Path

DEFAULT_SIZES = ("160x90", "320x180", "480x270")
DEFAULT_COUNTS = (5000, 20000, 50000)
# Issue 6 targets (320x180, 2 threads, forward + backward).
TARGETS_S = {("320x180", 20000): 0.15, ("320x180", 50000): 0.5}
TARGET_PEAK_MB = {("320x180", 50000): 2048}


def make_scene(n: int, width: int, height: int, device: str, seed: int = 0):
    """A plausible driving-like random scene (see the module docstring). Returns a dict."""
    import torch

    g = torch.Generator().manual_seed(seed)
    fx = float(width)
    z = 3.0 + 57.0 * torch.rand(n, generator=g)
    # uniform over the image at each depth (a little beyond its edges)
    u = (torch.rand(n, generator=g) * 1.2 - 0.1) * width
    v = (torch.rand(n, generator=g) * 1.2 - 0.1) * height
    x = (u - width / 2) / fx * z
    y = (v - height / 2) / fx * z
    log_s = math.log(0.05) + (math.log(0.5) - math.log(0.05)) * torch.rand(n, 3, generator=g)
    scene = {
        "means": torch.stack((x, y, z), -1),
        "quats": torch.randn(n, 4, generator=g),
        "scales": log_s.exp(),
        "opacities": 0.1 + 0.9 * torch.rand(n, generator=g),
        "colors": torch.rand(n, 3, generator=g),
    }
    K = torch.tensor([[fx, 0.0, width / 2], [0.0, fx, height / 2], [0.0, 0.0, 1.0]])
    out = {k: v.to(device).requires_grad_(True) for k, v in scene.items()}
    out["viewmats"] = torch.eye(4, device=device)[None]
    out["Ks"] = K.to(device)[None]
    return out


def peak_rss_mb() -> float:
    """Peak resident memory of this process in MB (psutil if installed, else /proc VmHWM)."""
    try:
        import psutil  # type: ignore[import-not-found]

        info = psutil.Process().memory_info()
        return getattr(info, "peak_wset", info.rss) / 2**20
    except ImportError:
        pass
    try:
        for line in Path("/proc/self/status").read_text().splitlines():
            if line.startswith("VmHWM:"):
                return int(line.split()[1]) / 1024
    except OSError:
        pass
    import resource

    return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024


def run_one(size: str, n: int, backend: str, device: str, runs: int, threads: int,
            checkpoint: bool) -> dict:  # fmt: skip
    """Time forward+backward of one configuration in this process; returns a result row."""
    import torch

    from radar4dgs.render import rasterize

    torch.set_num_threads(threads)
    width, height = (int(s) for s in size.split("x"))
    scene = make_scene(n, width, height, device)
    params = [scene[k] for k in ("means", "quats", "scales", "opacities", "colors")]
    base_rss = peak_rss_mb()
    if device == "cuda":
        torch.cuda.reset_peak_memory_stats()

    def cpu_s() -> float:
        r = resource.getrusage(resource.RUSAGE_SELF)
        return r.ru_utime + r.ru_stime

    def step() -> tuple[float, float, float, float]:
        for p in params:
            p.grad = None
        sync = torch.cuda.synchronize if device == "cuda" else (lambda: None)
        sync()
        c0 = cpu_s()
        t0 = time.perf_counter()
        colors, alphas, meta = rasterize(
            *params, scene["viewmats"], scene["Ks"], width, height,
            backend=backend, checkpoint=checkpoint,
        )  # fmt: skip
        meta["means2d"].retain_grad()
        sync()
        t1 = time.perf_counter()
        loss = (colors * wc).sum() + (alphas * wa).sum()
        loss.backward()
        sync()
        t2 = time.perf_counter()
        c2 = cpu_s()
        return t1 - t0, t2 - t1, float(alphas.mean()), c2 - c0

    g = torch.Generator().manual_seed(1)
    wc = torch.rand(1, height, width, 3, generator=g).to(device)
    wa = torch.rand(1, height, width, 1, generator=g).to(device)
    step()  # warm-up
    times = [step() for _ in range(runs)]
    total = [f + b for f, b, _, _ in times]
    row = {
        "size": size,
        "n": n,
        "backend": backend,
        "device": device,
        "threads": threads,
        "checkpoint": checkpoint,
        "runs": runs,
        "fwd_bwd_median_s": statistics.median(total),
        "fwd_median_s": statistics.median(t[0] for t in times),
        "bwd_median_s": statistics.median(t[1] for t in times),
        "fwd_bwd_min_s": min(total),
        "fwd_bwd_cpu_median_s": statistics.median(t[3] for t in times),
        "fwd_bwd_cpu_min_s": min(t[3] for t in times),
        "load_avg_1min": os.getloadavg()[0],
        "mean_alpha": times[0][2],
        "peak_rss_mb": peak_rss_mb(),
        "peak_rss_delta_mb": peak_rss_mb() - base_rss,
    }
    if device == "cuda":
        row["peak_cuda_mb"] = torch.cuda.max_memory_allocated() / 2**20
    return row


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--device", default="cpu", choices=["cpu", "cuda"])
    ap.add_argument("--sizes", nargs="+", default=list(DEFAULT_SIZES))
    ap.add_argument("--counts", nargs="+", type=int, default=list(DEFAULT_COUNTS))
    ap.add_argument("--runs", type=int, default=5, help="timed runs per configuration (>= 5)")
    ap.add_argument("--threads", type=int, default=2)
    ap.add_argument("--checkpoint", action="store_true", help="torch backend: recompute in bwd")
    ap.add_argument("--out", type=Path, default=Path(__file__).parent / "results" / "raster.json")
    ap.add_argument("--one", nargs=3, metavar=("SIZE", "N", "BACKEND"), help=argparse.SUPPRESS)
    args = ap.parse_args(argv)

    if args.one:  # child process: one configuration, JSON row on stdout
        size, n, backend = args.one[0], int(args.one[1]), args.one[2]
        row = run_one(size, n, backend, args.device, args.runs, args.threads, args.checkpoint)
        print("ROW " + json.dumps(row))
        return 0

    backends = ["torch"] if args.device == "cpu" else ["gsplat", "torch"]
    rows = []
    header = f"{'size':>8} {'N':>6} {'backend':>7} {'fwd+bwd s':>9} {'fwd s':>7} {'bwd s':>7} " \
             f"{'cpu s':>7} {'peak MB':>8} {'target':>8}"  # fmt: skip
    print(header)
    env = dict(os.environ, OMP_NUM_THREADS=str(args.threads), MKL_NUM_THREADS=str(args.threads))
    for size in args.sizes:
        for n in args.counts:
            for backend in backends:
                cmd = [sys.executable, __file__, "--one", size, str(n), backend,
                       "--device", args.device, "--runs", str(args.runs),
                       "--threads", str(args.threads)]  # fmt: skip
                if args.checkpoint:
                    cmd.append("--checkpoint")
                proc = subprocess.run(cmd, capture_output=True, text=True, env=env)
                lines = [line for line in proc.stdout.splitlines() if line.startswith("ROW ")]
                if proc.returncode != 0 or not lines:
                    print(f"{size:>8} {n:>6} {backend:>7} FAILED: {proc.stderr.strip()[-300:]}")
                    continue
                row = json.loads(lines[-1][4:])
                target = TARGETS_S.get((size, n))
                if args.device == "cpu" and target is not None:
                    row["target_s"] = target
                    row["meets_target"] = row["fwd_bwd_median_s"] <= target
                peak_target = TARGET_PEAK_MB.get((size, n))
                if args.device == "cpu" and peak_target is not None:
                    row["target_peak_mb"] = peak_target
                    row["meets_peak_target"] = row["peak_rss_mb"] <= peak_target
                rows.append(row)
                mark = "" if target is None or args.device != "cpu" else (
                    f"{'ok' if row['meets_target'] else 'MISS'} {target}")
                print(f"{size:>8} {n:>6} {backend:>7} {row['fwd_bwd_median_s']:9.3f} "
                      f"{row['fwd_median_s']:7.3f} {row['bwd_median_s']:7.3f} "
                      f"{row['fwd_bwd_cpu_median_s']:7.3f} "
                      f"{row.get('peak_cuda_mb', row['peak_rss_mb']):8.0f} {mark:>8}", flush=True)  # fmt: skip
    args.out.parent.mkdir(parents=True, exist_ok=True)
    result = {
        "machine": {"platform": platform.platform(), "processor": platform.processor(),
                    "cpu_count": os.cpu_count(), "python": platform.python_version()},
        "device": args.device,
        "threads": args.threads,
        "runs": args.runs,
        "load_avg": os.getloadavg(),
        "rows": rows,
    }  # fmt: skip
    args.out.write_text(json.dumps(result, indent=2) + "\n")
    print(f"wrote {args.out}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
