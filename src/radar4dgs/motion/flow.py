"""Pseudo scene flow: 2D optical flow between frames, a forward-backward consistency mask, and
lifting to 3D world-frame point pairs with the metric depth of both frames and the poses.

Optical flow: OpenCV DIS (Kroeger et al., ECCV 2016; no weights needed) by default, torchvision
RAFT (Teed & Deng, ECCV 2020) when the user gives a checkpoint (``raft_small``/``raft_large``
built with ``weights=None``, then the user's state dict loaded: nothing is downloaded).

Convention for every flow here: ``flow[v, u] = (du, dv)`` maps the pixel ``(u, v)`` of the first
image to ``(u + du, v + dv)`` in the second; pixel centres are at integer coordinates (OpenCV,
as the scene format's ``K``).

Scene level, :func:`prepare_flow` writes ``<prepared>/flow/<frame>.npz`` for each frame that has a
successor (the next frame, or with ``skip_test_frames`` the next TRAINING frame, so held-out test
images never supervise the field), with keys

    ``flow``       (H, W, 2) float32  forward 2D flow, this frame -> ``index_j``
    ``consistent`` (H, W) bool        forward-backward consistent and landing inside frame j
    ``points_i``   (M, 3) float32     world points of the kept pixels at this frame's time
    ``points_j``   (M, 3) float32     the same surface points at frame j's time
    ``pixels``     (M, 2) float32     (u, v) integer pixel coordinates of the kept pixels
    ``index_i``, ``index_j`` int; ``timestamp_i``, ``timestamp_j`` float64 (s)

Each dynamic-mask component whose single 2D translation explains the two images better than the
dense flow gets that translation in ``flow`` (both directions, before the consistency check; see
``FlowConfig.rigid_objects``). kept = dynamic (mask) & consistent & valid depth in both frames.
``flow/config.json`` holds the resolved :class:`FlowConfig`.
"""

from __future__ import annotations

import io
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Callable, ClassVar, Iterable, Literal, Mapping, Sequence

import numpy as np

from radar4dgs.config import to_dict
from radar4dgs.io.atomic import atomic_directory, atomic_write_bytes, atomic_write_json
from radar4dgs.io.scene import read_mask_png

DIS_PRESETS = ("ultrafast", "fast", "medium")


@dataclass
class FlowConfig:
    """Optical flow, consistency check and lifting to 3D (the pseudo scene flow of stage 6)."""

    # "dis": OpenCV DIS, no weights. "raft": torchvision RAFT, needs `raft_checkpoint`.
    method: Literal["dis", "raft"] = "dis"
    # DIS preset; "medium" is accurate enough on 320x180 and runs in a few ms there.
    dis_preset: Literal["ultrafast", "fast", "medium"] = "medium"
    # RAFT state dict (a torchvision checkpoint or a dict with a "state_dict"/"model" entry).
    raft_checkpoint: Path | None = None
    # RAFT architecture matching the checkpoint.
    raft_model: Literal["small", "large"] = "small"
    # RAFT refinement iterations (torchvision's default is 12).
    raft_iterations: int = 12
    # Device for RAFT ("cpu", "cuda", "cuda:1", ...).
    device: str = "cpu"
    # Forward-backward consistency (UnFlow, Meister et al. AAAI 2018, eq. 4): a pixel is consistent
    # when |f_fw + f_bw(x + f_fw)|^2 < alpha (|f_fw|^2 + |f_bw(x + f_fw)|^2) + beta (pixels^2).
    consistency_alpha: float = 0.01
    # See consistency_alpha; UnFlow uses 0.5 px^2.
    consistency_beta: float = 0.5
    # Depth of frame j is sampled bilinearly at x + f; the 4 neighbours must agree within this
    # relative tolerance (max/min - 1), else the sample straddles a depth edge (object boundary)
    # and mixes foreground with background, and the pixel is dropped.
    depth_edge_tolerance: float = 0.1
    # Keep a pixel only when its match x + f lands on the dynamic mask of frame j too (all 4
    # bilinear neighbours): a dynamic pixel whose flow lands on the background would be lifted
    # with the background's depth, a metres-large error along the line of sight.
    require_dynamic_target: bool = True
    # Reject lifted pairs whose 3D flow deviates from the median flow of their connected component
    # of the dynamic mask (one object, moving nearly rigidly over one frame) by more than
    # max(outlier_min_deviation, outlier_mad_factor * 1.4826 * MAD). A few mismatched pixels at
    # object boundaries carry metres of error (up to 35 m on synthetic scenes) and dominate a
    # squared loss; with the filter the mean error of the kept pairs drops ~2.5x. False = keep all.
    outlier_filter: bool = True
    # See outlier_filter (m).
    outlier_min_deviation: float = 0.1
    # See outlier_filter.
    outlier_mad_factor: float = 3.0
    # Components with fewer lifted pairs than this cannot be checked and are dropped.
    outlier_min_points: int = 3
    # Compare each pair with the median flow of its this many nearest pairs (3D, frame i, same
    # component) instead of the whole component's; 0 = the component's median. Two cars that
    # touch in the image form one component: against one median the slower car's pairs are all
    # "outliers" and it loses its flow supervision (synthetic seed 1: a lane-changing car beside
    # the lead car).
    outlier_neighbours: int = 16
    # Per connected component of the dynamic mask (one object), also try a single 2D translation
    # for the whole object and use it for the component's pixels when it explains the image
    # better (mean absolute grey-level error below rigid_accept x the dense flow's). A small,
    # uniformly coloured object crossing the view (a bus 45-95 m away) has texture only at its
    # ends: dense flow meets the aperture problem inside it and its smoothing pulls the interior
    # towards the background's flow (DIS "medium" gave 2.2 of 5.0 px, forward and backward
    # agreeing, so the consistency check kept it). Synthetic seed 1, adjacent pairs,
    # dynamic pixels beyond 40 m: EPE 2.47 -> 0.82 px; all dynamic pixels 0.51 -> 0.23 px.
    rigid_objects: bool = True
    # Integer search radius (px) of the translation around the component's median dense flow; a
    # best shift on the border of the window is not trusted (the true one may lie beyond).
    rigid_search: int = 12
    # See rigid_objects: the translation replaces the dense flow of a component when its error is
    # below this fraction of the dense flow's.
    rigid_accept: float = 0.9
    # Components smaller than this (px) keep their dense flow (too little to match reliably).
    rigid_min_pixels: int = 10
    # Where metric depth comes from: "prepared" = <prepared>/depth/<frame>.npy (stage 3);
    # "oracle" = the scene's gt/depth (ablations and tests only).
    depth_source: Literal["prepared", "oracle"] = "prepared"
    # Where dynamic masks come from: "prepared" = <prepared>/masks/<frame>.png (stage 4);
    # "oracle" = the scene's gt/dynamic_mask.
    mask_source: Literal["prepared", "oracle"] = "prepared"
    # Pair each training frame with the next training frame (skipping test frames, whose images
    # are held out for novel-view evaluation); False pairs every frame with the next frame.
    skip_test_frames: bool = True

    PRESETS: ClassVar[Mapping[str, Mapping[str, Any]]] = {
        "tiny": {"dis_preset": "fast"},
        "small": {},
        "paper": {},
    }


# --------------------------------------------------------------------------------------------
# 2D optical flow


def to_gray(image: np.ndarray) -> np.ndarray:
    """(H, W) uint8 grey image from (H, W, 3) RGB uint8 or (H, W) uint8."""
    import cv2

    image = np.asarray(image)
    if image.ndim == 2:
        return np.ascontiguousarray(image, dtype=np.uint8)
    return cv2.cvtColor(np.ascontiguousarray(image, dtype=np.uint8), cv2.COLOR_RGB2GRAY)


def dis_flow(image_a: np.ndarray, image_b: np.ndarray, preset: str = "medium", dis: Any = None) -> np.ndarray:
    """Dense optical flow a -> b with OpenCV DIS.

    Args:
        image_a, image_b: (H, W, 3) RGB or (H, W) grey uint8 images.
        preset: "ultrafast", "fast" or "medium".
        dis: an existing ``cv2.DISOpticalFlow`` to reuse (saves its construction per pair).
    Returns:
        (H, W, 2) float32 flow, ``image_a[v, u] ~ image_b[v + dv, u + du]``.
    """
    if dis is None:
        dis = make_dis(preset)
    return dis.calc(to_gray(image_a), to_gray(image_b), None).astype(np.float32, copy=False)


def make_dis(preset: str = "medium"):
    """A ``cv2.DISOpticalFlow`` with the named preset."""
    import cv2

    presets = {"ultrafast": cv2.DISOPTICAL_FLOW_PRESET_ULTRAFAST, "fast": cv2.DISOPTICAL_FLOW_PRESET_FAST,
               "medium": cv2.DISOPTICAL_FLOW_PRESET_MEDIUM}
    if preset not in presets:
        raise ValueError(f"unknown DIS preset {preset!r}; choose one of {list(presets)}")
    return cv2.DISOpticalFlow_create(presets[preset])


def build_raft(model: str = "small"):
    """A randomly initialised torchvision RAFT (``weights=None``: nothing is downloaded)."""
    from torchvision.models.optical_flow import raft_large, raft_small

    builders = {"small": raft_small, "large": raft_large}
    if model not in builders:
        raise ValueError(f"unknown RAFT model {model!r}; choose 'small' or 'large'")
    return builders[model](weights=None, progress=False)


def load_raft(checkpoint: str | Path, model: str = "small", device: str = "cpu"):
    """torchvision RAFT with the user's weights from ``checkpoint``, in eval mode on ``device``.

    The checkpoint is a state dict, or a dict holding one under "state_dict" or "model"; a
    ``module.`` prefix (DataParallel) is stripped. Keys must match the architecture exactly.
    """
    import torch

    path = Path(checkpoint)
    if not path.is_file():
        raise FileNotFoundError(f"{path}: RAFT checkpoint not found (set flow.raft_checkpoint to a "
                                f"torchvision raft_{model} state dict, or use flow.method='dis')")
    state = torch.load(path, map_location="cpu", weights_only=True)
    for key in ("state_dict", "model"):
        if isinstance(state, dict) and key in state and isinstance(state[key], dict):
            state = state[key]
    state = {k[len("module."):] if k.startswith("module.") else k: v for k, v in state.items()}
    network = build_raft(model)
    try:
        network.load_state_dict(state, strict=True)
    except RuntimeError as exc:
        raise ValueError(f"{path}: not a torchvision raft_{model} state dict ({exc})") from exc
    return network.to(device).eval()


def raft_flow(network, image_a: np.ndarray, image_b: np.ndarray, iterations: int = 12) -> np.ndarray:
    """Dense optical flow a -> b with a torchvision RAFT network (on the network's device).

    Args:
        image_a, image_b: (H, W, 3) RGB uint8.
    Returns:
        (H, W, 2) float32 flow, same convention as :func:`dis_flow`.
    """
    import torch
    import torch.nn.functional as F

    device = next(network.parameters()).device
    height, width = image_a.shape[:2]

    def prepare(image: np.ndarray):
        tensor = torch.from_numpy(np.ascontiguousarray(image)).to(device).permute(2, 0, 1)[None].float()
        return tensor / 127.5 - 1.0  # RAFT expects [-1, 1] (torchvision's Raft_*_Weights transforms)

    # RAFT works at 1/8 resolution with a 4-level correlation pyramid: pad (edge replication) to
    # multiples of 8 and at least 128 px per side, crop after.
    pad_w, pad_h = max((-width) % 8, 128 - width), max((-height) % 8, 128 - height)
    a = F.pad(prepare(image_a), (0, pad_w, 0, pad_h), mode="replicate")
    b = F.pad(prepare(image_b), (0, pad_w, 0, pad_h), mode="replicate")
    with torch.no_grad():
        flow = network(a, b, num_flow_updates=iterations)[-1]
    return flow[0, :, :height, :width].permute(1, 2, 0).cpu().numpy().astype(np.float32)


class FlowEstimator:
    """Computes 2D flow with the method of a :class:`FlowConfig`, holding the DIS object or the
    RAFT network so they are built once per scene."""

    def __init__(self, config: FlowConfig):
        self.config = config
        if config.method == "dis":
            self._dis = make_dis(config.dis_preset)
            self._raft = None
        elif config.method == "raft":
            if config.raft_checkpoint is None:
                raise ValueError("flow.method='raft' needs flow.raft_checkpoint (no weights can be "
                                 "downloaded); use flow.method='dis' otherwise")
            self._dis = None
            self._raft = load_raft(config.raft_checkpoint, config.raft_model, config.device)
        else:
            raise ValueError(f"unknown flow method {config.method!r}; choose 'dis' or 'raft'")

    def __call__(self, image_a: np.ndarray, image_b: np.ndarray) -> np.ndarray:
        """(H, W, 2) float32 flow a -> b."""
        if self._raft is not None:
            return raft_flow(self._raft, image_a, image_b, self.config.raft_iterations)
        return dis_flow(image_a, image_b, dis=self._dis)


# --------------------------------------------------------------------------------------------
# Whole-object translations


def _photometric_error(gray_a: np.ndarray, gray_b: np.ndarray, pixels: np.ndarray, targets: np.ndarray) -> float:
    """Mean |a(pixels) - b(targets)| (grey levels), b sampled bilinearly; a target outside b counts
    as the largest error (255), so leaving the image is never cheap."""
    values, inside = bilinear_sample(gray_b, targets)
    source = gray_a[pixels[:, 1].astype(np.int64), pixels[:, 0].astype(np.int64)].astype(np.float64)
    return float(np.where(inside, np.abs(source - values), 255.0).mean())


def object_translation(gray_a: np.ndarray, gray_b: np.ndarray, pixels: np.ndarray, start: np.ndarray,
                       search: int, max_pixels: int = 4000) -> tuple[np.ndarray, float] | None:
    """The 2D translation that best carries an object's pixels of image a onto image b.

    Exhaustive integer search of the mean absolute grey-level error over a (2 search + 1)^2
    window around ``start``, then a parabola through the neighbours of the best shift on each axis
    for the sub-pixel part. Written here: OpenCV's matchTemplate takes rectangular templates only,
    and an object's mask is not a rectangle.

    Args:
        gray_a, gray_b: (H, W) uint8 grey images.
        pixels: (N, 2) integer (u, v) of the object in image a.
        start: (2,) the window centre (du, dv) in pixels, rounded to integers.
        search: the window's radius in pixels.
        max_pixels: larger objects are matched on an evenly strided subset of their pixels.
    Returns:
        ((2,) float64 shift (du, dv), its mean error), or None when the best integer shift lies on
        the window's border (the true one may lie beyond it).
    """
    height, width = gray_a.shape
    pixels = np.asarray(pixels, dtype=np.int64)
    if len(pixels) > max_pixels:
        pixels = pixels[:: -(-len(pixels) // max_pixels)]
    start = np.round(np.asarray(start, dtype=np.float64)).astype(np.int64)
    offsets = np.arange(-search, search + 1)
    source = gray_a[pixels[:, 1], pixels[:, 0]].astype(np.float32)
    b = gray_b.astype(np.float32)
    # errors[y, x]: shift (start + (offsets[x], offsets[y])); targets outside b cost 255.
    u = pixels[None, :, 0] + start[0] + offsets[:, None]  # (S, N)
    v = pixels[None, :, 1] + start[1] + offsets[:, None]
    u_in, v_in = (u >= 0) & (u < width), (v >= 0) & (v < height)
    u, v = np.clip(u, 0, width - 1), np.clip(v, 0, height - 1)
    errors = np.empty((len(offsets), len(offsets)))
    for row, (v_row, v_ok) in enumerate(zip(v, v_in)):
        diff = np.abs(source[None] - b[v_row[None], u])
        errors[row] = np.where(v_ok[None] & u_in, diff, 255.0).mean(axis=1)
    y, x = np.unravel_index(int(np.argmin(errors)), errors.shape)
    if y in (0, len(offsets) - 1) or x in (0, len(offsets) - 1):
        return None
    shift = (start + offsets[[x, y]]).astype(np.float64)
    for axis, (minus, centre, plus) in enumerate(((errors[y, x - 1], errors[y, x], errors[y, x + 1]),
                                                  (errors[y - 1, x], errors[y, x], errors[y + 1, x]))):
        curvature = minus - 2 * centre + plus
        if curvature > 0:
            shift[axis] += float(np.clip(0.5 * (minus - plus) / curvature, -0.5, 0.5))
    return shift, _photometric_error(gray_a, gray_b, pixels, pixels + shift)


def rigid_object_flow(gray_a: np.ndarray, gray_b: np.ndarray, flow: np.ndarray, mask: np.ndarray,
                      search: int = 12, accept: float = 0.9, min_pixels: int = 10) -> np.ndarray:
    """``flow`` with each object's pixels set to the object's single translation where that explains
    the images better (see ``FlowConfig.rigid_objects``).

    Args:
        gray_a, gray_b: (H, W) uint8 grey images a and b.
        flow: (H, W, 2) dense flow a -> b.
        mask: (H, W) bool dynamic mask of image a; its 8-connected components are the objects.
        search, accept, min_pixels: ``FlowConfig.rigid_search``, ``rigid_accept``, ``rigid_min_pixels``.
    Returns:
        (H, W, 2) float32 flow (a copy).
    """
    import cv2

    out = np.array(flow, dtype=np.float32, copy=True)
    count, labels = cv2.connectedComponents(np.asarray(mask, dtype=np.uint8), connectivity=8)
    for label in range(1, count):
        rows, cols = np.nonzero(labels == label)
        if len(rows) < min_pixels:
            continue
        pixels = np.stack([cols, rows], axis=1)
        dense = flow[rows, cols].astype(np.float64)
        found = object_translation(gray_a, gray_b, pixels, np.median(dense, axis=0), search)
        if found is None:
            continue
        shift, error = found
        if error < accept * _photometric_error(gray_a, gray_b, pixels, pixels + dense):
            out[rows, cols] = shift
    return out


# --------------------------------------------------------------------------------------------
# Sampling and consistency


def bilinear_sample(array: np.ndarray, xy: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Bilinear samples of ``array`` at continuous pixel coordinates.

    Args:
        array: (H, W) or (H, W, C).
        xy: (M, 2) (u, v) coordinates, pixel centres at integers.
    Returns:
        values (M,) or (M, C) float64 (0 where outside), inside (M,) bool: all 4 neighbours exist.
    """
    array = np.asarray(array)
    height, width = array.shape[:2]
    u, v = xy[:, 0].astype(np.float64), xy[:, 1].astype(np.float64)
    inside = np.isfinite(u) & np.isfinite(v) & (u >= 0) & (v >= 0) & (u <= width - 1) & (v <= height - 1)
    u = np.where(inside, u, 0.0)
    v = np.where(inside, v, 0.0)
    # Clamp the upper neighbour so u == W - 1 samples the last column with weight 1.
    u0 = np.minimum(np.floor(u).astype(np.int64), width - 2 if width > 1 else 0)
    v0 = np.minimum(np.floor(v).astype(np.int64), height - 2 if height > 1 else 0)
    u1, v1 = np.minimum(u0 + 1, width - 1), np.minimum(v0 + 1, height - 1)
    du, dv = u - u0, v - v0
    if array.ndim == 3:
        du, dv = du[:, None], dv[:, None]
    a = array.astype(np.float64, copy=False)
    values = ((1 - du) * (1 - dv) * a[v0, u0] + du * (1 - dv) * a[v0, u1]
              + (1 - du) * dv * a[v1, u0] + du * dv * a[v1, u1])
    values = np.where(inside[:, None] if array.ndim == 3 else inside, values, 0.0)
    return values, inside


def sample_depth(depth: np.ndarray, xy: np.ndarray, edge_tolerance: float = 0.1) -> tuple[np.ndarray, np.ndarray]:
    """Bilinear depth at (M, 2) pixel coordinates, refusing samples across depth edges.

    Returns:
        z (M,) float64 and valid (M,) bool: inside the image, the 4 neighbours finite and positive
        and within ``edge_tolerance`` of each other (max / min - 1), so a sample never blends an
        object's depth with the background's.
    """
    depth = np.asarray(depth, dtype=np.float64)
    height, width = depth.shape
    z, inside = bilinear_sample(np.where(np.isfinite(depth), depth, 0.0), xy)
    u = np.clip(np.floor(np.where(inside, xy[:, 0], 0)).astype(np.int64), 0, max(width - 2, 0))
    v = np.clip(np.floor(np.where(inside, xy[:, 1], 0)).astype(np.int64), 0, max(height - 2, 0))
    corners = np.stack([depth[v, u], depth[v, np.minimum(u + 1, width - 1)],
                        depth[np.minimum(v + 1, height - 1), u],
                        depth[np.minimum(v + 1, height - 1), np.minimum(u + 1, width - 1)]], axis=1)
    finite = np.isfinite(corners).all(axis=1) & (corners > 0).all(axis=1)
    with np.errstate(invalid="ignore", divide="ignore"):
        ratio = corners.max(axis=1) / corners.min(axis=1)
    valid = inside & finite & (ratio <= 1 + edge_tolerance)
    return np.where(valid, z, np.nan), valid


def _corner_min(array: np.ndarray, xy: np.ndarray) -> np.ndarray:
    """(M,) minimum of (H, W) ``array`` over the 4 bilinear neighbours of each (u, v); -inf outside."""
    height, width = array.shape
    u, v = xy[:, 0], xy[:, 1]
    inside = np.isfinite(u) & np.isfinite(v) & (u >= 0) & (v >= 0) & (u <= width - 1) & (v <= height - 1)
    u0 = np.floor(np.where(inside, u, 0)).astype(np.int64)
    v0 = np.floor(np.where(inside, v, 0)).astype(np.int64)
    u1, v1 = np.minimum(u0 + 1, width - 1), np.minimum(v0 + 1, height - 1)
    values = np.minimum(np.minimum(array[v0, u0], array[v0, u1]), np.minimum(array[v1, u0], array[v1, u1]))
    return np.where(inside, values, -np.inf)


def pixel_grid(height: int, width: int) -> np.ndarray:
    """(H, W, 2) float64 (u, v) coordinates of every pixel centre."""
    u, v = np.meshgrid(np.arange(width, dtype=np.float64), np.arange(height, dtype=np.float64))
    return np.stack([u, v], axis=-1)


def consistency_mask(flow_fw: np.ndarray, flow_bw: np.ndarray, alpha: float = 0.01,
                     beta: float = 0.5) -> np.ndarray:
    """Forward-backward consistency (UnFlow, Meister, Hur & Roth, AAAI 2018, eq. 4).

    A pixel x of image a is consistent when
    ``|f_fw(x) + f_bw(x + f_fw(x))|^2 < alpha (|f_fw(x)|^2 + |f_bw(x + f_fw(x))|^2) + beta``
    (squared norms, pixels^2; alpha 0.01, beta 0.5 in the paper), with ``f_bw`` sampled bilinearly.
    Pixels whose target lands outside image b are inconsistent (they left the view).

    Args:
        flow_fw: (H, W, 2) flow a -> b; flow_bw: (H, W, 2) flow b -> a.
    Returns:
        (H, W) bool.
    """
    height, width = flow_fw.shape[:2]
    target = (pixel_grid(height, width) + flow_fw).reshape(-1, 2)
    back, inside = bilinear_sample(flow_bw, target)
    fw = flow_fw.reshape(-1, 2).astype(np.float64)
    residual = np.sum((fw + back) ** 2, axis=1)
    bound = alpha * (np.sum(fw ** 2, axis=1) + np.sum(back ** 2, axis=1)) + beta
    return (inside & (residual < bound)).reshape(height, width)


# --------------------------------------------------------------------------------------------
# Lifting to 3D


def backproject(pixels: np.ndarray, z: np.ndarray, K: np.ndarray, world_to_cam: np.ndarray) -> np.ndarray:
    """World points of pixels with known z-depth.

    Args:
        pixels: (M, 2) (u, v); z: (M,) z-depth along the optical axis (m); K: (3, 3);
        world_to_cam: (4, 4) OpenCV axes.
    Returns:
        (M, 3) float64 world points.
    """
    K = np.asarray(K, dtype=np.float64)
    x = (pixels[:, 0] - K[0, 2]) / K[0, 0]
    y = (pixels[:, 1] - K[1, 2]) / K[1, 1]
    cam = np.stack([x * z, y * z, z], axis=1)
    cam_to_world = np.linalg.inv(np.asarray(world_to_cam, dtype=np.float64))
    return cam @ cam_to_world[:3, :3].T + cam_to_world[:3, 3]


def lift_flow(flow: np.ndarray, depth_i: np.ndarray, depth_j: np.ndarray, K: np.ndarray,
              world_to_cam_i: np.ndarray, world_to_cam_j: np.ndarray, valid: np.ndarray,
              edge_tolerance: float = 0.1, target_mask: np.ndarray | None = None
              ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Lift 2D flow i -> j to world-frame 3D point pairs (pseudo scene flow).

    Pixel x of frame i with depth ``depth_i[x]`` gives the world point at time i; its match
    ``x + flow[x]`` in frame j, with ``depth_j`` sampled bilinearly there (see
    :func:`sample_depth`), gives the same surface point at time j. ``points_j - points_i`` is the
    world-frame scene flow.

    Args:
        flow: (H, W, 2) flow i -> j. depth_i, depth_j: (H, W) metric z-depth (inf/NaN/<=0 invalid).
        K: (3, 3). world_to_cam_i, world_to_cam_j: (4, 4).
        valid: (H, W) bool, pixels to lift (e.g. dynamic & forward-backward consistent).
        edge_tolerance: see :func:`sample_depth`.
        target_mask: optional (H, W) bool of frame j; a match must land where its 4 bilinear
            neighbours are all in it (e.g. frame j's dynamic mask).
    Returns:
        points_i (M, 3), points_j (M, 3) float64 world points and pixels (M, 2) float64 (u, v) of
        the kept pixels: ``valid`` with a finite positive depth_i and a valid depth_j sample.
    """
    height, width = depth_i.shape
    if flow.shape != (height, width, 2) or depth_j.shape != (height, width) or valid.shape != (height, width):
        raise ValueError(f"shapes disagree: flow {flow.shape}, depth_i {depth_i.shape}, "
                         f"depth_j {depth_j.shape}, valid {valid.shape}")
    z_i = np.asarray(depth_i, dtype=np.float64)
    keep = np.asarray(valid, dtype=bool) & np.isfinite(z_i) & (z_i > 0)
    rows, cols = np.nonzero(keep)
    pixels = np.stack([cols, rows], axis=1).astype(np.float64)
    targets = pixels + flow[rows, cols].astype(np.float64)
    z_j, ok = sample_depth(depth_j, targets, edge_tolerance)
    if target_mask is not None:
        # All 4 neighbours inside the mask <=> the bilinear sample of the 0/1 mask is 1.
        corners = _corner_min(np.asarray(target_mask, dtype=np.float64), targets)
        ok &= corners > 0.5
    pixels, targets, z_j = pixels[ok], targets[ok], z_j[ok]
    points_i = backproject(pixels, z_i[rows[ok], cols[ok]], K, world_to_cam_i)
    points_j = backproject(targets, z_j, K, world_to_cam_j)
    return points_i, points_j, pixels


# --------------------------------------------------------------------------------------------
# Scene level


def reject_flow_outliers(points_i: np.ndarray, points_j: np.ndarray, pixels: np.ndarray, mask: np.ndarray,
                         min_deviation: float = 0.1, mad_factor: float = 3.0, min_points: int = 3,
                         neighbours: int = 0) -> np.ndarray:
    """(M,) bool: lifted pairs consistent with the median 3D flow around them.

    Args:
        points_i, points_j: (M, 3) lifted pairs; pixels: (M, 2) their (u, v) in frame i;
        mask: (H, W) bool dynamic mask of frame i (its 8-connected components are the objects).
        neighbours: 0 compares each pair with the median flow of its whole component; k > 0 with
            the median of its k nearest pairs of the component (3D distance in frame i, itself
            included), so two objects in one component keep their own motions.
    A pair is kept when |flow - reference median| <= max(min_deviation, mad_factor * 1.4826 *
    median absolute deviation over the component) and its component has >= min_points pairs.
    """
    import cv2
    from scipy.spatial import cKDTree

    keep = np.zeros(len(points_i), dtype=bool)
    if len(points_i) == 0:
        return keep
    _, labels = cv2.connectedComponents(np.asarray(mask, dtype=np.uint8), connectivity=8)
    component = labels[pixels[:, 1].astype(np.int64), pixels[:, 0].astype(np.int64)]
    flow = points_j - points_i
    for label in np.unique(component):
        members = np.nonzero(component == label)[0]
        if label == 0 or len(members) < min_points:  # 0: not on the mask (cannot happen for masked pixels)
            continue
        if neighbours > 0 and len(members) > neighbours:
            _, nearest = cKDTree(points_i[members]).query(points_i[members], k=neighbours)
            reference = np.median(flow[members][nearest], axis=1)
        else:
            reference = np.median(flow[members], axis=0)
        deviation = np.linalg.norm(flow[members] - reference, axis=1)
        bound = max(min_deviation, mad_factor * 1.4826 * float(np.median(deviation)))
        keep[members] = deviation <= bound
    return keep


def frame_pairs(scene, skip_test_frames: bool = True) -> list[tuple[int, int]]:
    """(i, j) pairs of consecutive frames; with ``skip_test_frames`` only training frames, each
    paired with the next training frame (test images stay unseen)."""
    indices = scene.train_indices if skip_test_frames else list(range(len(scene)))
    return list(zip(indices[:-1], indices[1:]))


def load_depth(scene, index: int, source: str, prepared_dir: str | Path | None,
               depth_dir: str | Path | None = None) -> np.ndarray:
    """(H, W) float64 metric z-depth of frame ``index`` from ``source`` ("prepared" or "oracle")."""
    if source == "oracle":
        return scene.load_optional("gt/depth", index).astype(np.float64)
    if source != "prepared":
        raise ValueError(f"unknown depth source {source!r}; choose 'prepared' or 'oracle'")
    folder = Path(depth_dir) if depth_dir is not None else Path(prepared_dir) / "depth"
    path = folder / f"{scene.frames[index].name}.npy"
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
    """(H, W) bool dynamic mask of frame ``index`` from ``source`` ("prepared" or "oracle")."""
    if source == "oracle":
        return scene.load_optional("gt/dynamic_mask", index)
    if source != "prepared":
        raise ValueError(f"unknown mask source {source!r}; choose 'prepared' or 'oracle'")
    folder = Path(mask_dir) if mask_dir is not None else Path(prepared_dir) / "masks"
    path = folder / f"{scene.frames[index].name}.png"
    if not path.is_file():
        raise FileNotFoundError(f"{path}: no prepared dynamic mask in {folder} (run the segmentation "
                                f"front end first, or set mask_source='oracle' to use the scene's "
                                f"gt/dynamic_mask)")
    return read_mask_png(path, (scene.camera.height, scene.camera.width))


def _npz_bytes(**arrays: np.ndarray) -> bytes:
    buffer = io.BytesIO()
    np.savez_compressed(buffer, **arrays)
    return buffer.getvalue()


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
    return {"pairs": summary["pairs"], "points": sum(p["points"] for p in summary["per_pair"])}


def write_flow(scene, out_dir: str | Path, config: FlowConfig | None = None,
               prepared_dir: str | Path | None = None, depth_dir: str | Path | None = None,
               mask_dir: str | Path | None = None,
               progress: bool | Callable[[Iterable], Iterable] = False) -> dict:
    """Write the per-pair ``<frame>.npz`` files, ``summary.json`` and ``config.json`` into ``out_dir``
    (not atomically as a whole: :func:`prepare_flow` wraps it in a temporary folder).

    Returns:
        a summary dict (pairs, kept points per pair, consistent fraction, flow seconds per call).
    """
    config = config or FlowConfig()
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    pairs = frame_pairs(scene, config.skip_test_frames)
    cache: dict[int, tuple[np.ndarray, np.ndarray]] = {}
    # Load the first frame up front, so a missing input folder fails before any flow is computed.
    if pairs:
        first = pairs[0][0]
        cache[first] = (load_depth(scene, first, config.depth_source, prepared_dir, depth_dir),
                        load_mask(scene, first, config.mask_source, prepared_dir, mask_dir))
    estimator = FlowEstimator(config)
    K = scene.camera.K
    iterator: Iterable = pairs
    if progress is True:
        from tqdm import tqdm

        iterator = tqdm(pairs, desc="flow", unit="pair")
    elif callable(progress):
        iterator = progress(pairs)
    per_pair = []
    flow_seconds = 0.0
    for i, j in iterator:
        image_i, image_j = scene.load_image(i), scene.load_image(j)
        started = time.perf_counter()
        forward = estimator(image_i, image_j)
        backward = estimator(image_j, image_i)
        flow_seconds += time.perf_counter() - started
        for k in (i, j):
            if k not in cache:
                cache[k] = (load_depth(scene, k, config.depth_source, prepared_dir, depth_dir),
                            load_mask(scene, k, config.mask_source, prepared_dir, mask_dir))
        depth_i, mask_i = cache.pop(i)  # pairs are visited in order; frame i is not needed again
        depth_j, mask_j = cache[j]
        if config.rigid_objects:
            gray_i, gray_j = to_gray(image_i), to_gray(image_j)
            rigid = (config.rigid_search, config.rigid_accept, config.rigid_min_pixels)
            forward = rigid_object_flow(gray_i, gray_j, forward, mask_i, *rigid)
            backward = rigid_object_flow(gray_j, gray_i, backward, mask_j, *rigid)
        consistent = consistency_mask(forward, backward, config.consistency_alpha, config.consistency_beta)
        points_i, points_j, pixels = lift_flow(
            forward, depth_i, depth_j, K, scene.world_to_camera(i), scene.world_to_camera(j),
            mask_i & consistent, config.depth_edge_tolerance,
            mask_j if config.require_dynamic_target else None)
        if config.outlier_filter:
            keep = reject_flow_outliers(points_i, points_j, pixels, mask_i, config.outlier_min_deviation,
                                        config.outlier_mad_factor, config.outlier_min_points,
                                        config.outlier_neighbours)
            points_i, points_j, pixels = points_i[keep], points_j[keep], pixels[keep]
        name = scene.frames[i].name
        atomic_write_bytes(out / f"{name}.npz", _npz_bytes(
            flow=forward.astype(np.float32), consistent=consistent,
            points_i=points_i.astype(np.float32), points_j=points_j.astype(np.float32),
            pixels=pixels.astype(np.float32), index_i=np.int64(i), index_j=np.int64(j),
            timestamp_i=np.float64(scene.frames[i].timestamp),
            timestamp_j=np.float64(scene.frames[j].timestamp)))
        per_pair.append({"frame": name, "index_i": i, "index_j": j, "points": int(len(points_i)),
                         "dynamic_pixels": int(mask_i.sum()),
                         "consistent_fraction": float(consistent.mean())})
    summary = {"pairs": len(pairs), "method": config.method,
               "flow_seconds_per_call": flow_seconds / max(2 * len(pairs), 1),
               "depth_source": config.depth_source, "mask_source": config.mask_source,
               "per_pair": per_pair}
    atomic_write_json(out / "summary.json", summary)
    atomic_write_json(out / "config.json", to_dict(config))
    return summary


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


def gt_flow_2d(scene, index: int, next_index: int | None = None) -> tuple[np.ndarray, np.ndarray]:
    """Ground-truth 2D flow of frame ``index`` to ``index + 1`` from gt/depth and gt/flow (evaluation).

    Each pixel's surface point ``X`` (from gt/depth) moves to ``X + gt_flow`` (world) and is
    projected into frame ``index + 1``.

    Returns:
        flow (H, W, 2) float64 and valid (H, W) bool (finite depth, in front of camera j).
    """
    j = index + 1 if next_index is None else next_index
    if j != index + 1:
        raise ValueError("gt/flow is a one-frame displacement; only next_index = index + 1 is defined")
    depth = scene.load_optional("gt/depth", index).astype(np.float64)
    motion = scene.load_optional("gt/flow", index).astype(np.float64)
    height, width = depth.shape
    grid = pixel_grid(height, width).reshape(-1, 2)
    z = depth.reshape(-1)
    finite = np.isfinite(z) & (z > 0)
    world = backproject(grid, np.where(finite, z, 1.0), scene.camera.K, scene.world_to_camera(index))
    moved = world + motion.reshape(-1, 3)
    w2c = scene.world_to_camera(j)
    cam = moved @ w2c[:3, :3].T + w2c[:3, 3]
    with np.errstate(divide="ignore", invalid="ignore"):
        uv = (cam @ np.asarray(scene.camera.K, dtype=np.float64).T)[:, :2] / cam[:, 2:3]
    valid = finite & (cam[:, 2] > 1e-6) & np.isfinite(uv).all(axis=1)
    flow = np.where(valid[:, None], uv - grid, 0.0)
    return flow.reshape(height, width, 2), valid.reshape(height, width)


def motion_frontend_metrics(scene, prepared_dir: str | Path, max_pairs: int | None = None) -> dict:
    """Front-end metrics of the pseudo scene flow in ``<prepared>/flow`` against the scene's gt/.

    Only pairs of adjacent frames (``index_j = index_i + 1``) are scored, since gt/flow is a
    one-frame displacement.

    - ``flow2d_epe_dynamic`` (px): mean over all gt-dynamic pixels with finite gt depth, pooled
      over pairs, of |stored 2D flow - gt 2D flow| (gt 2D flow from :func:`gt_flow_2d`).
    - ``sceneflow_epe_dynamic`` (m): mean over the stored lifted pairs whose pixel is gt-dynamic
      of |(points_j - points_i) - gt/flow[pixel]|.
    - ``sceneflow_coverage``: fraction of gt-dynamic pixels (finite depth) that got a lifted pair.
    - ``flow2d_pairs``: pairs scored.
    """
    pairs = [p for p in load_flow_pairs(prepared_dir) if int(p["index_j"]) == int(p["index_i"]) + 1]
    if max_pairs is not None:
        pairs = pairs[:max_pairs]
    errors_2d, errors_3d = [], []
    dynamic_total, covered = 0, 0
    for pair in pairs:
        i = int(pair["index_i"])
        gt2d, valid = gt_flow_2d(scene, i)
        dynamic = scene.load_optional("gt/dynamic_mask", i) & valid
        errors_2d.append(np.linalg.norm(pair["flow"][dynamic] - gt2d[dynamic], axis=1))
        motion = scene.load_optional("gt/flow", i)
        cols = pair["pixels"][:, 0].astype(np.int64)
        rows = pair["pixels"][:, 1].astype(np.int64)
        keep = dynamic[rows, cols]
        predicted = (pair["points_j"] - pair["points_i"]).astype(np.float64)[keep]
        errors_3d.append(np.linalg.norm(predicted - motion[rows[keep], cols[keep]], axis=1))
        dynamic_total += int(dynamic.sum())
        covered += int(keep.sum())
    e2 = np.concatenate(errors_2d) if errors_2d else np.zeros(0)
    e3 = np.concatenate(errors_3d) if errors_3d else np.zeros(0)
    return {"flow2d_epe_dynamic": float(e2.mean()) if len(e2) else None,
            "sceneflow_epe_dynamic": float(e3.mean()) if len(e3) else None,
            "sceneflow_coverage": covered / dynamic_total if dynamic_total else None,
            "flow2d_pairs": len(pairs)}


def time_dis(width: int = 320, height: int = 180, preset: str = "medium", repeats: int = 20,
             shift: Sequence[float] = (3.0, 1.5), seed: int = 0) -> float:
    """Median seconds of one DIS call on a textured (H, W) pair shifted by ``shift`` pixels."""
    import cv2

    rng = np.random.default_rng(seed)
    texture = cv2.GaussianBlur((rng.random((height + 20, width + 20)) * 255).astype(np.uint8), (0, 0), 2.0)
    a = np.ascontiguousarray(texture[10:10 + height, 10:10 + width])
    M = np.array([[1.0, 0.0, shift[0]], [0.0, 1.0, shift[1]]])
    b = np.ascontiguousarray(cv2.warpAffine(texture, M, (width + 20, height + 20),
                                            borderMode=cv2.BORDER_REFLECT)[10:10 + height, 10:10 + width])
    dis = make_dis(preset)
    dis.calc(a, b, None)  # warm-up
    times = []
    for _ in range(repeats):
        started = time.perf_counter()
        dis.calc(a, b, None)
        times.append(time.perf_counter() - started)
    return float(np.median(times))
