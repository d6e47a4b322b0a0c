"""First-hit ray casting against a triangle soup: embree (embreex, as used by trimesh) in float32
for the traversal, then the hit distance is recomputed in float64 from the hit triangle (eq. 5.28)
so that distances are smooth functions of the vertices. A vectorised numpy fallback is used for
small scenes or when embreex is not installed (e.g. inside Blender).
"""

from __future__ import annotations

import numpy as np

from ..errors import UserError
from .distance_derivatives import ray_triangle_distance

try:  # pragma: no cover - depends on the environment
    from embreex import rtcore_scene as _rtcs
    from embreex.mesh_construction import TriangleMesh as _EmbreeMesh
except ImportError:  # pragma: no cover
    _rtcs = None

RAY_EPS = 1e-4  # mm, origin offset when continuing a ray from a surface


class RayCaster:
    """``first_hit(o, d, tmax)`` -> (triangle index or -1, float64 distance) for triangles (T, 3, 3)."""

    def __init__(self, triangles: np.ndarray, use_embree: bool | None = None):
        self.tris = np.ascontiguousarray(triangles, dtype=np.float64)
        if use_embree is None:
            use_embree = _rtcs is not None
        if use_embree and _rtcs is None:
            raise UserError("embreex is not installed")
        self.use_embree = bool(use_embree)
        if self.use_embree:
            self._scene = _rtcs.EmbreeScene()
            self._mesh = _EmbreeMesh(self._scene, self.tris.astype(np.float32))

    def first_hit(self, o: np.ndarray, d: np.ndarray, tmax: np.ndarray | None = None,
                  refine: bool = True) -> tuple[np.ndarray, np.ndarray]:
        """Hit triangle (-1 for a miss) and, with ``refine``, the float64 distance from ``o``."""
        n = len(o)
        if n == 0:
            return np.zeros(0, dtype=np.int64), np.zeros(0)
        start = o + RAY_EPS * d
        if self.use_embree:
            dists = None if tmax is None else np.ascontiguousarray(np.maximum(tmax - RAY_EPS, 0.0), np.float32)
            res = self._scene.run(np.ascontiguousarray(start, np.float32), np.ascontiguousarray(d, np.float32),
                                  dists=dists, output=1)
            tri = np.asarray(res["primID"], dtype=np.int64)
            tri[tri < 0] = -1
        else:
            tri = self._brute(start, d, tmax)
        t = np.full(n, np.inf)
        if not refine:
            return tri, t
        hit = tri >= 0
        if np.any(hit):
            tv = self.tris[tri[hit]]
            t[hit], _ = ray_triangle_distance(o[hit], d[hit], tv[:, 0], tv[:, 1], tv[:, 2])
            bad = hit.copy()
            bad[hit] = ~(t[hit] > 0)
            tri[bad] = -1
            t[bad] = np.inf
        return tri, t

    def _brute(self, o: np.ndarray, d: np.ndarray, tmax: np.ndarray | None) -> np.ndarray:
        n = len(o)
        best_t = np.full(n, np.inf) if tmax is None else np.asarray(tmax, dtype=np.float64) - RAY_EPS
        best = np.full(n, -1, dtype=np.int64)
        v0, e1, e2 = self.tris[:, 0], self.tris[:, 1] - self.tris[:, 0], self.tris[:, 2] - self.tris[:, 0]
        chunk = max(1, 2_000_000 // max(n, 1))
        for s in range(0, len(self.tris), chunk):
            sl = slice(s, s + chunk)
            p = np.cross(d[:, None, :], e2[None, sl])
            det = np.einsum("tk,ntk->nt", e1[sl], p)
            with np.errstate(divide="ignore", invalid="ignore"):
                inv = 1.0 / det
                sv = o[:, None, :] - v0[None, sl]
                u = np.einsum("ntk,ntk->nt", sv, p) * inv
                q = np.cross(sv, e1[None, sl])
                v = np.einsum("nk,ntk->nt", d, q) * inv
                t = np.einsum("tk,ntk->nt", e2[sl], q) * inv
            ok = (np.abs(det) > 1e-14) & (u >= 0) & (v >= 0) & (u + v <= 1) & (t > 0)
            t = np.where(ok, t, np.inf)
            j = np.argmin(t, axis=1)
            tj = t[np.arange(n), j]
            better = tj < best_t
            best_t[better] = tj[better]
            best[better] = j[better] + s
        return best
