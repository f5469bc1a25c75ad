"""Anchors, patches and paste-back: the geometry around the segmentation network.

A frame's radar points are projected into the camera (:class:`RadarFrame`); a fixed number of
dynamic points become anchors; a square patch of side ``patch_side(W)`` (256 px at 1920 px width,
scaled with the image: 43 px at 320×180) is cut around each anchor and resized to the network
input; the network's per-patch probabilities are resized back and pasted into a full-frame map by
per-pixel maximum (a pixel is dynamic if any patch says so).

Pixel convention (OpenCV, and the synthetic generator's): pixel (i, j) is centred at u = i,
v = j, so a projected point belongs to pixel ``floor(u + 0.5)``. Patch boxes are integer pixel-index
boxes ``(x0, y0, x1, y1)`` with ``x1 = x0 + side`` (pixels x0 … x1 − 1), centred on the anchor's
pixel; the same boxes serve extraction and paste-back, so the two are inverses up to resampling.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import torch
import torch.nn.functional as F
from torchvision.ops import roi_align

from radar4dgs.segment.config import AnchorSampling
from radar4dgs.segment.model import NUM_RADAR_FEATURES

# Reference patch size of the paper: 256×256 px at 1920×1080.
PAPER_PATCH_SIDE = 256
PAPER_IMAGE_WIDTH = 1920
# Feature scales (see radar_features): offsets in patch sides, depths in tens of metres, speeds
# in tens of m/s, rcs in tens of dBsm — all land in about [-3, 3] for driving scenes.
DEPTH_SCALE = 10.0
RANGE_SCALE = 50.0
SPEED_SCALE = 10.0
RCS_SCALE = 20.0


def patch_side(image_width: int, scale: float = 1.0) -> int:
    """Patch side (px) for an image ``image_width`` wide: ``round(256 · W / 1920 · scale)``, at least 8."""
    return max(8, int(round(PAPER_PATCH_SIDE * image_width / PAPER_IMAGE_WIDTH * scale)))


@dataclass
class RadarFrame:
    """One frame's radar points, projected into the camera.

    Attributes (N points, all in front of the camera):
        uv: (N, 2) float32 pixel coordinates (may fall outside the image).
        cam: (N, 3) float32 camera-frame positions (m), OpenCV axes.
        v_comp: (N,) float32 ego-motion-compensated radial velocity (m/s); 0 where unknown.
        dynamic: (N,) bool, the points the radar front end calls moving.
        rcs: (N,) float32 radar cross-section, 0 where the scene has none.
    """

    uv: np.ndarray
    cam: np.ndarray
    v_comp: np.ndarray
    dynamic: np.ndarray
    rcs: np.ndarray

    def __len__(self) -> int:
        return len(self.uv)

    @staticmethod
    def empty() -> "RadarFrame":
        return RadarFrame(np.zeros((0, 2), np.float32), np.zeros((0, 3), np.float32), np.zeros(0, np.float32),
                          np.zeros(0, bool), np.zeros(0, np.float32))

    def subset(self, keep: np.ndarray) -> "RadarFrame":
        return RadarFrame(self.uv[keep], self.cam[keep], self.v_comp[keep], self.dynamic[keep], self.rcs[keep])


def make_radar_frame(cam: np.ndarray, K: np.ndarray, v_comp: np.ndarray, dynamic: np.ndarray,
                     rcs: np.ndarray | None = None, min_depth: float = 0.5) -> RadarFrame:
    """Project (N, 3) camera-frame points with intrinsics ``K`` (3, 3); keep those in front
    (z > ``min_depth``). NaN velocities become 0 (unknown, and then never dynamic)."""
    cam = np.asarray(cam, np.float64)
    front = cam[:, 2] > min_depth
    cam = cam[front]
    uv = (cam @ np.asarray(K, np.float64).T)[:, :2] / cam[:, 2:3] if len(cam) else np.zeros((0, 2))
    v = np.nan_to_num(np.asarray(v_comp, np.float64)[front], nan=0.0)
    dyn = np.asarray(dynamic, bool)[front]
    r = np.zeros(len(cam)) if rcs is None else np.nan_to_num(np.asarray(rcs, np.float64)[front], nan=0.0)
    return RadarFrame(uv.astype(np.float32), cam.astype(np.float32), v.astype(np.float32), dyn, r.astype(np.float32))


def in_image(uv: np.ndarray, width: int, height: int) -> np.ndarray:
    """(N,) bool: pixel positions that fall on a pixel of a W × H image (centres at integers)."""
    return (uv[:, 0] >= -0.5) & (uv[:, 0] < width - 0.5) & (uv[:, 1] >= -0.5) & (uv[:, 1] < height - 0.5)


def pixel_index(uv: np.ndarray) -> np.ndarray:
    """(N, 2) int64 pixel (column, row) that (N, 2) positions fall on."""
    return np.floor(uv + 0.5).astype(np.int64)


def candidate_anchors(radar: RadarFrame, width: int, height: int) -> np.ndarray:
    """(M,) indices of the dynamic points that project inside the image."""
    return np.flatnonzero(radar.dynamic & in_image(radar.uv, width, height))


def sample_anchors(uv: np.ndarray, candidates: np.ndarray, count: int, rng: np.random.Generator,
                   method: AnchorSampling = "random", cover_radius: float = 0.0) -> np.ndarray:
    """Choose at most ``count`` anchors among ``candidates`` (M,) indices into ``uv`` (N, 2).

    ``random``: ``min(count, M)`` uniformly without replacement, as the paper.
    ``farthest``: farthest-point sampling in the image from a random start.
    ``cover``: visit the candidates in random order and keep one unless a kept anchor lies within
    ``cover_radius`` px (Chebyshev) — every dynamic point then sits near some patch centre, with
    no two patches nearly on top of each other; stops at ``count``.
    """
    candidates = np.asarray(candidates, np.int64)
    if method == "cover":
        kept: list[int] = []
        for c in rng.permutation(candidates):
            if len(kept) == count:
                break
            if not kept or np.abs(uv[kept] - uv[c]).max(axis=1).min() > cover_radius:
                kept.append(int(c))
        return np.sort(np.asarray(kept, np.int64))
    if len(candidates) <= count:
        return candidates
    if method == "random":
        return np.sort(rng.choice(candidates, size=count, replace=False))
    points = uv[candidates].astype(np.float64)
    chosen = [int(rng.integers(len(candidates)))]
    distance = np.linalg.norm(points - points[chosen[0]], axis=1)
    for _ in range(count - 1):
        chosen.append(int(np.argmax(distance)))
        distance = np.minimum(distance, np.linalg.norm(points - points[chosen[-1]], axis=1))
    return np.sort(candidates[chosen])


def patch_boxes(centres: np.ndarray, side: int) -> np.ndarray:
    """(K, 4) int64 boxes ``x0, y0, x1, y1`` (x1 = x0 + side) centred on the pixels of (K, 2) positions."""
    corner = pixel_index(centres) - side // 2
    return np.stack([corner[:, 0], corner[:, 1], corner[:, 0] + side, corner[:, 1] + side], axis=1)


def extract_patches(image: torch.Tensor, boxes: np.ndarray, size: int) -> torch.Tensor:
    """Cut and resize patches; pixels outside the image read as 0.

    Args:
        image: (C, H, W) float tensor.
        boxes: (K, 4) integer pixel boxes (see :func:`patch_boxes`).
        size: output side.

    Returns:
        (K, C, size, size), bilinear (area-averaged when shrinking).
    """
    if len(boxes) == 0:
        return image.new_zeros((0, image.shape[0], size, size))
    # roi_align replicates the border for samples less than a pixel outside the image; explicit
    # zero padding makes "outside reads 0" exact.
    pad = int(max(0, -boxes[:, :2].min(), (boxes[:, 2] - image.shape[2]).max(),
                  (boxes[:, 3] - image.shape[1]).max())) + 1
    padded = F.pad(image, (pad, pad, pad, pad))
    rois = torch.zeros((len(boxes), 5), dtype=image.dtype, device=image.device)
    rois[:, 1:] = torch.as_tensor(boxes + pad, dtype=image.dtype, device=image.device)
    # aligned=True: pixel i covers [i, i+1), so an integer box maps exactly onto its pixels.
    # One bilinear sample per output pixel when enlarging (exact crop at equal size), an average of
    # ceil(side / size)² samples when shrinking (anti-aliasing).
    ratio = max(1, int(np.ceil((boxes[:, 2] - boxes[:, 0]).max() / size)))
    return roi_align(padded[None], rois, output_size=size, spatial_scale=1.0, sampling_ratio=ratio, aligned=True)


def radar_features(radar: RadarFrame, boxes: np.ndarray, anchors: np.ndarray, max_points: int,
                   use_rcs: bool = False) -> tuple[np.ndarray, np.ndarray]:
    """The radar points inside each patch as network inputs.

    Args:
        radar: the frame's projected points (N).
        boxes: (K, 4) patch boxes; anchors: (K,) indices of the anchor point of each patch.
        max_points: P, the padded point count (the nearest points to the anchor are kept when a
            patch holds more).
        use_rcs: fill the rcs column (else 0).

    Returns:
        features (K, P, NUM_RADAR_FEATURES) float32 with columns ``model.RADAR_FEATURES``:
        pixel offset from the anchor in patch sides (du, dv), depth offset from the anchor and
        depth (scaled), compensated radial velocity (scaled), the dynamic flag, rcs (scaled);
        and valid (K, P) bool.
    """
    k = len(boxes)
    features = np.zeros((k, max_points, NUM_RADAR_FEATURES), np.float32)
    valid = np.zeros((k, max_points), bool)
    pix = pixel_index(radar.uv)
    for row, (box, anchor) in enumerate(zip(boxes, anchors, strict=True)):
        side = float(box[2] - box[0])
        inside = np.flatnonzero((pix[:, 0] >= box[0]) & (pix[:, 0] < box[2])
                                & (pix[:, 1] >= box[1]) & (pix[:, 1] < box[3]))
        offset = radar.uv[inside] - radar.uv[anchor]
        if len(inside) > max_points:
            keep = np.argsort(np.linalg.norm(offset, axis=1), kind="stable")[:max_points]
            inside, offset = inside[keep], offset[keep]
        n = len(inside)
        features[row, :n, 0:2] = offset / side
        features[row, :n, 2] = (radar.cam[inside, 2] - radar.cam[anchor, 2]) / DEPTH_SCALE
        features[row, :n, 3] = radar.cam[inside, 2] / RANGE_SCALE
        features[row, :n, 4] = radar.v_comp[inside] / SPEED_SCALE
        features[row, :n, 5] = radar.dynamic[inside]
        if use_rcs:
            features[row, :n, 6] = np.clip(radar.rcs[inside] / RCS_SCALE, -3.0, 3.0)
        valid[row, :n] = True
    return features, valid


def resize_patches(prob: torch.Tensor, side: int) -> torch.Tensor:
    """(K, 1, S, S) network-resolution maps → (K, side, side), bilinear (inverse of extraction)."""
    if prob.shape[0] == 0:
        return prob.new_zeros((0, side, side))
    return F.interpolate(prob, size=(side, side), mode="bilinear", align_corners=False)[:, 0]


def paste_max(patches: torch.Tensor, boxes: np.ndarray, height: int, width: int) -> torch.Tensor:
    """Paste (K, s, s) patch maps into an (H, W) map by per-pixel maximum; parts outside the
    image are dropped; pixels no patch covers are 0."""
    out = patches.new_zeros((height, width))
    for patch, (x0, y0, x1, y1) in zip(patches, boxes.tolist(), strict=True):
        cx0, cy0, cx1, cy1 = max(x0, 0), max(y0, 0), min(x1, width), min(y1, height)
        if cx0 >= cx1 or cy0 >= cy1:
            continue
        region = patch[cy0 - y0:cy1 - y0, cx0 - x0:cx1 - x0]
        out[cy0:cy1, cx0:cx1] = torch.maximum(out[cy0:cy1, cx0:cx1], region)
    return out
