"""Time the synthetic scene generator per preset.

    python benchmarks/synth.py                 # tiny and small
    python benchmarks/synth.py --paper         # also paper (slow); --paper-frames N to extrapolate

Prints a table and writes JSON (default benchmarks/results/synth.json). A `paper` run with fewer
frames than the preset reports the measured time and a linear extrapolation to the full preset.
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import tempfile
import time
from pathlib import Path

from radar4dgs.config import preset
from radar4dgs.datasets.synth import SynthConfig, synthesize


def time_preset(name: str, seed: int, frames: int | None, workdir: Path) -> dict:
    """Wall-clock seconds to synthesise one scene of preset ``name`` (optionally fewer frames)."""
    config = preset(SynthConfig, name, seed=seed)
    full_frames = config.num_frames
    if frames is not None:
        config = preset(SynthConfig, name, seed=seed, num_frames=frames)
    start = time.perf_counter()
    synthesize(config, workdir / f"{name}-{seed}", overwrite=True, progress=False)
    seconds = time.perf_counter() - start
    result = {"preset": name, "width": config.width, "height": config.height, "frames": config.num_frames,
              "seconds": round(seconds, 2), "seconds_per_frame": round(seconds / config.num_frames, 3)}
    if config.num_frames != full_frames:
        result["extrapolated_full_seconds"] = round(seconds / config.num_frames * full_frames, 1)
        result["extrapolated_frames"] = full_frames
    return result


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--paper", action="store_true", help="also time the paper preset (1920x1080)")
    parser.add_argument("--paper-frames", type=int, default=None,
                        help="frames for the paper run; fewer than 50 reports an extrapolation")
    parser.add_argument("--seed", type=int, default=1)
    parser.add_argument("--out", type=Path, default=Path(__file__).parent / "results" / "synth.json")
    args = parser.parse_args()

    runs = [("tiny", None), ("small", None)] + ([("paper", args.paper_frames)] if args.paper else [])
    results = []
    with tempfile.TemporaryDirectory(prefix="synth-bench-") as tmp:
        for name, frames in runs:
            results.append(time_preset(name, args.seed, frames, Path(tmp)))
            r = results[-1]
            extra = (f"  (-> {r['extrapolated_full_seconds']} s for {r['extrapolated_frames']} frames, extrapolated)"
                     if "extrapolated_full_seconds" in r else "")
            print(f"{r['preset']:<6} {r['width']:>4}x{r['height']:<4} {r['frames']:>3} frames "
                  f"{r['seconds']:>8.2f} s  {r['seconds_per_frame']:>7.3f} s/frame{extra}", flush=True)
    payload = {"benchmark": "synth", "seed": args.seed, "cpu_count": os.cpu_count(),
               "affinity": len(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity") else None,
               "python": platform.python_version(), "machine": platform.machine(), "results": results}
    args.out.parent.mkdir(parents=True, exist_ok=True)
    args.out.write_text(json.dumps(payload, indent=2) + "\n")
    print(f"wrote {args.out}")


if __name__ == "__main__":
    main()
