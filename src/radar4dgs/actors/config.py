"""Options of actor discovery (:mod:`radar4dgs.actors.discover`)."""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any, ClassVar, Mapping


@dataclass
class ActorConfig:
    """Grouping the dynamic Gaussians into actors: trajectories sampled under the deformation field,
    a motion-affinity graph, its connected components, opacity-weighted tracks, merges of pieces that
    move as one body, then a spurious-actor filter."""

    # Trajectories are sampled at this many of the scene's frame times (evenly spread, first and last
    # included); all frames when the scene has fewer. The affinity test is a max over these samples.
    sample_frames: int = 16
    # Two Gaussians are linked when, at EVERY sampled time, they lie within this distance (m, per axis:
    # the Chebyshev distance of their stacked trajectories). Neighbouring Gaussians on one car are
    # ~0.1-0.5 m apart, so the chain of links spans the car; two cars that pass each other are close
    # at one time only, and two cars in adjacent lanes ~3.5 m apart are never linked.
    link_distance: float = 0.8
    # Each Gaussian links to at most this many nearest others within `link_distance` (a sparse graph
    # that stays connected across a body, at a cost linear in the number of Gaussians).
    neighbours: int = 12
    # Gaussians whose opacity is below this take no part (they barely render).
    min_opacity: float = 0.05
    # Gaussians that move less than this (m, largest displacement from their mean position over the
    # sampled times) are not part of any moving actor (dynamic Gaussians the field keeps still).
    min_motion: float = 0.5
    # A component with fewer Gaussians is no actor; its Gaussians join the nearest actor when within
    # `attach_distance` (same Chebyshev measure), else stay unassigned.
    min_gaussians: int = 15
    # See `min_gaussians`.
    attach_distance: float = 2.0
    # Two pieces seen together in at least `merge_frames` frames are one body when the median offset of
    # their opacity-weighted centroids is within this distance along the first's heading (m: half a car
    # length, centroid to centroid of two halves), within `merge_lateral` across it, and their median
    # velocity difference is below `merge_velocity`. Tuned on realistic seed 101 (small) only.
    merge_distance: float = 5.0
    # See `merge_distance` (m). Cars side by side in adjacent lanes are ~3.5 m apart: never merged.
    merge_lateral: float = 1.5
    # See `merge_distance` (m/s, planar); also the largest velocity jump of a hand-over.
    merge_velocity: float = 2.0
    # See `merge_distance`; fewer common frames: only a hand-over can merge them.
    merge_frames: int = 3
    # One piece takes over where another stops (the same car, its Gaussians of two time spans apart):
    # the later starts at most this many seconds after the earlier's last frame, where the earlier's
    # constant-velocity extrapolation (or the later's, backwards) puts it within the offsets above.
    handover_seconds: float = 1.0
    # An actor is there in a frame when its opacity mass (sum of its Gaussians' opacities, life span
    # included) is at least this fraction of its largest over the sequence.
    presence_fraction: float = 0.3
    # Spurious-actor filter: an actor seen in fewer frames is dropped (the benchmark needs 3 common frames
    # to match an actor to anything).
    min_frames: int = 3
    # Spurious-actor filter (m): an actor whose centroid moves less than this, planar, between its first
    # and last frame of visibility is dropped (dynamic residue on still surfaces).
    min_displacement: float = 1.0
    # A radar object belongs to an actor in a frame when its centroid lies within this margin (m, planar)
    # of the actor's Gaussians' bounding box there.
    radar_margin: float = 1.5
    # A frame counts as a frame of visibility when the actor is there (`presence_fraction`) and at least
    # this fraction of its opacity mass projects inside the image in front of the camera and within `max_range` of it.
    visible_fraction: float = 0.2
    # See `visible_fraction` (m).
    max_range: float = 80.0
    # Radar cues (radar_cues.py; only when the prepared folder has radar objects). Radar tracks are
    # linked into chains (the tracker loses a car for a few scans, or sees a near one as two clusters):
    # tracks seen together with a median centroid distance within this (m), or one continuing the other
    # within `handover_seconds` where the first's radar velocity predicts it, within this distance.
    radar_link_distance: float = 2.5
    # A chain seen in fewer frames is clutter (one or two scans of two returns) and supports nothing.
    radar_chain_frames: int = 3
    # A piece of Gaussians is supported by radar in a frame when a confirmed chain's object lies within
    # this planar distance (m) of its centroid (both are centroids of the surfaces their sensor sees).
    radar_gate: float = 3.0
    # Spurious-actor filter: an actor supported by radar in fewer of its frames of visibility is dropped
    # (the radar saw nothing move there); 0 turns the filter off.
    min_radar_frames: int = 2
    # A confirmed chain that no actor took seeds an actor from the unassigned moving Gaussians along it
    # (at least `min_gaussians` of them): a car the short training learnt too faintly to form a piece.
    radar_seeds: bool = True
    # In the frames where a radar chain supports an actor, its velocity is the radar's (Doppler measures
    # it; the deformation field of a short training learns it roughly); elsewhere its Gaussians'.
    radar_velocity: bool = True
    # A car-like actor's centre is completed to this footprint (length, width; m), away from the camera,
    # where less of it was seen: its Gaussians are those of the faces the camera saw, so their centroid
    # sits on the camera's side of the body. A common car's size; 0 0 keeps the Gaussians' centroid.
    car_size: tuple[float, float] = (4.4, 1.8)

    PRESETS: ClassVar[Mapping[str, Mapping[str, Any]]] = {
        # One set of values for every size: the thresholds are metres in the world, not pixels.
        "tiny": {}, "small": {}, "paper": {"sample_frames": 24},
    }
