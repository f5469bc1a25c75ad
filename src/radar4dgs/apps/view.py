"""``radar4dgs view RUN``: browse a trained run in a web browser (:mod:`radar4dgs.apps.viewer`)."""

from __future__ import annotations

import sys
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Annotated, Optional

import tyro

from radar4dgs.apps.options import default_is


@dataclass
class ViewCommand:
    """Browse a trained run in a web browser (viser): Gaussian splats, a time slider, CPU renders."""

    # The run folder written by `radar4dgs train`.
    run_dir: tyro.conf.Positional[Path]
    # Address to listen on (0.0.0.0 to reach the viewer from another machine).
    host: str = "127.0.0.1"
    # Port of the web page (viser picks the next free one when it is taken).
    port: int = 8080
    # Pixel height of the CPU renders in the "radar4dgs render" display.
    render_height: int = 180
    # Torch device for the CPU renders.
    device: Annotated[Optional[str], default_is("the one the run was trained on")] = None
    # Torch intra-op threads of the renders (0 = torch's default).
    threads: int = 0

    def run(self) -> int:
        import torch

        from radar4dgs.apps.viewer import Viewer, ViewerUnavailable, require_viser

        try:
            require_viser()
        except ViewerUnavailable as exc:
            print(f"radar4dgs view: {exc}", file=sys.stderr)
            return 1
        from radar4dgs.model.run import load_run

        run = load_run(self.run_dir, self.device)  # a missing or broken run is one line (radar4dgs.cli)
        if self.threads > 0:
            torch.set_num_threads(self.threads)  # the process is the viewer's alone until it exits
        viewer = Viewer(run, self.host, self.port, self.render_height)
        print(f"viewer running at http://{self.host}:{viewer.port} (Ctrl+C to stop)")
        try:
            while True:
                time.sleep(1.0)
        except KeyboardInterrupt:
            pass
        finally:
            viewer.stop()
        return 0
