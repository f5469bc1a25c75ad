"""Configuration of the pseudo scene flow (stage 6 front end): optical flow method, consistency
check, whole-object translations, lifting to 3D, outlier filter and input sources. Torch-free (the
CLI's config path imports it)."""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import Any, ClassVar, Literal, Mapping

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
