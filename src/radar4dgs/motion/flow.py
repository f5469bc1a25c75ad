"""Pseudo scene flow of a scene: every frame pair's 2D optical flow (:mod:`.optical_flow`), a
forward-backward consistency mask, whole-object translations (:mod:`.rigid`) and the lifting to 3D
world-frame point pairs with the metric depth of both frames and the poses (:mod:`.lift`); the
prepared ``flow/`` folder it writes and reads back.

Scene level, :func:`prepare_flow` writes ``<prepared>/flow/<frame>.npz`` for each frame that has a
successor (the next frame, or with ``skip_test_frames`` the next TRAINING frame, so held-out test
images never supervise the field), with keys

    ``flow``       (H, W, 2) float32  forward 2D flow, this frame -> ``index_j`` (a pixel whose radar
                                      prediction passes the camera lands ~1e5 px out: out of view)
    ``consistent`` (H, W) bool        forward-backward consistent and landing inside frame j
    ``points_i``   (M, 3) float32     world points of the kept pixels at this frame's time
    ``points_j``   (M, 3) float32     the same surface points at frame j's time
    ``pixels``     (M, 2) float32     (u, v) integer pixel coordinates of the kept pixels
    ``index_i``, ``index_j`` int; ``timestamp_i``, ``timestamp_j`` float64 (s)

    ``reliable``   (H, W) bool        not dropped as a photometric failure (objects_flow.reliable_pixels)
    ``filled``     (H, W) bool        mask pixels the checks rejected whose ``flow`` is their nearest
                                      lifted neighbour's (objects_flow.fill_rejected_flow) or, with
                                      no neighbour, their radar object's prediction, or that of an
                                      object only the split radar objects have

Each dynamic-mask component gets the motion that explains the two images best (both directions,
before the consistency check): with ``FlowConfig.radar_guided`` and ``<prepared>/radar/objects.json``,
among its dense flow, its single translation, its radar object's predicted motion and a warp matched
around that (:mod:`.objects_flow`); otherwise its translation where that beats the dense flow
(``FlowConfig.rigid_objects``). kept = dynamic (mask) & consistent & reliable & valid depth in both
frames. The stored ``flow`` of mask pixels the checks reject is then filled from the lifted pixels of
their object (:func:`.objects_flow.fill_rejected_flow`), else (``FlowConfig.fill_radar_prediction``) set
to their radar object's predicted motion, and (``FlowConfig.fill_split_objects``) the pixels of an object
that only ``radar/objects_split.json`` has (a second mover whose returns fell among another's outliers) to
its prediction (:func:`.objects_flow.claimed_predictions`); they stay unlifted. Where the object-depth
stage rescaled a frame, frame j's end of each pair is lifted with the depth stage's map of j times
frame i's object scale (``FlowConfig.one_scale_per_pair``): both ends on one scale. ``flow/config.json``
holds the resolved :class:`FlowConfig` (pixel lengths scaled to the scene's width when
``reference_width`` asks); ``summary.json`` counts the components per chosen model (``models``).
"""

from __future__ import annotations

import time
from pathlib import Path
from typing import Callable, Iterable, NamedTuple

import numpy as np

from radar4dgs.config import to_dict
from radar4dgs.io.atomic import atomic_directory, atomic_save_npz, atomic_write_json
from radar4dgs.io.scene import read_mask_png
from radar4dgs.io.scene_files import FLOW_MASKS, prepared_depth_path
from radar4dgs.motion.config import FlowConfig, flow_settings_at_width
from radar4dgs.motion.lift import lift_flow, reject_flow_outliers
from radar4dgs.motion.object_hints import ObjectHint, frame_hints, moved_in_camera_b, static_hint
from radar4dgs.motion.objects_flow import (
    PairGeometry,
    claimed_predictions,
    fill_rejected_flow,
    object_flow,
    reliable_pixels,
)
from radar4dgs.motion.optical_flow import FlowEstimator, consistency_mask, to_gray
from radar4dgs.motion.rigid import rigid_object_flow
from radar4dgs.motion.truth import gt_scene_flow, image_flow, visible_surface
from radar4dgs.radar.objects import SPLIT_OBJECTS_FILE, optional_radar_objects
from radar4dgs.radar.process import load_radar_dynamics_flags


def frame_pairs(scene, skip_test_frames: bool = True) -> list[tuple[int, int]]:
    """(i, j) pairs of consecutive frames; with ``skip_test_frames`` only training frames, each
    paired with the next training frame (test images stay unseen)."""
    indices = scene.train_indices if skip_test_frames else list(range(len(scene)))
    return list(zip(indices[:-1], indices[1:], strict=True))


def load_depth(scene, index: int, source: str, prepared_dir: str | Path | None,
               depth_dir: str | Path | None = None) -> np.ndarray:
    """(H, W) float64 metric z-depth of frame ``index`` from ``source`` ("prepared" or "oracle")."""
    if source == "oracle":
        return scene.load_optional("gt/depth", index).astype(np.float64)
    if source != "prepared":
        raise ValueError(f"unknown depth source {source!r}; choose 'prepared' or 'oracle'")
    name = scene.frames[index].name
    path = Path(depth_dir) / f"{name}.npy" if depth_dir is not None else prepared_depth_path(prepared_dir, name)
    folder = path.parent
    if not path.is_file():
        raise FileNotFoundError(f"{path}: no prepared depth in {folder} (run the depth front end, "
                                f"`radar4dgs prepare`, first, or set depth_source='oracle' to use the "
                                f"scene's gt/depth)")
    depth = np.load(path, allow_pickle=False)
    if depth.shape != (scene.camera.height, scene.camera.width):
        raise ValueError(f"{path}: depth has shape {depth.shape}, expected "
                         f"{(scene.camera.height, scene.camera.width)}")
    return depth.astype(np.float64)


def load_mask(scene, index: int, source: str, prepared_dir: str | Path | None,
              mask_dir: str | Path | None = None) -> np.ndarray:
    """(H, W) bool dynamic mask of frame ``index`` from ``source`` ("prepared" or "oracle"). The
    prepared masks are those the segmentation stage completed for this stage
    (``<prepared>/masks/flow/``) when it wrote them, else ``<prepared>/masks/``; ``mask_dir`` overrides both."""
    if source == "oracle":
        return scene.load_optional("gt/dynamic_mask", index)
    if source != "prepared":
        raise ValueError(f"unknown mask source {source!r}; choose 'prepared' or 'oracle'")
    folder = Path(mask_dir) if mask_dir is not None else Path(prepared_dir) / "masks"
    if mask_dir is None and (folder / FLOW_MASKS).is_dir():
        folder = folder / FLOW_MASKS
    path = folder / f"{scene.frames[index].name}.png"
    if not path.is_file():
        raise FileNotFoundError(f"{path}: no prepared dynamic mask in {folder} (run the segmentation "
                                f"front end first, or set mask_source='oracle' to use the scene's "
                                f"gt/dynamic_mask)")
    return read_mask_png(path, (scene.camera.height, scene.camera.width))


class FrameInputs(NamedTuple):
    """One frame's inputs: (H, W) float64 depth (None for the oracle flow, which takes the generator's
    own), (H, W) float64 ``base`` the depth stage's own map where the object-depth stage rescaled it
    (else ``depth`` itself), and (H, W) bool dynamic mask."""

    depth: np.ndarray | None
    base: np.ndarray | None
    mask: np.ndarray


def frame_inputs(scene, index: int, config: FlowConfig, prepared_dir: str | Path | None,
                 depth_dir: str | Path | None, mask_dir: str | Path | None) -> FrameInputs:
    """The :class:`FrameInputs` of frame ``index`` from the config's sources."""
    if config.method == "oracle":
        return FrameInputs(None, None, load_mask(scene, index, config.mask_source, prepared_dir, mask_dir))
    depth = load_depth(scene, index, config.depth_source, prepared_dir, depth_dir)
    mask = load_mask(scene, index, config.mask_source, prepared_dir, mask_dir)
    base = depth
    if config.depth_source == "prepared" and depth_dir is None and prepared_dir is not None:
        stage_dir = Path(prepared_dir) / "depth"
        if prepared_depth_path(prepared_dir, scene.frames[index].name).parent != stage_dir:
            base = load_depth(scene, index, "prepared", None, stage_dir)
    return FrameInputs(depth, base, mask)


def object_scale(depth: np.ndarray, base: np.ndarray) -> np.ndarray:
    """(H, W) ``depth / base`` where both are finite and positive, else 1: the object-depth stage's scale."""
    with np.errstate(invalid="ignore", divide="ignore"):
        scale = depth / base
    return np.where(np.isfinite(scale) & (scale > 0), scale, 1.0)


def _with_progress(pairs: list[tuple[int, int]], progress: bool | Callable[[Iterable], Iterable]) -> Iterable:
    """``pairs`` wrapped in a tqdm bar (``progress`` True) or the caller's wrapper (a callable)."""
    iterator: Iterable = pairs
    if progress is True:
        from tqdm import tqdm

        iterator = tqdm(pairs, desc="flow", unit="pair")
    elif callable(progress):
        iterator = progress(pairs)
    return iterator


class PairFlow(NamedTuple):
    """One pair's pseudo scene flow (:func:`pair_scene_flow`)."""

    forward: np.ndarray  # (H, W, 2) float32 flow i -> j after the object steps and the fill
    consistent: np.ndarray  # (H, W) bool forward-backward consistent
    points_i: np.ndarray  # (M, 3) float64 world points of the kept pixels at time i
    points_j: np.ndarray  # (M, 3) the same points at time j
    pixels: np.ndarray  # (M, 2) (u, v) of the kept pixels
    reliable: np.ndarray  # (H, W) bool not dropped as a photometric failure
    models: dict[str, int]  # components per chosen model (objects_flow.MODELS, "no_radar")
    filled: np.ndarray  # (H, W) bool rejected mask pixels whose flow was filled


def pair_scene_flow(config: FlowConfig, image_i: np.ndarray, image_j: np.ndarray, forward: np.ndarray,
                    backward: np.ndarray, depth_i: np.ndarray, depth_j: np.ndarray, mask_i: np.ndarray,
                    mask_j: np.ndarray, K: np.ndarray, world_to_cam_i: np.ndarray, world_to_cam_j: np.ndarray,
                    hints_i: list[ObjectHint] | None = None, hints_j: list[ObjectHint] | None = None,
                    dt: float = 0.0, base_i: np.ndarray | None = None,
                    base_j: np.ndarray | None = None, fill_hints_i: list[ObjectHint] | None = None) -> PairFlow:
    """The pseudo scene flow of one pair i -> j from its two dense flows (module doc).

    Args:
        config: options (object steps, consistency, failure drops, depth edges, target mask, outliers).
        image_i, image_j: (H, W, 3) RGB uint8. forward, backward: (H, W, 2) dense flow i -> j, j -> i.
        depth_i, depth_j: (H, W) metric z-depth. mask_i, mask_j: (H, W) bool dynamic masks.
        K: (3, 3). world_to_cam_i, world_to_cam_j: (4, 4).
        hints_i, hints_j: the radar objects of frames i and j (None or empty: no radar guidance).
        dt: time of j minus time of i (s).
        base_i, base_j: the depth stage's maps of i and j where the object-depth stage rescaled
            ``depth_i``, ``depth_j`` (:class:`FrameInputs`); with both and FlowConfig.one_scale_per_pair,
            a match's depth is ``base_j``'s times frame i's scale ``depth_i / base_i`` (:func:`.lift.lift_flow`).
        fill_hints_i: frame i's split radar objects (``FlowConfig.fill_split_objects``): each of them that
            ``hints_i`` lacks (same projected returns) gives its rejected pixels its prediction.
    """
    gray_i, gray_j = to_gray(image_i), to_gray(image_j)
    failed = np.zeros(mask_i.shape, dtype=bool)
    models: dict[str, int] = {}
    predicted = target_depth = None
    components_i = mask_i  # before the static returns' parts leave it: the components the objects claimed
    if config.radar_guided:
        geometry = PairGeometry(depth_i, K, world_to_cam_i, world_to_cam_j, dt)
        forward, failed, models, static, predicted, displacement = object_flow(
            gray_i, gray_j, forward, mask_i, hints_i or [], geometry, config)
        if config.radar_target_depth:
            target_depth = radar_target_depth(displacement, geometry)
        backward = object_flow(gray_j, gray_i, backward, mask_j, hints_j or [],
                               PairGeometry(depth_j, K, world_to_cam_j, world_to_cam_i, -dt), config).flow
        mask_i = mask_i & ~static  # the static returns' part of a mask component is not a mover's
    elif config.rigid_objects:
        rigid = (config.rigid_search, config.rigid_accept, config.rigid_min_pixels, config.rigid_wide_search)
        forward = rigid_object_flow(gray_i, gray_j, forward, mask_i, *rigid)
        backward = rigid_object_flow(gray_j, gray_i, backward, mask_j, *rigid)
    consistent = consistency_mask(forward, backward, config.consistency_alpha, config.consistency_beta)
    reliable = reliable_pixels(gray_i, gray_j, forward, mask_i, failed, config)
    lift_j, scale = depth_j, None
    if config.one_scale_per_pair and base_i is not None and base_j is not None:
        lift_j, scale = base_j, object_scale(depth_i, base_i)
    points_i, points_j, pixels = lift_flow(
        forward, depth_i, lift_j, K, world_to_cam_i, world_to_cam_j,
        mask_i & consistent & reliable, config.depth_edge_tolerance,
        mask_j if config.require_dynamic_target else None, scale, target_depth,
        config.radar_target_depth_tolerance)
    if config.outlier_filter:
        keep = reject_flow_outliers(points_i, points_j, pixels, mask_i, config.outlier_min_deviation,
                                    config.outlier_mad_factor, config.outlier_min_points,
                                    config.outlier_neighbours)
        points_i, points_j, pixels = points_i[keep], points_j[keep], pixels[keep]
    lifted = np.zeros(mask_i.shape, dtype=bool)
    lifted[pixels[:, 1].astype(np.int64), pixels[:, 0].astype(np.int64)] = True
    rejected = mask_i & ~(consistent & reliable)
    forward, filled = fill_rejected_flow(forward, mask_i, lifted, rejected, config.fill_min_lifted,
                                         config.fill_max_distance)
    if config.fill_radar_prediction and predicted is not None:
        # Only the stored map changes (nothing rejected is lifted): where no lifted neighbour could fill
        # a rejected pixel, its object's tracked velocity is a better guess than the motion that failed.
        take = rejected & ~filled & np.isfinite(predicted).all(axis=-1)
        forward[take] = predicted[take]
        filled |= take
        # A second mover whose returns the first one's velocity fit left as outliers has an object only
        # among the split objects (an oncoming car passing the lead car within the clustering radius).
        # Its rejected pixels take its prediction even where the fill or the first object's gave one:
        # those came from the other mover.
        known = [hint.uv for hint in hints_i or []]
        further = ([not any(np.array_equal(hint.uv, uv) for uv in known) for hint in fill_hints_i]
                   if config.fill_split_objects and fill_hints_i else [])
        if any(further) and rejected.any():
            guess = claimed_predictions(components_i, fill_hints_i,
                                        PairGeometry(depth_i, K, world_to_cam_i, world_to_cam_j, dt), config, further)
            take = rejected & np.isfinite(guess).all(axis=-1)
            forward[take] = guess[take]
            filled |= take
    return PairFlow(forward, consistent, points_i, points_j, pixels, reliable, models, filled)


def radar_target_depth(displacement: np.ndarray, geometry: PairGeometry) -> np.ndarray:
    """(H, W) z-depth in camera b of each pixel of frame a moved by its (H, W, 3) world ``displacement`` (NaN
    where it has none or no valid depth; ``FlowConfig.radar_target_depth``)."""
    out = np.full(geometry.depth.shape, np.nan)
    rows, cols = np.nonzero(np.isfinite(displacement).all(axis=-1))
    z = geometry.depth[rows, cols]
    valid = np.isfinite(z) & (z > 0)
    rows, cols = rows[valid], cols[valid]
    if len(rows):
        moved = moved_in_camera_b(np.stack([cols, rows], axis=1), z[valid], geometry.K,
                                  geometry.world_to_cam_a, geometry.world_to_cam_b, displacement[rows, cols])
        out[rows, cols] = moved[:, 2]
    return out


def oracle_pair_flow(scene, index_i: int, index_j: int, mask_i: np.ndarray) -> PairFlow:
    """The generator's true pseudo scene flow of pair i -> j (``FlowConfig.method="oracle"``, an
    upper bound for ablations): every pixel of ``mask_i`` (H, W) bool whose true surface point
    (:func:`radar4dgs.motion.truth.gt_scene_flow`) is still the visible surface in frame j, at its
    true positions at both times. No flow estimate, object step, consistency check or outlier
    filter: the depth and motion are the truth whatever ``depth_source`` says."""
    world_i, world_j, valid = gt_scene_flow(scene, index_i, index_j)
    # The flow is the truth wherever the point is known, occluded in frame j or not; only the
    # pixels still visible there become pairs.
    forward, _ = image_flow(world_j, valid, scene, index_j)
    visible, _ = visible_surface(world_j.reshape(-1, 3), scene, index_j)
    consistent = valid & visible.reshape(valid.shape)
    kept = mask_i & consistent
    rows, cols = np.nonzero(kept)
    return PairFlow(forward.astype(np.float32), consistent, world_i[kept], world_j[kept],
                    np.stack([cols, rows], axis=1).astype(np.float64), np.ones_like(consistent), {},
                    np.zeros_like(consistent))


def prepare_flow(scene, prepared_dir: str | Path, config: FlowConfig | None = None,
                 depth_dir: str | Path | None = None, mask_dir: str | Path | None = None,
                 progress: bool | Callable[[Iterable], Iterable] = False) -> dict:
    """Compute the pseudo scene flow of every frame pair and write ``<prepared>/flow/`` (module doc),
    replacing it atomically.

    Args:
        scene: a loaded :class:`radar4dgs.io.scene.Scene`.
        prepared_dir: the prepared folder (depth and masks are read from it, flow/ written into it).
        config: options (default :class:`FlowConfig`).
        depth_dir, mask_dir: override ``<prepared>/depth`` and ``<prepared>/masks`` (sources "prepared").
        progress: True for a tqdm bar, or a callable wrapping an iterable (the prepare command's).
    Returns:
        the summary dict of :func:`write_flow`.
    """
    prepared = Path(prepared_dir)
    prepared.mkdir(parents=True, exist_ok=True)
    with atomic_directory(prepared / "flow", overwrite=True) as out:
        return write_flow(scene, out, config, prepared, depth_dir, mask_dir, progress)


def run_flow_stage(scene, out_dir: Path, config: FlowConfig, progress: Callable[[Iterable], Iterable]) -> dict:
    """``radar4dgs.apps.prepare`` stage runner: ``out_dir`` is the (temporary) ``<prepared>/flow`` folder,
    so depth and masks are read from its parent, the prepared folder."""
    summary = write_flow(scene, Path(out_dir), config, Path(out_dir).parent, progress=progress)
    result = {"pairs": summary["pairs"], "points": sum(p["points"] for p in summary["per_pair"]),
              "models": summary["models"]}
    if summary["radar_objects"] == "used" and summary["split_objects"].startswith("unavailable"):
        result["note"] = (f"no second movers' predictions, {summary['split_objects']}; "
                          f"`--only radar flow --force` adds them")
    return result


def write_flow(scene, out_dir: str | Path, config: FlowConfig | None = None,
               prepared_dir: str | Path | None = None, depth_dir: str | Path | None = None,
               mask_dir: str | Path | None = None,
               progress: bool | Callable[[Iterable], Iterable] = False) -> dict:
    """Write the per-pair ``<frame>.npz`` files, ``summary.json`` and ``config.json`` into ``out_dir``
    (not atomically as a whole: :func:`prepare_flow` wraps it in a temporary folder).

    Returns:
        a summary dict (pairs, kept points per pair, consistent fraction, flow seconds per call).
    """
    config = flow_settings_at_width(config or FlowConfig(), scene.camera.width)
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    pairs = frame_pairs(scene, config.skip_test_frames)
    cache: dict[int, FrameInputs] = {}
    # Load the first frame up front, so a missing input folder fails before any flow is computed.
    if pairs:
        first = pairs[0][0]
        cache[first] = frame_inputs(scene, first, config, prepared_dir, depth_dir, mask_dir)
    estimator = None if config.method == "oracle" else FlowEstimator(config)
    K = scene.camera.K
    objects, objects_note = _radar_objects(scene, prepared_dir, config)
    split_objects, split_note = _split_objects(scene, prepared_dir, config, objects)
    hints: dict[int, list[ObjectHint]] = {}
    iterator = _with_progress(pairs, progress)
    per_pair = []
    totals: dict[str, int] = {}
    flow_seconds = 0.0
    for i, j in iterator:
        for k in (i, j):
            if k not in cache:
                cache[k] = frame_inputs(scene, k, config, prepared_dir, depth_dir, mask_dir)
        depth_i, base_i, mask_i = cache.pop(i)  # pairs are visited in order; frame i is not needed again
        depth_j, base_j, mask_j = cache[j]
        if estimator is None:
            result = oracle_pair_flow(scene, i, j, mask_i)
        else:
            image_i, image_j = scene.load_image(i), scene.load_image(j)
            started = time.perf_counter()
            forward = estimator(image_i, image_j)
            backward = estimator(image_j, image_i)
            flow_seconds += time.perf_counter() - started
            if objects is not None:
                for k in (i, j):
                    if k not in hints:
                        hints[k] = frame_hints(scene, k, objects[k]) + static_hints(scene, k, objects[k], config,
                                                                                   prepared_dir)
            result = pair_scene_flow(
                config, image_i, image_j, forward, backward, depth_i, depth_j, mask_i, mask_j, K,
                scene.world_to_camera(i), scene.world_to_camera(j), hints.pop(i, None), hints.get(j),
                scene.frames[j].timestamp - scene.frames[i].timestamp, base_i, base_j,
                None if split_objects is None else frame_hints(scene, i, split_objects[i]))
        name = scene.frames[i].name
        atomic_save_npz(out / f"{name}.npz", dict(
            flow=result.forward.astype(np.float32), consistent=result.consistent, reliable=result.reliable,
            filled=result.filled,
            points_i=result.points_i.astype(np.float32), points_j=result.points_j.astype(np.float32),
            pixels=result.pixels.astype(np.float32), index_i=np.int64(i), index_j=np.int64(j),
            timestamp_i=np.float64(scene.frames[i].timestamp),
            timestamp_j=np.float64(scene.frames[j].timestamp)))
        for model, count in result.models.items():
            totals[model] = totals.get(model, 0) + count
        per_pair.append({"frame": name, "index_i": i, "index_j": j, "points": int(len(result.points_i)),
                         "dynamic_pixels": int(mask_i.sum()),
                         "consistent_fraction": float(result.consistent.mean()),
                         "dropped_pixels": int((mask_i & result.consistent & ~result.reliable).sum()),
                         "filled_pixels": int(result.filled.sum()),
                         "models": result.models})
    summary = {"pairs": len(pairs), "method": config.method,
               "flow_seconds_per_call": flow_seconds / max(2 * len(pairs), 1),
               "depth_source": config.depth_source, "mask_source": config.mask_source,
               "radar_objects": objects_note, "split_objects": split_note, "models": totals, "per_pair": per_pair}
    atomic_write_json(out / "summary.json", summary)
    atomic_write_json(out / "config.json", to_dict(config))
    return summary


def _radar_objects(scene, prepared_dir: str | Path | None, config: FlowConfig) -> tuple[list | None, str]:
    """The per-frame radar objects for the radar-guided step (None when off or unavailable) and a
    note for the summary. A missing or stale objects.json falls back to the unguided step: the flow
    stage must still run on a prepared folder from before the radar objects existed."""
    if not config.radar_guided:
        return None, "off (radar_guided=False)"
    objects, why = optional_radar_objects(prepared_dir, len(scene))
    return objects, "used" if objects is not None else f"unavailable: {why}"


def _split_objects(scene, prepared_dir: str | Path | None, config: FlowConfig, objects: list | None
                   ) -> tuple[list | None, str]:
    """The split radar objects for the fill of rejected pixels (``FlowConfig.fill_split_objects``; None
    when off, without radar objects, or where the radar stage wrote none: a prepared folder from before
    2026-12-05) and a note for the summary."""
    if objects is None or not (config.fill_radar_prediction and config.fill_split_objects):
        return None, "off"
    split, why = optional_radar_objects(prepared_dir, len(scene), SPLIT_OBJECTS_FILE)
    return split, "used" if split is not None else f"unavailable: {why}"


def static_hints(scene, index: int, objects, config: FlowConfig, prepared_dir: str | Path) -> list[ObjectHint]:
    """[frame ``index``'s static radar returns as one hint] (:func:`.object_hints.static_hint`) when
    ``FlowConfig.radar_static_min_returns`` asks for them and the radar stage flagged them, else []."""
    if config.radar_static_min_returns <= 0:
        return []
    xyz = scene.load_radar(index).xyz
    dynamic, _ = load_radar_dynamics_flags(Path(prepared_dir) / "radar", scene.frames[index].name, len(xyz))
    hint = static_hint(xyz, scene.radar_to_camera(index), scene.camera.K, objects, dynamic)
    return [] if hint is None else [hint]


def load_flow_pairs(prepared_dir: str | Path) -> list[dict[str, np.ndarray]]:
    """Every ``<prepared>/flow/*.npz`` as a dict of arrays, in frame order (``index_i``)."""
    folder = Path(prepared_dir) / "flow"
    if not folder.is_dir():
        raise FileNotFoundError(f"{folder}: no prepared flow (run prepare_flow / `radar4dgs fit-motion` "
                                f"computes it when missing)")
    pairs = []
    for path in sorted(folder.glob("*.npz")):
        with np.load(path, allow_pickle=False) as data:
            pairs.append({key: data[key] for key in data.files})
    return sorted(pairs, key=lambda p: int(p["index_i"]))
