"""Scene-level depth front end: relative depth -> per-frame radar scale recovery -> neighbour
fallback -> metric depth, confidence and sky masks in the prepared folder.

Outputs of :func:`prepare_depth` (each folder replaced atomically):

    <prepared>/depth/<frame>.npy             float32 (H, W) metric z-depth (m), +inf on sky
    <prepared>/depth/<frame>_confidence.npy  float32 (H, W) in [0, 1], 0 on sky
    <prepared>/depth/relative/<frame>.npy    float32 (H, W) the relative inverse depth x used
                                             (when config.keep_relative)
    <prepared>/depth/summary.json            per-frame scale/shift, pairs, fallbacks, timings
    <prepared>/depth/config.json             the resolved DepthConfig
    <prepared>/sky/<frame>.png               uint8 0/255, 255 = sky
"""

from __future__ import annotations

import math
import time
import warnings
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Callable, Sequence

import numpy as np
from PIL import Image

from radar4dgs.config import save_config, to_dict
from radar4dgs.depth.config import DepthConfig
from radar4dgs.depth.depth_maps import confidence_map, frame_confidences, metric_depth
from radar4dgs.depth.geometry import DirectionIndex, transform_points
from radar4dgs.depth.pairs import DYNAMIC, DepthWarning, FrameFit
from radar4dgs.depth.scale import recover_scale
from radar4dgs.depth.sky import fallback_sky_mask
from radar4dgs.depth.sources import (
    FLAT_WORLD_NOTICE,
    DepthModelError,
    build_depth_model,
    frame_inverse_depth,
    resolve_source,
)
from radar4dgs.depth.temporal import FrameParameters, fill_from_neighbours, limit_metric_correction, temporal_refine
from radar4dgs.io.atomic import atomic_directory, atomic_write_json

SUMMARY_VERSION = 1


# --------------------------------------------------------------------------------------------
# Static radar points


def static_mask(scene, index: int, num_points: int, radar_dir: str | Path | None = None, scan=None
                ) -> tuple[np.ndarray, str]:
    """(N,) bool static-point mask of frame ``index`` and where it came from.

    In order: ``<radar_dir>/<frame>.npz`` key ``dynamic`` (the radar stage's output,
    ``<prepared>/radar``; rows aligned with ``scene.load_radar``); else the radar front end
    (``radar4dgs.radar.estimate_ego_motion`` and ``classify_dynamic``) on ``scan``; else every
    point (the robust fits reject moving points as outliers, but less reliably), which the caller
    should warn about.
    """
    if radar_dir is not None:
        path = Path(radar_dir) / f"{scene.frames[index].name}.npz"
        if path.is_file():
            with np.load(path, allow_pickle=False) as data:
                if "dynamic" in data.files and data["dynamic"].shape == (num_points,):
                    return ~data["dynamic"].astype(bool), "prepared radar"
    from radar4dgs.radar import classify_dynamic, estimate_ego_motion

    if scan is None:
        scan = scene.load_radar(index)
    if len(scan) == 0:
        return np.ones(0, bool), "radar front end"
    ego = estimate_ego_motion(scan.xyz, scan.v_r)
    if not ego.ok:
        return np.ones(num_points, bool), f"all points (ego-motion failed: {ego.reason})"
    is_dynamic, _ = classify_dynamic(scan.xyz, scan.v_r, ego)
    return ~np.asarray(is_dynamic, dtype=bool), "radar front end"


# --------------------------------------------------------------------------------------------
# The depth source


def resolve_model(scene, config: DepthConfig, device: Any = None, model: Any = None) -> tuple[str, Any]:
    """The concrete depth source of ``scene`` and its model (the network for "depth-anything-v2",
    the :class:`~radar4dgs.depth.flat_world.FlatWorldDepth` for "flat-world", else None).

    With ``source="auto"`` and no ``priors/mono_depth``, a network that cannot be loaded (or a
    caller-given ``model``, used as the network) decides between Depth-Anything-V2 and the
    flat-world prior; falling back to flat-world issues one :class:`DepthWarning`.
    """
    from radar4dgs.depth.flat_world import FlatWorldDepth

    source = resolve_source(scene, config)
    why = ""
    if config.source == "auto" and source == "flat-world" and model is not None \
            and not isinstance(model, FlatWorldDepth):
        source = "depth-anything-v2"
    if source == "depth-anything-v2" and model is None:
        try:
            model = build_depth_model(config, device)
        except DepthModelError as exc:
            if config.source != "auto":
                raise
            source, why = "flat-world", f": {str(exc).splitlines()[0]}"
    if source == "flat-world":
        if config.source == "auto":
            warnings.warn(FLAT_WORLD_NOTICE.format(model=str(config.model), why=why), DepthWarning, stacklevel=3)
        if not isinstance(model, FlatWorldDepth):
            model = FlatWorldDepth(scene, config.flat_world_far, config.flat_world_ground_z)
    return source, model


# --------------------------------------------------------------------------------------------
# Per-frame steps


@dataclass
class FrameDepth:
    """Metric outputs of one frame: depth (H, W) float32 (+inf on sky), confidence (H, W)
    float32, sky (H, W) bool, and where the sky came from."""

    depth: np.ndarray
    confidence: np.ndarray
    sky: np.ndarray
    sky_source: str


def uses_sky_prior(scene, config: DepthConfig) -> bool:
    """Whether the configuration takes the sky from ``priors/sky_mask`` (decided once per scene:
    ``scene.has`` checks every frame's file)."""
    has_prior = config.sky_source in ("prior", "auto") and scene.has("priors/sky_mask")
    if config.sky_source == "prior" and not has_prior:
        raise FileNotFoundError(f"{scene.root}: sky_source 'prior' needs a complete priors/sky_mask/ folder")
    return has_prior


def sky_prior(scene, index: int, config: DepthConfig, use_prior: bool | None = None) -> np.ndarray | None:
    """The scene's sky mask for frame ``index`` when the configuration uses it, else None;
    ``use_prior`` is :func:`uses_sky_prior` when the caller already has it."""
    if use_prior is None:
        use_prior = uses_sky_prior(scene, config)
    return scene.load_optional("priors/sky_mask", index) if use_prior else None


def render_frame(x: np.ndarray, image: np.ndarray | None, parameters: FrameParameters, confidence: float,
                 x_range: tuple[float, float], config: DepthConfig, sky: np.ndarray | None) -> FrameDepth:
    """Metric depth, confidence and sky of one frame.

    Args:
        x: (H, W) relative inverse depth.
        image: (H, W, 3) uint8, needed by the fallback sky detector only.
        parameters: the frame's ``1 / z = a x + b``.
        confidence, x_range: from :func:`~radar4dgs.depth.depth_maps.frame_confidences`.
        sky: (H, W) bool prior sky mask, or None to run the fallback (or no sky, per config).
    """
    depth, valid = metric_depth(x, parameters.a, parameters.b, config.min_depth, config.max_depth)
    if sky is not None:
        source = "prior"
    elif config.sky_source == "none" or image is None:
        sky, source = np.zeros(x.shape, bool), "none"
    else:
        sky = fallback_sky_mask(image, x, depth, valid, far_fraction=config.sky_far_fraction,
                                min_depth=config.sky_min_depth, top_rows=config.sky_top_rows,
                                min_seed_pixels=config.sky_min_seed_pixels,
                                color_threshold=config.sky_color_threshold,
                                regularization=config.sky_color_regularization)
        source = "fallback"
    conf = confidence_map(depth, valid, x, confidence, x_range, config.edge_scale)
    depth = depth.copy()
    depth[sky] = np.inf
    conf[sky] = 0.0
    return FrameDepth(depth, conf, sky, source)


def fit_frames(scene, config: DepthConfig, inverse_depth: Callable[[int], np.ndarray], method: str,
               static_masks: Sequence[np.ndarray | None] | None = None, radar_dir: str | Path | None = None,
               progress: bool | Callable = False, index: DirectionIndex | None = None, flat_world: Any = None,
               anchors: Callable[[int], tuple[np.ndarray, np.ndarray, str]] | None = None
               ) -> tuple[list[FrameFit], list[FrameParameters], dict]:
    """Scale recovery on every frame, then the neighbour fallback.

    Args:
        inverse_depth: frame index -> (H, W) relative inverse depth.
        static_masks: per frame (N,) bool static masks (None entries or None: looked up with
            :func:`static_mask` in ``radar_dir``, the radar stage's folder).
        index: the camera's :class:`DirectionIndex` when the caller already built it.
        flat_world: the :class:`~radar4dgs.depth.flat_world.FlatWorldDepth` when that is the
            source: radar points on its wall are not paired (the wall is a stand-in, counted as
            "sky"), fits that correct it by more than ``config.flat_world_max_correction`` are
            rejected, and with no fit in any frame it is used unscaled instead of failing.
        anchors: frame index -> ((N, 3) metric camera-frame points, (N,) bool static, source):
            the points to fit instead of the radar's (a radar-less scene's point cloud).

    Returns:
        fits, per-frame parameters and info (static-mask sources, timings).
    """
    camera = scene.camera
    start = time.perf_counter()
    if index is None:
        index = DirectionIndex(camera.K, camera.width, camera.height, config.visual_stride)
    info: dict[str, Any] = {"direction_index_s": time.perf_counter() - start, "static_sources": [],
                            "scale_recovery_s": []}
    fits: list[FrameFit] = []
    use_sky_prior = uses_sky_prior(scene, config)
    for i in _progress(range(len(scene)), progress, "depth: scale recovery"):
        x = inverse_depth(i)
        if anchors is not None:
            points, static, source = anchors(i)
        else:
            scan = scene.load_radar(i)
            given = static_masks[i] if static_masks is not None else None
            if given is not None:
                static, source = np.asarray(given, bool), "given"
            else:
                static, source = static_mask(scene, i, len(scan), radar_dir, scan)
            points = transform_points(scene.radar_to_camera(i), scan.xyz)
        info["static_sources"].append(source)
        sky = sky_prior(scene, i, config, use_sky_prior)
        if flat_world is not None:
            sky = flat_world.wall if sky is None else (sky | flat_world.wall)
        start = time.perf_counter()
        fit = recover_scale(x, points, camera.K, config, method, static, sky, index,
                            np.random.default_rng(config.seed + i))
        info["scale_recovery_s"].append(time.perf_counter() - start)
        fits.append(fit)
    unavailable = sorted({s for s in info["static_sources"] if s.startswith("all points")})
    if unavailable:
        warnings.warn(f"depth: no static/dynamic radar flags for some frames ({'; '.join(unavailable)}); "
                      "all radar points used, the robust fit has to reject moving ones", DepthWarning, stacklevel=2)
    if method == "affine" and config.temporal_window > 1:
        start = time.perf_counter()
        fits = temporal_refine(fits, config)
        info["temporal_s"] = time.perf_counter() - start
    if flat_world is not None:
        fits = limit_metric_correction(fits, config.flat_world_max_correction, 1.0 / flat_world.far)
    names = [f.name for f in scene.frames]
    parameters = fill_from_neighbours(fits, [f.timestamp for f in scene.frames], names, flat_world is not None)
    return fits, parameters, info


def _progress(iterable, enabled: bool | Callable, description: str):
    """Wrap ``iterable`` in a tqdm bar (``enabled`` True), the caller's wrapper (a callable, as
    the prepare command passes), or nothing."""
    if callable(enabled):
        return enabled(iterable)
    if not enabled:
        return iterable
    from tqdm import tqdm

    return tqdm(iterable, desc=description, leave=False)


def _number(value: float) -> float | None:
    return float(value) if value is not None and math.isfinite(value) else None


def frame_summary(name: str, fit: FrameFit, parameters: FrameParameters, names: Sequence[str],
                  num_static: int, static_source: str, frame: FrameDepth | None, seconds: float) -> dict:
    """The summary.json entry of one frame."""
    entry = {
        "name": name,
        "scale": _number(parameters.a), "shift": _number(parameters.b),
        "depth_scale": _number(1.0 / parameters.a) if parameters.b == 0 and parameters.a > 0 else None,
        "parameters_from": parameters.source,
        "fallback_frames": [names[k] for k in parameters.from_frames],
        "fit": fit.reason, "scale_only": fit.scale_only,
        "num_radar_points": int(len(fit.pairs.z)), "num_static": int(num_static), "static_source": static_source,
        "num_valid_pairs": fit.num_valid, "num_inliers": fit.num_inliers,
        "residual_median": _number(fit.residual_median),
        "rejected": {k: v for k, v in fit.pairs.reason_counts().items() if k != "valid"},
        "scale_recovery_s": round(seconds, 5),
    }
    if frame is not None:
        entry["sky_source"] = frame.sky_source
        entry["sky_fraction"] = float(frame.sky.mean())
        entry["confidence_mean"] = float(frame.confidence[~frame.sky].mean()) if (~frame.sky).any() else 0.0
    return entry


# --------------------------------------------------------------------------------------------
# The stage


def prepare_depth(scene, prepared_dir: str | Path, config: DepthConfig | None = None, progress: bool = True, *,
                  static_masks: Sequence[np.ndarray | None] | None = None, device: Any = None,
                  model: Any = None) -> dict:
    """Write metric depth, confidence and sky masks of every frame into ``prepared_dir``.

    ``<prepared>/depth/`` (sky masks in ``<prepared>/depth/sky/``) is written in a temporary folder
    and renamed into place at the end (an error leaves the old outputs). Static radar flags come from
    ``<prepared>/radar/`` when the radar stage has run (see :func:`static_mask`).

    Args:
        scene: a loaded :class:`~radar4dgs.io.scene.Scene`.
        prepared_dir: the prepared folder.
        config: the :class:`DepthConfig` (default: its defaults).
        progress: show tqdm progress bars (or a callable wrapping an iterable).
        static_masks: per-frame (N,) bool static radar masks, overriding ``<prepared>/radar``.
        device: torch device of the depth network (overrides ``config.device``).
        model: a ready :class:`~radar4dgs.depth.sources.DepthAnythingV2` (skips loading).

    Returns:
        the summary dict also written to ``<prepared>/depth/summary.json``.
    """
    prepared = Path(prepared_dir)
    prepared.mkdir(parents=True, exist_ok=True)
    with atomic_directory(prepared / "depth", overwrite=True) as depth_dir:
        return write_depth(scene, depth_dir, depth_dir / "sky", config, progress, radar_dir=prepared / "radar",
                           static_masks=static_masks, device=device, model=model)


def write_depth(scene, depth_dir: str | Path, sky_dir: str | Path, config: DepthConfig | None = None,
                progress: bool | Callable = True, *, radar_dir: str | Path | None = None,
                static_masks: Sequence[np.ndarray | None] | None = None, device: Any = None,
                model: Any = None) -> dict:
    """The depth stage writing straight into ``depth_dir`` and ``sky_dir`` (created when absent,
    not atomic: for a caller that already writes into a temporary folder, as the ``prepare``
    stages do). Same outputs and arguments as :func:`prepare_depth`; ``radar_dir`` is the radar
    stage's folder with the static/dynamic flags (``<prepared>/radar``), or None. A scene without
    radar fits its point cloud instead of the radar when it has a monocular prior or network, else
    it gets the sparse depth of its point cloud (:mod:`radar4dgs.depth.points`).
    """
    from radar4dgs.depth.points import point_anchors, write_point_depth

    config = config or DepthConfig()
    if not scene.has_radar and (not scene.has_points or resolve_source(scene, config) == "flat-world"):
        return write_point_depth(scene, depth_dir, sky_dir, config, progress)
    depth_dir, sky_dir = Path(depth_dir), Path(sky_dir)
    depth_dir.mkdir(parents=True, exist_ok=True)
    sky_dir.mkdir(parents=True, exist_ok=True)
    source, model = resolve_model(scene, config, device, model)
    if not scene.has_radar and source == "flat-world":  # the network failed to load
        return write_point_depth(scene, depth_dir, sky_dir, config, progress)
    anchors = None if scene.has_radar else point_anchors(scene, config)
    if source == "oracle":
        warnings.warn("depth: source 'oracle' reads gt/depth: an ablation, not a result", DepthWarning, stacklevel=2)
    kind = config.resolved_kind(source, "metric" if getattr(model, "kind", "") == "depth" else None)
    method = config.resolved_method(kind)
    names = [f.name for f in scene.frames]

    relative_dir = depth_dir / "relative"
    relative_dir.mkdir(exist_ok=True)

    def inverse_depth(i: int) -> np.ndarray:
        # Computed once (the network may be slow), cached in the output folder.
        x = frame_inverse_depth(scene, i, source, kind, model)
        np.save(relative_dir / f"{names[i]}.npy", x)
        return x

    fits, parameters, info = fit_frames(scene, config, inverse_depth, method, static_masks, radar_dir, progress,
                                        flat_world=model if source == "flat-world" else None, anchors=anchors)
    frame_conf = frame_confidences(fits, parameters, config)
    entries = []
    use_sky_prior = uses_sky_prior(scene, config)
    for i in _progress(range(len(scene)), progress, "depth: metric depth and sky"):
        x = np.load(relative_dir / f"{names[i]}.npy")
        prior_sky = sky_prior(scene, i, config, use_sky_prior)
        image = scene.load_image(i) if prior_sky is None and config.sky_source != "none" else None
        frame = render_frame(x, image, parameters[i], *frame_conf[i], config, prior_sky)
        np.save(depth_dir / f"{names[i]}.npy", frame.depth)
        np.save(depth_dir / f"{names[i]}_confidence.npy", frame.confidence)
        Image.fromarray(np.where(frame.sky, 255, 0).astype(np.uint8)).save(sky_dir / f"{names[i]}.png")
        num_static = int((fits[i].pairs.reason != DYNAMIC).sum())
        entries.append(frame_summary(names[i], fits[i], parameters[i], names, num_static,
                                     info["static_sources"][i], frame, info["scale_recovery_s"][i]))
    if not config.keep_relative:
        for path in relative_dir.iterdir():
            path.unlink()
        relative_dir.rmdir()
    times = np.asarray(info["scale_recovery_s"])
    summary = {
        "version": SUMMARY_VERSION,
        "model": "1/z = scale * x + shift; x = relative inverse depth (depth/relative/<frame>.npy); "
                 "depth_scale = 1/scale for pure-scale (paper) frames",
        "source": source, "prior_kind": kind, "method": method,
        "network": config.model if source == "depth-anything-v2" else None,
        "flat_world": model.describe() if source == "flat-world" else None,
        "num_frames": len(scene),
        "fallbacks": [e["name"] for e in entries if e["parameters_from"] != "fit"],
        "sky_sources": sorted({e["sky_source"] for e in entries}),
        "timing": {"direction_index_s": round(info["direction_index_s"], 5),
                   "scale_recovery_mean_s": round(float(times.mean()), 5),
                   "scale_recovery_max_s": round(float(times.max()), 5)},
        "frames": entries,
    }
    if anchors is not None:
        summary["anchors"] = "the scene's point cloud (the scene has no radar)"
    atomic_write_json(depth_dir / "summary.json", summary)
    save_config(config, depth_dir / "config.json")
    return summary


def evaluate_depth_methods(scene, config: DepthConfig | None = None, methods: Sequence[str] = ("affine", "paper"),
                           static_masks: Sequence[np.ndarray | None] | None = None,
                           radar_dir: str | Path | None = None, model: Any = None,
                           relative: Callable[[int], np.ndarray] | None = None) -> dict[str, dict]:
    """Run scale recovery with each of ``methods`` in memory (nothing written) and score it against
    ``gt/depth`` and ``gt/sky_mask``: {method: metrics} as :func:`~radar4dgs.depth.metrics.score_frames`.

    The relative depth is computed once per frame and held in memory (fine for ``small`` scenes).
    ``relative`` (frame index -> (H, W) relative inverse depth) replaces the configured source, for
    benchmarks and ablations (e.g. gt depth divided by an unknown scale).
    """
    from radar4dgs.depth.metrics import score_frames

    config = config or DepthConfig()
    if relative is not None:
        source, kind = "given", "inverse-depth" if config.prior_kind == "auto" else config.prior_kind
    else:
        source, model = resolve_model(scene, config, model=model)
        kind = config.resolved_kind(source, "metric" if getattr(model, "kind", "") == "depth" else None)
    cache: dict[int, np.ndarray] = {}

    def inverse_depth(i: int) -> np.ndarray:
        if i not in cache:
            cache[i] = (np.asarray(relative(i), dtype=np.float32) if relative is not None
                        else frame_inverse_depth(scene, i, source, kind, model))
        return cache[i]

    # Shared by every method: the direction index and each frame's static radar points (a RANSAC
    # per frame when the radar stage has not run).
    camera = scene.camera
    index = DirectionIndex(camera.K, camera.width, camera.height, config.visual_stride)
    static_masks = [static_masks[i] if static_masks is not None and static_masks[i] is not None
                    else static_mask(scene, i, len(scan), radar_dir, scan)[0]
                    for i, scan in ((i, scene.load_radar(i)) for i in range(len(scene)))]
    results = {}
    use_sky_prior = uses_sky_prior(scene, config)
    for method in methods:
        fits, parameters, info = fit_frames(scene, config, inverse_depth, method, static_masks, radar_dir,
                                            index=index, flat_world=model if source == "flat-world" else None)
        frame_conf = frame_confidences(fits, parameters, config)
        frames = []
        for i in range(len(scene)):
            prior_sky = sky_prior(scene, i, config, use_sky_prior)
            image = scene.load_image(i) if prior_sky is None and config.sky_source != "none" else None
            frames.append(render_frame(inverse_depth(i), image, parameters[i], *frame_conf[i], config, prior_sky))
        metrics = score_frames(scene, [f.depth for f in frames], [f.sky for f in frames],
                               [inverse_depth(i) for i in range(len(scene))], [p.a for p in parameters])
        times = np.asarray(info["scale_recovery_s"])
        metrics.update({"method": method, "source": source, "prior_kind": kind,
                        "fallbacks": sum(p.source != "fit" for p in parameters),
                        "depth_scales": [_number(1.0 / p.a) if p.b == 0 else None for p in parameters],
                        "scale_recovery_mean_s": float(times.mean()), "scale_recovery_max_s": float(times.max()),
                        "config": to_dict(config)})
        results[method] = metrics
    return results
