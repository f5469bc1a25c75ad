"""Configuration of the pseudo scene flow (stage 6 front end): optical flow method, consistency
check, whole-object translations, lifting to 3D, outlier filter and input sources. Torch-free (the
CLI's config path imports it)."""

from __future__ import annotations

from dataclasses import dataclass, replace
from pathlib import Path
from typing import Any, ClassVar, Literal, Mapping

DIS_PRESETS = ("ultrafast", "fast", "medium")


@dataclass
class FlowConfig:
    """Optical flow, consistency check and lifting to 3D (the pseudo scene flow of stage 6)."""

    # "dis": OpenCV DIS, no weights. "raft": torchvision RAFT, needs `raft_checkpoint`.
    # "oracle": the generator's true motion (gt/depth and gt/flow, synthetic scenes only), an upper
    # bound for ablations: the masked pixels at their true positions, no estimate or checks.
    method: Literal["dis", "raft", "oracle"] = "dis"
    # DIS preset; "medium" is accurate enough on 320x180 and runs in a few ms there.
    dis_preset: Literal["ultrafast", "fast", "medium"] = "medium"
    # DIS runs on the images resized to at most this width (px), its flow scaled back; 0 = full size. Its patches
    # and pyramid are sized in pixels: on 640-px renders of hard tuning seeds 224-227 at full size the 2-D error on
    # moving pixels was 3.54 px, at 320 2.33 (scene flow 0.086 -> 0.080 m). RAFT always sees the full image.
    dense_width: int = 320
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
    # Lift frame j's end of a pair with the depth stage's map of frame j times frame i's object scale
    # (prepare stage object_depth) at the source pixel, so both ends share one scale. A scale measured
    # frame by frame moves by 0.3-1 % between frames on far cars, 0.1-0.4 m of false motion at 40 m,
    # while a bias shared by both ends costs only that bias times the displacement.
    one_scale_per_pair: bool = True
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
    # When the best translation lies on the border of the +-rigid_search window, a coarse search over
    # +-rigid_wide_search px across the image (+-rigid_search up and down; every second shift, blurred
    # images) re-centres the window; 0 = off. Only for components without a radar object (theirs is
    # predicted) and of at least rigid_min_pixels x rigid_wide_search / rigid_search pixels. An object
    # too fast for the window (a cyclist crossing at 27 px a frame at 5 Hz) otherwise keeps a dense
    # flow stuck to the background.
    rigid_wide_search: int = 0
    # Radar-guided matching of large motions (DESIGN.md "Realistic motion", motion/objects_flow.py):
    # a component that a radar object's returns land on also gets the radar prediction (its
    # pixels' 3D points moved by the object's velocity x dt and projected into frame j: ego motion,
    # object motion and zoom at once) and an affine warp matched around it (translation search, then
    # ECC); the candidate with the least photometric error wins (rigid_accept as for the
    # translation). At 10 Hz a car passing one lane away moves 70-200 px per frame, beyond DIS and
    # the +-rigid_search translation. Needs <prepared>/radar/objects.json; components without a
    # radar object keep today's step. False = dense flow and translation only.
    radar_guided: bool = True
    # Radius (px) of the translation search around the radar prediction; a velocity error of
    # 2 m/s moves an object 10 m away by ~45 px per frame at f = 230 px and 10 Hz, half that at
    # 20 m. Scale it with the image width.
    radar_search: int = 24
    # A radar return votes for the component it lands on or the nearest one within this (px):
    # 1 deg of elevation noise is 4 px at f = 230 px.
    radar_association_radius: float = 4.0
    # Votes an object needs on a component to be its radar object.
    radar_min_returns: int = 2
    # A component claimed by radar objects whose planar velocities differ by more than this (m/s) is
    # split between them (two movers overlapping in the image, such as a crossing car in front of the
    # car ahead, make one mask component); 0 = the object with most votes takes it all. At 1 m/s the
    # 2-D flow improves on every set (hard report seeds 1.78 -> 1.63 px with the body windows), and
    # trained at today's defaults the hard report seeds lose 0.24 dB of PSNR* on average, within the
    # rule fixed before (at most 0.6; docs: Motion, seventh pass).
    radar_split_velocity: float = 1.0
    # Iteration cap of the ECC refinement of the matched affine (cv2.findTransformECC).
    radar_ecc_iterations: int = 100
    # ECC may change the linear part (scale, shear) of the radar-predicted warp by at most this
    # (max |log singular value| of the ratio; 0.15 = 16 %); beyond, ECC has wandered off on a nearly
    # uniform object, and the searched translation stays.
    radar_max_shape_change: float = 0.15
    # For a component with a radar prediction, the dense flow wins over the best rigid candidate
    # (prediction, matched warp, translation) when its error is below this multiple of that one's.
    # The default, 1/0.9, is the rule the reconstructions were measured with: ties go to the dense
    # flow. 0.7 (the dense flow must win clearly; per pixel it can match grey levels it gets wrong)
    # gives a better 2-D flow but a worse reconstruction: rush 5 Hz tuning seeds 214-218, 2-D EPE on
    # dynamic pixels 0.89/1.10/0.81/1.57/1.92 -> 0.61/1.00/0.59/1.32/1.65 px and lifted scene flow
    # 0.068 -> 0.058 m on 214, but its novel-view PSNR* 20.46 -> 19.48 dB (21.42 -> 18.83 with
    # rigid actors): the rigid motion of a whole component also moves the road its mask bleeds onto.
    radar_dense_margin: float = 1.0 / 0.9
    # After the choice, a pixel keeps its dense flow where that agrees with the chosen motion
    # within this (px). 0 = the chosen motion on the whole component: measured better (synthetic
    # seeds 1-3 and realistic 101-103, 2D and scene-flow EPE), 1 px cost 0.02 m of scene-flow EPE
    # on the realistic ones (the dense flow's small errors near the object's edges are kept).
    radar_dense_agreement: float = 0.0
    # A component whose radar object has at least this many returns in the frame takes the best
    # rigid candidate, whatever the dense flow's error (0 = off): the dense flow often matches a
    # close car's grey levels better per pixel while missing its motion (rush 5 Hz tuning seeds:
    # the prediction or match within 0.1-0.8 px of the truth, the chosen dense flow 1-6 px off),
    # and with many returns the radar velocity is sound. Its pixels keep the dense flow only where
    # that explains their neighbourhood clearly better (``radar_pixel_dense_ratio``). 30 lowers the
    # 2-D EPE of hard tuning seeds 214-223 from 0.92 to 0.72 px and their scene flow from 0.081 to
    # 0.075 m (new tuning seeds 224-233: 1.42 -> 1.03 px). Alone it did not train better (four paired
    # full-small runs, -0.68 dB PSNR* on average); with masks.completion.for_flow (the default since
    # 2026-12-02) three more pairs gained -0.18 / +0.89 / +0.99 dB (hard tuning seeds 225 / 227 / 228;
    # benchmarks/results/flow-rigid-completed-masks.json), so 30 is the default.
    radar_rigid_min_returns: int = 30
    # In such a component, a pixel keeps its dense flow where its local photometric error
    # (``pixel_error_window``) is below this fraction of the rigid motion's: the mask's rim on the
    # road, or a part the rigid model misses, where the rigid motion is plainly wrong.
    radar_pixel_dense_ratio: float = 0.4
    # A component claimed by a radar object moving faster than radar_split_velocity, on which at least this
    # many of the frame's static radar returns land (within radar_association_radius; none of them an
    # object's), is split between that object and the static world like two movers
    # (objects_flow.component_owners): the pixels the static returns own are not lifted and keep their dense
    # flow. A parked car next to a mover joins its mask component (the network's mask or the radar-completed
    # one runs onto it) and was lifted with the mover's motion (hard report seed 212: 266 pairs, 2.4 m off).
    # Off by default: at 5 the pairs lifted off the moving pixels fell on four of six hard tuning seeds (214-219,
    # 181 -> 144 in all; 216: 16 -> 17, 217: 10 -> 10), short of the rule fixed before (every seed with >= 10),
    # 2-D error 0.587 -> 0.591 px (docs: Motion, thirteenth pass). 0 = off.
    radar_static_min_returns: int = 0
    # A candidate motion must keep at least this fraction of the object's pixels inside frame j to
    # be scored (a car passing the camera leaves the image; too few pixels left cannot verify it).
    radar_min_inside: float = 0.25
    # Drop (do not lift) every pixel of a component whose chosen motion explains the images no
    # better than chance: its mean absolute grey error is above this fraction of the error of the
    # same pixels paired with the same target values at random (every candidate failed). A ratio,
    # not grey levels: a right match on a contrasted car scores what a wrong one does on a dull
    # one. Synthetic seeds 1-3 and 101-103: right motions (< 1.5 px) 0.3 median, 0.76 at p95;
    # wrong ones (> 5 px) 0.79 median; a search on unrelated texture still finds ~0.88 (it
    # optimises the error), chance is 1. 0 = off (radar_guided only).
    max_component_error_ratio: float = 0.8
    # ... and above this (grey levels): on a nearly uniform object every motion scores near chance.
    min_component_error: float = 8.0
    # Drop (do not lift) dynamic pixels whose mean absolute grey error over a pixel_error_window
    # neighbourhood after the flow exceeds this (grey levels): local match failures that fail alike
    # forwards and backwards pass the consistency check. 0 = off.
    max_pixel_error: float = 30.0
    # See max_pixel_error (px, odd).
    pixel_error_window: int = 5
    # The stored 2-D flow (not the lifted pairs) of mask pixels the checks reject: the flow of the
    # nearest lifted pixel of their component within fill_max_distance px, when the component has at
    # least this many lifted pixels and a tenth of its own (objects_flow.fill_rejected_flow). Rush 5 Hz
    # tuning seeds 214-223: 2-D error on moving pixels 1.09 -> 0.97 px. 0 = off.
    fill_min_lifted: int = 20
    # See fill_min_lifted (px): beyond, an object's flow differs from its neighbour's (it turns, grows).
    fill_max_distance: float = 10.0
    # The stored 2-D flow of rejected mask pixels the fill leaves: their radar object's predicted motion
    # (radar_guided only), where the object has one. Only the stored map changes: nothing rejected is lifted.
    # Hard tuning seeds, 2-D error on moving pixels: 640 px 228 / 229 / 230 2.26 / 4.58 / 1.09 -> 2.22 / 4.23 /
    # 1.04; 320 px 231 / 232 / 233 0.93 / 0.47 / 0.47 -> 0.84 / 0.47 / 0.48; lifted pairs identical.
    fill_radar_prediction: bool = True
    # With fill_radar_prediction: the rejected pixels of an object only the split radar objects have
    # (<prepared>/radar/objects_split.json, each cluster's outliers fitted again: the second of two movers
    # passing within the clustering radius) store its prediction, over the fill and the first mover's
    # prediction. Only the stored map changes. Hard tuning seeds, 2-D error on moving pixels: 640 px
    # 228 / 229 / 230 2.22 / 4.23 / 1.04 -> 1.17 / 0.90 / 1.04; 320 px 231-233 0.48 -> 0.48 on 233, the
    # others unchanged; lifted pairs identical.
    fill_split_objects: bool = True
    # Lift frame j's end of an object's pixel with the depth its radar prediction gives there (frame i's point
    # moved by the radar object's velocity x dt, its z in camera j; radar_guided only) instead of the depth map
    # sampled at the match, where the two agree within radar_target_depth_tolerance (relative). Why: two depth
    # maps' errors do not cancel along the line of sight, and on a car 40-60 m away 1-3 % of depth is metres of
    # false motion a frame; the tracked velocity's radial error is centimetres. Offline on strict tuning 404 /
    # 409 (the ground truth's radar object per mover): crossing cars' lifted scene-flow error 0.26-0.68 ->
    # 0.04-0.13 m (median). Off: under a rule fixed before the runs the five strict tuning seeds' scene-flow error
    # fell 59 %, but novel-view PSNR* changed by +0.02 dB over ten grid runs with 404 at -0.63 (both of its runs
    # lost; docs/research/motion.md, seventeenth pass).
    radar_target_depth: bool = False
    # See radar_target_depth.
    radar_target_depth_tolerance: float = 0.2
    # Where metric depth comes from: "prepared" = <prepared>/depth/<frame>.npy (stage 3);
    # "oracle" = the scene's gt/depth (ablations and tests only).
    depth_source: Literal["prepared", "oracle"] = "prepared"
    # Where dynamic masks come from: "prepared" = <prepared>/masks/flow/<frame>.png, the masks
    # completed by the radar objects for this stage, when stage 4 wrote them, else
    # <prepared>/masks/<frame>.png; "oracle" = the scene's gt/dynamic_mask.
    mask_source: Literal["prepared", "oracle"] = "prepared"
    # Pair each training frame with the next training frame (skipping test frames, whose images
    # are held out for novel-view evaluation); False pairs every frame with the next frame.
    skip_test_frames: bool = True
    # With a width (px), the search windows, radii, the fill distance and the error window are given for images
    # that wide and scale with the scene's width (flow_settings_at_width); 0 = in pixels as given. At 320 on the
    # 640-px hard tuning seeds 224-227: 2-D error 3.54 -> 3.33 px, scene flow 0.0856 -> 0.0860 m, so off.
    reference_width: int = 0

    PRESETS: ClassVar[Mapping[str, Mapping[str, Any]]] = {
        "tiny": {"dis_preset": "fast"},
        "small": {},
        "paper": {},
    }


# FlowConfig's lengths in pixels that FlowConfig.reference_width scales (scaling the areas too, rigid_min_pixels
# and consistency_beta, made the scene flow of 640-px tuning seed 226 worse by 0.005 m).
PIXEL_LENGTH_SETTINGS = ("rigid_search", "rigid_wide_search", "radar_search", "radar_association_radius",
                         "fill_max_distance", "pixel_error_window")


def flow_settings_at_width(config: FlowConfig, width: int) -> FlowConfig:
    """``config`` with its :data:`PIXEL_LENGTH_SETTINGS` scaled from ``config.reference_width`` to images
    ``width`` px wide (integer ones rounded, the error window kept odd); ``config`` itself when the widths
    agree or ``reference_width`` is 0."""
    if config.reference_width <= 0 or width == config.reference_width:
        return config
    scale = width / config.reference_width
    changes = {}
    for name in PIXEL_LENGTH_SETTINGS:
        value = getattr(config, name) * scale
        changes[name] = int(round(value)) if isinstance(getattr(config, name), int) else float(value)
    changes["pixel_error_window"] |= 1
    return replace(config, **changes)
