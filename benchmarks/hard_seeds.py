"""Picks hard seeds as issue 21 defines them: scenes whose dynamic pixels move p90 >= 40 px a frame (from 300 on the
report set, from 400 on the tuning set).

Seeds are taken in order from ``--start``; each scene's image motion comes from its generator's ground truth
(``gt/flow``, as ``radar4dgs inspect`` prints it), never from a reconstruction, so picking by it tunes nothing. The
first ``--count`` scenes whose p90 at ``--size`` reaches ``--min-p90`` are the set. A cheaper render at
``--screen-size`` first skips the seeds that cannot reach it (image motion scales with the width, so the screen's
threshold is ``--min-p90`` times the width ratio, less ``--screen-margin``); the rule is the figure at ``--size``.

    python benchmarks/hard_seeds.py --start 300 --count 5 [--min-p90 40] [--size 640x360] [--traffic rush] [--fps 5]
                                    [--work /tmp/radar4dgs-hard-seeds] [--out benchmarks/results/hard-seeds.json]

The picked scenes stay under ``--work/scenes/<label>`` (``rush-s306-5hz-640x360``), where ``benchmarks/traffic.py
--size`` with the same ``--work`` finds them. Resumable: seeds already in ``--out`` are not made again.
"""

from __future__ import annotations

import argparse
import json
import shutil
import sys
from pathlib import Path

from radar4dgs.io.atomic import atomic_write_json
from radar4dgs.io.preview import dynamic_motion_statistics
from radar4dgs.io.scene import read_scene
from scene_configs import parse_size, scene_label, synth_config, synthesize_once

RESULTS = Path(__file__).parent / "results"


def scene_motion(seed: int, traffic: str, fps: float | None, size: tuple[int, int], folder: Path) -> dict | None:
    """Synthesize the ``small`` scene of ``seed`` at ``size`` into ``folder`` (reused when there) and return its
    dynamic pixels' p50 / p90 / p99 / max motion (px a frame)."""
    synthesize_once(synth_config("small", seed, traffic, fps, size=size), folder, "small")
    return dynamic_motion_statistics(read_scene(folder))


def screen_threshold(min_p90: float, size: tuple[int, int], screen_size: tuple[int, int], margin: float) -> float:
    """The screen's p90 below which a seed cannot reach ``min_p90`` at ``size``: image motion scales with width."""
    return min_p90 * screen_size[0] / size[0] - margin


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--start", type=int, default=300)
    parser.add_argument("--count", type=int, default=5)
    parser.add_argument("--max-seeds", type=int, default=100, help="give up after this many seeds")
    parser.add_argument("--min-p90", type=float, default=40.0, help="px a frame at --size")
    parser.add_argument("--size", type=parse_size, default=(640, 360))
    parser.add_argument("--screen-size", type=parse_size, default=(320, 180))
    parser.add_argument("--screen-margin", type=float, default=2.0, help="px at the screen size")
    parser.add_argument("--traffic", choices=("calm", "realistic", "rush"), default="rush")
    parser.add_argument("--fps", type=float, default=5.0)
    parser.add_argument("--work", type=Path, default=Path("/tmp/radar4dgs-hard-seeds"))
    parser.add_argument("--out", type=Path, default=RESULTS / "hard-seeds.json")
    args = parser.parse_args()
    size_text = f"{args.size[0]}x{args.size[1]}"
    report = json.loads(args.out.read_text()) if args.out.is_file() else {}
    report.update({"command": " ".join(["python", "benchmarks/hard_seeds.py"] + sys.argv[1:]),
                   "rule": f"the first {args.count} {args.traffic} seeds from {args.start} at {args.fps:g} Hz whose "
                           f"dynamic pixels move p90 >= {args.min_p90:g} px a frame at {size_text} (gt/flow)"})
    seeds = report.setdefault("seeds", {})
    threshold = screen_threshold(args.min_p90, args.size, args.screen_size, args.screen_margin)
    picked = [int(s) for s, row in seeds.items() if row.get("picked")]
    for seed in range(args.start, args.start + args.max_seeds):
        if len(picked) >= args.count:
            break
        if str(seed) in seeds:
            continue
        screen_folder = args.work / "screen" / scene_label(args.traffic, seed, args.fps, size=args.screen_size)
        row = {"screen": scene_motion(seed, args.traffic, args.fps, args.screen_size, screen_folder)}
        shutil.rmtree(screen_folder)
        if row["screen"] and row["screen"]["p90"] is not None and row["screen"]["p90"] >= threshold:
            folder = args.work / "scenes" / scene_label(args.traffic, seed, args.fps, size=args.size)
            row["motion"] = scene_motion(seed, args.traffic, args.fps, args.size, folder)
            row["picked"] = row["motion"]["p90"] is not None and row["motion"]["p90"] >= args.min_p90
            if row["picked"]:
                picked.append(seed)
                row["scene"] = str(folder)
            else:
                shutil.rmtree(folder)
        seeds[str(seed)] = row
        report["picked"] = picked
        atomic_write_json(args.out, report)
        shown = row.get("motion") or row["screen"] or {"p90": None}
        print(f"seed {seed}: p90 {shown['p90']} px at "
              f"{size_text if 'motion' in row else 'the screen size'}{'  <- picked' if row.get('picked') else ''}",
              flush=True)
    print(f"picked {picked} ({len(picked)} of {args.count}); wrote {args.out}")
    if len(picked) < args.count:
        sys.exit(f"only {len(picked)} of {args.count} seeds reach p90 {args.min_p90:g} px in {args.max_seeds} seeds")


if __name__ == "__main__":
    main()
