"""Radar objects as hints for the flow of the dynamic-mask components: each radar object's returns
projected into its frame's image (to find the component it belongs to) and its world velocity, and
the flow a component's pixels would have if their 3D points moved with that velocity.

The prediction moves each pixel's 3D point (depth lifted, as :mod:`.lift` does) by ``v dt`` in the
world and projects it into the other frame's camera, so it carries the ego motion, the object's
motion and the change of scale of an object coming closer (a zoom, not a translation) at once.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from radar4dgs.motion.lift import backproject


@dataclass(frozen=True)
class ObjectHint:
    """One radar object of one frame, seen from that frame's camera.

    Attributes:
        uv: (K, 2) float64 its returns projected into the image (in front of the camera only).
        velocity: (3,) float64 world velocity (m/s).
        track: the radar track id (for the summary).
        camera: (K, 3) float64 the same returns in camera coordinates (m), or None when unknown.
    """

    uv: np.ndarray
    velocity: np.ndarray
    track: int = -1
    camera: np.ndarray | None = None


# Track id of the hint that holds a frame's static radar returns (:func:`static_hint`), velocity zero.
STATIC_TRACK = -2


def project_returns(xyz_radar: np.ndarray, radar_to_camera: np.ndarray, K: np.ndarray
                    ) -> tuple[np.ndarray, np.ndarray]:
    """Pixel coordinates (K', 2) and camera coordinates (K', 3) of the (K, 3) radar-frame points in
    front of the camera (K' <= K)."""
    xyz = np.asarray(xyz_radar, dtype=np.float64).reshape(-1, 3)
    cam = xyz @ radar_to_camera[:3, :3].T + radar_to_camera[:3, 3]
    cam = cam[cam[:, 2] > 1e-3]
    uv = (cam @ np.asarray(K, dtype=np.float64).T)[:, :2] / cam[:, 2:3]
    return uv, cam


def frame_hints(scene, index: int, objects) -> list[ObjectHint]:
    """The hints of frame ``index`` from its radar objects (``radar.objects.RadarObject`` list).

    An object's ``points`` are rows of ``scene.load_radar(index)``; rows beyond the scan (a stale
    objects.json) are ignored rather than trusted. The velocity is the track's (Kalman-filtered
    over frames), steadier than one scan's fit.
    """
    if not objects:
        return []
    scan = scene.load_radar(index)
    xyz = scan.xyz.astype(np.float64)
    to_camera = scene.radar_to_camera(index)
    hints = []
    for obj in objects:
        rows = obj.points[(obj.points >= 0) & (obj.points < len(xyz))]
        velocity = np.asarray(obj.velocity, dtype=np.float64)
        if len(rows) == 0 or not np.all(np.isfinite(velocity)):
            continue
        uv, camera = project_returns(xyz[rows], to_camera, scene.camera.K)
        hints.append(ObjectHint(uv, velocity, int(obj.track), camera))
    return hints


def static_hint(xyz_radar: np.ndarray, radar_to_camera: np.ndarray, K: np.ndarray, objects,
                dynamic: np.ndarray) -> ObjectHint | None:
    """One scan's static radar returns as one hint of velocity zero (track :data:`STATIC_TRACK`):
    the rows of the (N, 3) radar-frame ``xyz_radar`` that the radar stage did not flag ``dynamic``
    ((N,) bool) and no radar object (``objects``, as :func:`frame_hints`) owns, seen through
    ``radar_to_camera`` (4, 4) and ``K`` (3, 3). None when none lies in front of the camera."""
    static = ~np.asarray(dynamic, dtype=bool)
    for obj in objects or []:
        rows = obj.points[(obj.points >= 0) & (obj.points < len(static))]
        static[rows] = False
    uv, camera = project_returns(np.asarray(xyz_radar, dtype=np.float64)[static], radar_to_camera, K)
    return ObjectHint(uv, np.zeros(3), STATIC_TRACK, camera) if len(uv) else None


def nearest_labels(labels: np.ndarray, radius: float) -> np.ndarray:
    """(H, W) int: each pixel's component label, or that of the nearest labelled pixel within
    ``radius`` px (0 beyond): where a radar return votes (elevation noise puts returns a few px off
    the mask)."""
    from scipy.ndimage import distance_transform_edt

    distance, (near_v, near_u) = distance_transform_edt(labels == 0, return_indices=True)
    return np.where(distance <= radius, labels[near_v, near_u], 0)


def landing_labels(uv: np.ndarray, nearest: np.ndarray) -> np.ndarray:
    """(K,) int the :func:`nearest_labels` label each of (K, 2) projected returns lands on (0: none,
    or outside the image)."""
    height, width = nearest.shape
    u, v = np.round(uv[:, 0]), np.round(uv[:, 1])
    inside = np.isfinite(u) & np.isfinite(v) & (u >= 0) & (u < width) & (v >= 0) & (v < height)
    out = np.zeros(len(uv), dtype=np.int64)
    out[inside] = nearest[v[inside].astype(np.int64), u[inside].astype(np.int64)]
    return out


def returns_on(hint: ObjectHint, labels: np.ndarray, label: int) -> ObjectHint:
    """``hint`` with only its returns whose ``labels`` ((K,) from :func:`landing_labels`) is ``label``."""
    keep = labels == label
    return ObjectHint(hint.uv[keep], hint.velocity, hint.track, None if hint.camera is None else hint.camera[keep])


def component_claims(nearest: np.ndarray, hints: list[ObjectHint], min_returns: int) -> dict[int, list[ObjectHint]]:
    """The radar objects claiming each component of a labelled dynamic mask, most votes first.

    Each object votes with its returns for the component each lands on, or the nearest one within
    the radius of ``nearest`` (radar elevation noise puts returns a few px off the mask); it claims
    the component with most votes if they are at least ``min_returns``. Several objects can claim one
    component: two movers that overlap in the image make one mask component.

    Args:
        nearest: (H, W) int :func:`nearest_labels` of the component labels (0 = background), as
            ``cv2.connectedComponents`` gives them.
        hints: the frame's objects.
    Returns:
        {component label: [hint, ...]}, each list ordered by votes, most first.
    """
    if not hints or nearest.max() == 0:
        return {}
    claims: dict[int, list[tuple[int, int, ObjectHint]]] = {}
    for order, hint in enumerate(hints):
        votes = landing_labels(hint.uv, nearest)
        votes = votes[votes > 0]
        if len(votes) == 0:
            continue
        label = int(np.bincount(votes).argmax())
        count = int((votes == label).sum())
        if count >= min_returns:
            claims.setdefault(label, []).append((-count, order, hint))
    return {label: [hint for _, _, hint in sorted(entries, key=lambda e: e[:2])] for label, entries in claims.items()}


def split_by_returns(pixels: np.ndarray, depth: np.ndarray, K: np.ndarray, hints: list[ObjectHint]) -> np.ndarray:
    """(N,) index into ``hints`` of the object each of one component's (N, 2) pixels belongs to:
    the object owning the nearest return in 3-D, the pixels lifted with their (N,) z-depth (invalid
    depths take the component's median; without any, the nearest return in the image).

    Where two movers overlap in the image the depth tells the one in front from the one behind,
    which the image position of radar returns (a few px of elevation noise) cannot. Every hint
    needs ``camera`` returns.
    """
    from scipy.spatial import cKDTree

    owner = np.concatenate([np.full(len(h.camera), k) for k, h in enumerate(hints)])
    z = np.asarray(depth, dtype=np.float64)
    valid = np.isfinite(z) & (z > 0)
    if valid.any():
        z = np.where(valid, z, np.median(z[valid]))
        in_camera = backproject(np.asarray(pixels, dtype=np.float64), z, K, np.eye(4))
        _, nearest = cKDTree(np.concatenate([h.camera for h in hints])).query(in_camera)
    else:
        _, nearest = cKDTree(np.concatenate([h.uv for h in hints])).query(np.asarray(pixels, dtype=np.float64))
    return owner[nearest]


# Depth (m) in front of camera b below which a predicted point counts as passing it, and how far
# outside the image (px) such a point is put: beyond any image, so every check reads it as out of view.
MIN_TARGET_DEPTH = 1e-3
BESIDE_CAMERA = 1e5


def passes_camera(targets: np.ndarray, K: np.ndarray) -> np.ndarray:
    """(N,) bool: which of :func:`predicted_targets`' (N, 2) targets are points passing the camera."""
    return np.linalg.norm(targets - np.asarray(K, dtype=np.float64)[:2, 2], axis=1) >= BESIDE_CAMERA / 2


def moved_in_camera_b(pixels: np.ndarray, depth: np.ndarray, K: np.ndarray, world_to_cam_a: np.ndarray,
                      world_to_cam_b: np.ndarray, displacement: np.ndarray) -> np.ndarray | None:
    """(N, 3) camera-b coordinates of frame a's (N, 2) ``pixels`` lifted with their (N,) ``depth`` (invalid ones
    take the median of the valid) and moved by the world ``displacement``, (3,) or one a pixel (N, 3); None without
    any valid depth.
    Shared by :func:`predicted_targets` (where they land) and the flow's radar target depth (how far)."""
    z = np.asarray(depth, dtype=np.float64)
    valid = np.isfinite(z) & (z > 0)
    if not valid.any():
        return None
    z = np.where(valid, z, np.median(z[valid]))
    world = backproject(np.asarray(pixels, dtype=np.float64), z, K, world_to_cam_a) + displacement
    return world @ world_to_cam_b[:3, :3].T + world_to_cam_b[:3, 3]


def predicted_targets(pixels: np.ndarray, depth: np.ndarray, K: np.ndarray, world_to_cam_a: np.ndarray,
                      world_to_cam_b: np.ndarray, displacement: np.ndarray) -> np.ndarray | None:
    """Where an object's pixels of frame a land in frame b if its points move by ``displacement``.

    Pixels without a valid depth take the median depth of the others (one object: similar depths).

    Args:
        pixels: (N, 2) (u, v) of frame a; depth: (N,) their z-depth in frame a (NaN/inf/<= 0 invalid).
        K: (3, 3). world_to_cam_a, world_to_cam_b: (4, 4). displacement: (3,) world (m), ``v dt``.
    Returns:
        (N, 2) float64 targets in frame b, or None when no pixel has a valid depth. A point that
        ends at or behind camera b's plane (a car passing the camera) lands :data:`BESIDE_CAMERA` px
        out on the side it passes: it leaves the view, and the prediction must say so rather than
        be dropped (at 5 Hz an oncoming car 16 m ahead passes the camera within two frames; without
        its prediction the dense flow kept it in place and the pairs were lifted onto the car behind it).
    """
    cam = moved_in_camera_b(pixels, depth, K, world_to_cam_a, world_to_cam_b, displacement)
    if cam is None:
        return None
    K = np.asarray(K, dtype=np.float64)
    in_front = cam[:, 2] > MIN_TARGET_DEPTH
    uv = (cam @ K.T)[:, :2] / np.where(in_front, cam[:, 2], 1.0)[:, None]
    # Beside the camera: out along the point's lateral offset from the optical axis (its x, y).
    side = cam[:, :2] / np.maximum(np.linalg.norm(cam[:, :2], axis=1, keepdims=True), 1e-9)
    return np.where(in_front[:, None], uv, K[:2, 2] + BESIDE_CAMERA * side)
