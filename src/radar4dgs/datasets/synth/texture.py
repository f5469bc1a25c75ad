"""Procedural textures: seeded value noise, anti-aliased stripes and pulses.

Textures are functions of the hit point in road coordinates, so a surface keeps its pattern as
the camera moves (optical flow needs that). Octaves and stripes finer than a pixel's footprint on
the surface are faded out, which stands in for supersampling.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np


@dataclass(frozen=True)
class ValueNoise:
    """A seeded 2D value-noise lattice: ``perm`` (512,) int64 hash table, ``values`` (256,) in 0..1."""

    perm: np.ndarray
    values: np.ndarray


def make_noise(rng: np.random.Generator) -> ValueNoise:
    perm = rng.permutation(256)
    return ValueNoise(np.concatenate([perm, perm]).astype(np.int64), rng.random(256))


def _lattice(noise: ValueNoise, ix: np.ndarray, iy: np.ndarray) -> np.ndarray:
    return noise.values[noise.perm[noise.perm[ix & 255] + (iy & 255)]]


def value_noise(noise: ValueNoise, x: np.ndarray, y: np.ndarray) -> np.ndarray:
    """Smooth noise in 0..1 at (...,) coordinates, one lattice cell per unit."""
    fx, fy = np.floor(x), np.floor(y)
    ix, iy = fx.astype(np.int64), fy.astype(np.int64)
    tx, ty = x - fx, y - fy
    tx, ty = tx * tx * (3 - 2 * tx), ty * ty * (3 - 2 * ty)
    top = _lattice(noise, ix, iy) * (1 - tx) + _lattice(noise, ix + 1, iy) * tx
    bottom = _lattice(noise, ix, iy + 1) * (1 - tx) + _lattice(noise, ix + 1, iy + 1) * tx
    return top * (1 - ty) + bottom * ty


def fbm(noise: ValueNoise, x: np.ndarray, y: np.ndarray, scale: float, octaves: int,
        footprint: np.ndarray | float = 0.0, gain: float = 0.55) -> np.ndarray:
    """Fractal noise in about 0..1 with feature size ``scale`` (m) and ``octaves`` finer octaves.

    Octave k has cells of ``scale / 2**k``; it fades to its mean once cells shrink below the
    ``footprint`` (m, (...,) or scalar) of a pixel, so distant texture does not alias.
    """
    total = np.zeros(np.broadcast(x, y).shape)
    weight_sum = 0.0
    for k in range(octaves):
        cell = scale / 2 ** k
        fade = np.clip(2.0 - 2.0 * np.asarray(footprint) / cell, 0.0, 1.0)
        weight = gain ** k
        offset = 37.7 * k
        total += weight * fade * (value_noise(noise, x / cell + offset, y / cell - offset) - 0.5)
        weight_sum += weight
    return 0.5 + total / weight_sum * 1.6


def hash01(index: np.ndarray, salt: int = 0) -> np.ndarray:
    """Deterministic pseudo-random value in 0..1 per integer (...,) ``index``."""
    h = (np.asarray(index, dtype=np.int64) * 2654435761 + salt * 97531) & 0xFFFFFFFF
    h = (h ^ (h >> 15)) * 2246822519 & 0xFFFFFFFF
    h = h ^ (h >> 13)
    return (h & 0xFFFF) / 65535.0


def band(x: np.ndarray, lo: float, hi: float, footprint: np.ndarray | float) -> np.ndarray:
    """Anti-aliased coverage (0..1) of the interval [lo, hi] at (...,) coordinates ``x``."""
    fw = np.maximum(np.asarray(footprint), 1e-4)
    return np.clip((np.minimum(x - lo, hi - x)) / fw + 0.5, 0.0, 1.0)


def periodic_band(x: np.ndarray, period: float, lo: float, hi: float,
                  footprint: np.ndarray | float) -> np.ndarray:
    """Coverage of [lo, hi] repeated every ``period``; fades to the mean duty when finer than a pixel."""
    cov = band(np.mod(x, period), lo, hi, footprint)
    duty = (hi - lo) / period
    fade = np.clip(2.0 - 2.0 * np.asarray(footprint) / ((hi - lo) + 1e-9), 0.0, 1.0)
    return fade * cov + (1 - fade) * duty


def smoothstep(lo: float, hi: float, x: np.ndarray) -> np.ndarray:
    t = np.clip((x - lo) / (hi - lo), 0.0, 1.0)
    return t * t * (3 - 2 * t)
