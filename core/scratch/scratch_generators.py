"""Scratch-set generators: uniform wear, circular polishing marks, hairline brushing, user curves.

All generators build polylines in micrometres on the patch [0, Px] x [0, Py], cut them into
segments no longer than ``segment_um`` (curved scratches become polylines), clip them to the patch
and index them with :func:`make_scratch_set`. Widths and depths default to the thesis' ranges,
uniform in 0.8-6 um, drawn once per scratch (constant along it).
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np
from numpy.typing import ArrayLike

from .scratch_set import ScratchSet, make_scratch_set

THESIS_RANGE_UM = (0.8, 6.0)


def _clip_to_patch(seg: np.ndarray, ps: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Liang-Barsky clip of segments (M, 4) to [0, Px] x [0, Py]; returns (clipped, kept mask)."""
    x0, y0 = seg[:, 0], seg[:, 1]
    dx, dy = seg[:, 2] - x0, seg[:, 3] - y0
    t0 = np.zeros(len(seg))
    t1 = np.ones(len(seg))
    keep = np.ones(len(seg), dtype=bool)
    for p, q in ((-dx, x0), (dx, ps[0] - x0), (-dy, y0), (dy, ps[1] - y0)):
        par = p == 0
        keep &= ~(par & (q < 0))
        with np.errstate(divide="ignore", invalid="ignore"):
            r = np.where(par, 0.0, q / np.where(par, 1.0, p))
        t0 = np.where(~par & (p < 0), np.maximum(t0, r), t0)
        t1 = np.where(~par & (p > 0), np.minimum(t1, r), t1)
    keep &= t1 - t0 > 1e-9
    out = np.stack([x0 + t0 * dx, y0 + t0 * dy, x0 + t1 * dx, y0 + t1 * dy], axis=1)
    return out[keep], keep


def polylines_to_segments(
    polylines: Sequence[ArrayLike], patch_size_um: ArrayLike, segment_um: float
) -> tuple[np.ndarray, np.ndarray]:
    """Resample each polyline (K, 2) so no piece exceeds ``segment_um``; clip to the patch.

    Returns (segments (M, 4), scratch index (M,)).
    """
    ps = np.asarray(patch_size_um, dtype=np.float64)
    segs, ids = [], []
    for i, pl in enumerate(polylines):
        p = np.asarray(pl, dtype=np.float64).reshape(-1, 2)
        if p.shape[0] < 2:
            raise ValueError(f"curve {i} needs at least two points, got {p.shape[0]}")
        if not np.all(np.isfinite(p)):
            raise ValueError(f"curve {i} holds non-finite coordinates")
        d = np.linalg.norm(np.diff(p, axis=0), axis=1)
        p = p[np.concatenate([[True], d > 0])]
        if p.shape[0] < 2:
            continue
        d = np.linalg.norm(np.diff(p, axis=0), axis=1)
        n = np.maximum(1, np.ceil(d / segment_um).astype(int))
        pts = [p[:1]]
        for j in range(len(d)):
            t = np.arange(1, n[j] + 1)[:, None] / n[j]
            pts.append(p[j] + t * (p[j + 1] - p[j]))
        q = np.concatenate(pts)
        segs.append(np.concatenate([q[:-1], q[1:]], axis=1))
        ids.append(np.full(len(q) - 1, i))
    if not segs:
        return np.zeros((0, 4)), np.zeros(0, np.int64)
    seg, keep = _clip_to_patch(np.concatenate(segs), ps)
    return seg, np.concatenate(ids)[keep]


def _finish(polylines, patch, rng, width_range, depth_range, segment_um, **kw) -> ScratchSet:
    seg, ids = polylines_to_segments(polylines, patch, segment_um)
    n = len(polylines)
    w = rng.uniform(*width_range, n)
    d = rng.uniform(*depth_range, n)
    return make_scratch_set(seg, w[ids], d[ids], patch, scratch_id=ids, **kw)


def uniform_wear(
    n_scratches: int,
    patch_size_um: ArrayLike = (20000.0, 20000.0),
    *,
    length_um: tuple[float, float] = (300.0, 4000.0),
    curvature_per_mm: float = 0.3,
    width_um: tuple[float, float] = THESIS_RANGE_UM,
    depth_um: tuple[float, float] = THESIS_RANGE_UM,
    segment_um: float = 250.0,
    seed: int = 0,
    **index_kw,
) -> ScratchSet:
    """Random wear: scratches at uniform positions and orientations, gently curved (random arc)."""
    rng = np.random.default_rng(seed)
    ps = np.asarray(patch_size_um, dtype=np.float64)
    lines = []
    for _ in range(int(n_scratches)):
        start = rng.uniform(0, 1, 2) * ps
        ang = rng.uniform(0, 2 * np.pi)
        length = rng.uniform(*length_um)
        kappa = rng.normal(0, curvature_per_mm) / 1000.0
        s = np.linspace(0, length, max(2, int(length / segment_um) + 2))
        th = ang + kappa * s
        dxy = np.stack([np.cos(th), np.sin(th)], 1)
        pts = start + np.concatenate([[[0, 0]], np.cumsum(dxy[1:] * np.diff(s)[:, None], axis=0)])
        lines.append(pts)
    return _finish(lines, ps, rng, width_um, depth_um, segment_um, **index_kw)


def circular_polish(
    n_scratches: int,
    patch_size_um: ArrayLike = (20000.0, 20000.0),
    *,
    radius_um: tuple[float, float] | None = None,
    arc_rad: tuple[float, float] = (0.2, 1.5),
    centre_um: ArrayLike | None = None,
    width_um: tuple[float, float] = THESIS_RANGE_UM,
    depth_um: tuple[float, float] = THESIS_RANGE_UM,
    segment_um: float = 250.0,
    seed: int = 0,
    **index_kw,
) -> ScratchSet:
    """Circular polishing marks: arcs of circles around one centre (default: the patch centre).

    ``radius_um`` defaults to (0.05, 0.7) x the patch's smaller side.
    """
    rng = np.random.default_rng(seed)
    ps = np.asarray(patch_size_um, dtype=np.float64)
    if radius_um is None:
        radius_um = (0.05 * ps.min(), 0.7 * ps.min())
    c = ps / 2 if centre_um is None else np.asarray(centre_um, dtype=np.float64)
    lines = []
    for _ in range(int(n_scratches)):
        r = rng.uniform(*radius_um)
        a0 = rng.uniform(0, 2 * np.pi)
        span = rng.uniform(*arc_rad)
        n = max(2, int(r * span / segment_um) + 2)
        a = a0 + np.linspace(0, span, n)
        lines.append(c + r * np.stack([np.cos(a), np.sin(a)], 1))
    return _finish(lines, ps, rng, width_um, depth_um, segment_um, **index_kw)


def hairline_brush(
    n_scratches: int,
    patch_size_um: ArrayLike = (20000.0, 20000.0),
    *,
    angle_rad: float = 0.0,
    jitter_rad: float = 0.01,
    waviness_um: float = 20.0,
    width_um: tuple[float, float] = THESIS_RANGE_UM,
    depth_um: tuple[float, float] = THESIS_RANGE_UM,
    segment_um: float = 500.0,
    seed: int = 0,
    **index_kw,
) -> ScratchSet:
    """Hairline brushing: long, nearly parallel lines crossing the whole patch along ``angle_rad``."""
    rng = np.random.default_rng(seed)
    ps = np.asarray(patch_size_um, dtype=np.float64)
    diag = float(np.hypot(*ps))
    lines = []
    for _ in range(int(n_scratches)):
        a = angle_rad + rng.normal(0, jitter_rad)
        t = np.array([np.cos(a), np.sin(a)])
        nrm = np.array([-t[1], t[0]])
        off = rng.uniform(-0.5, 0.5) * diag
        s = np.linspace(-0.6 * diag, 0.6 * diag, max(2, int(1.2 * diag / segment_um) + 1))
        wav = waviness_um * np.sin(2 * np.pi * s / rng.uniform(3000, 12000) + rng.uniform(0, 2 * np.pi))
        lines.append(ps / 2 + s[:, None] * t + (off + wav)[:, None] * nrm)
    return _finish(lines, ps, rng, width_um, depth_um, segment_um, **index_kw)


def from_curves(
    curves: Sequence[ArrayLike],
    patch_size_um: ArrayLike,
    *,
    width_um: float | ArrayLike | tuple[float, float] = THESIS_RANGE_UM,
    depth_um: float | ArrayLike | tuple[float, float] = THESIS_RANGE_UM,
    uv: bool = False,
    segment_um: float = 250.0,
    seed: int = 0,
    **index_kw,
) -> ScratchSet:
    """Scratches from user-drawn curves: a list of (K, 2) point arrays (um, or UV in [0, 1] with uv=True).

    ``width_um``/``depth_um``: a (lo, hi) range sampled per curve, a scalar, or one value per curve.
    """
    ps = np.asarray(patch_size_um, dtype=np.float64)
    rng = np.random.default_rng(seed)
    lines = [np.asarray(c, dtype=np.float64).reshape(-1, 2) * (ps if uv else 1.0) for c in curves]
    n = len(lines)

    def per_curve(v, name):
        if isinstance(v, tuple) and len(v) == 2:
            return rng.uniform(v[0], v[1], n)
        a = np.asarray(v, dtype=np.float64)
        if a.ndim == 0:
            return np.full(n, float(a))
        if a.shape == (n,):
            return a
        raise ValueError(f"{name} must be a (lo, hi) tuple, a scalar or one value per curve ({n})")

    w, d = per_curve(width_um, "width_um"), per_curve(depth_um, "depth_um")
    seg, ids = polylines_to_segments(lines, ps, segment_um)
    return make_scratch_set(seg, w[ids], d[ids], ps, scratch_id=ids, **index_kw)
