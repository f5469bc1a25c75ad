"""Scene-level treatment of the per-frame fits, across frames.

:func:`temporal_refine` re-fits each ``affine`` frame on a window of its neighbours' inliers;
:func:`limit_metric_correction` rejects fits that move an already metric prior too far; and
:func:`fill_from_neighbours` gives every frame its :class:`FrameParameters`, taking them from the
nearest good frames in time where its own fit failed.
"""

from __future__ import annotations

import math
import warnings
from dataclasses import dataclass

import numpy as np

from radar4dgs.depth.config import DepthConfig
from radar4dgs.depth.pairs import DepthWarning, FrameFit, finish_fit


def _window_irls(x: np.ndarray, z: np.ndarray, d: np.ndarray, w: np.ndarray, a: float, b: float,
                 scale_only: bool, drift: bool, threshold: float, huber_delta: float, iterations: int
                 ) -> tuple[float, float]:
    """Huber IRLS of ``z ((a + alpha d) x + (b + beta d)) = 1`` on pairs with prior weights ``w``
    (frame offsets ``d``), started at ``(a, b)`` with no drift; returns the centre ``(a, b)``
    (NaN when fewer than 2 pairs stay within ``threshold``). ``scale_only``: b = beta = 0;
    ``drift`` False: alpha = beta = 0."""
    columns = [z * x] + ([] if scale_only else [z])
    if drift:
        columns += [z * x * d] + ([] if scale_only else [z * d])
    design = np.stack(columns, axis=1)
    theta = np.zeros(design.shape[1])
    theta[0] = a
    if not scale_only:
        theta[1] = b
    for _ in range(iterations + 1):
        r = design @ theta - 1.0
        keep = np.abs(r) < threshold
        if keep.sum() < design.shape[1]:
            return math.nan, math.nan
        sw = np.sqrt(w[keep] * np.minimum(1.0, huber_delta / np.maximum(np.abs(r[keep]), 1e-12)))
        new, *_ = np.linalg.lstsq(design[keep] * sw[:, None], sw, rcond=None)
        step = np.abs(new[:2] - theta[:2]).max()
        theta = new
        if step <= 1e-12 * abs(theta[0]):
            break
    return float(theta[0]), (0.0 if scale_only else float(theta[1]))


def temporal_refine(fits: list[FrameFit], config: DepthConfig) -> list[FrameFit]:
    """Temporal consistency of the ``affine`` per-frame parameters (``config.temporal_window``).

    Frame i's ``(a_i, b_i)`` is re-fitted on the robust-fit inliers of every good frame j with
    ``|j - i| <= half = temporal_window // 2`` (its own included), each pair weighted
    ``1 - |j - i| / (half + 1)``, with the model ``1/z = (a_i + alpha (j - i)) x + (b_i + beta (j - i))``:
    scale and shift drift linearly across the window (locally linear regression in time), so a
    slow drift is followed without bias and the per-frame pair noise averages out. Each pair keeps
    its own frame's prior value ``x_j``. Frames whose fit failed are not used and stay failed (the
    neighbour fallback fills them afterwards); ``paper`` fits and ``temporal_window`` 1 are returned
    unchanged. Each refined fit keeps its per-frame parameters in ``extra["frame_a"]`` /
    ``extra["frame_b"]`` and the frames used in ``extra["window_frames"]``.
    """
    half = config.temporal_window // 2
    if half == 0:
        return list(fits)
    out: list[FrameFit] = []
    for i, fit in enumerate(fits):
        if not (fit.ok and fit.method == "affine"):
            out.append(fit)
            continue
        used = [j for j in range(max(0, i - half), min(len(fits), i + half + 1))
                if fits[j].ok and fits[j].method == "affine" and fits[j].num_inliers > 0]
        xs, zs, ds, ws = [], [], [], []
        for j in used:
            inl = fits[j].inliers
            xs.append(fits[j].pairs.x[inl])
            zs.append(fits[j].pairs.z[inl])
            ds.append(np.full(int(inl.sum()), float(j - i)))
            ws.append(np.full(int(inl.sum()), 1.0 - abs(j - i) / (half + 1.0)))
        # A drift needs data at two offsets at least; otherwise this is the frame's own fit again.
        a, b = _window_irls(np.concatenate(xs), np.concatenate(zs), np.concatenate(ds), np.concatenate(ws),
                            fit.a, fit.b, fit.scale_only, len(used) >= 2, config.inlier_threshold,
                            config.huber_delta, config.irls_iterations)
        if not (math.isfinite(a) and a > 0 and math.isfinite(b)):
            out.append(fit)  # keep the frame's own fit
            continue
        extra = {**fit.extra, "frame_a": fit.a, "frame_b": fit.b, "window_frames": used}
        refined = FrameFit(fit.method, a, b, True, fit.reason, fit.pairs, fit.inliers, fit.votes,
                           fit.scale_only, extra=extra)
        out.append(finish_fit(refined))
    return out


def limit_metric_correction(fits: list[FrameFit], max_change: float, x_min: float) -> list[FrameFit]:
    """Reject the fits that move an already metric prior (``x = 1 / depth``) too far.

    A fit multiplies the prior's depth by ``x / (a x + b)``, monotonic in ``x``; over the prior's
    whole range ``[x_min, inf)`` (``x_min = 1 / farthest depth``) the largest change is at an end:
    ``x_min / (a x_min + b)`` or ``1 / a``. The radar inliers of a sparse radar sit in a narrow
    span (the few ground returns are near), so the fit is judged where it is extrapolated too.
    Fits whose change exceeds ``max_change`` (a fraction) come back with ``ok`` False and the
    reason (pairs and inliers kept for the summary); the others unchanged.
    """
    out = []
    for fit in fits:
        if not fit.ok:
            out.append(fit)
            continue
        far = fit.a * x_min + fit.b
        ratios = np.array([x_min / far if far > 0 else math.inf, 1.0 / fit.a])
        change = float(np.max(np.abs(ratios - 1.0)))
        if change <= max_change:
            out.append(fit)
            continue
        what = f"by {change:.0%}" if math.isfinite(change) else "to beyond infinity at its far end"
        out.append(FrameFit(fit.method, math.nan, math.nan, False,
                            f"radar fit changes the metric prior's depth {what} (> {max_change:.0%})",
                            fit.pairs, fit.inliers, fit.votes, fit.scale_only,
                            extra={**fit.extra, "rejected_a": fit.a, "rejected_b": fit.b}))
    return out


@dataclass(frozen=True)
class FrameParameters:
    """The parameters a frame's metric depth is made with, and where they come from."""

    a: float
    b: float
    source: str  # "fit", "neighbours", "metric prior"
    from_frames: tuple[int, ...] = ()


def fill_from_neighbours(fits: list[FrameFit], timestamps, names=None, metric_prior: bool = False
                         ) -> list[FrameParameters]:
    """Per-frame parameters: a frame's own fit when ``ok``, else the time-interpolation of the
    nearest good frames before and after it (the one good neighbour where only one side has one),
    with a :class:`DepthWarning`. When no frame has a fit: a ``metric_prior`` (already metric, as
    the flat-world source) is used as it is (a = 1, b = 0, source "metric prior", one warning);
    otherwise ValueError.
    """
    timestamps = np.asarray(timestamps, dtype=np.float64)
    names = list(names) if names is not None else [str(i) for i in range(len(fits))]
    good = [i for i, fit in enumerate(fits) if fit.ok]
    if not good and metric_prior and fits:
        reasons = sorted({f.reason for f in fits})
        listed = "; ".join(reasons[:3]) + ("; ..." if len(reasons) > 3 else "")
        warnings.warn(f"depth: no frame has a radar fit ({listed}); the metric prior is used unscaled "
                      "(scale 1, shift 0)", DepthWarning, stacklevel=2)
        return [FrameParameters(1.0, 0.0, "metric prior") for _ in fits]
    if not good:
        raise ValueError("no frame has enough validated radar pairs for scale recovery "
                         f"({fits[0].reason if fits else 'no frames'}); check the radar calibration, "
                         "lower min_pairs, or use another scale method")
    out: list[FrameParameters] = []
    for i, fit in enumerate(fits):
        if fit.ok:
            out.append(FrameParameters(fit.a, fit.b, "fit"))
            continue
        before = [g for g in good if g < i]
        after = [g for g in good if g > i]
        p, q = (before[-1] if before else None), (after[0] if after else None)
        if p is not None and q is not None:
            t = (timestamps[i] - timestamps[p]) / (timestamps[q] - timestamps[p])
            a = (1 - t) * fits[p].a + t * fits[q].a
            b = (1 - t) * fits[p].b + t * fits[q].b
            sources = (p, q)
        else:
            g = p if p is not None else q
            a, b, sources = fits[g].a, fits[g].b, (g,)
        warnings.warn(f"depth: frame {names[i]}: {fit.reason}; using the scale of frame(s) "
                      f"{', '.join(names[s] for s in sources)}", DepthWarning, stacklevel=2)
        out.append(FrameParameters(float(a), float(b), "neighbours", tuple(int(s) for s in sources)))
    return out
