"""Radar-guided flow of dynamic objects (``FlowConfig.radar_guided``; DESIGN.md "Realistic motion").

At 10 Hz a car passing one lane away moves 70-200 px per frame and a lead car the ego closes in on
grows in the image: dense flow (DIS) and the +-``rigid_search`` translation of :mod:`.rigid` both
fail there, and often fail alike forwards and backwards, so the consistency check keeps the error.
Per connected component of the dynamic mask of frame a (one object):

1. its radar object: the object whose projected returns land on it (:mod:`.object_hints`); a
   component claimed by objects moving differently (two movers overlapping in the image) is split
   between them by their radar predictions and returns (:func:`component_owners`), and with
   ``radar_static_min_returns`` a mover's component that static returns land on is split between it
   and the static world (whose part keeps the dense flow and is not lifted);
2. candidates: the dense flow, today's translation (:func:`.rigid.component_translation`), the
   radar prediction (the pixels' 3D points moved by velocity x dt, projected into frame b) and an
   affine warp matched around the prediction (:mod:`.warp_match`: translation search, then ECC);
3. the rigid candidate with the least photometric error wins (the radar prediction unless another
   beats ``rigid_accept`` x its error), and the dense flow if its error is below
   ``radar_dense_margin`` x that one's; a radar prediction taking the object out of view wins (see
   :func:`choose_candidate`); with ``radar_dense_agreement`` > 0, pixels whose dense flow agrees
   with the winner within that many px keep it. A radar object with ``radar_rigid_min_returns``
   returns or more takes the best rigid candidate whatever the dense flow's error, but each pixel
   the dense flow explains clearly better locally keeps it (:func:`rigid_motion`).

Components without a radar object get today's translation step unchanged. After the choice,
:func:`reliable_pixels` marks the pixels the flow cannot be trusted on: components whose motion
explains the images no better than chance (:func:`no_better_than_chance`), and pixels with a
large local photometric error.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import NamedTuple

import numpy as np

from radar4dgs.motion.config import FlowConfig
from radar4dgs.motion.object_hints import (
    STATIC_TRACK,
    ObjectHint,
    component_claims,
    landing_labels,
    nearest_labels,
    passes_camera,
    predicted_targets,
    returns_on,
    split_by_returns,
)
from radar4dgs.motion.rigid import component_translation, object_translation
from radar4dgs.motion.sampling import bilinear_sample
from radar4dgs.motion.warp_match import (
    affine_targets,
    fit_similarity,
    mean_abs_error,
    refine_affine,
    search_translation,
    shape_change,
)

MODELS = ("dense", "translation", "radar", "matched")


class ObjectFlow(NamedTuple):
    """:func:`object_flow`'s result: ``flow`` (H, W, 2) float32; ``failed`` (H, W) bool pixels of components
    whose chosen motion explains the images no better than chance (to drop); ``counts`` components per model
    ("no_radar": today's translation step, no radar object; "static": parts given to the static returns);
    ``static`` (H, W) bool mask pixels given to the static returns (not movers: not to lift; they keep the dense
    flow); ``predicted`` (H, W, 2) float32 each object pixel's radar-predicted motion, NaN where its object has
    none; ``displacement`` (H, W, 3) float32 its object's world displacement over the pair (velocity x dt)."""

    flow: np.ndarray
    failed: np.ndarray
    counts: dict[str, int]
    static: np.ndarray
    predicted: np.ndarray
    displacement: np.ndarray


@dataclass(frozen=True)
class PairGeometry:
    """What the radar prediction needs of a pair a -> b.

    Attributes:
        depth: (H, W) z-depth of frame a (m; NaN/inf/<= 0 invalid).
        K: (3, 3). world_to_cam_a, world_to_cam_b: (4, 4).
        dt: time of b minus time of a (s; negative for the backward flow).
    """

    depth: np.ndarray
    K: np.ndarray
    world_to_cam_a: np.ndarray
    world_to_cam_b: np.ndarray
    dt: float


def interior(component: np.ndarray) -> np.ndarray:
    """(H, W) bool ``component`` without its 1-px rim, unless that removes half of it. Rim pixels
    mix the object with the background (anti-aliasing, segmentation masks bleeding onto the road),
    and the background differs between the frames. Matching on the interior: 2D EPE on synthetic
    seeds 1-3 0.33/0.47/0.69 -> 0.30/0.39/0.59 px."""
    import cv2

    core = cv2.erode(component.astype(np.uint8), np.ones((3, 3), np.uint8)) > 0
    return core if core.sum() * 2 >= component.sum() else component


def matched_targets(gray_a: np.ndarray, gray_b: np.ndarray, component: np.ndarray, pixels: np.ndarray,
                    predicted: np.ndarray, config: FlowConfig) -> np.ndarray | None:
    """(N, 2) targets of the warp matched around the prediction, or None when matching fails.

    The prediction's similarity fit, shifted by the translation search, then refined by ECC
    (affine) when ECC keeps the shape within ``radar_max_shape_change`` and lowers the error: on a
    nearly uniform car ECC can wander off into a shear.

    Args:
        component: (H, W) bool, the object in a. pixels: (N, 2) its (u, v). predicted: (N, 2) targets.
    """
    prior = fit_similarity(pixels, predicted)
    if prior is None or abs(np.linalg.det(prior[:, :2])) < 1e-3:
        return None
    core = interior(component)
    found = search_translation(gray_a, gray_b, core, prior, config.radar_search, config.radar_min_inside)
    if found is None:
        return None
    targets = affine_targets(found, pixels)
    refined = refine_affine(gray_a, gray_b, core, found, config.radar_ecc_iterations)
    if refined is not None and shape_change(refined, prior) <= config.radar_max_shape_change:
        better = affine_targets(refined, pixels)
        if (mean_abs_error(gray_a, gray_b, pixels, better, config.radar_min_inside)
                < mean_abs_error(gray_a, gray_b, pixels, targets, config.radar_min_inside)):
            targets = better
    return targets


def candidate_targets(gray_a: np.ndarray, gray_b: np.ndarray, component: np.ndarray, pixels: np.ndarray,
                      dense: np.ndarray, hint: ObjectHint, geometry: PairGeometry,
                      config: FlowConfig) -> dict[str, np.ndarray]:
    """{model: (N, 2) targets in b} of one object's (N, 2) pixels; ``dense`` (N, 2) its dense flow."""
    candidates = {"dense": pixels + dense}
    found = (object_translation(gray_a, gray_b, pixels, np.median(dense, axis=0), config.rigid_search)
             if config.rigid_objects else None)
    if found is not None:
        candidates["translation"] = pixels + found[0]
    depth = geometry.depth[pixels[:, 1], pixels[:, 0]]
    predicted = predicted_targets(pixels, depth, geometry.K, geometry.world_to_cam_a, geometry.world_to_cam_b,
                                  hint.velocity * geometry.dt)
    if predicted is None or not np.isfinite(predicted).all():
        return candidates
    candidates["radar"] = predicted
    if passes_camera(predicted, geometry.K).any():
        return candidates  # leaving past the camera: nothing in b to match it against
    matched = matched_targets(gray_a, gray_b, component, pixels, predicted, config)
    if matched is not None:
        candidates["matched"] = matched
    return candidates


def choose_candidate(gray_a: np.ndarray, gray_b: np.ndarray, pixels: np.ndarray,
                     candidates: dict[str, np.ndarray], accept: float, min_inside: float,
                     dense_margin: float = 1.0 / 0.9) -> tuple[str, float]:
    """(model, its mean abs grey error): the candidate explaining the images best.

    With a radar prediction, the rigid candidates ("radar", "translation", "matched") are compared
    first: "radar" over a translation or match unless that one's error is below ``accept`` x the
    radar prediction's (a search finds SOME shift with a lower error on a car's uniform paint; rush
    5 Hz tuning seed 214: a match 13 px off the truth scored 10.6 grey levels against the 2.8 px
    prediction's 10.9), since the prediction carries the tracked velocity. The dense flow then
    wins with an error below ``dense_margin`` x the chosen one's (``FlowConfig.radar_dense_margin``;
    the default 1/0.9 keeps it unless a rigid candidate beats 0.9 x its error). Without a radar
    prediction the dense flow stays unless another candidate's error is below ``accept`` x its own
    (the dense flow is finer where right).

    A radar prediction that takes the object out of view (a car passing the camera) cannot be
    checked in the images and wins: the candidates that keep it in view are the failures (DIS
    gave 250 px of error on a car leaving the view by 216 px). Its pixels that stay in view still
    face the per-pixel check (:func:`reliable_pixels`), and those that leave are never lifted.
    """
    errors = {name: mean_abs_error(gray_a, gray_b, pixels, targets, min_inside)
              for name, targets in candidates.items()}
    if "radar" not in errors:
        best = min(errors, key=errors.__getitem__)
        if best != "dense" and not errors[best] < accept * errors["dense"]:
            best = "dense"
        return best, errors[best]
    if errors["radar"] == np.inf:
        return "radar", np.inf
    rigid = {name: error for name, error in errors.items() if name != "dense"}
    best = min(rigid, key=rigid.__getitem__)
    if best != "radar" and not rigid[best] < accept * rigid["radar"]:
        best = "radar"
    if "dense" in errors and errors["dense"] < dense_margin * errors[best]:
        best = "dense"
    return best, errors[best]


def object_flow(gray_a: np.ndarray, gray_b: np.ndarray, flow: np.ndarray, mask: np.ndarray,
                hints: list[ObjectHint], geometry: PairGeometry, config: FlowConfig) -> ObjectFlow:
    """Flow a -> b with each object's motion chosen among candidates (module doc).

    Args:
        gray_a, gray_b: (H, W) uint8. flow: (H, W, 2) dense flow a -> b. mask: (H, W) bool
        dynamic mask of a. hints: a's radar objects, and its static returns as one hint of track
        :data:`STATIC_TRACK` (``FlowConfig.radar_static_min_returns``). geometry: the pair.
    Returns:
        :class:`ObjectFlow` (the flow is a copy).
    """
    import cv2

    out = np.array(flow, dtype=np.float32, copy=True)
    failed = np.zeros(mask.shape, dtype=bool)
    static = np.zeros(mask.shape, dtype=bool)
    predicted = np.full(out.shape, np.nan, dtype=np.float32)
    displacement = np.full((*mask.shape, 3), np.nan, dtype=np.float32)
    counts = dict.fromkeys((*MODELS, "no_radar", "static"), 0)
    count, labels = cv2.connectedComponents(np.asarray(mask, dtype=np.uint8), connectivity=8)
    static_returns = next((hint for hint in hints if hint.track == STATIC_TRACK), None)
    hints = [hint for hint in hints if hint.track != STATIC_TRACK]
    # Where returns vote, shared by the objects' claims and the static returns.
    nearest = nearest_labels(labels, config.radar_association_radius) if hints and count > 1 else None
    claims = {} if nearest is None else component_claims(nearest, hints, config.radar_min_returns)
    static_labels = (landing_labels(static_returns.uv, nearest)
                     if static_returns is not None and config.radar_static_min_returns > 0 and claims else None)
    for label in range(1, count):
        component = labels == label
        rows, cols = np.nonzero(component)
        if len(rows) < config.rigid_min_pixels:
            continue
        pixels = np.stack([cols, rows], axis=1)
        dense = flow[rows, cols].astype(np.float64)
        if label not in claims:
            counts["no_radar"] += 1
            shift = (component_translation(gray_a, gray_b, pixels, dense, config.rigid_search, config.rigid_accept,
                                           config.rigid_wide_search, config.rigid_min_pixels)
                     if config.rigid_objects else None)
            motion = dense if shift is None else np.broadcast_to(shift, dense.shape)
            out[rows, cols] = motion
            failed[rows, cols] = no_better_than_chance(gray_a, gray_b, pixels, pixels + motion, config)
            continue
        on_component = None
        if static_labels is not None and (static_labels == label).sum() >= config.radar_static_min_returns:
            on_component = returns_on(static_returns, static_labels, label)
        owner, objects = component_owners(gray_a, gray_b, component, pixels, claims[label], geometry, config,
                                          on_component)
        for k, hint in enumerate(objects):
            part = owner == k
            if hint.track == STATIC_TRACK:
                static[rows[part], cols[part]] = True
                counts["static"] += int(part.any())
                continue
            if part.sum() < config.rigid_min_pixels:
                continue
            if len(objects) == 1:
                part_mask = component
            else:
                part_mask = np.zeros_like(component)
                part_mask[rows[part], cols[part]] = True
            candidates = candidate_targets(gray_a, gray_b, part_mask, pixels[part], dense[part], hint, geometry,
                                           config)
            if "radar" in candidates:
                predicted[rows[part], cols[part]] = candidates["radar"] - pixels[part]
                displacement[rows[part], cols[part]] = hint.velocity * geometry.dt
            if 0 < config.radar_rigid_min_returns <= len(hint.uv) and "radar" in candidates:
                model, motion = rigid_motion(gray_a, gray_b, part_mask, pixels[part], candidates, config)
            else:
                model, _ = choose_candidate(gray_a, gray_b, pixels[part], candidates, config.rigid_accept,
                                            config.radar_min_inside, config.radar_dense_margin)
                motion = candidates[model] - pixels[part]
            counts[model] += 1
            if config.radar_dense_agreement > 0:
                agree = np.linalg.norm(dense[part] - motion, axis=1) <= config.radar_dense_agreement
                motion = np.where(agree[:, None], dense[part], motion)
            out[rows[part], cols[part]] = motion
            failed[rows[part], cols[part]] = no_better_than_chance(gray_a, gray_b, pixels[part],
                                                                   pixels[part] + motion, config)
    return ObjectFlow(out, failed, counts, static, predicted, displacement)


def rigid_motion(gray_a: np.ndarray, gray_b: np.ndarray, component: np.ndarray, pixels: np.ndarray,
                 candidates: dict[str, np.ndarray], config: FlowConfig) -> tuple[str, np.ndarray]:
    """(the rigid model chosen, (N, 2) motion) of an object the radar sees well
    (``FlowConfig.radar_rigid_min_returns``): the rigid candidates compared as in
    :func:`choose_candidate` without the dense flow, and each pixel whose local photometric error
    under the dense flow is below ``radar_pixel_dense_ratio`` x that under the rigid motion keeping
    its dense flow. A rigid motion taking the object out of view is kept whole (nothing to compare).

    Args:
        component: (H, W) bool the object. pixels: (N, 2) its (u, v). candidates: :func:`candidate_targets`
            (always with the dense flow).
    """
    rigid = {name: targets for name, targets in candidates.items() if name != "dense"}
    model, error = choose_candidate(gray_a, gray_b, pixels, rigid, config.rigid_accept, config.radar_min_inside)
    motion = rigid[model] - pixels
    if not np.isfinite(error):
        return model, motion
    dense_error = pixel_errors(gray_a, gray_b, component, pixels, candidates["dense"], config.pixel_error_window)
    rigid_error = pixel_errors(gray_a, gray_b, component, pixels, rigid[model], config.pixel_error_window)
    with np.errstate(invalid="ignore"):
        clearer = dense_error < config.radar_pixel_dense_ratio * rigid_error  # NaN: no evidence, rigid stays
    motion[clearer] = candidates["dense"][clearer] - pixels[clearer]
    return model, motion


def pixel_errors(gray_a: np.ndarray, gray_b: np.ndarray, component: np.ndarray, pixels: np.ndarray,
                 targets: np.ndarray, window: int) -> np.ndarray:
    """(N,) :func:`local_photometric_error` of an object's (N, 2) ``pixels`` moved to (N, 2)
    ``targets`` (NaN targets count as far outside b), scored over the (H, W) bool ``component``."""
    flow = np.zeros((*component.shape, 2))
    flow[pixels[:, 1], pixels[:, 0]] = targets - pixels
    return local_photometric_error(gray_a, gray_b, np.nan_to_num(flow, nan=1e6), component,
                                   window)[pixels[:, 1], pixels[:, 0]]


def component_owners(gray_a: np.ndarray, gray_b: np.ndarray, component: np.ndarray, pixels: np.ndarray,
                     claims: list[ObjectHint], geometry: PairGeometry, config: FlowConfig,
                     static_returns: ObjectHint | None = None) -> tuple[np.ndarray, list[ObjectHint]]:
    """Which radar object each of a component's (N, 2) pixels moves with: (N,) indices into the
    returned objects. One object unless ``radar_split_velocity`` > 0 and the component is claimed
    by objects whose velocities differ by more than that (m/s, planar); two radar clusters of one
    car move alike and stay one part, so a car is not matched in halves. ``static_returns`` (the
    static returns landing on the component, velocity zero) join as one more claimant when the
    first object moves faster than ``radar_split_velocity``: a parked car beside a mover that the
    mask runs onto is the static world's, not the mover's (hard report seed 212: 266 pairs lifted on
    such a car, moved 2.4 m a frame with the mover, against 43 without the radar-completed masks).

    When split, each pixel goes to the object whose radar prediction explains its neighbourhood best
    (:func:`local_photometric_error` over ``pixel_error_window``) when that error is below
    ``rigid_accept`` x the one of the object of its nearest return in 3-D
    (:func:`split_by_returns`), and to the latter otherwise: a car's returns cluster on the side
    facing the radar, so the far end of a car 4 m long can lie nearer another mover's returns, while
    its texture follows its own motion. Where the images cannot tell (uniform paint), the returns do.
    """
    first = claims[0]
    objects = [first] + [hint for hint in claims[1:] if config.radar_split_velocity > 0
                         and hint.camera is not None and first.camera is not None
                         and np.linalg.norm(hint.velocity[:2] - first.velocity[:2]) > config.radar_split_velocity]
    if (static_returns is not None and first.camera is not None and len(static_returns.uv)
            and np.linalg.norm(first.velocity[:2]) > config.radar_split_velocity):
        objects.append(static_returns)
    if len(objects) == 1:
        return np.zeros(len(pixels), dtype=np.int64), objects
    depth = geometry.depth[pixels[:, 1], pixels[:, 0]]
    owner = split_by_returns(pixels, depth, geometry.K, objects)
    errors = np.full((len(objects), len(pixels)), np.nan)
    for k, hint in enumerate(objects):
        targets = predicted_targets(pixels, depth, geometry.K, geometry.world_to_cam_a, geometry.world_to_cam_b,
                                    hint.velocity * geometry.dt)
        if targets is None:
            continue
        errors[k] = pixel_errors(gray_a, gray_b, component, pixels, targets, config.pixel_error_window)
    scored = np.isfinite(errors).all(axis=0)
    best = np.argmin(np.where(np.isfinite(errors), errors, np.inf), axis=0)
    nearest_error = errors[owner, np.arange(len(pixels))]
    clearer = scored & (errors[best, np.arange(len(pixels))] < config.rigid_accept * nearest_error)
    return np.where(clearer, best, owner), objects


def no_better_than_chance(gray_a: np.ndarray, gray_b: np.ndarray, pixels: np.ndarray, targets: np.ndarray,
                          config: FlowConfig) -> bool:
    """Whether an object's motion explains the images no better than chance
    (``FlowConfig.max_component_error_ratio``, ``min_component_error``): its mean absolute grey
    error against that of the same grey values paired at random (a fixed permutation).

    Too little of the object left in view to judge is not a failure: lifting needs the target
    inside frame b anyway, and the pixels that stay in view face the per-pixel check.

    Args:
        pixels: (N, 2) integer (u, v) in a; targets: (N, 2) in b.
    """
    if config.max_component_error_ratio <= 0:
        return False
    values, inside = bilinear_sample(gray_b, np.nan_to_num(targets, nan=-1.0))
    if inside.sum() < max(config.radar_min_inside * len(pixels), config.rigid_min_pixels):
        return False
    source = gray_a[pixels[inside, 1], pixels[inside, 0]].astype(np.float64)
    error = float(np.abs(source - values[inside]).mean())
    chance = float(np.abs(source - np.random.default_rng(0).permutation(values[inside])).mean())
    return error > config.min_component_error and error > config.max_component_error_ratio * chance


def local_photometric_error(gray_a: np.ndarray, gray_b: np.ndarray, flow: np.ndarray, mask: np.ndarray,
                            window: int) -> np.ndarray:
    """(H, W) float64 mean |a(x) - b(x + flow(x))| over the masked pixels of a ``window`` x ``window``
    neighbourhood whose targets lie inside b (NaN where there are none). One pixel's grey
    difference is noise; a neighbourhood's tells a wrong match from a right one.

    Args:
        gray_a, gray_b: (H, W) uint8. flow: (H, W, 2) a -> b. mask: (H, W) bool pixels to score.
    """
    import cv2

    height, width = gray_a.shape
    grid_u, grid_v = np.meshgrid(np.arange(width, dtype=np.float32), np.arange(height, dtype=np.float32))
    map_u, map_v = grid_u + flow[..., 0].astype(np.float32), grid_v + flow[..., 1].astype(np.float32)
    warped = cv2.remap(gray_b.astype(np.float32), map_u, map_v, cv2.INTER_LINEAR, borderValue=0.0)
    inside = (map_u >= 0) & (map_u <= width - 1) & (map_v >= 0) & (map_v <= height - 1)
    weight = (inside & mask).astype(np.float32)
    diff = np.abs(gray_a.astype(np.float32) - warped) * weight
    total = cv2.boxFilter(diff, -1, (window, window), normalize=False, borderType=cv2.BORDER_CONSTANT)
    count = cv2.boxFilter(weight, -1, (window, window), normalize=False, borderType=cv2.BORDER_CONSTANT)
    with np.errstate(invalid="ignore", divide="ignore"):
        return np.where(count > 0, total / count, np.nan).astype(np.float64)


def reliable_pixels(gray_a: np.ndarray, gray_b: np.ndarray, flow: np.ndarray, mask: np.ndarray,
                    failed: np.ndarray, config: FlowConfig) -> np.ndarray:
    """(H, W) bool: not in a ``failed`` component and, with ``max_pixel_error`` > 0, a local
    photometric error (:func:`local_photometric_error`) at most that. Pixels whose target leaves
    b are not judged here (the lifting drops them)."""
    reliable = ~np.asarray(failed, dtype=bool)
    if config.max_pixel_error > 0:
        error = local_photometric_error(gray_a, gray_b, flow, mask, config.pixel_error_window)
        reliable &= ~(error > config.max_pixel_error)  # NaN (no evidence) is not a failure
    return reliable


# A component needs this share of its pixels lifted before its rejected pixels take their flow: a
# few surviving pixels on one end of a car say little about the other end.
FILL_MIN_SHARE = 0.1


def fill_rejected_flow(flow: np.ndarray, mask: np.ndarray, lifted: np.ndarray, rejected: np.ndarray,
                       min_lifted: int, max_distance: float = np.inf) -> tuple[np.ndarray, np.ndarray]:
    """The stored 2-D flow with each ``rejected`` mask pixel given the flow of its nearest ``lifted``
    pixel of the same mask component (one object) when that lies within ``max_distance`` px, for
    components with at least ``min_lifted`` lifted pixels and :data:`FILL_MIN_SHARE` of their pixels;
    ``min_lifted`` 0 = off. Farther away the flow of an object that turns or grows in the image
    differs from its neighbour's (calm tuning seed 3: a close car's 44 lifted pixels at one end
    gave the rest 4.2 px of error against the rejected motion's 1.2). The rejected pixels keep the
    motion of whichever model failed the checks, which is mostly wrong where the checks say so (on
    rush 5 Hz tuning seeds two thirds of the 2-D error sat there), while the lifted neighbours of the
    same object passed every check. Only the stored map changes: nothing rejected is lifted.

    Args:
        flow: (H, W, 2) flow a -> b. mask: (H, W) bool dynamic mask of a. lifted: (H, W) bool its
        pixels that became point pairs. rejected: (H, W) bool pixels the checks dropped.
    Returns:
        (H, W, 2) float32 flow (a copy) and (H, W) bool the pixels filled.
    """
    import cv2
    from scipy import ndimage

    out = np.array(flow, dtype=np.float32, copy=True)
    filled = np.zeros(mask.shape, dtype=bool)
    if min_lifted <= 0:
        return out, filled
    count, labels = cv2.connectedComponents(np.asarray(mask, dtype=np.uint8), connectivity=8)
    for label in range(1, count):
        component = labels == label
        sources = component & lifted
        targets = component & rejected
        if not targets.any() or sources.sum() < max(min_lifted, FILL_MIN_SHARE * component.sum()):
            continue
        rows, cols = np.nonzero(component)
        box = (slice(rows.min(), rows.max() + 1), slice(cols.min(), cols.max() + 1))
        distance, (near_rows, near_cols) = ndimage.distance_transform_edt(~sources[box], return_indices=True)
        target_rows, target_cols = np.nonzero(targets[box] & (distance <= max_distance))
        out[box][target_rows, target_cols] = flow[box][near_rows[target_rows, target_cols],
                                                       near_cols[target_rows, target_cols]]
        filled[box][target_rows, target_cols] = True
    return out, filled


def claimed_predictions(mask: np.ndarray, hints: list[ObjectHint], geometry: PairGeometry,
                        config: FlowConfig, wanted: list[bool] | None = None) -> np.ndarray:
    """(H, W, 2) float32 the radar-predicted motion a -> b of each pixel of a mask component some
    object of ``hints`` claims (:func:`.object_hints.component_claims`), NaN elsewhere; a component
    several objects claim is split between them by their nearest return in 3-D
    (:func:`.object_hints.split_by_returns`). No candidate is matched or chosen: this is the radar's
    guess alone, for pixels whose flow failed the checks (``FlowConfig.fill_split_objects``).

    Args:
        mask: (H, W) bool dynamic mask of a. hints: a's radar objects. geometry: the pair.
        wanted: one flag per hint: only the pixels of flagged objects get a prediction (all claimants
            still share out their components). None: every object.
    """
    import cv2

    predicted = np.full((*mask.shape, 2), np.nan, dtype=np.float32)
    wanted = [True] * len(hints) if wanted is None else wanted
    chosen = {id(hint) for hint, flag in zip(hints, wanted, strict=True) if flag}
    hints = [hint for hint in hints if hint.track != STATIC_TRACK]
    count, labels = cv2.connectedComponents(np.asarray(mask, dtype=np.uint8), connectivity=8)
    if not hints or count <= 1:
        return predicted
    claims = component_claims(nearest_labels(labels, config.radar_association_radius), hints, config.radar_min_returns)
    for label, claimants in claims.items():
        rows, cols = np.nonzero(labels == label)
        pixels = np.stack([cols, rows], axis=1)
        depth = geometry.depth[rows, cols]
        owner = np.zeros(len(pixels), dtype=np.int64)
        if len(claimants) > 1 and all(hint.camera is not None and len(hint.camera) for hint in claimants):
            owner = split_by_returns(pixels, depth, geometry.K, claimants)
        for k, hint in enumerate(claimants):
            part = owner == k
            targets = None if not part.any() or id(hint) not in chosen else predicted_targets(
                pixels[part], depth[part], geometry.K, geometry.world_to_cam_a, geometry.world_to_cam_b,
                hint.velocity * geometry.dt)
            if targets is not None:
                predicted[rows[part], cols[part]] = targets - pixels[part]
    return predicted
