"""Configuration of the depth front end (stage 3): depth source, radar scale recovery, sky masks."""

from __future__ import annotations

from dataclasses import dataclass
from typing import ClassVar, Literal, Optional

DepthSource = Literal["auto", "prior", "depth-anything-v2", "flat-world", "oracle"]
PriorKind = Literal["auto", "inverse-depth", "depth"]
ScaleMethod = Literal["auto", "affine", "paper"]
SkySource = Literal["auto", "prior", "fallback", "none"]

DEFAULT_DEPTH_ANYTHING = "depth-anything/Depth-Anything-V2-Small-hf"


@dataclass
class DepthConfig:
    """How ``prepare`` turns a monocular depth prior and the static radar points into metric depth.

    Every depth source is first converted to a *relative inverse depth* ``x`` (larger = closer,
    ``x <= 0`` or non-finite = far / invalid); scale recovery then finds ``1/z = a * x + b`` per frame.
    """

    # ---- depth source
    # "prior": <scene>/priors/mono_depth; "depth-anything-v2": run the network through HuggingFace
    # transformers; "flat-world": no network and no prior, the ground plane of the ego frame seen
    # through the calibrated camera, capped by a wall at flat_world_far (already metric; right on
    # the road only: a last resort, see radar4dgs.depth.flat_world); "oracle": <scene>/gt/depth
    # (ablation only, never for real results); "auto": "prior" when the scene has
    # priors/mono_depth, else "depth-anything-v2" when its weights are on this machine (or
    # local_files_only is off), else "flat-world" (with a warning).
    source: DepthSource = "auto"
    # What the source's numbers are: "inverse-depth" (relative disparity, as Depth-Anything-V2's
    # relative models and priors/mono_depth), "depth" (depth up to scale, as metric networks and the
    # oracle); "auto": "depth" for the oracle and for Depth-Anything configs with
    # depth_estimation_type == "metric", else "inverse-depth". Ignored by "flat-world", which
    # always gives inverse depth.
    prior_kind: PriorKind = "auto"
    # HuggingFace model id or local folder holding config.json + weights + preprocessor_config.json.
    model: str = DEFAULT_DEPTH_ANYTHING
    # Never touch the network when loading the model: a pipeline run should not start downloads or
    # hang on a machine without internet. Set False to let transformers fetch `model` from the hub.
    local_files_only: bool = True
    # Torch device for the network: "auto" (CUDA when available, else CPU), "cpu", "cuda", "cuda:1"...
    device: str = "auto"
    # Network compute dtype; float16 halves memory on a GPU (CPU always runs float32).
    dtype: Literal["float32", "float16", "bfloat16"] = "float32"
    # "flat-world": the distance (m, along the optical axis) of the wall that closes the flat road:
    # rays at or above the horizon, and ground farther than this, get it.
    flat_world_far: float = 80.0
    # "flat-world": height of the road in the ego frame (m); None = from lidar/ when the scene has
    # it, else 0 (the scene format's ego origin is on the ground, as nuScenes').
    flat_world_ground_z: Optional[float] = None
    # "flat-world": a frame's radar fit is kept only when it changes the prior's depth by less
    # than this fraction anywhere from the camera to the wall (a small camera height or pitch
    # correction); a larger change is radar elevation error or a fit extrapolated from a few near
    # ground returns, and the frame takes its neighbours' fit or, when no frame has one, the
    # prior unscaled (scale 1, shift 0).
    flat_world_max_correction: float = 0.25

    # ---- scale recovery
    # "affine": robust fit of scale AND shift in inverse depth (right model for relative priors);
    # "paper": the paper's single scale from plane votes and histogram voting (right model for
    # depth-up-to-scale priors); "auto": "paper" for prior_kind "depth", "affine" otherwise.
    scale_method: ScaleMethod = "auto"
    # Radar points (camera z) outside this range are not used; also clamps the output depth (m).
    min_depth: float = 1.0
    max_depth: float = 1000.0
    # A frame needs at least this many validated radar-pixel pairs (inliers for "affine", valid
    # votes for "paper"), otherwise it takes its neighbours' parameters (with a warning).
    min_pairs: int = 12
    # The 3 nearest visual directions must lie within this angle of the radar direction (deg):
    # rejects radar points outside the image or in holes of the visual point set.
    max_sphere_angle_deg: float = 0.5
    # The 3 neighbours' (unscaled) depths must agree within this ratio (max/min - 1): rejects
    # radar points projecting onto a depth discontinuity, where a pixel triangle spans two surfaces.
    max_neighbour_depth_ratio: float = 0.1
    # Plane normal non-degenerate: |(pa-pb) x (pb-pc)| / (|pa-pb| |pb-pc|) (sine of the triangle
    # angle at pb) must reach this.
    min_normal_sine: float = 0.05
    # Ray not grazing the plane: |cos| between the radar ray and the plane normal must reach this;
    # grazing rays (distant road) turn small radar elevation errors into large scale errors.
    min_incidence_cos: float = 0.1
    # Use every stride-th pixel (both axes) as a visual point in "paper" mode (1 = all pixels).
    visual_stride: int = 1
    # "paper": number of bins of the log-scale vote histogram (over the 2nd-98th percentile range).
    histogram_bins: int = 64
    # "paper": the winning bin's estimate is the median of the votes in it and this many bins on
    # each side (1 keeps a peak that straddles a bin edge from being halved).
    histogram_refine_neighbours: int = 1
    # A pair is an inlier when its relative depth residual |z_fit / z_radar - 1| is below this
    # (RANSAC threshold for "affine"; vote agreement for "paper"; also used for confidence).
    inlier_threshold: float = 0.08
    # "affine": RANSAC iterations (2-point samples), then IRLS with a Huber loss.
    ransac_iterations: int = 256
    # "affine": Huber threshold of the IRLS refinement, on relative depth residuals.
    huber_delta: float = 0.03
    # "affine": IRLS iterations after RANSAC.
    irls_iterations: int = 10
    # "affine": when the inliers' radar inverse depths 1/z spread less than this (std/mean), scale
    # and shift are not separable (all points at one depth): fit the scale only (shift 0), say so.
    min_depth_spread: float = 0.05
    # Seed of the RANSAC random generator (each frame uses seed + frame index).
    seed: int = 0
    # "affine": temporal consistency. After the per-frame robust fits, frame i's (a, b) is
    # re-estimated from the radar inliers of the frames within +-(temporal_window // 2), weighted
    # by 1 - |j - i| / (half + 1), under a locally *linear* drift model
    # 1/z_j = (a_i + alpha (j - i)) x_j + (b_i + beta (j - i)) (Huber IRLS): parameters that drift
    # slowly (monocular networks on video) are followed without lag, the per-frame noise of ~300
    # radar pairs averages out (less frame-to-frame jitter of the metric scale, which scene flow
    # turns into spurious motion along the ray). Odd, >= 1; 1 = independent per-frame fits.
    temporal_window: int = 5

    # ---- output
    # Confidence multiplier of frames whose parameters came from neighbours.
    fallback_confidence: float = 0.5
    # Confidence falls as exp(-g / edge_scale) with g the largest |log z| step to a 4-neighbour:
    # depth at discontinuities is a mix of two surfaces.
    edge_scale: float = 0.1
    # Keep the relative inverse depth of every frame in <prepared>/depth/relative/<frame>.npy
    # (a cache: Depth-Anything is not rerun by evaluation).
    keep_relative: bool = True

    # ---- sky
    # "prior": <scene>/priors/sky_mask (error when absent); "fallback": the weight-free detector;
    # "auto": prior when present, else fallback; "none": no sky (every pixel gets a depth).
    sky_source: SkySource = "auto"
    # Fallback: a pixel is "far" when its relative inverse depth lies in the lowest
    # sky_far_fraction of the frame's range [x_min, x_99.5] ...
    sky_far_fraction: float = 0.04
    # ... and its metric depth after scale recovery is at least this (m) (or non-positive inverse).
    sky_min_depth: float = 40.0
    # Fallback: the colour model is fitted on far pixels of this top fraction of the image rows.
    sky_top_rows: float = 0.1
    # Fallback: at least this many far top-row pixels are needed to believe there is sky at all.
    sky_min_seed_pixels: int = 20
    # Fallback: squared Mahalanobis distance (RGB, 0-255) accepted by the sky colour model.
    sky_color_threshold: float = 25.0
    # Fallback: regularisation of the colour covariance (added to its diagonal, in 0-255 units^2),
    # so that a flat synthetic sky does not give a zero-width model.
    sky_color_regularization: float = 36.0

    PRESETS: ClassVar[dict[str, dict]] = {
        "tiny": {"ransac_iterations": 128, "histogram_bins": 48},
        "small": {},
        # 1920x1080: every second pixel is plenty of visual points and keeps the KD-tree small.
        "paper": {"visual_stride": 2},
    }

    def __post_init__(self) -> None:
        if self.min_depth <= 0 or self.max_depth <= self.min_depth:
            raise ValueError(f"need 0 < min_depth < max_depth, got {self.min_depth}, {self.max_depth}")
        if self.min_pairs < 2:
            raise ValueError(f"min_pairs must be >= 2 (two unknowns), got {self.min_pairs}")
        if self.visual_stride < 1 or self.histogram_bins < 1:
            raise ValueError("visual_stride and histogram_bins must be >= 1")
        if self.temporal_window < 1 or self.temporal_window % 2 == 0:
            raise ValueError(f"temporal_window must be an odd number >= 1, got {self.temporal_window}")
        if not self.flat_world_far > self.min_depth:
            raise ValueError(f"flat_world_far must exceed min_depth, got {self.flat_world_far}")
        if not self.flat_world_max_correction >= 0:
            raise ValueError(f"flat_world_max_correction must be >= 0, got {self.flat_world_max_correction}")
        if not 0 < self.sky_top_rows <= 1:
            raise ValueError(f"sky_top_rows must be in (0, 1], got {self.sky_top_rows}")

    def resolved_kind(self, source: str, model_kind: str | None = None) -> str:
        """The prior kind ("inverse-depth" or "depth") for a resolved ``source``."""
        if source == "flat-world":
            return "inverse-depth"  # made here, always 1 / depth
        if self.prior_kind != "auto":
            return self.prior_kind
        if source == "oracle":
            return "depth"
        if source == "depth-anything-v2" and model_kind == "metric":
            return "depth"
        return "inverse-depth"

    def resolved_method(self, kind: str) -> str:
        """The scale method for a prior of ``kind``."""
        if self.scale_method != "auto":
            return self.scale_method
        return "paper" if kind == "depth" else "affine"


@dataclass
class ObjectDepthConfig:
    """How each moving object's prepared depth is rescaled by its radar returns."""

    # Off: the stage writes only its summary and every later stage reads the depth stage's maps.
    enabled: bool = True
    # A mask component is rescaled only with at least this many dynamic returns on it, each frame on its
    # own: on the hard tuning seeds 10 gave the lowest scene-flow error (3 and 30 higher), measured before
    # the flow stage lifted both ends of a pair on one scale (FlowConfig.one_scale_per_pair).
    min_returns: int = 10
    # And only when the median ratio lies within 1 +- this: a larger correction says the returns
    # belong to something else (a merged component, a ghost), not that the prior is that far off.
    max_correction: float = 0.25
    # Components smaller than this many pixels are left alone (speckle of the mask).
    min_pixels: int = 20

    PRESETS: ClassVar[dict[str, dict]] = {"tiny": {}, "small": {}, "paper": {}}

    def __post_init__(self) -> None:
        if self.min_returns < 1 or self.min_pixels < 1:
            raise ValueError(f"min_returns and min_pixels must be >= 1, got {self.min_returns}, {self.min_pixels}")
        if not 0.0 < self.max_correction < 1.0:
            raise ValueError(f"max_correction must lie in (0, 1), got {self.max_correction}")
