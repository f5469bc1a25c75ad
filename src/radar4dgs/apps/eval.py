"""``radar4dgs eval RUN``: evaluate a trained run (:mod:`radar4dgs.evaluate.reconstruction`)."""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import Annotated, ClassVar, Optional

import tyro

from radar4dgs.apps.options import default_is


@dataclass
class EvalCommand:
    """Evaluate a trained run: metrics.json, renders, a video and an HTML report."""

    run_dir: tyro.conf.Positional[Path]  # the run folder written by `radar4dgs train`
    # torch device
    device: Annotated[Optional[str], default_is("the one the run was trained on")] = None
    lpips: bool = True  # compute LPIPS when the backbone weights are present (null otherwise)
    video: bool = True  # write RUN/video.mp4
    report: bool = True  # write RUN/report.html
    # find the moving objects (RUN/actors.json, RUN/actors.png; `radar4dgs actors`), shown in the report
    actors: bool = True

    # A run folder another process holds is a one-line error (radar4dgs.cli).
    USER_ERRORS: ClassVar[tuple[str, ...]] = ("radar4dgs.io.locks.FolderInUseError",)

    def run(self) -> int:
        from radar4dgs.io.atomic import remove_dead_temporaries
        from radar4dgs.io.locks import folder_lock

        # One process per run folder (train holds it while it evaluates: the lock is re-entrant).
        with folder_lock(self.run_dir):
            remove_dead_temporaries(self.run_dir, recursive=True)
            return self._evaluate()

    def _evaluate(self) -> int:
        from radar4dgs.evaluate.reconstruction import (
            METRICS_FILE,
            RENDERS_DIR,
            REPORT_FILE,
            VIDEO_FILE,
            evaluate_run,
            format_metrics,
        )

        if self.actors:
            self._actors()
        metrics = evaluate_run(self.run_dir, self.device, self.lpips, self.video, self.report)
        print(format_metrics(metrics))
        print(f"written: {self.run_dir / METRICS_FILE}, {self.run_dir / RENDERS_DIR}/"
              + (f", {self.run_dir / VIDEO_FILE}" if self.video else "")
              + (f", {self.run_dir / REPORT_FILE}" if self.report else ""))
        return 0

    def _actors(self) -> None:
        """RUN/actors.json and RUN/actors.png before the report is written (runs with dynamic Gaussians)."""
        from radar4dgs.actors.plot import write_actors_picture
        from radar4dgs.actors.store import run_actors
        from radar4dgs.model.run import load_run

        run = load_run(self.run_dir, self.device)
        if run.model.dynamic is not None and len(run.model.dynamic) > 0:
            write_actors_picture(run, run_actors(run))
