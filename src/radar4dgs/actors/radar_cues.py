"""Radar cues of actor discovery: the prepared radar objects (``<prepared>/radar/objects.json``, every
moving car's returns with their Doppler velocity) as an independent witness of what moves.

1. **Chains.** The radar tracker's tracks break up (a near car's returns split into two clusters, a
   far one drops out for a few scans), so tracks are linked into chains: two tracks seen in the same
   frames whose centroids stay within ``radar_link_distance`` (median), or one starting at most
   ``handover_seconds`` after the other ends where the other's constant-velocity prediction (radar
   velocity) puts it, at a similar velocity. Chains seen in at least ``radar_chain_frames`` frames are
   confirmed; the rest (clutter: one or two scans of two returns) supports nothing.
2. **Support.** A piece of dynamic Gaussians is supported in a frame when a confirmed chain's object
   lies within ``radar_gate`` of its centroid there; its chain is the one supporting most of its frames.
3. **Use.** Pieces on different confirmed chains seen at the same time are different objects (never
   merged); pieces on the same chain are one object (merged); an actor supported in fewer than
   ``min_radar_frames`` frames is dropped (dynamic residue the radar never saw move); and a confirmed
   chain that no actor took seeds an actor from the unassigned dynamic Gaussians along its path.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from radar4dgs.actors.config import ActorConfig


@dataclass
class RadarChains:
    """Per frame (F lists), the confirmed radar objects: ``centroids`` (M_f, 2) planar world, ``velocities``
    (M_f, 2) and ``chain`` (M_f,) chain id; ``frames`` chain id -> (n,) frame indices it is seen in."""

    centroids: list[np.ndarray]
    velocities: list[np.ndarray]
    chain: list[np.ndarray]
    frames: dict[int, np.ndarray]


def _track_table(radar_objects) -> dict[int, dict[int, tuple[np.ndarray, np.ndarray]]]:
    """track id -> {frame: (centroid (2,), velocity (2,))}; several objects of one track in one frame
    (never written by the tracker) keep the last."""
    table: dict[int, dict[int, tuple[np.ndarray, np.ndarray]]] = {}
    for f, objects in enumerate(radar_objects):
        for o in objects:
            state = (np.asarray(o.centroid[:2], float), np.asarray(o.velocity[:2], float))
            table.setdefault(int(o.track), {})[f] = state
    return table


def tracks_linked(a: dict, b: dict, timestamps: np.ndarray, config: ActorConfig) -> bool:
    """Whether two tracks ({frame: (centroid, velocity)}) are one object: seen together with a median
    centroid distance within ``radar_link_distance``, or ``b`` continuing ``a`` (or the reverse) within
    ``handover_seconds`` where the constant-velocity prediction puts it (``radar_link_distance``) at a
    velocity within twice ``merge_velocity``."""
    common = sorted(set(a) & set(b))
    if common:
        gaps = [np.linalg.norm(a[f][0] - b[f][0]) for f in common]
        return bool(np.median(gaps) <= config.radar_link_distance)
    if min(a) > min(b):
        a, b = b, a
    end, start = max(a), min(b)
    dt = float(timestamps[start] - timestamps[end])
    if dt > config.handover_seconds:
        return False
    (pa, va), (pb, vb) = a[end], b[start]
    return bool(np.linalg.norm(pa + va * dt - pb) <= config.radar_link_distance
                and np.linalg.norm(va - vb) <= 2 * config.merge_velocity)


def radar_chains(radar_objects, timestamps: np.ndarray, config: ActorConfig) -> RadarChains:
    """The confirmed chains (module doc) of the radar objects of F frames (``load_radar_objects``) at the
    frames' ``timestamps`` (F,) s."""
    from scipy.sparse import coo_matrix
    from scipy.sparse.csgraph import connected_components

    num_frames = len(timestamps)
    table = _track_table(radar_objects[:num_frames])
    ids = sorted(table)
    pairs = [(i, j) for i in range(len(ids)) for j in range(i + 1, len(ids))
             if tracks_linked(table[ids[i]], table[ids[j]], timestamps, config)]
    rows, cols = (list(x) for x in zip(*pairs, strict=True)) if pairs else ([], [])
    component = connected_components(coo_matrix((np.ones(len(rows)), (rows, cols)), shape=(len(ids),) * 2),
                                     directed=False)[1] if ids else np.zeros(0, dtype=np.int64)
    seen: dict[int, set[int]] = {}
    for k, track in enumerate(ids):
        seen.setdefault(int(component[k]), set()).update(table[track])
    confirmed = {c for c, frames in seen.items() if len(frames) >= config.radar_chain_frames}
    chain_of = {track: int(component[k]) for k, track in enumerate(ids) if int(component[k]) in confirmed}
    centroids, velocities, chains = [], [], []
    for f in range(num_frames):
        kept = [(table[t][f], chain_of[t]) for t in ids if t in chain_of and f in table[t]]
        centroids.append(np.array([k[0][0] for k in kept]).reshape(-1, 2))
        velocities.append(np.array([k[0][1] for k in kept]).reshape(-1, 2))
        chains.append(np.array([k[1] for k in kept], dtype=np.int64))
    return RadarChains(centroids, velocities, chains, {c: np.array(sorted(seen[c])) for c in sorted(confirmed)})


def support(centroid: np.ndarray, frames: np.ndarray, chains: RadarChains, gate: float) -> np.ndarray:
    """(len(frames),) int64: per frame of ``frames``, the chain of the nearest confirmed radar object
    within ``gate`` m (planar) of the track ``centroid`` (F, 3), -1 where none."""
    out = np.full(len(frames), -1, dtype=np.int64)
    for k, f in enumerate(frames):
        if len(chains.chain[f]):
            distance = np.linalg.norm(chains.centroids[f] - centroid[f, :2], axis=1)
            if distance.min() <= gate:
                out[k] = chains.chain[f][int(distance.argmin())]
    return out


def main_chain(supported: np.ndarray) -> int:
    """The chain supporting most frames of (V,) ``support`` output, -1 when none does."""
    hits = supported[supported >= 0]
    return int(np.bincount(hits).argmax()) if len(hits) else -1


def radar_velocity(centroid: np.ndarray, frames: np.ndarray, chains: RadarChains, gate: float,
                   min_frames: int) -> np.ndarray:
    """(len(frames), 2) planar velocity (m/s) that the radar measured for a body with track ``centroid``
    (F, 3) at ``frames``, NaN where none: the (mean) velocity of the objects of the chains that support
    it (:func:`support`) in at least ``min_frames`` frames or most often. Doppler measures the velocity;
    the deformation field of a short training learns it only roughly."""
    supported = support(centroid, frames, chains, gate)
    counts = np.bincount(supported[supported >= 0], minlength=1)
    trusted = set(np.flatnonzero(counts >= min_frames).tolist()) | {main_chain(supported)}
    out = np.full((len(frames), 2), np.nan)
    for k, (f, chain) in enumerate(zip(frames, supported, strict=True)):
        if chain >= 0 and chain in trusted:
            out[k] = chains.velocities[f][chains.chain[f] == chain].mean(axis=0)
    return out


def distinct_objects(chain_a: int, chain_b: int, chains: RadarChains) -> bool:
    """Whether two confirmed chains are two objects seen at the same time (so pieces on them never merge);
    chains never seen together may be one object the tracker lost in between."""
    if chain_a < 0 or chain_b < 0 or chain_a == chain_b:
        return False
    return len(np.intersect1d(chains.frames[chain_a], chains.frames[chain_b])) > 0


def seed_members(chain: int, chains: RadarChains, trajectories: np.ndarray, opacities: np.ndarray,
                 candidates: np.ndarray, config: ActorConfig) -> np.ndarray:
    """(K,) the ``candidates`` (indices into the N dynamic Gaussians' ``trajectories`` (N, F, 3) and
    ``opacities`` (N, F)) that follow confirmed chain ``chain``: opaque (``min_opacity``) in at least
    ``radar_chain_frames`` of its frames, and within ``radar_gate`` of its object in most (half) of those."""
    frames = chains.frames[chain]
    # A near car can show as two objects of one chain in a frame: their mean.
    where = np.stack([chains.centroids[f][chains.chain[f] == chain].mean(axis=0) for f in frames])  # (n, 2)
    points = trajectories[candidates][:, frames, :2]  # (C, n, 2)
    opaque = opacities[candidates][:, frames] >= config.min_opacity
    near = np.linalg.norm(points - where[None], axis=2) <= config.radar_gate
    count = opaque.sum(axis=1)
    keep = (count >= config.radar_chain_frames) & ((near & opaque).sum(axis=1) * 2 >= np.maximum(count, 1))
    return candidates[keep]
