"""``radar4dgs actors RUN``: the moving objects of a trained run, found without boxes
(:mod:`radar4dgs.actors`): a table, ``RUN/actors.json``, ``RUN/actors.png`` (bird's-eye view of
their tracks) and, with ``--json OUT``, the actors in the issue's shape (``{"actors": [{"id",
"frames": [{"name", "centroid_world", "velocity_world", ...}], "n_gaussians", ...}]}``)."""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path
from typing import Annotated, Optional

import tyro

from radar4dgs.actors.config import ActorConfig
from radar4dgs.apps.options import default_is


def actors_table(actors) -> str:
    """The printed table: id, frames of visibility, Gaussians, mean speed, class guess, size."""
    lines = [f"{'id':>3}  {'frames':>11}  {'gaussians':>9}  {'speed m/s':>9}  {'class':<10}  size l x w x h (m)"]
    for a in actors:
        span = f"{int(a.frames[0])}-{int(a.frames[-1])} ({len(a.frames)})" if len(a.frames) else "-"
        lines.append(f"{a.id:>3}  {span:>11}  {len(a.gaussians):>9}  {a.mean_speed:>9.1f}  {a.category:<10}  "
                     + " x ".join(f"{v:.1f}" for v in a.size))
    if not actors:
        lines.append("  (no actor: no dynamic Gaussians move together)")
    return "\n".join(lines)


@dataclass
class ActorsCommand:
    """List the moving objects (actors) of a trained run, found from its dynamic Gaussians' motion."""

    # The run folder written by `radar4dgs train`.
    run_dir: tyro.conf.Positional[Path]
    # Also write the actors as JSON here (the format of RUN/actors.json).
    json: Optional[Path] = None
    # Find the actors again even when RUN/actors.json is current (same model.pt).
    recompute: bool = False
    # Torch device.
    device: Annotated[Optional[str], default_is("the one the run was trained on")] = None
    # Discovery options (used when the actors are found, not when read back from RUN/actors.json).
    actors: ActorConfig = field(default_factory=ActorConfig)

    def run(self) -> int:
        from radar4dgs.actors.plot import write_actors_picture
        from radar4dgs.actors.store import ACTORS_FILE, run_actors
        from radar4dgs.model.run import load_run

        run = load_run(self.run_dir, self.device)
        custom = self.actors if self.actors != ActorConfig() else None
        actors = run_actors(run, custom, recompute=self.recompute)
        picture = write_actors_picture(run, actors)
        print(actors_table(actors))
        written = [self.run_dir / ACTORS_FILE, picture]
        if self.json is not None:
            from radar4dgs.io.atomic import atomic_write_bytes

            atomic_write_bytes(self.json, (self.run_dir / ACTORS_FILE).read_bytes())
            written.append(self.json)
        print("written: " + ", ".join(str(p) for p in written))
        return 0
