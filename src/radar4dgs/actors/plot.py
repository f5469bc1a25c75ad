"""Bird's-eye view of the actors' tracks over the static map (``RUN/actors.png``): the static Gaussians'
ground-plane positions in grey, the ego camera's path dashed, each actor's centroid over its frames of
visibility as a coloured line with an arrow at its last frame and its id. Drawn on matplotlib's Agg
canvas (``matplotlib.figure.Figure``), never through pyplot."""

from __future__ import annotations

from pathlib import Path

import numpy as np

ACTORS_PICTURE = "actors.png"
# At most this many static Gaussians are drawn (a random subset: the map's look, not every point).
MAX_MAP_POINTS = 60_000


def static_map(model, min_opacity: float = 0.2, seed: int = 0) -> np.ndarray:
    """(P, 2) world xy of the model's static Gaussians above ``min_opacity`` (a subset of at most
    :data:`MAX_MAP_POINTS`)."""
    import torch

    with torch.no_grad():
        g = model.static.activated()
        keep = (g["opacities"] >= min_opacity).cpu().numpy()
        xy = g["means"][:, :2].double().cpu().numpy()[keep]
    if len(xy) > MAX_MAP_POINTS:
        xy = xy[np.random.default_rng(seed).choice(len(xy), MAX_MAP_POINTS, replace=False)]
    return xy


def draw_actors(actors, static_xy: np.ndarray, ego_xy: np.ndarray, title: str = ""):
    """A matplotlib Figure: ``static_xy`` (P, 2) map, ``ego_xy`` (F, 2) path, the actors' tracks."""
    from matplotlib.figure import Figure

    tracks = [a.centroid[a.frames, :2] for a in actors if len(a.frames)]
    extent = np.concatenate([ego_xy] + tracks) if tracks else ego_xy
    low, high = extent.min(axis=0) - 15.0, extent.max(axis=0) + 15.0
    inside = np.all((static_xy >= low) & (static_xy <= high), axis=1)
    aspect = (high[1] - low[1]) / max(high[0] - low[0], 1e-6)
    fig = Figure(figsize=(10, float(np.clip(10 * aspect, 4.5, 12))), dpi=100)
    ax = fig.add_subplot()
    ax.scatter(static_xy[inside, 0], static_xy[inside, 1], s=0.3, c="0.7", linewidths=0, rasterized=True)
    ax.plot(ego_xy[:, 0], ego_xy[:, 1], "k--", lw=1.2, label="ego camera")
    from matplotlib import colormaps

    for k, actor in enumerate(a for a in actors if len(a.frames)):
        colour = colormaps["tab10"](k % 10)
        xy = actor.centroid[actor.frames, :2]
        ax.plot(xy[:, 0], xy[:, 1], "-", color=colour, lw=2)
        ax.plot(xy[0, 0], xy[0, 1], "o", color=colour, ms=4)
        heading = actor.heading[actor.frames[-1]]
        ax.annotate("", xy=(xy[-1, 0] + np.cos(heading), xy[-1, 1] + np.sin(heading)), xytext=tuple(xy[-1]),
                    arrowprops={"arrowstyle": "->", "color": colour, "lw": 2})
        ax.text(xy[-1, 0], xy[-1, 1] + 1.0, f"{actor.id} {actor.category}", color=colour, fontsize=9,
                fontweight="bold")
    ax.set_xlim(low[0], high[0])
    ax.set_ylim(low[1], high[1])
    ax.set_aspect("equal")
    ax.set_xlabel("world x (m)")
    ax.set_ylabel("world y (m)")
    ax.set_title(title or f"{len(tracks)} actors: tracks of their centroids (dot = first visible frame)")
    ax.legend(loc="upper left", fontsize=8)
    fig.tight_layout()
    return fig


def write_actors_picture(run, actors, path: Path | None = None) -> Path:
    """Draw the actors of the loaded ``run`` to ``path`` (default RUN/actors.png), atomically."""
    from radar4dgs.io.atomic import atomic_path

    scene = run.scene
    ego = np.stack([np.linalg.inv(scene.world_to_camera(i))[:2, 3] for i in range(len(scene))])
    fig = draw_actors(actors, static_map(run.model), ego)
    path = Path(path) if path is not None else Path(run.root) / ACTORS_PICTURE
    with atomic_path(path, suffix=".png") as tmp:
        fig.savefig(tmp, format="png", metadata={"Software": None})
    return path
