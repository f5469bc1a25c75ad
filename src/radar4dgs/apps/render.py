"""``radar4dgs render RUN --trajectory SPEC``: re-render a trained run along a camera path.

The path is built by :func:`radar4dgs.apps.trajectory.build_trajectory` from the scene's recorded
cameras (every frame, test frames included, in time order) and their normalised times; each pose is
rendered by the run's model at the pose's time, so dynamic objects move with the scene time
(``stop-time:T`` freezes them while the camera keeps moving). ``nerfstudio:FILE`` renders every
camera of a nerfstudio camera path instead, with its own field of view, size and render time
(:mod:`radar4dgs.apps.camera_paths`).

Outputs (``<slug>`` is the spec made file-name safe, e.g. ``lane-shift_2``, ``stop-time_0.5``,
``custom_<file stem>``, ``nerfstudio_<file stem>``, with ``_x<K>`` for ``--interpolate K`` and
``_s<S>`` for ``--scale S``):

- ``RUN/renders/<slug>/<00000>.png`` one RGB frame per pose; with ``--with-depth`` also
  ``<00000>_depth.png`` and ``<00000>_dynamic.png`` (eval's colour scale and mask threshold);
  ``trajectory.json``: the rendered poses, in the ``custom:FILE`` format, so a path can be
  replayed or edited. The folder is written under a temporary name and renamed when complete.
- ``RUN/<slug>.mp4``: the frames (rgb | depth | dynamic side by side with ``--with-depth``).

``--out DIR`` puts the frames in ``DIR`` and the video in ``DIR/<slug>.mp4`` instead.

Actor edits (:mod:`radar4dgs.actors.edit`; ids from ``radar4dgs actors RUN``, found on demand):
``--remove-actors all|ID[,ID...]``, ``--move-actor ID:DX,DY``, ``--retime-actor ID:SCALE|+SECONDS``,
each repeatable and combinable with every trajectory. They change the actors' Gaussians, not the
picture. The slug gets the edits appended (``recorded_rm-all``, ``recorded_mv2_3.5,0``), and each frame
gets ``<00000>_never_observed.png``: the pixels an actor left (dynamic in the unedited render, not in the
edited one) whose static surface no training frame saw, or moving objects hid in nearly every frame it
was in view in (:mod:`radar4dgs.actors.background`); those
pixels are filled from their surroundings (OpenCV inpainting), and the sky map's texels that only dynamic
objects fitted take the colour of the nearest ones that the sky itself did, unless ``--no-fill-unobserved``.
"""

from __future__ import annotations

import os
import re
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING, Annotated, Iterator, Optional

import numpy as np
import tyro

if TYPE_CHECKING:
    import torch

    from radar4dgs.model.view import View

from radar4dgs.actors.spec import ActorEdits, parse_edits
from radar4dgs.apps.options import default_is
from radar4dgs.apps.trajectory import CameraPose, TrajectorySpec, build_trajectory, parse_trajectory

TRAJECTORY_FILE = "trajectory.json"
# The rendered values whose finiteness is checked: a NaN anywhere in them means a broken model or
# a degenerate camera, and would silently become black pixels in a PNG.
_CHECKED = ("rgb", "depth", "alpha", "dynamic")


class NonFiniteRenderError(ValueError):
    """A rendered pixel is NaN or infinite."""


@dataclass
class RenderResult:
    """What :func:`render_trajectory` wrote: ``frames`` folder, ``video`` path (None without one),
    ``slug``, number of rendered ``poses`` and the image size ``width`` x ``height``."""

    frames: Path
    video: Optional[Path]
    slug: str
    poses: int
    width: int
    height: int


def trajectory_slug(spec: TrajectorySpec, interpolate: int = 1, scale: float = 1.0) -> str:
    """File-name-safe name of a rendering: ``recorded``, ``lane-shift_-1.5``, ``custom_loop_x4``, ..."""
    if spec.kind in ("custom", "nerfstudio"):
        body = f"{spec.kind}_{spec.path.stem if spec.path is not None else 'path'}"
    else:
        body = spec.text.strip().lower().replace(":", "_", 1)
    if interpolate > 1:
        body += f"_x{interpolate}"
    if scale != 1.0:
        body += f"_s{scale:g}"
    # Anything but letters, digits and . + - (slashes, spaces, a second colon) would make a bad
    # or nested file name.
    return re.sub(r"[^A-Za-z0-9.+-]+", "_", body).strip("_") or "trajectory"


def check_finite(out: dict, where: str) -> None:
    """Raise :class:`NonFiniteRenderError` naming ``where`` if a rendered map has NaN/inf."""
    import torch  # here, not at the top: `radar4dgs render --help` should not wait for torch

    for key in _CHECKED:
        value = out[key]
        bad = ~torch.isfinite(value)
        if bool(bad.any()):
            count = int(bad.reshape(value.shape[0], value.shape[1], -1).any(dim=-1).sum())
            raise NonFiniteRenderError(
                f"{where}: the rendered {key} has {count} non-finite pixel(s) (NaN/inf); the model "
                "holds non-finite parameters or the camera pose is degenerate")


def render_pose(run, pose: CameraPose, scale: float = 1.0) -> dict[str, torch.Tensor]:
    """Render ``pose`` with ``run``'s model (no gradient, no dropout) at ``scale`` of the recorded
    resolution: ``rgb`` (H, W, 3), ``depth`` (H, W), ``alpha`` (H, W), ``dynamic`` (H, W)."""
    import torch

    from radar4dgs.evaluate.reconstruction import render_view
    from radar4dgs.model.view import camera_view

    with torch.no_grad():
        return render_view(run, camera_view(run.scene.camera, pose.world_to_camera, pose.time, scale))


def recorded_cameras(scene) -> tuple[np.ndarray, np.ndarray]:
    """The scene's recorded cameras: world_to_camera (N, 4, 4) and normalised times (N,)."""
    from radar4dgs.io.scene import normalized_times

    w2c = np.stack([scene.world_to_camera(i) for i in range(len(scene))]).astype(np.float64)
    return w2c, normalized_times(scene)


def trajectory_views(run, trajectory: str, interpolate: int = 1, scale: float = 1.0) -> tuple[str, list[View]]:
    """(slug, views) of ``trajectory`` for the loaded ``run``: a spec of
    :mod:`radar4dgs.apps.trajectory` built from the recorded cameras, or ``nerfstudio:FILE``
    (:mod:`radar4dgs.apps.camera_paths`, every camera of the file)."""
    from radar4dgs.apps.camera_paths import camera_path_views, is_nerfstudio
    from radar4dgs.model.view import camera_view

    if is_nerfstudio(trajectory):
        path = Path(os.path.expanduser(trajectory.strip()[len("nerfstudio:"):].strip()))
        slug = trajectory_slug(TrajectorySpec(kind="nerfstudio", text=trajectory, path=path), 1, scale)
        return slug, camera_path_views(path, run.scene.camera, scale)
    spec = parse_trajectory(trajectory)
    w2c, times = recorded_cameras(run.scene)
    poses = build_trajectory(spec, w2c, times, interpolate=interpolate)
    views = [camera_view(run.scene.camera, p.world_to_camera, p.time, scale) for p in poses]
    return trajectory_slug(spec, interpolate, scale), views


def _check_options(trajectory: str, interpolate: int, scale: float, fps: float) -> None:
    """Refuse bad options, a bad spec or an unreadable path file before the model loads."""
    from radar4dgs.apps.camera_paths import is_nerfstudio, read_camera_path

    if isinstance(interpolate, bool) or not isinstance(interpolate, int) or interpolate < 1:
        raise ValueError(f"--interpolate must be an integer >= 1, got {interpolate!r}")
    if not (np.isfinite(scale) and 0 < scale <= 4):
        raise ValueError(f"--scale must lie in (0, 4] (a fraction of the recorded resolution), got {scale}")
    if not (np.isfinite(fps) and fps > 0):
        raise ValueError(f"--fps must be positive, got {fps}")
    if not is_nerfstudio(trajectory):
        parse_trajectory(trajectory)
        return
    if interpolate != 1:
        raise ValueError("--interpolate applies to the recorded-camera specs, not to a nerfstudio camera path "
                         "(its cameras are already one per frame)")
    path = Path(os.path.expanduser(trajectory.strip()[len("nerfstudio:"):].strip()))
    if not path.is_file():
        raise ValueError(f"trajectory spec {trajectory!r}: {path}: nerfstudio camera path file not found")
    read_camera_path(path)


def edit_run(run, edits: ActorEdits | None, repair_sky: bool = True):
    """(the run with its model edited, the unedited model) for ``edits`` of its actors (RUN/actors.json,
    found when missing); ``(run, None)`` without edits. ``repair_sky``: render with
    :func:`~radar4dgs.actors.background.background_sky`. Raises ValueError naming an unknown actor id."""
    from dataclasses import replace

    from radar4dgs.actors.background import background_sky
    from radar4dgs.actors.edit import edited_model
    from radar4dgs.actors.spec import check_ids
    from radar4dgs.actors.store import ACTORS_FILE, run_actors
    from radar4dgs.io.scene import normalized_times

    if edits is None or edits.empty:
        return run, None
    actors = run_actors(run) if edits.ids() or not edits.remove_all else []
    check_ids(edits, actors, str(run.root / ACTORS_FILE))
    sky = background_sky(run) if repair_sky else None
    model = edited_model(run.model, actors, edits, normalized_times(run.scene), run.scene.duration, sky)
    return replace(run, model=model), run.model


def render_trajectory(run_dir, trajectory: str = "recorded", *, interpolate: int = 1, with_depth: bool = False,
                      out: Path | None = None, fps: float = 10.0, scale: float = 1.0, device: str | None = None,
                      video: bool = True, progress: bool = True, edits: ActorEdits | None = None,
                      fill_unobserved: bool = True) -> RenderResult:
    """Render the run in ``run_dir`` (a path, or a loaded :class:`~radar4dgs.evaluate.reconstruction.Run`)
    along ``trajectory`` with actor ``edits``; see the module docstring for the outputs. Raises ValueError
    on a bad spec, option or actor id, FileNotFoundError on an incomplete run, :class:`NonFiniteRenderError`
    on NaN pixels (nothing is left behind then)."""
    from radar4dgs.apps.trajectory import write_custom_trajectory
    from radar4dgs.evaluate.reconstruction import RENDERS_DIR
    from radar4dgs.io.atomic import atomic_directory
    from radar4dgs.model.run import Run, load_run

    _check_options(trajectory, interpolate, scale, fps)  # a bad spec or file fails before the model loads
    run = run_dir if isinstance(run_dir, Run) else load_run(run_dir, device)
    run, unedited = edit_run(run, edits, fill_unobserved)
    slug, views = trajectory_views(run, trajectory, interpolate, scale)
    if unedited is not None:
        slug = f"{slug}_{edits.slug()}"
    frames_dir = Path(out) if out is not None else run.root / RENDERS_DIR / slug
    video_path = (frames_dir / f"{slug}.mp4" if out is not None else run.root / f"{slug}.mp4") if video else None
    # The folder is replaced whole: refuse to replace one that is not an earlier rendering (a
    # mistyped --out must not wipe an unrelated folder).
    if frames_dir.exists() and (not frames_dir.is_dir() or (any(frames_dir.iterdir())
                                                           and not (frames_dir / TRAJECTORY_FILE).is_file())):
        raise ValueError(f"{frames_dir}: exists and is not an earlier `radar4dgs render` output (no "
                         f"{TRAJECTORY_FILE}); choose another --out")

    indices = range(len(views))
    if progress:
        from tqdm import tqdm

        indices = tqdm(indices, desc=f"render {slug}", unit="view")
    with atomic_directory(frames_dir, overwrite=True) as folder:
        write_custom_trajectory(folder / TRAJECTORY_FILE, [CameraPose(v.world_to_camera, v.time) for v in views])
        frames = _render_frames(run, views, indices, folder, with_depth, trajectory,
                                Unobserved.of(run, unedited, fill_unobserved))
        if video_path is None:
            for _ in frames:
                pass
        else:
            from radar4dgs.evaluate.video import write_video

            # The video is encoded while rendering, so a long path never holds all its frames in
            # memory; with --out it lands inside the temporary folder and moves with it.
            target = folder / video_path.name if out is not None else video_path
            write_video(frames, target, fps=fps)
    return RenderResult(frames_dir, video_path, slug, len(views), views[0].width, views[0].height)


@dataclass
class Unobserved:
    """What marks and fills the pixels edited actors leave: the ``unedited`` model, the training frames'
    ``visibility`` (:func:`radar4dgs.actors.background.training_visibility`), ``fill`` (inpaint them)."""

    unedited: object
    visibility: list
    fill: bool

    @classmethod
    def of(cls, run, unedited, fill: bool) -> Optional["Unobserved"]:
        from radar4dgs.actors.background import training_visibility

        return None if unedited is None else cls(unedited, training_visibility(run, scale=0.5), fill)

    def mask(self, run, view: View, rendered: dict, unedited_render: dict | None = None) -> np.ndarray:
        """(H, W) bool never-observed pixels of ``view`` among those the edited actors left;
        ``unedited_render``: the unedited model's render of ``view`` when the caller has it."""
        import torch

        from radar4dgs.actors.background import DYNAMIC_WEIGHT, never_observed_mask

        if unedited_render is None:
            with torch.no_grad():
                unedited_render = self.unedited.render(view, run.config.raster)
        before = unedited_render["dynamic"].cpu().numpy()
        region = (before > DYNAMIC_WEIGHT) & (rendered["dynamic"].cpu().numpy() <= DYNAMIC_WEIGHT)
        return never_observed_mask(run, view, region, self.visibility)


def _render_frames(run, views: list[View], indices, folder: Path, with_depth: bool, label: str,
                   unobserved: Unobserved | None = None) -> Iterator[np.ndarray]:
    """Render and save each view (and its never-observed mask with ``unobserved``); yield the video frame
    of each (rgb, or rgb | depth | dynamic)."""
    import torch

    from radar4dgs.actors.background import fill_never_observed
    from radar4dgs.evaluate.reconstruction import DEPTH_FAR, DEPTH_NEAR, render_view, to_uint8
    from radar4dgs.evaluate.visualize import depth_to_rgb, mask_to_rgb, side_by_side
    from radar4dgs.io.preview import save_png

    for i in indices:
        view = views[i]
        with torch.no_grad():
            rendered = render_view(run, view)
        check_finite(rendered, f"view {i} of trajectory {label!r} (time {view.time:.4f})")
        rgb = to_uint8(rendered["rgb"])
        if unobserved is not None:
            never = unobserved.mask(run, view, rendered)
            save_png(folder / f"{i:05d}_never_observed.png", mask_to_rgb(never))
            if unobserved.fill:
                rgb = fill_never_observed(rgb, never)
        save_png(folder / f"{i:05d}.png", rgb)
        if not with_depth:
            yield rgb
            continue
        alpha = rendered["alpha"].cpu().numpy()
        depth = depth_to_rgb(np.where(alpha > 0.05, rendered["depth"].cpu().numpy(), np.nan),
                             near=DEPTH_NEAR, far=DEPTH_FAR)
        dynamic = mask_to_rgb(rendered["dynamic"].cpu().numpy() > 0.5)
        save_png(folder / f"{i:05d}_depth.png", depth)
        save_png(folder / f"{i:05d}_dynamic.png", dynamic)
        yield side_by_side([rgb, depth, dynamic], [f"render t={view.time:.3f}", "depth", "dynamic"])


@dataclass
class RenderCommand:
    """Re-render a trained run along a camera path: recorded, lane shift, height, bullet time, custom, nerfstudio."""

    # The run folder written by `radar4dgs train`.
    run_dir: tyro.conf.Positional[Path]
    # Camera path: recorded | lane-shift:M (metres, + = left) | height:M (metres, + = up) |
    # stop-time:T (integer = frame index, decimal = normalised time in [0, 1]) | custom:FILE (JSON) |
    # nerfstudio:FILE (a nerfstudio / gsplat viewer camera_path.json: every camera of it).
    trajectory: str = "recorded"
    # Insert K - 1 interpolated views between consecutive poses (smoother video).
    interpolate: int = 1
    # Also write depth and dynamic-mask pictures; the video shows rgb | depth | dynamic.
    with_depth: bool = False
    # Folder for the frames (and the video).
    out: Annotated[Optional[Path], default_is("RUN/renders/<slug>, and RUN/<slug>.mp4")] = None
    # Frame rate of the video.
    fps: float = 10.0
    # Render at this fraction of the recorded resolution (0.5 = half width and height).
    scale: float = 1.0
    # Torch device.
    device: Annotated[Optional[str], default_is("the one the run was trained on")] = None
    # Write the video.
    video: bool = True
    # Remove actors: all | ID[,ID...] (ids from `radar4dgs actors RUN`).
    remove_actors: tyro.conf.UseAppendAction[tuple[str, ...]] = ()
    # Move an actor: ID:DX,DY metres in its own frame (DX lateral, + = its left; DY longitudinal, + =
    # forward); repeatable.
    move_actor: tyro.conf.UseAppendAction[tuple[str, ...]] = ()
    # Re-time an actor: ID:SCALE (its time runs SCALE times as fast) or ID:+SECONDS / ID:-SECONDS
    # (later / earlier).
    retime_actor: tyro.conf.UseAppendAction[tuple[str, ...]] = ()
    # Inpaint the never-observed pixels an edited actor leaves (their mask is written either way) and
    # repair the sky map behind the actors.
    fill_unobserved: bool = True
    # Torch intra-op threads (0 = torch's default; 1 is much faster on a machine busy with other jobs).
    threads: int = 0
    # Hide the progress bar.
    quiet: bool = False

    def run(self) -> int:
        from radar4dgs.train.fit_motion import torch_threads

        # A missing run, a bad trajectory or edit raises a user error: one line (radar4dgs.cli).
        edits = parse_edits(self.remove_actors, self.move_actor, self.retime_actor)
        with torch_threads(self.threads):
            result = render_trajectory(self.run_dir, self.trajectory, interpolate=self.interpolate,
                                       with_depth=self.with_depth, out=self.out, fps=self.fps,
                                       scale=self.scale, device=self.device, video=self.video,
                                       progress=not self.quiet, edits=edits,
                                       fill_unobserved=self.fill_unobserved)
        print(f"rendered {result.poses} views ({result.width}x{result.height}) of {self.trajectory!r}: "
              f"{result.frames}/" + (f", {result.video}" if result.video is not None else ""))
        return 0
