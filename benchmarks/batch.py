"""Benchmark of `radar4dgs batch` on Ray (issue 23): the speed-up of two scenes at once against one
after the other on this machine, and what Ray itself costs (the local cluster's start and stop, a
trivial task on a fresh and on a warm worker, the batch's own overhead per scene beyond its work).

    python benchmarks/batch.py [--seeds 1 2] [--preset tiny] [--iterations 100] [--repeats 2]
                               [--work /tmp/radar4dgs-batch-bench] [--out benchmarks/results/batch.json]

The scenes are synthetic (`--preset` scenes of `--seeds`, made once under --work/scenes and reused).
Each batch goes through the public `radar4dgs.apps.batch.run_batch` into a fresh folder under --work
(deleted first, so nothing is skipped), with the preset's task resources (tiny: 1 CPU per task),
`--iterations` training iterations, no LPIPS and no video: `jobs=1` (one after the other) and
`jobs=None` (as many at once as the CPUs allow), each call starting and stopping its own local
cluster as `radar4dgs batch` does. The sequential and the parallel batches alternate `--repeats`
times; the speed-up is the ratio of the median wall times. Every batch must give the same metrics
for each scene (checked; the run fails otherwise).

Each scene task's start and end come from its status.json (wall clock, the worker's): the batch's
wall time splits into the time to the first task's start (cluster start, scheduling, the worker's
first import), the tasks themselves (prepare, train, eval, report, as the task measures them), the
gaps between tasks, and the time after the last (results, table, cluster stop). The per-scene
overhead is the sequential wall time less the cluster's measured start and stop and the tasks' own
seconds, per scene. The machine's CPU count and its load average before and after (other jobs may
share the cores) are recorded; timings depend on that load. Prints a table and writes the JSON
(atomically, after every phase).
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import shutil
import statistics
import sys
import time
from pathlib import Path

from radar4dgs.io.atomic import atomic_write_json
from scene_configs import synth_config, synthesize_once

RESULTS = Path(__file__).parent / "results" / "batch.json"
# Trivial tasks timed on a warm worker, and tasks each on a new worker process (max_calls=1).
WARM_TASKS = 20
FRESH_TASKS = 3
# What a scene task imports on a fresh worker before it can prepare or train (timed in a worker).
TASK_MODULES = ("torch", "radar4dgs.apps.prepare", "radar4dgs.train.trainer", "radar4dgs.evaluate.reconstruction")


def noop(item: int) -> int:
    return item


def import_seconds(modules: tuple[str, ...]) -> float:
    """Seconds to import ``modules`` in this (worker) process."""
    import importlib

    started = time.perf_counter()
    for name in modules:
        importlib.import_module(name)
    return time.perf_counter() - started


def load() -> list[float]:
    return [round(value, 2) for value in os.getloadavg()]


def make_scenes(seeds: list[int], preset_name: str, work: Path) -> list[Path]:
    """The synthetic scenes, made once under work/scenes/<preset>-s<seed> and reused."""
    return [synthesize_once(synth_config(preset_name, seed), work / "scenes" / f"{preset_name}-s{seed}", preset_name)
            for seed in seeds]


def ray_costs(repeats: int) -> dict:
    """The local cluster's start and stop (``repeats`` times), and trivial tasks: the first after
    the start, ``FRESH_TASKS`` each on a new worker process, ``WARM_TASKS`` on a warm worker (one
    after the other, each a round trip), the same through the engine's run_tasks, and the imports
    a scene task pays on a fresh worker."""
    import ray

    from radar4dgs.apps.batch_engine import Resources, cluster, run_tasks

    starts, stops, out = [], [], {}
    for index in range(repeats):
        started = time.perf_counter()
        with cluster(None) as available:
            starts.append(time.perf_counter() - started)
            if index == 0:
                out["cluster_resources"] = {k: v for k, v in available.items() if k in ("CPU", "GPU", "memory")}
                task = ray.remote(noop).options(num_cpus=1)
                fresh_task = ray.remote(num_cpus=1, max_calls=1)(noop)
                begun = time.perf_counter()
                ray.get(task.remote(0))
                out["first_task_after_start_s"] = time.perf_counter() - begun
                fresh = []
                for item in range(FRESH_TASKS):
                    begun = time.perf_counter()
                    ray.get(fresh_task.remote(item))
                    fresh.append(time.perf_counter() - begun)
                out["fresh_worker_task_s"] = fresh
                ray.get(task.remote(0))  # a worker that stays
                warm = []
                for item in range(WARM_TASKS):
                    begun = time.perf_counter()
                    ray.get(task.remote(item))
                    warm.append(time.perf_counter() - begun)
                out["warm_worker_task_s"] = {"median": statistics.median(warm), "min": min(warm), "max": max(warm),
                                             "n": len(warm)}
                begun = time.perf_counter()
                run_tasks(noop, list(range(WARM_TASKS)), resources=Resources(cpus=1), window=1,
                          on_done=lambda *_: None)
                out["run_tasks_per_item_s"] = (time.perf_counter() - begun) / WARM_TASKS
                imports = ray.remote(num_cpus=1, max_calls=1)(import_seconds)
                out["fresh_worker_task_imports_s"] = ray.get(imports.remote(TASK_MODULES))
            stopping = time.perf_counter()
        stops.append(time.perf_counter() - stopping)
    out["cluster_start_s"], out["cluster_stop_s"] = starts, stops
    out["cluster_start_stop_median_s"] = statistics.median(a + b for a, b in zip(starts, stops, strict=True))
    return out


def timed_batch(scenes: list[Path], out: Path, preset_name: str, jobs: int | None, iterations: int) -> dict:
    """One run_batch call into a fresh ``out``: its wall time, each task's start and end (from its
    status.json, relative to the call) and seconds, and its metrics per scene."""
    from radar4dgs.apps.batch import run_batch
    from radar4dgs.apps.batch_scene import read_status

    shutil.rmtree(out, ignore_errors=True)
    load_before = load()
    called = time.time()
    started = time.perf_counter()
    result = run_batch(scenes, out, preset_name, jobs=jobs, iterations=iterations, lpips=False, video=False,
                       progress=False, log=lambda line: None)
    wall = time.perf_counter() - started
    returned = called + wall
    tasks = {}
    for record in result["scenes"]:
        if record["status"] != "ok" or record.get("action") != "trained":
            raise SystemExit(f"{record['scene']}: {record['status']} / {record.get('action')}: {record.get('error')}")
        status = read_status(out / "scenes" / record["scene"])
        tasks[record["scene"]] = {"seconds": record["seconds"], "start_s": status["started"] - called,
                                  "end_s": status["updated"] - called, "metrics": record["metrics"]}
    starts = sorted(t["start_s"] for t in tasks.values())
    ends = sorted(t["end_s"] for t in tasks.values())
    return {"jobs": jobs, "wall_s": wall, "load_avg_before": load_before, "load_avg_after": load(),
            "to_first_task_s": starts[0], "after_last_task_s": returned - called - ends[-1],
            "gaps_between_tasks_s": [b - a for a, b in zip(ends[:-1], starts[1:], strict=True)] if jobs == 1 else None,
            "task_seconds_sum": sum(t["seconds"] for t in tasks.values()), "tasks": tasks}


def same_metrics(runs: list[dict]) -> bool:
    """Whether every batch gave each scene exactly the same metrics (compared as JSON text)."""
    texts = {json.dumps({k: t["metrics"] for k, t in run["tasks"].items()}, sort_keys=True) for run in runs}
    return len(texts) == 1


def summarize(report: dict) -> dict:
    seq, par = report["batches"]["sequential"], report["batches"]["parallel"]
    ray_ = report["ray"]
    n = len(report["scenes"])
    seq_wall = statistics.median(r["wall_s"] for r in seq)
    par_wall = statistics.median(r["wall_s"] for r in par)
    start_stop = ray_["cluster_start_stop_median_s"]
    overheads = [(r["wall_s"] - start_stop - r["task_seconds_sum"]) / n for r in seq]
    return {"sequential_wall_s": seq_wall, "parallel_wall_s": par_wall, "speedup": seq_wall / par_wall,
            "speedup_without_cluster_start_stop": (seq_wall - start_stop) / (par_wall - start_stop),
            "cluster_start_stop_s": start_stop, "fresh_worker_task_s": statistics.median(ray_["fresh_worker_task_s"]),
            "warm_worker_task_s": ray_["warm_worker_task_s"]["median"],
            "batch_overhead_per_scene_s": statistics.median(overheads),
            "identical_metrics": same_metrics(seq + par),
            "nvs_psnr": {k: t["metrics"]["nvs"]["psnr"] for k, t in seq[0]["tasks"].items()}}


def print_table(report: dict) -> None:
    s, ray_ = report["summary"], report["ray"]
    print(f"\n{report['machine']['cpu_count']} CPUs, load average {report['load_avg_before']} before, "
          f"{report['load_avg_after']} after")
    print(f"  {'local Ray cluster start + stop':<48} {s['cluster_start_stop_s']:7.2f} s  "
          f"(start {statistics.median(ray_['cluster_start_s']):.2f} s)")
    print(f"  {'trivial task, first after the start':<48} {ray_['first_task_after_start_s']:7.3f} s")
    print(f"  {'trivial task on a fresh worker (median)':<48} {s['fresh_worker_task_s']:7.3f} s")
    print(f"  {'trivial task on a warm worker (median)':<48} {s['warm_worker_task_s']:7.4f} s")
    print(f"  {'trivial task through run_tasks (per item)':<48} {ray_['run_tasks_per_item_s']:7.4f} s")
    print(f"  {'a scene task imports on a fresh worker':<48} {ray_['fresh_worker_task_imports_s']:7.2f} s")
    for name in ("sequential", "parallel"):
        for run in report["batches"][name]:
            tasks = ", ".join(f"{k} {t['seconds']:.1f} s [{t['start_s']:.1f}-{t['end_s']:.1f}]"
                              for k, t in run["tasks"].items())
            print(f"  {name + ' batch':<48} {run['wall_s']:7.2f} s  (first task at {run['to_first_task_s']:.1f} s, "
                  f"{run['after_last_task_s']:.1f} s after the last; tasks {tasks}; load {run['load_avg_before'][0]})")
    print(f"  {'speed-up of two at once':<48} {s['speedup']:7.2f} x  "
          f"({s['speedup_without_cluster_start_stop']:.2f} x without the cluster's start and stop)")
    print(f"  {'batch overhead per scene beyond its work':<48} {s['batch_overhead_per_scene_s']:7.2f} s")
    print(f"  identical metrics in every batch: {s['identical_metrics']} (novel-view PSNR "
          + ", ".join(f"{k} {v:.2f}" for k, v in s["nvs_psnr"].items()) + ")")


def main() -> None:
    import ray

    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--seeds", type=int, nargs="+", default=[1, 2])
    parser.add_argument("--preset", default="tiny")
    parser.add_argument("--iterations", type=int, default=100)
    parser.add_argument("--repeats", type=int, default=2, help="sequential and parallel batches, alternating")
    parser.add_argument("--work", type=Path, default=Path("/tmp/radar4dgs-batch-bench"))
    parser.add_argument("--out", type=Path, default=RESULTS)
    args = parser.parse_args()

    from radar4dgs.apps.batch import PRESET_RESOURCES

    report: dict = {"command": " ".join(["python", "benchmarks/batch.py"] + sys.argv[1:]),
                    "machine": {"cpu_count": os.cpu_count(), "platform": platform.platform(),
                                "python": platform.python_version(), "ray": ray.__version__},
                    "load_avg_before": load(),
                    "settings": {"preset": args.preset, "seeds": args.seeds, "iterations": args.iterations,
                                 "task_resources": PRESET_RESOURCES[args.preset].text(), "lpips": False,
                                 "video": False, "repeats": args.repeats}}
    scenes = make_scenes(args.seeds, args.preset, args.work)
    report["scenes"] = [str(s) for s in scenes]
    print(f"scenes: {', '.join(map(str, scenes))}; load average {report['load_avg_before']}", flush=True)
    report["ray"] = ray_costs(max(2, args.repeats))
    atomic_write_json(args.out, report)
    print(f"Ray: cluster start + stop {report['ray']['cluster_start_stop_median_s']:.2f} s", flush=True)
    report["batches"] = {"sequential": [], "parallel": []}
    for repeat in range(args.repeats):
        for name, jobs in (("sequential", 1), ("parallel", None)):
            run = timed_batch(scenes, args.work / f"{name}-{repeat}", args.preset, jobs, args.iterations)
            report["batches"][name].append(run)
            atomic_write_json(args.out, report)
            print(f"{name} batch {repeat + 1}/{args.repeats}: {run['wall_s']:.1f} s", flush=True)
    report["load_avg_after"] = load()
    report["summary"] = summarize(report)
    atomic_write_json(args.out, report)
    print_table(report)
    if not report["summary"]["identical_metrics"]:
        raise SystemExit("the batches gave different metrics for the same scene")
    print(f"wrote {args.out}")


if __name__ == "__main__":
    main()
