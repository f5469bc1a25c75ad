"""Depth sources: the scene's prior, Depth-Anything-V2 through HuggingFace ``transformers``, the
weight-free flat-world ground plane (:mod:`radar4dgs.depth.flat_world`) and the ground-truth
oracle (ablations only).

Every source is returned as a *relative inverse depth* ``x`` (H, W) float32: larger = closer,
``x <= 0`` or non-finite = far / no depth. A depth-like source (the oracle, a metric network) is
converted with ``x = 1 / depth`` (``+inf`` depth, i.e. sky, becomes 0).
"""

from __future__ import annotations

import importlib.util
from pathlib import Path
from typing import Any

import numpy as np

from radar4dgs.depth.config import DepthConfig
from radar4dgs.io.devices import resolve_device

WEIGHTS_HELP = (
    "Depth-Anything-V2 weights are not available here. On a machine with internet run\n"
    "    huggingface-cli download depth-anything/Depth-Anything-V2-Small-hf --local-dir DA2-small\n"
    "copy the folder over and pass it with `radar4dgs prepare SCENE --config.depth.model DA2-small` "
    "(any *-hf Depth-Anything checkpoint works; --config.depth.no-local-files-only lets transformers "
    "download it), or give the scene a priors/mono_depth/ folder (relative inverse depth per frame)."
)


class DepthModelError(RuntimeError):
    """The depth network cannot be loaded (transformers missing or weights absent)."""


FLAT_WORLD_NOTICE = ("depth: no learned depth prior (no priors/mono_depth, no local Depth-Anything-V2 weights "
                     "for {model!r}{why}): using the flat-world ground-plane prior, right on the road only; "
                     "Depth-Anything-V2 weights (--config.depth.model FOLDER) give much better depth")


def resolve_source(scene, config: DepthConfig) -> str:
    """The concrete source for ``scene``: "auto" picks "prior" when the scene has
    ``priors/mono_depth``, else "depth-anything-v2" when :func:`depth_anything_available`, else
    "flat-world" (the caller warns with :data:`FLAT_WORLD_NOTICE`)."""
    if config.source == "auto":
        if scene.has("priors/mono_depth"):
            return "prior"
        return "depth-anything-v2" if depth_anything_available(config) else "flat-world"
    if config.source == "prior" and not scene.has("priors/mono_depth"):
        raise FileNotFoundError(f"{scene.root}: depth source 'prior' needs a complete priors/mono_depth/ folder")
    if config.source == "oracle" and not scene.has("gt/depth"):
        raise FileNotFoundError(f"{scene.root}: depth source 'oracle' needs a complete gt/depth/ folder")
    return config.source


def depth_anything_available(config: DepthConfig) -> bool:
    """Whether ``config.model`` can be loaded without reaching the network: ``transformers`` is
    installed and the model is a local folder with a ``config.json`` or, for a hub id, its config
    and weights are in the HuggingFace cache. True whenever ``local_files_only`` is off (the user
    allowed the download). Cheap: nothing is imported or loaded."""
    if importlib.util.find_spec("transformers") is None:
        return False
    if not config.local_files_only:
        return True
    folder = Path(str(config.model)).expanduser()
    if folder.exists():
        return (folder / "config.json").is_file()
    if str(config.model).startswith((".", "/", "~")):
        return False
    try:
        from huggingface_hub import try_to_load_from_cache
    except ImportError:
        return False

    def cached(filename: str) -> bool:
        try:
            return isinstance(try_to_load_from_cache(str(config.model), filename), str)
        except ValueError:  # not a valid repo id
            return False

    return cached("config.json") and (cached("model.safetensors") or cached("pytorch_model.bin"))


def to_inverse(values: np.ndarray, kind: str) -> np.ndarray:
    """(H, W) float32 relative inverse depth from a map of ``kind`` "inverse-depth" or "depth"."""
    values = np.asarray(values, dtype=np.float32)
    if kind == "inverse-depth":
        return values
    if kind == "depth":
        with np.errstate(divide="ignore", invalid="ignore"):
            inverse = np.where(values > 0, 1.0 / values, np.nan).astype(np.float32)
        inverse[np.isposinf(values)] = 0.0  # sky: infinitely far, not "unknown"
        return inverse
    raise ValueError(f"unknown prior kind {kind!r}; choose 'inverse-depth' or 'depth'")


class DepthAnythingV2:
    """Depth-Anything-V2 (any HuggingFace ``DepthAnythingForDepthEstimation`` checkpoint).

    Call it on an (H, W, 3) uint8 RGB image to get its raw (H, W) float32 output resized to the
    image: relative inverse depth for the relative checkpoints, metres for the metric ones
    (``self.kind`` says which: "inverse-depth" or "depth").

    Args:
        model: model id or local folder, or an already built ``PreTrainedModel``.
        processor: the image processor (loaded from ``model`` when it is a path or id).
        device: torch device; dtype: torch dtype (float16/bfloat16 only on CUDA).
        local_files_only: never reach the network while loading.
    """

    def __init__(self, model: str | Path | Any, processor: Any = None, device: Any = "cpu", dtype: Any = None,
                 local_files_only: bool = False):
        import torch

        self.device = resolve_device(device)
        self.dtype = dtype if dtype is not None else torch.float32
        if self.device.type == "cpu":
            self.dtype = torch.float32  # half precision convolutions are slow or missing on CPU
        if isinstance(model, (str, Path)):
            model, processor = load_depth_anything(model, local_files_only)
        elif processor is None:
            raise ValueError("pass the image processor together with a built model")
        self.model = model.to(self.device, self.dtype).eval()
        self.processor = processor
        kind = getattr(model.config, "depth_estimation_type", "relative")
        self.kind = "depth" if kind == "metric" else "inverse-depth"

    def __call__(self, image: np.ndarray) -> np.ndarray:
        """(H, W, 3) uint8 RGB -> (H, W) float32 raw network output at the image size."""
        import torch

        height, width = image.shape[:2]
        # transformers turns the array into a tensor in place; a read-only one (a decoded PNG) makes
        # torch warn that writing to it would be undefined.
        image = image if image.flags.writeable else image.copy()
        inputs = self.processor(images=image, return_tensors="pt")
        pixels = inputs["pixel_values"].to(self.device, self.dtype)
        with torch.inference_mode():
            predicted = self.model(pixel_values=pixels).predicted_depth  # (1, h, w)
            predicted = torch.nn.functional.interpolate(predicted[:, None].float(), size=(height, width),
                                                        mode="bicubic", align_corners=False)[0, 0]
        # Bicubic overshoot can dip below zero next to the sky; the network's output is >= 0.
        return predicted.clamp_min(0).cpu().numpy().astype(np.float32)


def load_depth_anything(model: str | Path, local_files_only: bool = False) -> tuple[Any, Any]:
    """(model, processor) from a HuggingFace id or local folder; a :class:`DepthModelError` with
    download instructions when ``transformers`` or the weights are missing."""
    try:
        from transformers import AutoImageProcessor, AutoModelForDepthEstimation
    except ImportError as exc:
        raise DepthModelError("the depth source 'depth-anything-v2' needs HuggingFace transformers: "
                              "pip install 'radar4dgs[models]' (or pip install transformers)\n"
                              + WEIGHTS_HELP) from exc
    name = str(model)
    if Path(name).expanduser().exists():
        name = str(Path(name).expanduser())
    elif name.startswith((".", "/", "~")):
        raise DepthModelError(f"model folder {model} does not exist.\n{WEIGHTS_HELP}")
    try:
        network = AutoModelForDepthEstimation.from_pretrained(name, local_files_only=local_files_only)
        processor = AutoImageProcessor.from_pretrained(name, local_files_only=local_files_only)
    except (OSError, ValueError) as exc:
        raise DepthModelError(f"cannot load depth model {model!r} ({str(exc).splitlines()[0]}).\n"
                              f"{WEIGHTS_HELP}") from exc
    return network, processor


def build_depth_model(config: DepthConfig, device: Any = None) -> DepthAnythingV2:
    """The configured Depth-Anything-V2 network (``device`` overrides ``config.device``)."""
    import torch

    dtype = {"float32": torch.float32, "float16": torch.float16, "bfloat16": torch.bfloat16}[config.dtype]
    return DepthAnythingV2(config.model, device=device if device is not None else config.device, dtype=dtype,
                           local_files_only=config.local_files_only)


def frame_inverse_depth(scene, index: int, source: str, kind: str, model: Any = None) -> np.ndarray:
    """(H, W) float32 relative inverse depth of frame ``index`` from a resolved ``source``;
    ``model`` is the :class:`DepthAnythingV2` or the
    :class:`~radar4dgs.depth.flat_world.FlatWorldDepth` of those sources (built here when None)."""
    if source == "prior":
        values = scene.load_optional("priors/mono_depth", index)
    elif source == "oracle":
        values = scene.load_optional("gt/depth", index)
    elif source == "depth-anything-v2":
        if model is None:
            raise ValueError("source 'depth-anything-v2' needs the model (build_depth_model)")
        values = model(scene.load_image(index))
    elif source == "flat-world":
        if model is None:
            from radar4dgs.depth.flat_world import FlatWorldDepth

            model = FlatWorldDepth(scene)
        values = model()
    else:
        raise ValueError(f"unknown depth source {source!r}; choose 'prior', 'depth-anything-v2', 'flat-world' "
                         "or 'oracle'")
    return to_inverse(values, kind)
