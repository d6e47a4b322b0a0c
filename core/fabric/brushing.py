"""Editing the fabric parameter maps by brushing (thesis section 3.5).

Strokes are polylines rasterised as 2-D capsules (one per segment) with linear fall-off from the
centre line to ``radius``. The fibre basis turns toward the stroke direction by quaternion slerp
(the SGGX ellipsoid leans toward the brushing direction, tilt limited by the fibre length); edits
recolor ``k_d, k_s``, change smoothness (scale sigma) and anisotropy (shrink the smallest axis); the
data-driven mode blends 8 measured brushing-direction states by stroke direction.

All functions are pure: :class:`FabricMaps` in, new :class:`FabricMaps` out (only the maps that
change are copied; unchanged maps are shared), so undo = keep the previous object. Coordinates
are pixels ``(x, y)`` = (column, row) of the maps, matching the tangent frame (x along columns,
y along rows).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from .parameter_maps import SIGMA_RANGE, FabricMaps
from .quaternion import quat_from_axis_angle, quat_multiply, quat_normalize, quat_slerp

# sigma stays within the fitter's range: repeated smoothness or anisotropy segments multiply it, and one
# back-and-forth stroke of 60 segments at factor 0.1 reached 0 (maps the import then refused), at 2.0 5.7e17


@dataclass(frozen=True)
class Window:
    """The part of a map a capsule touches: rows ``y0:y1``, columns ``x0:x1`` and weights (h, w)."""

    y0: int
    y1: int
    x0: int
    x1: int
    weight: np.ndarray

    @property
    def slices(self) -> tuple[slice, slice]:
        return slice(self.y0, self.y1), slice(self.x0, self.x1)


def capsule_window(shape: tuple[int, int], p0, p1, radius: float, strength: float = 1.0) -> Window | None:
    """Weights of the capsule around segment ``p0 -> p1`` (pixel centres at integer + 0.5):
    ``strength * max(0, 1 - distance / radius)``. ``None`` if it misses the map."""
    h, w = shape
    p0 = np.asarray(p0, dtype=np.float64)
    p1 = np.asarray(p1, dtype=np.float64)
    lo = np.floor(np.minimum(p0, p1) - radius).astype(int)
    hi = np.ceil(np.maximum(p0, p1) + radius).astype(int) + 1
    x0, y0 = max(lo[0], 0), max(lo[1], 0)
    x1, y1 = min(hi[0], w), min(hi[1], h)
    if x0 >= x1 or y0 >= y1 or radius <= 0:
        return None
    xs = np.arange(x0, x1, dtype=np.float32) + 0.5
    ys = np.arange(y0, y1, dtype=np.float32) + 0.5
    d = (p1 - p0).astype(np.float32)
    dd = float(d @ d)
    px = xs[None, :] - np.float32(p0[0])
    py = ys[:, None] - np.float32(p0[1])
    t = np.clip((px * d[0] + py * d[1]) / dd, 0.0, 1.0) if dd > 0 else np.zeros((1, 1), np.float32)
    ex = px - t * d[0]
    ey = py - t * d[1]
    dist = np.sqrt(ex * ex + ey * ey)
    wgt = np.float32(strength) * np.maximum(np.float32(0.0), 1.0 - dist / np.float32(radius))
    return Window(y0, y1, x0, x1, wgt.astype(np.float32))


def stroke_weight_map(shape: tuple[int, int], points, radius: float, strength: float = 1.0) -> np.ndarray:
    """Full-map weights of a polyline stroke: the maximum of its segment capsules (H, W)."""
    out = np.zeros(shape, dtype=np.float32)
    pts = np.asarray(points, dtype=np.float64)
    segs = zip(pts[:-1], pts[1:], strict=True) if len(pts) > 1 else [(pts[0], pts[0])]
    for a, b in segs:
        win = capsule_window(shape, a, b, radius, strength)
        if win is not None:
            sl = win.slices
            out[sl] = np.maximum(out[sl], win.weight)
    return out


def max_tilt(fibre_length: float) -> float:
    """Largest lean (radians) of a fibre of length ``fibre_length`` (in units of the pile height)
    that still spans the pile: ``arccos(1 / L)`` (0 for ``L <= 1``)."""
    return float(np.arccos(min(1.0, 1.0 / fibre_length))) if fibre_length > 1.0 else 0.0


def brushed_basis(direction, fibre_length: float = 1.2) -> np.ndarray:
    """Target fibre basis for brushing along the 2-D ``direction`` (x, y): the tangent axis (x) along
    the stroke and the ellipsoid (z axis) leaning toward it by :func:`max_tilt`."""
    d = np.asarray(direction, dtype=np.float64)
    phi = np.arctan2(d[..., 1], d[..., 0])
    q_az = quat_from_axis_angle(np.broadcast_to([0.0, 0.0, 1.0], np.shape(phi) + (3,)), phi)
    axis = np.stack([-np.sin(phi), np.cos(phi), np.zeros_like(phi)], axis=-1)  # n x d
    return quat_multiply(quat_from_axis_angle(axis, np.full(np.shape(phi), max_tilt(fibre_length))), q_az)


def _flip_z(q: np.ndarray) -> np.ndarray:
    """``q * (0, 0, 0, 1)``: the same SGGX ellipsoid with x and y negated."""
    return np.stack([-q[..., 3], q[..., 2], -q[..., 1], q[..., 0]], axis=-1)


def _slerp_toward(q: np.ndarray, target: np.ndarray, w: np.ndarray) -> np.ndarray:
    """Slerp ``q`` toward whichever of the two equivalent targets (x, y negated) is closer."""
    q = np.asarray(q, dtype=np.float64)
    t = np.broadcast_to(target, q.shape)
    alt = _flip_z(t)
    closer = np.abs(np.sum(q * alt, -1, keepdims=True)) > np.abs(np.sum(q * t, -1, keepdims=True))
    return quat_slerp(q, np.where(closer, alt, t), w)


def _write(arr: np.ndarray, win: Window, values: np.ndarray) -> np.ndarray:
    out = np.array(arr, copy=True)
    out[win.slices] = values
    return out


def brush_fibres(maps: FabricMaps, p0, p1, radius: float, strength: float = 1.0,
                 fibre_length: float = 1.2) -> FabricMaps:
    """One stroke segment: rotate the fibre basis toward the stroke direction by slerp weighted by the
    capsule fall-off. Returns new maps (only ``basis`` is copied)."""
    win = capsule_window(maps.shape, p0, p1, radius, strength)
    d = np.asarray(p1, dtype=np.float64) - np.asarray(p0, dtype=np.float64)
    if win is None or not np.any(d):
        return maps
    target = brushed_basis(d, fibre_length)
    q = maps.basis[win.slices]
    new = _slerp_toward(q, target, np.clip(win.weight, 0.0, 1.0))
    return maps.replace(basis=_write(maps.basis, win, new.astype(np.float32)))


def brush_stroke(maps: FabricMaps, points, radius: float, strength: float = 1.0,
                 fibre_length: float = 1.2) -> FabricMaps:
    """A whole polyline stroke: :func:`brush_fibres` per segment (copies ``basis`` once)."""
    pts = np.asarray(points, dtype=np.float64)
    basis = np.array(maps.basis, copy=True)
    work = maps.replace(basis=basis)
    for a, b in zip(pts[:-1], pts[1:], strict=True):
        win = capsule_window(maps.shape, a, b, radius, strength)
        if win is None or not np.any(b - a):
            continue
        basis[win.slices] = _slerp_toward(basis[win.slices], brushed_basis(b - a, fibre_length),
                                          np.clip(win.weight, 0.0, 1.0))
    return work


def _weights(maps: FabricMaps, weight) -> np.ndarray:
    w = np.asarray(weight, dtype=np.float64)
    return np.broadcast_to(w, maps.shape)[..., None]


def recolor(maps: FabricMaps, kd=None, ks=None, weight=1.0) -> FabricMaps:
    """Blend ``k_d`` and/or ``k_s`` toward RGB colours with ``weight`` (scalar or (H, W) map)."""
    w = _weights(maps, weight)
    changes = {}
    if kd is not None:
        changes["kd"] = (maps.kd * (1 - w) + w * np.asarray(kd, dtype=np.float64)).astype(np.float32)
    if ks is not None:
        changes["ks"] = (maps.ks * (1 - w) + w * np.asarray(ks, dtype=np.float64)).astype(np.float32)
    return maps.replace(**changes)


def _within_range(scaled: np.ndarray, before: np.ndarray) -> np.ndarray:
    """``scaled`` kept within ``SIGMA_RANGE``; a value already outside it (maps from elsewhere) may move toward the
    range, never away from it, and is not pulled into it in one step."""
    return np.clip(scaled, np.minimum(before, SIGMA_RANGE[0]), np.maximum(before, SIGMA_RANGE[1]))


def smoothness(maps: FabricMaps, factor: float, weight=1.0) -> FabricMaps:
    """Scale ``sigma_x, sigma_y`` by ``factor ** weight`` (factor < 1: smoother, as lower deviation
    means a sharper lobe), kept within ``SIGMA_RANGE`` (:func:`_within_range`)."""
    w = _weights(maps, weight)
    scaled = _within_range(maps.sigma * np.power(float(factor), w), maps.sigma)
    return maps.replace(sigma=np.where(w > 0, scaled, maps.sigma).astype(np.float32))  # untouched texels as they were


def anisotropy(maps: FabricMaps, factor: float, weight=1.0) -> FabricMaps:
    """Boost anisotropy by scaling the smallest ellipsoid axis by ``factor ** weight`` (factor < 1), kept within
    ``SIGMA_RANGE`` (:func:`_within_range`)."""
    w = _weights(maps, weight)[..., 0]
    s = np.array(maps.sigma, dtype=np.float64)
    k = np.argmin(s, axis=-1)
    row = np.take_along_axis(s, k[..., None], -1)[..., 0]
    rows = np.where(w > 0, _within_range(row * np.power(float(factor), w), row), row)
    np.put_along_axis(s, k[..., None], rows[..., None], -1)
    return maps.replace(sigma=s.astype(np.float32))


def brush_edit(maps: FabricMaps, p0, p1, radius: float, strength: float = 1.0, *, kd=None, ks=None,
               smooth_factor: float | None = None, anisotropy_factor: float | None = None) -> FabricMaps:
    """One stroke segment of the recolor / smoothness / anisotropy brushes (capsule weights)."""
    win = capsule_window(maps.shape, p0, p1, radius, strength)
    if win is None:
        return maps
    sl = win.slices
    sub = FabricMaps(maps.kd[sl], maps.ks[sl], maps.sigma[sl], maps.basis[sl])
    w = np.clip(win.weight, 0.0, 1.0)
    if kd is not None or ks is not None:
        sub = recolor(sub, kd, ks, w)
    if smooth_factor is not None:
        sub = smoothness(sub, smooth_factor, w)
    if anisotropy_factor is not None:
        sub = anisotropy(sub, anisotropy_factor, w)
    changes = {n: _write(getattr(maps, n), win, getattr(sub, n))
               for n in ("kd", "ks", "sigma") if getattr(sub, n) is not getattr(maps, n)[sl]}
    return maps.replace(**changes)


@dataclass(frozen=True)
class BrushStates:
    """The thesis' data-driven mode: 8 parameter states measured on patches brushed toward
    ``k * 45`` degrees (k = 0..7, angle from +x toward +y), each a (h, w) FabricMaps tiled over the
    target map. States should be post-processed consistently (aligned bases)."""

    states: tuple[FabricMaps, ...]

    def __post_init__(self) -> None:
        if len(self.states) != 8:
            raise ValueError(f"BrushStates needs 8 states (one per 45 degrees), got {len(self.states)}")
        shapes = {s.shape for s in self.states}
        if len(shapes) != 1:
            raise ValueError(f"all 8 states must have the same size, got {sorted(shapes)}")

    def blend(self, direction, rows: np.ndarray, cols: np.ndarray) -> FabricMaps:
        """Parameters for brushing along ``direction`` at pixel ``rows x cols`` (tiled): linear blend
        of the two states adjacent in angle (slerp for the basis)."""
        ang = np.degrees(np.arctan2(direction[1], direction[0])) % 360.0
        k0 = int(ang // 45) % 8
        k1 = (k0 + 1) % 8
        t = (ang - 45.0 * (ang // 45)) / 45.0
        h, w = self.states[0].shape
        ri, ci = np.ix_(rows % h, cols % w)
        a, b = self.states[k0], self.states[k1]

        def lerp(name):
            return (getattr(a, name)[ri, ci] * (1 - t) + getattr(b, name)[ri, ci] * t).astype(np.float32)

        qa, qb = a.basis[ri, ci].astype(np.float64), b.basis[ri, ci].astype(np.float64)
        return FabricMaps(lerp("kd"), lerp("ks"), lerp("sigma"),
                          quat_normalize(quat_slerp(qa, qb, np.full(qa.shape[:-1], t))).astype(np.float32))


def brush_data_driven(maps: FabricMaps, p0, p1, radius: float, states: BrushStates,
                      strength: float = 1.0) -> FabricMaps:
    """One stroke segment in the data-driven mode: blend every parameter toward the state for the
    stroke direction with the capsule weights."""
    win = capsule_window(maps.shape, p0, p1, radius, strength)
    d = np.asarray(p1, dtype=np.float64) - np.asarray(p0, dtype=np.float64)
    if win is None or not np.any(d):
        return maps
    sl = win.slices
    tgt = states.blend(d, np.arange(win.y0, win.y1), np.arange(win.x0, win.x1))
    w = np.clip(win.weight, 0.0, 1.0)[..., None]
    changes = {n: _write(getattr(maps, n), win, (getattr(maps, n)[sl] * (1 - w) + getattr(tgt, n) * w))
               for n in ("kd", "ks", "sigma")}
    basis = quat_slerp(maps.basis[sl], tgt.basis, w[..., 0]).astype(np.float32)
    changes["basis"] = _write(maps.basis, win, basis)
    return maps.replace(**changes)
