"""Scratch sets: straight segments of scratch polylines plus a uniform grid index (thesis Sec. 4.4).

A scratch is a polyline in the scratch plane (the surface's UV/tangent plane mapped to micrometres:
x_um = u * patch_size_um[0], y_um = v * patch_size_um[1]) with a width W_s, a depth D_s (um) and a
profile per segment. Only the rectangular profile (code 0) is modelled (thesis Table 4.3); the code
is stored so that files stay forward compatible.

Grid index: the patch [0, Px] x [0, Py] is cut into nx x ny square cells of side ``cell_size_um``.
Cell (ix, iy) covers [ix c, (ix+1) c) x [iy c, (iy+1) c) and lists every segment that comes within
``query_radius_um`` of the cell. A shaded point therefore only walks the list of its own cell, as
long as its footprint's semi-major axis plus 3.5 sigma stays below the query radius (the evaluator
shrinks larger footprints to that size). Lists are stored CSR-style: ``cell_segments`` holds segment
indices cell after cell (row-major, iy * nx + ix), ``grid_offset``/``grid_count`` (ny, nx) give each
cell's slice.

The patch tiles the plane, so the index is periodic: a cell also lists every segment one of whose
periodic images (the segment shifted by (kx Px, ky Py), integers kx, ky) comes within the query
radius of it, and the lookup (``scratch_radiance`` and the OSL shader) shades, per listed segment,
each image that comes within reach of the point (:func:`image_range`). A footprint near a patch
border therefore sees the scratches of the neighbouring tile: no seam. The tables keep the segment
index only (the file format is unchanged); sets indexed before this (no images listed) still load
and shade, with the old seam.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, field

import numpy as np
from numpy.typing import ArrayLike

from ..errors import UserError

PROFILE_RECTANGULAR = 0
KNOWN_PROFILES = (PROFILE_RECTANGULAR,)
MAX_TABLE_INDEX = 2**24  # integers stored in float32 tables are exact below this
REACH_SIGMAS = 3.5  # scratches farther than the footprint + 3.5 sigma contribute nothing

ProgressFn = Callable[[float], None]  # called with the fraction done, 0..1


class Progress:
    """Forwards a long computation's progress to ``fn`` as strictly increasing fractions in [0, 1].

    ``sub(lo, hi)`` maps a stage's own 0..1 onto [lo, hi] of the whole. Steps below ``min_step`` are
    dropped (a bar needs no more than ~1000 updates); 1.0 is always passed on. An exception raised by
    ``fn`` (e.g. a user's cancel) propagates and stops the computation.
    """

    def __init__(self, fn: ProgressFn | None = None, lo: float = 0.0, hi: float = 1.0, *,
                 min_step: float = 1e-3, _root: Progress | None = None) -> None:
        self.fn, self.lo, self.hi, self.min_step = fn, float(lo), float(hi), float(min_step)
        self._root = _root if _root is not None else self
        self.last = -1.0

    def __call__(self, fraction: float) -> None:
        root = self._root
        if root.fn is None:
            return
        f = min(1.0, max(0.0, self.lo + (self.hi - self.lo) * float(fraction)))
        if f > root.last and (f - root.last >= root.min_step or f == 1.0):
            root.last = f
            root.fn(f)

    def sub(self, lo: float, hi: float) -> Progress:
        span = self.hi - self.lo
        return Progress(None, self.lo + span * lo, self.lo + span * hi, _root=self._root)

    @property
    def active(self) -> bool:
        return self._root.fn is not None


@dataclass
class ScratchSet:
    """Segments of a scratch set and its grid index. Arrays are float64/int64; lengths in um."""

    segments: np.ndarray  # (M, 4) x0, y0, x1, y1
    width_um: np.ndarray  # (M,)
    depth_um: np.ndarray  # (M,)
    profile: np.ndarray  # (M,) int
    scratch_id: np.ndarray  # (M,) int, polyline each segment belongs to
    patch_size_um: np.ndarray  # (2,)
    sigma_um: float
    cell_size_um: float
    query_radius_um: float
    grid_offset: np.ndarray = field(repr=False)  # (ny, nx) int
    grid_count: np.ndarray = field(repr=False)  # (ny, nx) int
    cell_segments: np.ndarray = field(repr=False)  # (K,) int

    @property
    def n_segments(self) -> int:
        return int(self.segments.shape[0])

    @property
    def n_scratches(self) -> int:
        return int(np.unique(self.scratch_id).size) if self.n_segments else 0

    @property
    def grid_shape(self) -> tuple[int, int]:
        return tuple(int(v) for v in self.grid_count.shape)  # (ny, nx)

    def validate(self) -> None:
        validate_scratch_set(self)


def validate_scratch_set(s: ScratchSet) -> None:
    """Raise ValueError with a precise message if ``s`` is inconsistent."""
    seg = np.asarray(s.segments)
    if seg.ndim != 2 or seg.shape[1] != 4:
        raise UserError(f"segments must have shape (M, 4) = x0, y0, x1, y1; got {seg.shape}")
    m = seg.shape[0]
    for name in ("width_um", "depth_um", "profile", "scratch_id"):
        a = np.asarray(getattr(s, name))
        if a.shape != (m,):
            raise UserError(f"{name} must have shape ({m},) like the segment table; got {a.shape}")
    if not np.all(np.isfinite(seg)):
        raise UserError("segment table holds non-finite coordinates")
    if m and np.any(np.hypot(seg[:, 2] - seg[:, 0], seg[:, 3] - seg[:, 1]) <= 0):
        raise UserError("segment table holds zero-length segments")
    w, d = np.asarray(s.width_um), np.asarray(s.depth_um)
    if m and (not np.all(np.isfinite(w)) or np.any(w <= 0)):
        raise UserError("scratch widths must be finite and > 0 um")
    if m and (not np.all(np.isfinite(d)) or np.any(d < 0)):
        raise UserError("scratch depths must be finite and >= 0 um")
    bad = np.setdiff1d(np.unique(np.asarray(s.profile)), KNOWN_PROFILES)
    if bad.size:
        raise UserError(f"unknown scratch profile code(s) {bad.tolist()}; known: {list(KNOWN_PROFILES)}")
    ps = np.asarray(s.patch_size_um, dtype=np.float64)
    if ps.shape != (2,) or not np.all(np.isfinite(ps)) or np.any(ps <= 0):
        raise UserError(f"patch_size_um must be two positive numbers; got {ps}")
    for name in ("sigma_um", "cell_size_um", "query_radius_um"):
        v = float(getattr(s, name))
        if not np.isfinite(v) or v <= 0:
            raise UserError(f"{name} must be > 0; got {v}")
    off, cnt, cs = np.asarray(s.grid_offset), np.asarray(s.grid_count), np.asarray(s.cell_segments)
    nx = int(np.ceil(ps[0] / s.cell_size_um - 1e-9))
    ny = int(np.ceil(ps[1] / s.cell_size_um - 1e-9))
    if off.shape != (ny, nx) or cnt.shape != (ny, nx):
        raise UserError(f"grid tables must have shape (ny, nx) = {(ny, nx)}; got {off.shape} and {cnt.shape}")
    if cs.ndim != 1:
        raise UserError("cell_segments must be one-dimensional")
    if np.any(cnt < 0) or np.any(off < 0) or np.any(off + cnt > cs.size):
        raise UserError(f"grid offset/count point outside the cell-segment list (length {cs.size})")
    if cs.size and (cs.min() < 0 or cs.max() >= m):
        raise UserError(f"cell-segment list references segments outside 0..{m - 1}")
    if max(m, cs.size) >= MAX_TABLE_INDEX:
        raise UserError(f"too many entries for exact float32 tables (limit {MAX_TABLE_INDEX})")


def image_range(
    lo: ArrayLike, hi: ArrayLike, a: ArrayLike, b: ArrayLike, period: float
) -> tuple[np.ndarray, np.ndarray]:
    """Integers k0, k1 such that [lo + k P, hi + k P] meets [a, b] exactly for k0 <= k <= k1 (P = period;
    k1 < k0: none). Elementwise; the periodic-image range of a segment's extent along one axis."""
    lo, hi, a, b = (np.asarray(v, dtype=np.float64) for v in (lo, hi, a, b))
    return np.ceil((a - hi) / period).astype(np.int64), np.floor((b - lo) / period).astype(np.int64)


def periodic_images(seg: np.ndarray, ps: np.ndarray, a: np.ndarray, b: np.ndarray):
    """Periodic images of segments (P, 4) whose bounding boxes meet the boxes [a, b] ((P, 2) or (2,)
    corners): the image rule of the index and of the lookup (the OSL shader ports it).

    Returns (row (Q,) index into ``seg``, shifted segments (Q, 4)). Rows with exactly one image, the
    segment itself, are the common case and cost one pass."""
    lo = np.minimum(seg[:, :2], seg[:, 2:])
    hi = np.maximum(seg[:, :2], seg[:, 2:])
    kx0, kx1 = image_range(lo[:, 0], hi[:, 0], a[..., 0], b[..., 0], ps[0])
    ky0, ky1 = image_range(lo[:, 1], hi[:, 1], a[..., 1], b[..., 1], ps[1])
    wx = np.maximum(kx1 - kx0 + 1, 0)
    n = wx * np.maximum(ky1 - ky0 + 1, 0)
    if np.all(n == 1) and not np.any(kx0) and not np.any(ky0):
        return np.arange(seg.shape[0]), seg
    row = np.repeat(np.arange(seg.shape[0]), n)
    local = np.arange(row.size) - np.repeat(np.cumsum(n) - n, n)
    kx = kx0[row] + local % np.maximum(wx[row], 1)
    ky = ky0[row] + local // np.maximum(wx[row], 1)
    shift = np.stack([kx * ps[0], ky * ps[1]], -1)
    return row, seg[row] + np.concatenate([shift, shift], 1)


def build_grid_index(
    segments: ArrayLike,
    patch_size_um: ArrayLike,
    cell_size_um: float,
    query_radius_um: float,
    *,
    progress: ProgressFn | None = None,
    chunk_candidates: int = 250_000,
    periodic: bool = True,
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """CSR grid index: (grid_offset (ny, nx), grid_count (ny, nx), cell_segments (K,)).

    A segment is listed in a cell when it, or with ``periodic`` (default) one of its periodic images
    (module docstring), comes within ``query_radius_um`` of the cell's square (exact segment-square
    distance); each segment is listed once per cell, cells' lists in segment order. Segments are
    tested in chunks of about ``chunk_candidates`` (segment, cell) pairs (bounded memory; the result
    does not depend on the chunking), reporting the fraction of pairs tested to ``progress``. An
    index that would exceed the float32 tables' limit (``MAX_TABLE_INDEX`` entries) is refused as
    soon as it does, not after the whole grid is built.
    """
    seg0 = np.asarray(segments, dtype=np.float64).reshape(-1, 4)
    ps = np.asarray(patch_size_um, dtype=np.float64)
    c = float(cell_size_um)
    r = float(query_radius_um)
    nx = int(np.ceil(ps[0] / c - 1e-9))
    ny = int(np.ceil(ps[1] / c - 1e-9))
    if nx * ny > MAX_TABLE_INDEX:  # the cell tables address cells through the same float32 index
        raise UserError(f"a grid of {nx} x {ny} cells of {c:g} um is more than the tables can address "
                        f"({MAX_TABLE_INDEX} cells): use a larger footprint or coherence length, or a smaller patch")
    if periodic and seg0.shape[0]:
        src, seg = periodic_images(seg0, ps, np.full(2, -r), np.array([nx * c, ny * c]) + r)
    else:
        src, seg = np.arange(seg0.shape[0]), seg0
    lo = np.minimum(seg[:, :2], seg[:, 2:]) - r
    hi = np.maximum(seg[:, :2], seg[:, 2:]) + r
    ix0 = np.clip(np.floor(lo[:, 0] / c).astype(np.int64), 0, nx - 1)
    iy0 = np.clip(np.floor(lo[:, 1] / c).astype(np.int64), 0, ny - 1)
    ix1 = np.clip(np.floor(hi[:, 0] / c).astype(np.int64), 0, nx - 1)
    iy1 = np.clip(np.floor(hi[:, 1] / c).astype(np.int64), 0, ny - 1)
    wx = ix1 - ix0 + 1
    n = wx * (iy1 - iy0 + 1)  # candidate cells per segment
    ends = np.cumsum(n)
    total = int(ends[-1]) if ends.size else 0
    # chunk boundaries (segment indices): about chunk_candidates pairs each, at least one segment
    bounds = [0]
    while bounds[-1] < seg.shape[0]:
        start = bounds[-1]
        base = int(ends[start - 1]) if start else 0
        stop = int(np.searchsorted(ends, base + max(1, int(chunk_candidates)), side="right"))
        bounds.append(max(stop, start + 1))
    reps, cells = [], []
    kept = 0
    for a, b in zip(bounds[:-1], bounds[1:], strict=False):
        nn = n[a:b]
        rep = a + np.repeat(np.arange(b - a), nn)
        local = np.arange(rep.size) - np.repeat(np.cumsum(nn) - nn, nn)
        ix = ix0[rep] + local % wx[rep]
        iy = iy0[rep] + local // wx[rep]
        # the cell's centre decides most pairs: the square lies within c / sqrt(2) of its centre, so a centre
        # within r keeps the pair and one beyond r + c / sqrt(2) drops it; the exact test settles the rest
        centre = point_segment_distance(np.stack([(ix + 0.5) * c, (iy + 0.5) * c], -1), seg[rep, :2],
                                        seg[rep, 2:])
        keep = centre <= r
        edge = np.flatnonzero(~keep & (centre <= r + c * np.sqrt(0.5) * (1.0 + 1e-9)))
        keep[edge] = segment_rect_distance(seg[rep[edge]], ix[edge] * c, iy[edge] * c, c) <= r
        reps.append(src[rep[keep]])
        cells.append((iy * nx + ix)[keep])
        kept += int(keep.sum())
        if kept >= MAX_TABLE_INDEX:
            raise UserError(
                f"too many grid entries for exact float32 tables (more than {MAX_TABLE_INDEX} after "
                f"{b} of {seg.shape[0]} segments): use fewer scratches, a larger patch or a smaller "
                "footprint/coherence length"
            )
        if progress is not None:
            progress(float(ends[b - 1]) / total)
    rep = np.concatenate(reps) if reps else np.zeros(0, np.int64)
    cell = np.concatenate(cells) if cells else np.zeros(0, np.int64)
    if periodic and rep.size:  # images: one entry per (cell, segment), in segment order
        key = np.sort(cell * max(seg0.shape[0], 1) + rep)
        key = key[np.concatenate([[True], key[1:] != key[:-1]])]
        cell, rep = key // max(seg0.shape[0], 1), key % max(seg0.shape[0], 1)
    order = np.argsort(cell, kind="stable")
    cell_segments = rep[order]
    count = np.bincount(cell, minlength=nx * ny)
    offset = np.cumsum(count) - count
    if progress is not None:
        progress(1.0)
    return offset.reshape(ny, nx), count.reshape(ny, nx), cell_segments


def segment_rect_distance(seg: np.ndarray, x0: np.ndarray, y0: np.ndarray, size: float) -> np.ndarray:
    """Distance between segments (P, 4) and the squares [x0, x0 + size] x [y0, y0 + size] (0 if they meet)."""
    p0, p1 = seg[:, :2], seg[:, 2:]
    lo = np.stack([x0, y0], -1)
    hi = lo + size
    # endpoints to the square
    d0 = np.linalg.norm(np.maximum(np.maximum(lo - p0, p0 - hi), 0.0), axis=-1)
    d1 = np.linalg.norm(np.maximum(np.maximum(lo - p1, p1 - hi), 0.0), axis=-1)
    dist = np.minimum(d0, d1)
    # square corners to the segment
    for cx, cy in ((lo[:, 0], lo[:, 1]), (hi[:, 0], lo[:, 1]), (lo[:, 0], hi[:, 1]), (hi[:, 0], hi[:, 1])):
        dist = np.minimum(dist, point_segment_distance(np.stack([cx, cy], -1), p0, p1))
    # a segment crossing the square (Liang-Barsky slab test)
    d = p1 - p0
    t0 = np.zeros(len(seg))
    t1 = np.ones(len(seg))
    ok = np.ones(len(seg), dtype=bool)
    for k in (0, 1):
        par = d[:, k] == 0
        ok &= ~(par & ((p0[:, k] < lo[:, k]) | (p0[:, k] > hi[:, k])))
        with np.errstate(divide="ignore", invalid="ignore"):
            ta = (lo[:, k] - p0[:, k]) / d[:, k]
            tb = (hi[:, k] - p0[:, k]) / d[:, k]
        t0 = np.where(par, t0, np.maximum(t0, np.minimum(ta, tb)))
        t1 = np.where(par, t1, np.minimum(t1, np.maximum(ta, tb)))
    return np.where(ok & (t0 <= t1), 0.0, dist)


def point_segment_distance(x: ArrayLike, p0: ArrayLike, p1: ArrayLike) -> np.ndarray:
    """Euclidean distance from points x to segments p0-p1 (broadcast over leading axes)."""
    x, p0, p1 = (np.asarray(a, dtype=np.float64) for a in (x, p0, p1))
    d = p1 - p0
    dd = np.einsum("...i,...i->...", d, d)
    t = np.clip(np.einsum("...i,...i->...", x - p0, d) / np.where(dd > 0, dd, 1.0), 0.0, 1.0)
    return np.linalg.norm(x - (p0 + t[..., None] * d), axis=-1)


def make_scratch_set(
    segments: ArrayLike,
    width_um: ArrayLike,
    depth_um: ArrayLike,
    patch_size_um: ArrayLike,
    *,
    scratch_id: ArrayLike | None = None,
    profile: ArrayLike | None = None,
    sigma_um: float = 60.0,
    max_footprint_um: float = 500.0,
    cell_size_um: float | None = None,
    progress: ProgressFn | None = None,
) -> ScratchSet:
    """Assemble and index a scratch set.

    The query radius is ``max_footprint_um + 3.5 sigma``: footprints with a semi-major axis up to
    ``max_footprint_um`` are evaluated exactly. The cell size defaults to half the query radius.
    ``progress`` is called with the fraction of the grid index built (see :func:`build_grid_index`).
    """
    seg = np.asarray(segments, dtype=np.float64)
    if seg.ndim != 2 or seg.shape[1] != 4:
        raise UserError(f"segments must have shape (M, 4) = x0, y0, x1, y1; got {seg.shape}")
    m = seg.shape[0]
    q = float(max_footprint_um) + REACH_SIGMAS * float(sigma_um)
    c = float(cell_size_um) if cell_size_um is not None else 0.5 * q
    ps = np.asarray(patch_size_um, dtype=np.float64).reshape(2)
    off, cnt, cs = build_grid_index(seg, ps, c, q, progress=progress)
    s = ScratchSet(
        segments=seg,
        width_um=np.broadcast_to(np.asarray(width_um, dtype=np.float64), (m,)).copy(),
        depth_um=np.broadcast_to(np.asarray(depth_um, dtype=np.float64), (m,)).copy(),
        profile=(np.zeros(m, np.int64) if profile is None else np.broadcast_to(profile, (m,)).astype(np.int64)),
        scratch_id=(np.arange(m) if scratch_id is None else np.asarray(scratch_id, dtype=np.int64).reshape(m)),
        patch_size_um=ps,
        sigma_um=float(sigma_um),
        cell_size_um=c,
        query_radius_um=q,
        grid_offset=off,
        grid_count=cnt,
        cell_segments=cs,
    )
    validate_scratch_set(s)
    return s
