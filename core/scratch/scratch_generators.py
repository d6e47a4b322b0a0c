"""Scratch-set generators: uniform wear, circular polishing marks, hairline brushing, user curves.

All generators build polylines in micrometres on the patch [0, Px] x [0, Py], cut them into
segments no longer than ``segment_um`` (curved scratches become polylines), bring them onto the patch
(``boundary``, below) and index them with :func:`make_scratch_set`. Widths and depths default to
the thesis' ranges, uniform in 0.8-6 um, drawn once per scratch (constant along it).

The patch tiles the surface. ``boundary="wrap"`` moves each segment by a whole number of patch sizes
so that its midpoint lies in the patch: a scratch leaving the patch at one side comes back at the
opposite side, as it continues into the neighbouring tile, so the pattern tiles without a seam (the
grid index and the lookup see across borders, ``scratch_set``). ``boundary="clip"`` cuts scratches
at the patch border: the scratch density then falls towards the borders (points within a scratch
length of a border miss the scratches that would have started outside; 4000 wear scratches of
0.3-4 mm on a 20 mm patch, 300 um footprint: mean rho_P 0.62 x its interior value within 100 um of
a border, 0.72 x at 0.4-0.8 mm), a frame around every tile. Defaults: ``uniform_wear`` wraps;
``circular_polish`` and ``hairline_brush`` clip (their patterns have a centre / run across the whole
patch); ``from_curves`` clips (the user drew them where they are). ``circular_polish(...,
centres=k, boundary="wrap")`` is the tileable polishing variant: k polishing centres at random
positions instead of one at the patch centre.

Each takes an optional ``progress`` callback, called with strictly increasing fractions of the work
done, the last one 1.0 (stages: polylines 0-20 %, segments 20-35 %, grid index 35-100 %; the grid
index is most of the time). An exception raised by the callback stops the generation (a cancel).
Measured on this project's 2-core machine (defaults, 20 mm patch): 10 000 wear scratches 3.5 s,
50 000 17 s (10.3 M grid entries). 200 000 need about 40 M entries, more than the float32 tables'
2^24, whatever the patch size (entries per segment depend on the cell size, not the patch): refused
after 46 s, about 40 % into the grid stage (was: after the whole grid, 11.5 GB).
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np
from numpy.typing import ArrayLike

from ..errors import UserError
from .scratch_set import Progress, ProgressFn, ScratchSet, make_scratch_set

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


def _wrap_to_patch(seg: np.ndarray, ps: np.ndarray) -> np.ndarray:
    """Shift each segment (M, 4) by whole patch sizes so that its midpoint lies in [0, Px) x [0, Py)."""
    mid = 0.5 * (seg[:, :2] + seg[:, 2:])
    shift = -np.floor(mid / ps) * ps
    return seg + np.concatenate([shift, shift], 1)


BOUNDARIES = ("wrap", "clip")


def polylines_to_segments(
    polylines: Sequence[ArrayLike], patch_size_um: ArrayLike, segment_um: float,
    progress: ProgressFn | None = None, boundary: str = "clip",
) -> tuple[np.ndarray, np.ndarray]:
    """Resample each polyline (K, 2) so no piece exceeds ``segment_um``; clip them to the patch
    (``boundary="clip"``) or wrap them onto it (``"wrap"``, module docstring).

    Returns (segments (M, 4), scratch index (M,)). ``progress``: fraction of the polylines done.
    """
    if boundary not in BOUNDARIES:
        raise UserError(f"boundary must be one of {BOUNDARIES}; got {boundary!r}")
    ps = np.asarray(patch_size_um, dtype=np.float64)
    segs, ids = [], []
    every = max(1, len(polylines) // 100)
    for i, pl in enumerate(polylines):
        if progress is not None and i % every == 0:
            progress(i / len(polylines))
        p = np.asarray(pl, dtype=np.float64).reshape(-1, 2)
        if p.shape[0] < 2:
            raise UserError(f"curve {i} needs at least two points, got {p.shape[0]}")
        if not np.all(np.isfinite(p)):
            raise UserError(f"curve {i} holds non-finite coordinates")
        d = np.linalg.norm(np.diff(p, axis=0), axis=1)
        p = p[np.concatenate([[True], d > 0])]
        if p.shape[0] < 2:
            continue
        d = np.linalg.norm(np.diff(p, axis=0), axis=1)
        n = np.maximum(1, np.ceil(d / segment_um).astype(int))
        # piece j of edge j0 -> j0 + 1 ends at p[j0] + k / n[j0] (p[j0 + 1] - p[j0]), k = 1..n[j0]
        j0 = np.repeat(np.arange(len(d)), n)
        k = np.arange(1, j0.size + 1) - np.repeat(np.cumsum(n) - n, n)
        t = (k / n[j0])[:, None]
        q = np.concatenate([p[:1], p[j0] + t * (p[j0 + 1] - p[j0])])
        segs.append(np.concatenate([q[:-1], q[1:]], axis=1))
        ids.append(np.full(len(q) - 1, i))
    if progress is not None:
        progress(1.0)
    if not segs:
        return np.zeros((0, 4)), np.zeros(0, np.int64)
    if boundary == "wrap":
        return _wrap_to_patch(np.concatenate(segs), ps), np.concatenate(ids)
    seg, keep = _clip_to_patch(np.concatenate(segs), ps)
    return seg, np.concatenate(ids)[keep]


def _finish(polylines, patch, rng, width_range, depth_range, segment_um, progress: Progress, boundary: str,
            **kw) -> ScratchSet:
    seg, ids = polylines_to_segments(polylines, patch, segment_um, progress=progress.sub(0.2, 0.35),
                                     boundary=boundary)
    n = len(polylines)
    w = rng.uniform(*width_range, n)
    d = rng.uniform(*depth_range, n)
    return make_scratch_set(seg, w[ids], d[ids], patch, scratch_id=ids, progress=progress.sub(0.35, 1.0), **kw)


def _stepper(n: int, progress: Progress):
    """Report the polyline stage (0-20 %) about every 1 % of ``n`` scratches."""
    every = max(1, n // 100)

    def step(i: int) -> None:
        if i % every == 0:
            progress(0.2 * i / max(n, 1))

    return step


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
    boundary: str = "wrap",
    progress: ProgressFn | None = None,
    **index_kw,
) -> ScratchSet:
    """Random wear: scratches at uniform positions and orientations, gently curved (random arc).

    ``boundary="wrap"`` (default): tileable, uniform density up to the patch borders; ``"clip"``:
    cut at the patch border (module docstring)."""
    rng = np.random.default_rng(seed)
    ps = np.asarray(patch_size_um, dtype=np.float64)
    prog = Progress(progress)
    step = _stepper(int(n_scratches), prog)
    lines = []
    for i in range(int(n_scratches)):
        step(i)
        start = rng.uniform(0, 1, 2) * ps
        ang = rng.uniform(0, 2 * np.pi)
        length = rng.uniform(*length_um)
        kappa = rng.normal(0, curvature_per_mm) / 1000.0
        s = np.linspace(0, length, max(2, int(length / segment_um) + 2))
        th = ang + kappa * s
        dxy = np.stack([np.cos(th), np.sin(th)], 1)
        pts = start + np.concatenate([[[0, 0]], np.cumsum(dxy[1:] * np.diff(s)[:, None], axis=0)])
        lines.append(pts)
    return _finish(lines, ps, rng, width_um, depth_um, segment_um, prog, boundary, **index_kw)


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
    centres: int | None = None,
    boundary: str = "clip",
    progress: ProgressFn | None = None,
    **index_kw,
) -> ScratchSet:
    """Circular polishing marks: arcs of circles around one centre (default: the patch centre).

    ``radius_um`` defaults to (0.05, 0.7) x the patch's smaller side. One centre per patch makes a
    tiled surface show one polishing centre (a bow-tie highlight) per tile. The tileable variant:
    ``centres=k`` draws k centres uniformly in the patch (each arc around one of them, chosen at
    random; ``centre_um`` is then ignored) and ``boundary="wrap"`` continues the arcs into the
    neighbouring tiles (module docstring).
    """
    rng = np.random.default_rng(seed)
    ps = np.asarray(patch_size_um, dtype=np.float64)
    if radius_um is None:
        radius_um = (0.05 * ps.min(), 0.7 * ps.min())
    if centres is not None:
        if int(centres) < 1:
            raise UserError(f"centres must be >= 1; got {centres}")
        cs = rng.uniform(0, 1, (int(centres), 2)) * ps
    else:
        cs = (ps / 2 if centre_um is None else np.asarray(centre_um, dtype=np.float64))[None]
    prog = Progress(progress)
    step = _stepper(int(n_scratches), prog)
    lines = []
    for i in range(int(n_scratches)):
        step(i)
        c = cs[rng.integers(cs.shape[0])] if cs.shape[0] > 1 else cs[0]
        r = rng.uniform(*radius_um)
        a0 = rng.uniform(0, 2 * np.pi)
        span = rng.uniform(*arc_rad)
        n = max(2, int(r * span / segment_um) + 2)
        a = a0 + np.linspace(0, span, n)
        lines.append(c + r * np.stack([np.cos(a), np.sin(a)], 1))
    return _finish(lines, ps, rng, width_um, depth_um, segment_um, prog, boundary, **index_kw)


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
    boundary: str = "clip",
    progress: ProgressFn | None = None,
    **index_kw,
) -> ScratchSet:
    """Hairline brushing: long, nearly parallel lines crossing the whole patch along ``angle_rad``."""
    rng = np.random.default_rng(seed)
    ps = np.asarray(patch_size_um, dtype=np.float64)
    diag = float(np.hypot(*ps))
    prog = Progress(progress)
    step = _stepper(int(n_scratches), prog)
    lines = []
    for i in range(int(n_scratches)):
        step(i)
        a = angle_rad + rng.normal(0, jitter_rad)
        t = np.array([np.cos(a), np.sin(a)])
        nrm = np.array([-t[1], t[0]])
        off = rng.uniform(-0.5, 0.5) * diag
        s = np.linspace(-0.6 * diag, 0.6 * diag, max(2, int(1.2 * diag / segment_um) + 1))
        wav = waviness_um * np.sin(2 * np.pi * s / rng.uniform(3000, 12000) + rng.uniform(0, 2 * np.pi))
        lines.append(ps / 2 + s[:, None] * t + (off + wav)[:, None] * nrm)
    return _finish(lines, ps, rng, width_um, depth_um, segment_um, prog, boundary, **index_kw)


def from_curves(
    curves: Sequence[ArrayLike],
    patch_size_um: ArrayLike,
    *,
    width_um: float | ArrayLike | tuple[float, float] = THESIS_RANGE_UM,
    depth_um: float | ArrayLike | tuple[float, float] = THESIS_RANGE_UM,
    uv: bool = False,
    segment_um: float = 250.0,
    seed: int = 0,
    boundary: str = "clip",
    progress: ProgressFn | None = None,
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
        raise UserError(f"{name} must be a (lo, hi) tuple, a scalar or one value per curve ({n})")

    w, d = per_curve(width_um, "width_um"), per_curve(depth_um, "depth_um")
    prog = Progress(progress)
    seg, ids = polylines_to_segments(lines, ps, segment_um, progress=prog.sub(0.0, 0.2), boundary=boundary)
    return make_scratch_set(seg, w[ids], d[ids], ps, scratch_id=ids, progress=prog.sub(0.2, 1.0), **index_kw)
