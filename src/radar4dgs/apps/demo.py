"""``radar4dgs demo``: the whole pipeline on the built-in synthetic scene, from synthesis to metrics and video."""

from __future__ import annotations

import time
from dataclasses import dataclass, replace
from pathlib import Path

from radar4dgs.config import PresetName, preset


@dataclass
class DemoCommand:
    """Run the whole pipeline on a synthetic scene: synthesise, inspect, prepare, score the front end, train, evaluate.
    """

    out: Path = Path("runs/demo")  # folder for the scene and every output
    preset: PresetName = "small"  # scene and pipeline size: tiny (seconds), small (CPU default), paper (GPU)
    seed: int = 1  # synthetic scene seed
    fresh: bool = False  # regenerate the scene even if OUT/scene exists

    def run(self) -> int:
        from radar4dgs.datasets.synth import SynthConfig, synthesize
        from radar4dgs.io.preview import contact_sheet, format_summary, save_png, summarize_scene
        from radar4dgs.io.scene import read_scene

        started = time.perf_counter()
        scene_dir = self.out / "scene"
        print(f"[1] synthesise a '{self.preset}' scene (seed {self.seed}) -> {scene_dir}")
        if self.fresh or not (scene_dir / "scene.json").is_file():
            synthesize(replace(preset(SynthConfig, self.preset), seed=self.seed), scene_dir, overwrite=True,
                       preset=self.preset)
        else:
            print("    reusing the existing scene (--fresh to regenerate)")
        scene = read_scene(scene_dir)

        print("[2] inspect")
        print("    " + format_summary(summarize_scene(scene)).replace("\n", "\n    "))
        sheet = save_png(self.out / "inspect.png", contact_sheet(scene))
        print(f"    contact sheet: {sheet}")

        from radar4dgs.apps.prepare import PrepareConfig, run_prepare
        from radar4dgs.evaluate.frontend import evaluate_frontend, format_report
        from radar4dgs.io.atomic import atomic_write_json

        prepared = self.out / "prepared"
        print(f"[3] prepare the front end -> {prepared}")
        status = run_prepare(scene_dir, prepared, preset(PrepareConfig, self.preset))
        print("    " + ", ".join(f"{stage}: {what}" for stage, what in status.items()))

        print("[4] score the front end against the scene's ground truth")
        report = evaluate_frontend(scene, prepared)
        atomic_write_json(self.out / "frontend_metrics.json", report)
        print("    " + format_report(report).replace("\n", "\n    "))
        print(f"    written to {self.out / 'frontend_metrics.json'}")

        from radar4dgs.evaluate.reconstruction import evaluate_run, format_metrics
        from radar4dgs.model.config import TrainConfig
        from radar4dgs.train.trainer import train_run

        run_dir = self.out / "run"
        print(f"[5] train the Gaussian scene (three stages, '{self.preset}' preset) -> {run_dir}")
        train_config = preset(TrainConfig, self.preset)
        resume = (run_dir / "checkpoints" / "last.pt").is_file() and not self.fresh
        if self.fresh and run_dir.exists():
            import shutil

            shutil.rmtree(run_dir)
        if (run_dir / "model.pt").is_file() and resume:
            print("    reusing the finished run (--fresh to retrain)")
        else:
            train_run(scene_dir, prepared, run_dir, train_config, resume=resume, progress=True)

        print("[6] evaluate: training frames (recon) and held-out frames (nvs)")
        metrics = evaluate_run(run_dir, progress=True)
        print("    " + format_metrics(metrics).replace("\n", "\n    "))
        print(f"    metrics: {run_dir / 'metrics.json'}\n    video:   {run_dir / 'video.mp4'}\n"
              f"    report:  {run_dir / 'report.html'}")
        print(f"done in {time.perf_counter() - started:.1f} s")
        return 0
