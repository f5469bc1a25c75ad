"""Options of the radar front end (ego-motion RANSAC, dynamic classification, scene processing)."""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any, ClassVar, Literal, Mapping


@dataclass
class RadarObjectConfig:
    """Dynamic radar points grouped into objects, each object's planar velocity from its returns'
    compensated Doppler, and coordinated-turn tracking in the world (``objects.py``, ``tracking.py``)."""

    # Dynamic points closer than this (m) join one object (single linkage on a cKDTree radius graph):
    # a car's returns are at most ~1 m apart along its outline, cars in adjacent lanes ~3.5 m.
    radius: float = 2.5
    # Heights are multiplied by this before the distance test: elevation noise (1 deg = 0.9 m at
    # 50 m) and multipath ghosts mirrored below the road must not split an object from its returns.
    z_scale: float = 0.25
    # Objects with fewer returns are not reported: one return says no more than the point's own
    # radial velocity (already in <frame>.npz), and isolated clutter is one return.
    min_returns: int = 2
    # Fit a cluster's outliers again (sequential RANSAC) and report each further fit with split_min_returns inliers
    # as an object of its own: two movers passing within ``radius`` of each other (an oncoming car beside the lead
    # car) join one cluster, and the second one's returns were lost as the first one's outliers.
    # Off: it makes the 2-D flow of such scenes much better, but cost 0.64 dB of novel-view PSNR* on hard tuning
    # seed 229 at the full small budget (0.71 with split_min_returns 4), and trained the same on 231.
    split_outliers: bool = False
    # Inliers a further object of a cluster needs. Two returns fit some velocity exactly and three out of a car's
    # scattered outliers often agree by chance (hard tuning seeds 228 / 229 / 231: five such 3-return objects,
    # 11-68 m/s off, within 2.2 m of the car; every true second mover had 4 or more).
    split_min_returns: int = 4
    # A return fits an object velocity v when |v_r_comp - d . v| is below this (m/s): 3 sigma of the
    # Doppler noise (0.1 m/s) plus azimuth noise times the speed across the line of sight
    # (0.005 rad x 30 m/s = 0.15 m/s).
    inlier_threshold: float = 0.5
    # Robust fit: every pair of returns is a hypothesis up to this many pairs, else this many random
    # pairs (plus one radial hypothesis per return).
    max_hypotheses: int = 300
    # Pairs whose planar directions differ by less than this (deg) are not tried: they amplify the
    # Doppler noise by 1 / sin(angle).
    min_pair_angle_deg: float = 0.2
    # Prior on the residual std (m/s), pooled with the fit's own residuals with this weight in degrees
    # of freedom (next field), so that 2-4 returns cannot claim a tiny covariance from one lucky fit.
    residual_prior_std: float = 0.15
    # Weight (degrees of freedom) of `residual_prior_std` in the pooled residual variance.
    residual_prior_dof: float = 2.0
    # The tangential velocity (across the mean line of sight) counts as unobservable when the inlier
    # returns' azimuths spread less than this std (deg); the estimate then falls back to radial-only.
    min_azimuth_spread_deg: float = 1.0
    # It also counts as unobservable when its predicted std (residual std / sqrt of the smallest
    # eigenvalue of A^T A, A the inliers' planar directions) exceeds this (m/s).
    max_tangential_std: float = 2.0
    # Inlier returns an object needs for its full planar velocity; with fewer it gets the radial-only estimate.
    # Why: two returns solve the 2x2 system exactly, with no residual to check it, and two returns of two
    # things (or one clutter return) 4-6 degrees apart solve to any speed (50-120 m/s seen in rush traffic),
    # reported with the prior's small std. 2 (the default): any two returns spreading enough. Opt-in (3): with
    # tentative_hits 2 it cost 0.42 dB of novel-view PSNR* at the grid budget on three strict tuning seeds, one run
    # each (docs/research/motion.md, fourteenth pass).
    min_full_fit_returns: int = 2
    # Correct the fit for the noise of the returns' directions (RadarConfig.azimuth_std, elevation_std):
    # plain least squares on noisy directions pulls the velocity across the line of sight toward the
    # radar's own (errors in variables); on crossing cars 1.5-2 deg wide that is 0.4-0.8 m/s too slow.
    correct_direction_noise: bool = True
    # Std (m/s) across the line of sight given to a radial-only (fallback) estimate: the speed scale of
    # road traffic, i.e. "unknown" without being infinite for the tracker.
    unobserved_std: float = 10.0
    # Tracking: std (m) of the returns' centroid about a fixed point of the object: returns wander over
    # the visible side of a car from scan to scan.
    centroid_std: float = 1.0
    # Tracking: white-acceleration process noise std (m/s^2) of the constant-velocity Kalman filter;
    # ordinary traffic accelerates and brakes within +-2 m/s^2 (3 made the tracked velocity ~20 %
    # noisier on the small synthetic scenes, 1.5 barely better).
    accel_std: float = 2.0
    # Tracking: the straight model's acceleration std (m/s^2) across the velocity of a track faster than
    # 1 m/s: a road vehicle brakes and accelerates along its heading; sideways it turns (the turning
    # model). 0.5 broke tracks where a car starts a lane change; 2 (isotropic) lost the calm seeds' gain.
    lateral_accel_std: float = 1.0
    # Tracking: std (rad/s) of a new track's yaw rate (it starts at 0): a lane change turns at up to
    # ~0.5 rad/s, a turn at an intersection ~0.3 rad/s.
    yaw_rate_std: float = 0.3
    # Tracking: white yaw-acceleration process noise std (rad/s^2); a lane change goes from 0 to
    # 0.45 rad/s and back within ~1 s.
    yaw_accel_std: float = 1.0
    # Tracking: a third model between straight and turning, for long bends: yaw-rate noise std
    # (rad/s^2) of a model that turns gently and accelerates like the straight one; 0 = no such model.
    gentle_turn_yaw_accel_std: float = 0.2
    # Tracking: per-scan probability of switching between the straight and the gently turning model.
    gentle_turn_switch_probability: float = 0.05
    # Tracking (interacting multiple models, straight and turning): per-scan probability that a
    # straight track starts turning, and that a turning one goes straight again.
    turn_start_probability: float = 0.05
    turn_end_probability: float = 0.2
    # Tracking: a detection may update a track when its squared Mahalanobis distance (4 dof: centroid
    # and velocity) is below this (chi-square 4 dof at 99.9 % = 18.47).
    gate_chi2: float = 18.47
    # Tracking: fuse every track's forward estimate with a backward pass over its later detections
    # (fixed-interval smoothing, `tracking.smooth_tracks`): a reconstruction is offline, and a track's
    # first scans, which often see only the radial velocity, then get what the later scans measured.
    smooth: bool = True
    # Tracking: a track not updated for more than this many consecutive frames is ended (0.5 s at
    # 10 Hz: a distant car's few returns drop out for several scans, and each new track has to learn
    # the tangential velocity again from the centroid's motion).
    max_missed: int = 5
    # Tracking: a track updated fewer than this many times is tentative: once it has missed a scan it takes a
    # detection only within `tentative_gate_chi2`. Why: a new track often knows only its radial velocity, so
    # after one coasted scan its full gate spans tens of metres across the line of sight and takes another
    # object's detection, whose offset the filter then reads as a velocity (a pedestrian tracked at 5 m/s).
    # 2 (the default since 2026-12-07, with anchor_visible_end): together they bring the per-scene velocity p90
    # over 36 tuning scenes from 0.503 to 0.367 m/s (anchored alone 0.424) and change novel-view PSNR* by +0.19 dB
    # over ten strict tuning grid runs (docs/research/motion.md, sixteenth pass). 1: no track is tentative.
    tentative_hits: int = 2
    # See tentative_hits: the squared Mahalanobis gate of a tentative track that has missed a scan (4 dof;
    # 4.0 keeps about 60 % of true re-detections: a distant crossing car seen every other scan still
    # learns its tangential velocity from them). 0: such a track ends at its first missed scan instead.
    tentative_gate_chi2: float = 4.0
    # Tracking: measure a moving track's position at the end of the object that faces the radar (its front-most
    # return along the heading when the front faces the radar, else its rear-most) moved half the object's
    # length inward, not at the returns' centroid. Why: the centroid slides along the body as the aspect
    # changes (a car crossing 40 m ahead at 17 m/s: +1.1 -> -1.9 m in 3.2 s), and the track reads that as
    # 0.95 m/s too slow; the end facing the radar stays put. A second tracking pass, on the first pass's
    # headings; the length is the track's anchor_length_quantile of its scans' extents along the heading.
    # The reported velocity is then the body's at that point (about the box centre), not at the returns' centroid:
    # moved to the centroid by the track's yaw rate, the strict tuning seeds' p90 error against the truth's velocity
    # rose on four of five (409: 0.23 -> 0.39 m/s) and against the body's at the centroid fell by at most 0.014.
    # On by default since 2026-12-07, with tentative_hits 2 (docs/research/motion.md, fifteenth and sixteenth
    # passes); alone it brings the velocity p90 over 36 tuning scenes from 0.503 to 0.424 m/s.
    anchor_visible_end: bool = True
    # See anchor_visible_end: tracks slower than this (m/s) keep the centroid (their heading is noise).
    anchor_min_speed: float = 2.0
    # See anchor_visible_end: a track needs this many scans with at least 3 returns to have a length.
    anchor_min_scans: int = 3
    # See anchor_visible_end: which quantile of those scans' extents is the object's length.
    anchor_length_quantile: float = 0.9
    # See anchor_visible_end: a scan is anchored only with this many returns and with the end facing the radar
    # by at least anchor_min_aspect (|cos| of the heading against the line of sight); the track's other scans keep
    # the centroid with an along-heading std of half its length. Why: a car 70 m out with 2-4 returns a scan and
    # seen nearly side-on shows no return on its end face, and its anchored position lay 1.3-3.3 m off.
    anchor_min_returns: int = 4
    anchor_min_aspect: float = 0.3


@dataclass
class RadarConfig:
    """Radar front-end options. Defaults suit an imaging radar with ~0.1 m/s Doppler noise."""

    # Doppler measurement noise std sigma_vr (m/s): sets the RANSAC inlier band and the dynamic
    # threshold. A 77 GHz imaging radar resolves about 0.1 m/s.
    noise_std: float = 0.1
    # Azimuth noise std sigma_az (rad). A direction error changes the predicted Doppler of a static
    # point by (dd/daz . v_s) * daz, so the inlier band widens with speed (0.005 rad = 0.3 deg).
    azimuth_std: float = 0.005
    # Elevation noise std sigma_el (rad); imaging radars resolve elevation worse (0.017 = 1 deg).
    elevation_std: float = 0.017
    # Inlier band half-width in sigmas for RANSAC and for the final inlier set.
    inlier_sigma: float = 3.0
    # A point is dynamic when |compensated v_r| exceeds this many sigmas (of the combined noise,
    # see classify_dynamic).
    dynamic_sigma: float = 3.0
    # RANSAC: probability of drawing at least one all-inlier sample (adaptive iteration count).
    confidence: float = 0.999
    # RANSAC: hard cap on the number of hypotheses.
    max_iterations: int = 1000
    # RANSAC: hypotheses evaluated together in one vectorised numpy batch.
    batch_size: int = 32
    # Least-squares refinement rounds (inliers -> LS -> inliers); stops early when the set is stable.
    refine_iterations: int = 3
    # The fit is `ok` only when at least this fraction of the valid points are inliers.
    min_inlier_fraction: float = 0.25
    # The fit needs at least this many valid points (and this many inliers).
    min_points: int = 5
    # Points closer than this (m) have no usable direction and are ignored.
    min_range: float = 0.1
    # Minimal samples whose (k x k) direction matrix has a smallest singular value below this are
    # skipped: they amplify the Doppler noise by 1/sigma_min.
    sample_min_singular: float = 0.02
    # The final normalised design matrix (inlier directions / sqrt(n)) must have its smallest
    # singular value above this, else the velocity is unobservable and ok = False.
    min_conditioning: float = 0.01
    # "3d" solves (vx, vy, vz); "2d" solves the planar model, vz = 0 (in the ego's x-y plane when
    # the scene processor passes the mounting, else the radar's), for radars with almost no
    # elevation spread, like a conventional automotive radar; "auto" fits 2d first and goes 3d only when the
    # STATIC INLIERS of that fit spread enough in elevation to determine vz (smallest singular
    # value of their directions >= `min_conditioning` * 3), and keeps 3d only when the 3d fit's own
    # inliers still do. (Deciding from all points let a tall moving truck make a flat radar 3d.)
    model: Literal["auto", "3d", "2d"] = "auto"
    # Variance prior (m/s) put on vz in 2d mode, so the covariance stays 3x3 and honest.
    vertical_std_2d: float = 0.5
    # Standstill check: when this fraction of the points have |v_r| below the inlier band, the
    # radar is taken as standing still (velocity 0 is added as a hypothesis and wins ties).
    standstill_fraction: float = 0.5
    # RANSAC scores each inlier by 1 / (points in its azimuth-elevation bin of this size, degrees), so
    # a compact dense object (a big truck) cannot outvote the static world spread over the field of
    # view. 0 = plain inlier count.
    angular_bin_deg: float = 5.0
    # Honesty check: the fit is not `ok` when more than this fraction of its inliers lie inside one
    # azimuth window (`cluster_window_fraction` of the scan's azimuth extent, at least two angular
    # bins): the static world seen from a moving radar spans the field of view, a big moving
    # object does not. 1 disables the check.
    max_cluster_fraction: float = 0.9
    # Width of that azimuth window as a fraction of the scan's azimuth extent (5-95 % percentiles).
    cluster_window_fraction: float = 0.25
    # Honesty check (when a prior velocity is given, e.g. the previous scan's): the fit is not `ok`
    # when it differs from the prior by more than this (m/s) plus 3 sigma of its own covariance.
    # 3 m/s between consecutive scans at 10 Hz is 30 m/s^2 (3 g), beyond any car. 0 disables it.
    prior_gate: float = 3.0
    # Random seed of the RANSAC sampler (np.random.default_rng); per frame the scene processor adds
    # the frame index so frames are independent but reproducible.
    seed: int = 0
    # Scene processing: ground-vehicle prior, the ego's velocity along its own z axis is 0 +- this
    # (m/s), added as one pseudo-observation to the least-squares refinement. A car moves along its
    # own x-y plane even on slopes; only suspension pitch breaks it. The radar's vertical velocity
    # is otherwise the worst-determined component (elevation noise, narrow elevation field).
    # 0 disables it.
    vertical_prior_std: float = 0.1
    # Scene processing: offer the previous frame's velocity as an extra RANSAC hypothesis.
    temporal_prior: bool = True
    # Scene processing: temporal smoothing of the ego velocity across frames; "none" keeps the
    # per-frame fit, "median" a running median, "mean" a covariance-weighted running mean.
    smoothing: Literal["none", "median", "mean"] = "none"
    # Scene processing: smoothing window in frames (odd).
    smoothing_window: int = 5
    # Scene processing: camera-radar clock offset (radar/sync.py, estimated from the Doppler speed against
    # the speed of the camera-time poses; always reported in summary.json "time_sync"). "auto" re-stamps
    # the radar scans by it (and places them at the ego pose of the corrected time) when it is
    # observable and larger than `sync_threshold`; "off" only reports it.
    sync: Literal["auto", "off"] = "auto"
    # Offsets up to this magnitude (s) are left alone: 10 ms moves a scan by 0.3 m at 30 m/s, and the
    # estimate's own error on the synthetic scenes is a few ms.
    sync_threshold: float = 0.01
    # The estimate scans offsets in [-sync_max_offset, sync_max_offset] (s).
    sync_max_offset: float = 0.2
    # Scene processing: dynamic points grouped into objects with a planar velocity each, tracked
    # across frames (<prepared>/radar/objects.json).
    objects: RadarObjectConfig = field(default_factory=RadarObjectConfig)

    PRESETS: ClassVar[Mapping[str, Mapping[str, Any]]] = {
        "tiny": {"max_iterations": 200},
        "small": {},
        "paper": {"max_iterations": 2000},
    }
