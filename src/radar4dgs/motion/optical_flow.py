"""Dense 2D optical flow between two images and its forward-backward consistency check.

Optical flow: OpenCV DIS (Kroeger et al., ECCV 2016; no weights needed) by default, torchvision
RAFT (Teed & Deng, ECCV 2020) when the user gives a checkpoint (``raft_small``/``raft_large``
built with ``weights=None``, then the user's state dict loaded: nothing is downloaded).

Convention for every flow here: ``flow[v, u] = (du, dv)`` maps the pixel ``(u, v)`` of the first
image to ``(u + du, v + dv)`` in the second; pixel centres are at integer coordinates (OpenCV,
as the scene format's ``K``).
"""

from __future__ import annotations

import time
from pathlib import Path
from typing import Any, Sequence

import numpy as np

from radar4dgs.motion.config import FlowConfig
from radar4dgs.motion.sampling import bilinear_sample, pixel_grid


def to_gray(image: np.ndarray) -> np.ndarray:
    """(H, W) uint8 grey image from (H, W, 3) RGB uint8 or (H, W) uint8."""
    import cv2

    image = np.asarray(image)
    if image.ndim == 2:
        return np.ascontiguousarray(image, dtype=np.uint8)
    return cv2.cvtColor(np.ascontiguousarray(image, dtype=np.uint8), cv2.COLOR_RGB2GRAY)


def dis_flow(image_a: np.ndarray, image_b: np.ndarray, preset: str = "medium", dis: Any = None,
             max_width: int = 0) -> np.ndarray:
    """Dense optical flow a -> b with OpenCV DIS.

    Args:
        image_a, image_b: (H, W, 3) RGB or (H, W) grey uint8 images.
        preset: "ultrafast", "fast" or "medium".
        dis: an existing ``cv2.DISOpticalFlow`` to reuse (saves its construction per pair).
        max_width: wider images are resized to this width (area averaging) for DIS, and its flow is
            resized back and scaled to the full size (``FlowConfig.dense_width``); 0 = full size.
    Returns:
        (H, W, 2) float32 flow, ``image_a[v, u] ~ image_b[v + dv, u + du]``.
    """
    import cv2

    if dis is None:
        dis = make_dis(preset)
    gray_a, gray_b = to_gray(image_a), to_gray(image_b)
    height, width = gray_a.shape
    if not 0 < max_width < width:
        return dis.calc(gray_a, gray_b, None).astype(np.float32, copy=False)
    size = (max_width, max(1, round(height * max_width / width)))
    small = dis.calc(*(cv2.resize(g, size, interpolation=cv2.INTER_AREA) for g in (gray_a, gray_b)), None)
    flow = cv2.resize(small, (width, height), interpolation=cv2.INTER_LINEAR)  # float32, a new array
    flow[..., 0] *= width / size[0]
    flow[..., 1] *= height / size[1]
    return flow


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
            raise ValueError(f"flow method {config.method!r} estimates nothing here; choose 'dis' or 'raft' "
                             f"('oracle' is the flow stage's copy of the truth, radar4dgs.motion.flow)")

    def __call__(self, image_a: np.ndarray, image_b: np.ndarray) -> np.ndarray:
        """(H, W, 2) float32 flow a -> b."""
        if self._raft is not None:
            return raft_flow(self._raft, image_a, image_b, self.config.raft_iterations)
        return dis_flow(image_a, image_b, dis=self._dis, max_width=self.config.dense_width)


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
