"""``radar4dgs demo``: the whole pipeline on the built-in synthetic scene, from synthesis to metrics and video.

The demo folder keeps what each step made (``scene/``, ``prepared/``, ``run/``) and reuses it on the
next call with the same request. ``OUT/demo.json`` records what produced it: the preset, the seed,
the scene's fingerprint and the prepared stages the run was trained on. A call with another preset,
seed or config is refused with one line saying what differs (``--force`` starts over), so old numbers
are never printed under a new request's name; a run trained on prepared outputs that have changed
since is retrained.
"""

from __future__ import annotations

import shutil
import sys
import time
from dataclasses import dataclass, replace
from pathlib import Path
from typing import Any

from radar4dgs.apps.reuse import config_digest, run_conflict, scene_conflict, scene_fingerprint
from radar4dgs.apps.reuse import read_json as _read_json
from radar4dgs.apps.reuse import request_text as _request
from radar4dgs.config import PresetName, preset

__all__ = ["DEMO_FILE", "DEMO_OUTPUTS", "DemoCommand", "run_conflict", "scene_conflict"]

DEMO_FILE = "demo.json"
# What `--force` removes from OUT: everything the demo writes there, nothing else.
DEMO_OUTPUTS = ("scene", "prepared", "run", "inspect.png", "frontend_metrics.json", DEMO_FILE)


@dataclass
class DemoCommand:
    """Run the whole pipeline on a synthetic scene: synthesise, inspect, prepare, score the front end, train, evaluate.
    """

    out: Path = Path("runs/demo")  # folder for the scene and every output
    preset: PresetName = "small"  # scene and pipeline size: tiny (seconds), small (CPU default), paper (GPU)
    seed: int = 1  # synthetic scene seed
    # Overwrite: delete what an earlier demo wrote in OUT (scene, prepared stages, run) and redo every
    # step. Without it a folder made with another preset, seed or config is refused.
    force: bool = False

    # A run that cannot train (a non-finite loss) is one line too (radar4dgs.cli).
    USER_ERRORS = ("radar4dgs.train.trainer.TrainingError",)

    def run(self) -> int:
        from radar4dgs.apps.prepare import PrepareConfig
        from radar4dgs.datasets.synth import SynthConfig
        from radar4dgs.datasets.synth.generate import config_record
        from radar4dgs.model.config import TrainConfig

        started = time.perf_counter()
        synth_config = replace(preset(SynthConfig, self.preset), seed=self.seed)
        prepare_config = preset(PrepareConfig, self.preset)
        train_config = preset(TrainConfig, self.preset)
        scene_dir, prepared, run_dir = self.out / "scene", self.out / "prepared", self.out / "run"
        print(f"radar4dgs demo: {_request(self.preset, self.seed)} -> {self.out}")
        self.print_config(synth_config, prepare_config, train_config)
        if self.force:
            for name in DEMO_OUTPUTS:
                path = self.out / name
                if path.is_dir():
                    shutil.rmtree(path)
                elif path.exists():
                    path.unlink()
        else:
            conflict = self.conflict(record=config_record(synth_config), train_config=train_config)
            if conflict:
                print(f"radar4dgs demo: {conflict}; pass --force to redo the demo in {self.out}, "
                      f"or choose another --out", file=sys.stderr)
                return 1
        self.synthesise(synth_config, scene_dir)
        scene = self.inspect(scene_dir)
        status = self.prepare(scene_dir, prepared, prepare_config)
        self.score_frontend(scene, prepared)
        self.train(scene_dir, prepared, run_dir, train_config, status)
        self.evaluate(run_dir)
        print(f"    config:  {scene_dir / 'scene.json'} (scene), {prepared / 'config.json'} (prepare), "
              f"{run_dir / 'config.json'} (train)")
        print(f"done in {time.perf_counter() - started:.1f} s ({_request(self.preset, self.seed)})")
        return 0

    def print_config(self, synth_config: Any, prepare_config: Any, train_config: Any) -> None:
        """The configuration this demo runs with: what each step is made with, and the digest of
        each resolved config (the train digest is the report's and metrics.json's config hash)."""
        from radar4dgs.datasets.synth.generate import config_record

        scene = f"{synth_config.width}x{synth_config.height}, {synth_config.num_frames} frames"
        print(f"    config: scene {scene} (synth config {config_digest(config_record(synth_config))}); "
              f"prepare config {config_digest(prepare_config)}; train method {train_config.method}, "
              f"{train_config.optim.iterations} iterations, mask source {train_config.mask_source} "
              f"(config hash {config_digest(train_config)})")

    def conflict(self, record: dict[str, Any], train_config: Any) -> str | None:
        """Why OUT holds another request's demo (None when it holds this one's, part of it, or nothing)."""
        demo = _read_json(self.out / DEMO_FILE)
        if demo is not None and (demo.get("preset"), demo.get("seed")) != (self.preset, self.seed):
            return (f"{self.out / DEMO_FILE}: the demo there was made with "
                    f"{_request(demo.get('preset'), demo.get('seed'))}, not {_request(self.preset, self.seed)}")
        return (scene_conflict(self.out / "scene", self.preset, self.seed, record)
                or run_conflict(self.out / "run", train_config))

    def synthesise(self, config: Any, scene_dir: Path) -> None:
        from radar4dgs.datasets.synth import synthesize

        print(f"[1] synthesise a '{self.preset}' scene (seed {self.seed}) -> {scene_dir}")
        if (scene_dir / "scene.json").is_file():
            print("    reusing the scene (same preset, seed and config; --force to regenerate)")
            return
        synthesize(config, scene_dir, overwrite=True, preset=self.preset)

    def inspect(self, scene_dir: Path):
        from radar4dgs.io.preview import contact_sheet, format_summary, save_png, summarize_scene
        from radar4dgs.io.scene import read_scene

        scene = read_scene(scene_dir)
        print("[2] inspect")
        print("    " + format_summary(summarize_scene(scene)).replace("\n", "\n    "))
        sheet = save_png(self.out / "inspect.png", contact_sheet(scene))
        print(f"    contact sheet: {sheet}")
        return scene

    def prepare(self, scene_dir: Path, prepared: Path, config: Any) -> dict[str, str]:
        from radar4dgs.apps.prepare import run_prepare

        print(f"[3] prepare the front end -> {prepared}")
        status = run_prepare(scene_dir, prepared, config)
        print("    " + ", ".join(f"{stage}: {what}" for stage, what in status.items()))
        return status

    def score_frontend(self, scene, prepared: Path) -> None:
        from radar4dgs.evaluate.frontend import evaluate_frontend, format_report
        from radar4dgs.io.atomic import atomic_write_json

        print("[4] score the front end against the scene's ground truth")
        report = evaluate_frontend(scene, prepared)
        atomic_write_json(self.out / "frontend_metrics.json", report)
        print("    " + format_report(report).replace("\n", "\n    "))
        print(f"    written to {self.out / 'frontend_metrics.json'}")

    def train(self, scene_dir: Path, prepared: Path, run_dir: Path, config: Any, status: dict[str, str]) -> None:
        from radar4dgs.apps.prepare import stage_stamps
        from radar4dgs.evaluate.reconstruction import write_provenance
        from radar4dgs.io.atomic import atomic_write_json
        from radar4dgs.train.trainer import train_run

        print(f"[5] train the Gaussian scene (three stages, '{self.preset}' preset) -> {run_dir}")
        inputs = {"scene": scene_fingerprint(scene_dir), "prepared": stage_stamps(prepared)}
        demo = _read_json(self.out / DEMO_FILE) or {}
        # A run trained on other inputs than the current ones is stale: demo.json names the scene
        # and prepared stages it was trained on; in a folder from an older demo without it, a stage
        # that reran just now tells.
        stale = demo["trained_on"] != inputs if "trained_on" in demo else any(v == "ran" for v in status.values())
        if run_dir.exists() and stale:
            print("    the scene or its prepared stages changed since the run was trained: retraining")
            shutil.rmtree(run_dir)
        if (run_dir / "model.pt").is_file():
            print("    reusing the finished run (same preset, seed and config; --force to retrain)")
        else:
            resume = (run_dir / "checkpoints" / "last.pt").is_file()
            train_run(scene_dir, prepared, run_dir, config, resume=resume, progress=True)
        write_provenance(run_dir, preset=self.preset, method="ours",
                         command=f"radar4dgs demo --out {self.out} --preset {self.preset} --seed {self.seed}")
        atomic_write_json(self.out / DEMO_FILE, {"preset": self.preset, "seed": self.seed, "trained_on": inputs})

    def evaluate(self, run_dir: Path) -> None:
        from radar4dgs.evaluate.reconstruction import evaluate_run, format_metrics

        print("[6] evaluate: training frames (recon) and held-out frames (nvs)")
        metrics = evaluate_run(run_dir, progress=True)
        print("    " + format_metrics(metrics).replace("\n", "\n    "))
        print(f"    metrics: {run_dir / 'metrics.json'}\n    video:   {run_dir / 'video.mp4'}\n"
              f"    report:  {run_dir / 'report.html'}")
