"""Wavefront Monte Carlo volumetric path tracer with per-path analytic derivatives (eq. 5.7-5.32).

Estimator. Camera paths are sampled with the *sampling* parameters theta_0: pinhole camera with box
filter, thin-boundary events chosen with probability F (reflect) / 1 - F (transmit straight on,
eq. 5.1-5.2), free-flight distances by analytic transmittance in the piecewise-homogeneous media
(enamel, dentin, gums; one hero colour channel per path, combined over channels with the balance
heuristic), scattering directions from the two-lobe HG phase function (eq. 5.4), cosine sampling on
the Lambertian oral-cavity proxy. Every scattering / cavity vertex connects to every point light
(next-event estimation through the non-bending boundaries, attenuated by all media crossed and by
a_t (1 - F) at each boundary). The contribution is f(path; theta) / p(path; theta_0).

Path length. ``RenderSettings.max_depth`` = n stops every path after n vertices (biased low: the
light that needs more bounces is missing, a lot in teeth media with albedo 0.7-0.97); ``None`` renders
all bounces, ending paths by Russian roulette (unbiased; the roulette decisions are part of
p(path; theta_0), see ``RenderSettings``) with a safety cap of ``MAX_PATH_VERTICES``.

Derivatives. With the path and its discrete structure fixed, d/dtheta [f / p] = (f / p) d log f,
and d log f is the sum of per-interaction terms (eq. 5.8): 1 / a_t (eq. 5.10), phase-function terms
(eq. 5.11-5.14), blended albedo / phase terms via l(q) (eq. 5.15-5.21), (N - 1) / sigma_t -
sum t_k (eq. 5.23), and the dentin-shape term (S_i - S_e) dt/dc for every dentin crossing
(eq. 5.25-5.32). The extinction at a vertex is its region's own (see ``scene``), so these are the
thesis' derivatives, complete for every parameter but the dentin shape c: moving the dentin surface
across a fixed scattering vertex steps its sigma_t, a boundary term that no per-path term holds. The
fit differences c instead (``dentin_shape_gradient``), which also serves a sharp boundary (spread
1e-5 mm, as in a photograph), where the blend terms lie too close to the surface for any practical
number of samples to reach them (docs/teeth-fit.md).
With ``adjoint`` = d rho / d C (eq. 5.7) the tracer returns grad = sum adjoint * dC/dtheta; terms that
precede a vertex are weighted by the adjoint-weighted contributions of all later vertices (suffix
sums), connection terms by the connection's own contribution.

The sampling and evaluation scenes are the same for ordinary rendering; the finite-difference tests
evaluate the same estimator at theta +- h with the sampling fixed at theta_0 (common random numbers).
With roulette, the per-path levels of the suffix sums grow with the deepest path of a batch.
"""

from __future__ import annotations

import time
from dataclasses import dataclass, field

import numpy as np

from ..errors import UserError
from ..forked_map import forked_map
from .capture import Camera, PointLight
from .compiled_scene import (
    KIND_DIELECTRIC,
    KIND_INDEX_MATCHED,
    KIND_OPAQUE,
    MED_AIR,
    MED_DENTIN,
    CompiledScene,
)
from .distance_derivatives import ray_distance_vertex_derivative, ray_triangle_distance
from .enamel_transmission import lookup_a_t
from .fresnel import fresnel_dielectric
from .phase_function import direction_from_mu, hg, hg_dlog_dg, sample_hg_mu
from .sigmoid_blend import blend_weight, blend_weight_dq

MAX_CROSSINGS = 12
JACOBIAN_MAX_BYTES = 8 * 2**30
# Safety cap on path vertices with Russian roulette (``RenderSettings.max_depth = None``). Not a bias in
# practice: after the roulette start the survival probability of a path is about the product of its
# albedos (see ``RenderSettings``), so a path reaches 1000 vertices with probability ~ 0.97^1000 ~ 6e-14
# at the teeth's highest albedo; ``RenderResult.stats["capped_paths"]`` counts those that did.
MAX_PATH_VERTICES = 1000


@dataclass
class RenderSettings:
    """Sampling settings of ``render``.

    ``max_depth``: ``None`` (the default) renders all bounces with Russian roulette from vertex
    ``rr_depth`` on (capped at ``MAX_PATH_VERTICES``); an int stops every path after that many vertices
    (scattering + surface events), a biased estimator kept for experiments:

    Roulette. After each of its vertices b >= ``rr_depth`` (counted from 1) a path survives with probability
        q = min(1, max_c beta_c),   beta_c = f_c(x_0..x_b; theta_0) / mean_k p_k(x_0..x_b; theta_0),
    the path throughput at the *sampling* parameters in the hero-channel balance form of the estimator
    (it includes the 1 / q of earlier roulettes, and is independent of the hero channel). The roulette
    is one more sampling decision: a survivor's pdf gets the factor q in every channel, p_k -> q p_k, so
    its contribution f / p is divided by q (unbiased: E[1{u < q} / q] = 1), a killed path contributes
    nothing from then on. Why the throughput (and not the per-channel albedo product): once the
    throughput has dropped below 1, every later roulette keeps it near 1, so the survival probability
    per vertex is about the vertex's own albedo x a_t (1 - F) x rho factor, i.e. analog absorption, and
    the weights of the surviving paths stay bounded (max_c beta_c <= 1 right after a roulette that
    could kill) instead of growing as 1 / q. The per-channel albedo product would leave out the
    spectral balance-heuristic ratio f_c / mean_k p_k (up to 3) and the a_t (1 - F) and rho factors,
    so its survivors' weights would not be held near 1: weights that spread more are more variance
    for the same number of traced vertices. q is not capped below 1 (Mitsuba caps at 0.95): paths whose
    throughput is still >= 1 are not worth killing, and termination is guaranteed by absorption, by
    escape, and by the ``MAX_PATH_VERTICES`` cap.

    Derivatives with roulette. q is a function of the path prefix and theta_0 only (sampling-scene
    albedos, a_t, rho, sigma_t and geometry; never the evaluation scene), so it is part of
    p(path; theta_0): the per-path derivative d/dtheta [f / p] = (f / p) d log f (eq. 5.7-5.8) keeps
    exactly the same per-interaction terms (eq. 5.10-5.32), with f / p now including 1 / q. With
    common random numbers (``sampling_scene``) the roulette decisions and the q at theta_0 +- h are
    the same, so finite differences check the same estimator. (Computing q from the evaluation
    throughput instead would add the missing term -d log q / dtheta and flip decisions under h.)
    """

    spp: int = 4
    # None: all bounces, paths ended by Russian roulette (unbiased); an int stops every path after that many
    # vertices (scattering + surface events): biased dark, for experiments only (docs/teeth-tracer.md)
    max_depth: int | None = None
    seed: int = 0
    chunk: int = 4096  # camera paths per wavefront batch
    jitter: bool = True
    # processes that trace the chunks (each chunk has its own random stream, so the result does not
    # depend on this beyond floating-point summation order); > 1 forks (POSIX only)
    workers: int = 1
    # with max_depth None: roulette may end a path once it has this many vertices (Mitsuba's rr_depth).
    # Vertices here include every boundary event. On the 2-tooth acceptance scene (index-matched, 96 x 64)
    # 5 is more efficient than 10: variance x time of the tooth pixels 5 / 9 / 16 % lower (R, G, B), 20 %
    # less time per sample (24 seeds, docs/teeth-tracer.md); on the 1-tooth test scene the two were
    # within noise
    rr_depth: int = 5


@dataclass
class RenderResult:
    images: np.ndarray  # (n_cam, n_light, H, W, 3)
    grad: np.ndarray | None  # (n_params,) physical-parameter gradient of sum(adjoint * C)
    stats: dict = field(default_factory=dict)
    # (n_traced_pixels, n_lights, 3, P): d C / d x[jacobian_cols] per traced pixel (see ``render``)
    jacobian: np.ndarray | None = None


def traced_values(images: np.ndarray, pixels: list[np.ndarray]) -> np.ndarray:
    """The traced pixels of (n_cam, n_light, H, W, 3) ``images`` as (n_light, n_rows, 3), rows in the
    order of ``render``'s ``pixels`` (camera 0's first), i.e. the rows of ``RenderResult.jacobian``."""
    n_cam, n_l = images.shape[:2]
    flat = images.reshape(n_cam, n_l, -1, 3)
    return np.concatenate([flat[c][:, p] for c, p in enumerate(pixels)], axis=1)


def traced_tiles(pixels: list[np.ndarray], height: int, width: int, block: int) -> tuple[np.ndarray, int]:
    """Tile of every traced row (rows as in ``traced_values``) for block x block pixel tiles per camera:
    (tile index per row, number of tiles), tiles numbered by (camera, tile row, tile column) and only
    those that hold a traced pixel counted."""
    wb = -(-width // block)
    per_cam = -(-height // block) * wb
    keys = np.concatenate([c * per_cam + (np.asarray(p, dtype=np.int64) // width // block) * wb
                           + (np.asarray(p, dtype=np.int64) % width) // block for c, p in enumerate(pixels)])
    tiles, tile_of = np.unique(keys, return_inverse=True)
    return tile_of, len(tiles)


def traced_tile_sums(values: np.ndarray, tile_of: np.ndarray, n_tiles: int) -> np.ndarray:
    """(n_light, rows, C) traced values (``traced_values``) summed per tile of ``traced_tiles``:
    (n_light, n_tiles, C)."""
    out = np.zeros((values.shape[0], n_tiles, values.shape[2]))
    np.add.at(out, (slice(None), tile_of), values)
    return out


def _accumulate(g: np.ndarray, rows: np.ndarray, cols: np.ndarray, vals: np.ndarray, w: np.ndarray) -> None:
    """g[cols[k, j]] += sum_c vals[k, j, c] * w[rows[k], c]."""
    if len(rows) == 0:
        return
    contrib = np.einsum("kjc,kc->kj", vals, w[rows])
    ok = cols >= 0
    g += np.bincount(cols[ok], contrib[ok], minlength=g.size)


def _diag(vals: np.ndarray) -> np.ndarray:
    """(k, 3) per-channel values -> (k, 3, 3) with vals on the channel diagonal."""
    out = np.zeros(vals.shape + (3,))
    idx = np.arange(3)
    out[:, idx, idx] = vals
    return out


class _Tracer:
    def __init__(self, cs: CompiledScene, want_grad: bool, jacobian_cols: np.ndarray | None = None):
        self.cs = cs
        self.want_grad = want_grad
        self.n_shadow = 0
        self.n_casts = 0
        # forward mode: layout column -> Jacobian column (-1: not requested)
        self.jmap = None
        self.n_j = 0
        if jacobian_cols is not None:
            self.jmap = np.full(cs.layout.size + 1, -1, dtype=np.int64)  # last slot: cols == -1
            self.jmap[np.asarray(jacobian_cols, dtype=np.int64)] = np.arange(len(jacobian_cols))
            self.n_j = len(jacobian_cols)

    def add_scores(self, S: np.ndarray, rows: np.ndarray, cols: np.ndarray, vals: np.ndarray) -> None:
        """Forward mode: S[rows[k], jmap[cols[k, j]], c] += vals[k, j, c] (S is (n, P, 3), C-contiguous)."""
        if len(rows) == 0:
            return
        jc = self.jmap[np.asarray(cols)]  # cols == -1 reads the last slot (-1)
        ok = jc >= 0
        if not np.any(ok):
            return
        k_idx = np.broadcast_to(np.asarray(rows)[:, None], jc.shape)[ok]
        base = (k_idx * self.n_j + jc[ok]) * 3
        flat = (base[:, None] + np.arange(3)).ravel()
        np.add.at(S.reshape(-1), flat, vals[ok].ravel())  # cost ~ the record's entries, not S.size

    # ---------------------------------------------------------------- ray traversal
    def through(self, o, d, tmax, shadow: bool):
        """All crossings along rays. Path mode stops at the first non-index-matched surface;
        shadow mode passes dielectric boundaries and stops at opaque surfaces or tmax."""
        cs = self.cs
        n = len(o)
        tri_x = np.full((n, MAX_CROSSINGS), -1, dtype=np.int64)
        t_x = np.full((n, MAX_CROSSINGS), np.inf)
        cnt = np.zeros(n, dtype=np.int64)
        end_tri = np.full(n, -1, dtype=np.int64)
        end_t = np.full(n, np.inf) if tmax is None else tmax.copy()
        blocked = np.zeros(n, dtype=bool)
        act = np.arange(n)
        cur = o.copy()
        tcur = np.zeros(n)
        for _ in range(MAX_CROSSINGS + 1):
            if len(act) == 0:
                break
            tm = None if tmax is None else tmax[act] - tcur[act]
            tri, _ = cs.caster.first_hit(cur[act], d[act], tm, refine=False)
            self.n_casts += len(act)
            hit = tri >= 0
            act_h, tri_h = act[hit], tri[hit]
            tv = cs.tris_s[tri_h]
            th, _ = ray_triangle_distance(o[act_h], d[act_h], tv[:, 0], tv[:, 1], tv[:, 2])
            k = cs.kind[tri_h]
            if shadow:
                stop = k == KIND_OPAQUE
                blocked[act_h[stop]] = True
            else:
                stop = k != KIND_INDEX_MATCHED
                end_tri[act_h[stop]] = tri_h[stop]
                end_t[act_h[stop]] = th[stop]
            go = ~stop
            full = cnt[act_h[go]] >= MAX_CROSSINGS
            if np.any(full):  # degenerate geometry: give up on these rays
                blocked[act_h[go][full]] = True
                end_tri[act_h[go][full]] = -1
            go_idx = np.flatnonzero(go)[~full]
            rows = act_h[go_idx]
            tri_x[rows, cnt[rows]] = tri_h[go_idx]
            t_x[rows, cnt[rows]] = th[go_idx]
            cnt[rows] += 1
            cur[rows] = o[rows] + th[go_idx, None] * d[rows]
            tcur[rows] = th[go_idx]
            act = rows
        kmax = int(cnt.max()) if n else 0
        return tri_x[:, :kmax], t_x[:, :kmax], cnt, end_tri, end_t, blocked

    def media_sequence(self, med0, d, tri_x):
        """Medium of each piece between crossings, (n, K + 1)."""
        cs = self.cs
        n, k = tri_x.shape
        med = np.zeros((n, k + 1), dtype=np.int64)
        med[:, 0] = med0
        valid = tri_x >= 0
        tx = np.where(valid, tri_x, 0)
        entering = np.einsum("nkx,nx->nk", cs.normal_s[tx], d) < 0
        nxt = np.where(entering, cs.inside[tx], cs.outside[tx])
        for j in range(k):
            med[:, j + 1] = np.where(valid[:, j], nxt[:, j], med[:, j])
        return med

    def eval_crossings(self, o, d, tri_x, t_x, upper):
        """Crossing distances on the evaluation geometry (dentin moves with c), (n, K), and which were clipped.

        A crossing is re-solved on the moved triangle's plane, which is first-order exact; far from the
        sampling geometry (a grazing ray, a large change of c) the plane distance can leave the segment or
        overtake the next crossing, which would give negative piece lengths and overflowing weights. The
        distances are therefore kept ordered and within [0, ``upper``] (the path's vertex or the shadow
        ray's light); a clipped crossing no longer depends on c (its dt/dc term is dropped). With equal
        sampling and evaluation geometry only crossings beyond a path's vertex are clipped, which the
        estimator does not use."""
        cs = self.cs
        t_e = t_x.copy()
        rows, cols = np.nonzero((tri_x >= 0) & (cs.kind[np.maximum(tri_x, 0)] == KIND_INDEX_MATCHED))
        if len(rows) == 0:
            return t_e, None
        tv = cs.tris_e[tri_x[rows, cols]]
        t_e[rows, cols], _ = ray_triangle_distance(o[rows], d[rows], tv[:, 0], tv[:, 1], tv[:, 2])
        valid = tri_x >= 0
        kept = np.minimum(np.maximum.accumulate(np.where(valid, np.maximum(t_e, 0.0), 0.0), axis=1), upper[:, None])
        clipped = valid & (kept != t_e)
        if not np.any(clipped):
            return t_e, None
        return np.where(valid, kept, t_e), clipped

    def crossing_records(self, o, d, tri_x, med, upto, rows_out, clipped=None):
        """Dentin-shape terms (S_i - S_e) dt/dc for dentin crossings j < upto (eq. 5.29-5.32)."""
        cs = self.cs
        valid = (tri_x >= 0) & (np.arange(tri_x.shape[1])[None, :] < upto[:, None])
        valid &= cs.kind[np.maximum(tri_x, 0)] == KIND_INDEX_MATCHED
        if clipped is not None:
            valid &= ~clipped
        r, j = np.nonzero(valid)
        if len(r) == 0:
            return None
        tri = tri_x[r, j]
        tv = cs.tris_e[tri]
        _, bary = ray_triangle_distance(o[r], d[r], tv[:, 0], tv[:, 1], tv[:, 2])
        dt_dv = ray_distance_vertex_derivative(d[r], tv[:, 0], tv[:, 1], tv[:, 2], bary)
        tooth = cs.dentin_tooth[tri]
        dt_dc = np.zeros((len(r), 3))
        for i in np.unique(tooth):
            m = tooth == i
            dp = cs.dentin[i]
            dB = dp.deltas[:, dp.faces[cs.dentin_face[tri[m]]], :]  # (3, k, 3v, 3)
            dt_dc[m] = np.einsum("nvx,knvx->nk", dt_dv[m], dB)
        s_diff = cs.sigma_e[med[r, j + 1]] - cs.sigma_e[med[r, j]]  # S_i - S_e
        cols = cs.c_col[tooth][:, None] + np.arange(3)[None, :]
        vals = dt_dc[:, :, None] * s_diff[:, None, :]
        return rows_out[r], cols, vals

    def sigma_records(self, lens_e, med, rows_out):
        """Beer-Lambert terms -t_k per medium piece (eq. 5.23, second term)."""
        cs = self.cs
        r, j = np.nonzero((lens_e != 0) & (med != MED_AIR))
        if len(r) == 0:
            return None
        m = med[r, j]
        cols = cs.col_sigma[m][:, None] + np.arange(3)[None, :]
        return rows_out[r], cols, _diag(-np.repeat(lens_e[r, j][:, None], 3, axis=1))

    def a_t_at(self, tri, o, d, t, which: str):
        """a_t at boundary hits (n, 3) plus (texel cols (n, 12), 1/a_t weights) for eq. 5.10."""
        cs = self.cs
        tv = cs.tris_s[tri]
        _, bary = ray_triangle_distance(o, d, tv[:, 0], tv[:, 1], tv[:, 2])
        uv = np.einsum("nv,nvk->nk", bary, cs.corner_uv[tri])
        tid = cs.tex_id[tri]
        a = np.ones((len(tri), 3))
        cols = np.full((len(tri), 12), -1, dtype=np.int64)
        w4 = np.zeros((len(tri), 4))
        for k in np.unique(tid):
            m = tid == k
            tex = cs.tex_e[k] if which == "e" else cs.tex_s[k]
            vals, idx, wts = lookup_a_t(tex, uv[m])
            a[m] = vals
            cols[m] = (cs.tex_col[k] + 3 * idx[:, :, None] + np.arange(3)[None, None, :]).reshape(-1, 12)
            w4[m] = wts
        return a, cols, w4

    @staticmethod
    def a_t_vals(a, w4):
        """(n, 12, 3) values w_i / a_t on the texel-channel diagonal."""
        n = len(a)
        vals = np.zeros((n, 4, 3, 3))
        idx = np.arange(3)
        vals[:, :, idx, idx] = w4[:, :, None] / a[:, None, :]
        return vals.reshape(n, 12, 3)

    # ---------------------------------------------------------------- shadow rays
    def shadow(self, x, w, r, med0):
        """Transmittance (n, 3) from x towards a point light at distance r, and score records."""
        cs = self.cs
        self.n_shadow += len(x)
        tri_x, t_x, cnt, _, _, blocked = self.through(x, w, r, shadow=True)
        med = self.media_sequence(med0, w, tri_x)
        t_e, clipped = self.eval_crossings(x, w, tri_x, t_x, r)
        k = tri_x.shape[1]
        tb = np.concatenate([np.zeros((len(x), 1)), np.where(tri_x >= 0, t_e, r[:, None]), r[:, None]], axis=1)
        lens = np.diff(tb, axis=1)
        logT = -np.einsum("nk,nkc->nc", lens, cs.sigma_e[med])
        recs = []
        rows_all = np.arange(len(x))
        rb, jb = np.nonzero((tri_x >= 0) & (cs.kind[np.maximum(tri_x, 0)] == KIND_DIELECTRIC))
        if len(rb):
            tri = tri_x[rb, jb]
            cosv = np.einsum("nx,nx->n", cs.normal_s[tri], w[rb])
            a, cols, w4 = self.a_t_at(tri, x[rb], w[rb], t_x[rb, jb], "e")
            np.add.at(logT, rb, np.log(a) + np.log1p(-fresnel_dielectric(cosv, cs.eta[tri]))[:, None])
            if self.want_grad:
                recs.append((rb, cols, self.a_t_vals(a, w4)))
        T = np.exp(logT)
        T[blocked] = 0.0
        if self.want_grad:
            rs = self.sigma_records(lens, med, rows_all)
            if rs is not None:
                recs.append(rs)
            rc = self.crossing_records(x, w, tri_x, med, np.full(len(x), k), rows_all, clipped)
            if rc is not None:
                recs.append(rc)
        return T, recs

    # ---------------------------------------------------------------- phase function at a vertex
    def vertex_phase(self, med, lw, which: str):
        cs = self.cs
        pe, pd = cs.ph["E" + which][med], cs.ph["D" + which][med]
        mixp = pe * lw[:, None] + pd * (1.0 - lw[:, None])
        return pe, pd, mixp

    def phase_eval(self, mu, mixp):
        g1, g2, beta = mixp[:, 0:1], mixp[:, 1:2], mixp[:, 2:3]
        h1, h2 = hg(mu, g1), hg(mu, g2)
        return beta * h1 + (1 - beta) * h2, h1, h2

    def phase_scores(self, mu, med, lw, dl, dqdc, pe, pd, mixp):
        """d log f_p per vertex and direction: cols (n, m, 9), vals (n, m, 9) (eq. 5.11-5.19)."""
        cs = self.cs
        g1, g2, beta = mixp[:, 0:1], mixp[:, 1:2], mixp[:, 2:3]
        h1, h2 = hg(mu, g1), hg(mu, g2)
        f = beta * h1 + (1 - beta) * h2
        d1 = beta * h1 * hg_dlog_dg(mu, g1) / f
        d2 = (1 - beta) * h2 * hg_dlog_dg(mu, g2) / f
        db = (h1 - h2) / f
        l_ = lw[:, None]
        vals = [d1 * l_, d1 * (1 - l_), d2 * l_, d2 * (1 - l_), db * l_, db * (1 - l_)]
        dmix = d1 * (pe[:, 0:1] - pd[:, 0:1]) + d2 * (pe[:, 1:2] - pd[:, 1:2]) + db * (pe[:, 2:3] - pd[:, 2:3])
        for k in range(3):
            vals.append(dmix * (dl * dqdc[:, k])[:, None])
        vals = np.stack(vals, axis=-1)  # (n, m, 9)
        cE, cD = cs.col_ph["E"][med], cs.col_ph["D"][med]
        tooth = cs.med_tooth[med]
        ccol = np.where(tooth[:, None] >= 0, cs.c_col[np.maximum(tooth, 0)][:, None] + np.arange(3), -1)
        cols = np.stack([cE[:, 0], cD[:, 0], cE[:, 1], cD[:, 1], cE[:, 2], cD[:, 2]], axis=1)
        cols = np.concatenate([cols, ccol], axis=1)
        return cols, vals


def render(scene, cameras: list[Camera], lights: list[PointLight], settings: RenderSettings | None = None, *,
           pixels: list[np.ndarray] | None = None, light_ids: np.ndarray | None = None, sampling_scene=None,
           adjoint: np.ndarray | None = None, compiled: CompiledScene | None = None,
           jacobian_cols: np.ndarray | None = None, reference: bool = False) -> RenderResult:
    """Render ``scene`` for every camera and (selected) light; optionally the gradient of sum(adjoint * C).

    ``pixels``: per camera, flat pixel indices (row * W + col) to trace (default: all).
    ``adjoint``: (n_cam, n_selected_lights, H, W, 3) = d rho / d C; returns ``grad`` (physical params).
    ``jacobian_cols``: physical-parameter columns; returns ``jacobian`` (n_traced, n_selected_lights, 3, P),
    the per-pixel image derivatives of the same estimator in forward mode (each path carries its
    running score d log f, every connection adds its own terms), rows in the order of ``pixels``
    (camera 0's pixels first). Contracting it with the adjoint gives ``grad`` of the same paths.
    ``sampling_scene``: theta_0 for the path sampling (default ``scene``), see module docstring.
    ``settings.max_depth = None``: all bounces with Russian roulette; ``grad`` and ``jacobian`` are then
    the exact derivatives of that estimator (roulette probabilities at theta_0, see ``RenderSettings``),
    and ``stats["capped_paths"]`` counts the paths stopped by ``MAX_PATH_VERTICES``.
    The paths are traced by the compiled tracer (``path_tracer_compiled``, all cores) when numba is
    installed; ``reference=True`` (or no numba) traces them with this module's numpy implementation,
    ``settings.workers`` processes. Both are the same estimator with different random numbers.
    """
    settings = settings or RenderSettings()
    cs = compiled or CompiledScene(scene, sampling_scene)
    light_ids = np.arange(len(lights)) if light_ids is None else np.asarray(light_ids, dtype=np.int64)
    lp = np.array([lights[i].position for i in light_ids])
    li = np.array([lights[i].intensity for i in light_ids])
    n_l = len(light_ids)
    h, w = cameras[0].height, cameras[0].width
    hw = h * w
    if pixels is None:
        pixels = [np.arange(hw) for _ in cameras]
    cam_of = np.concatenate([np.full(len(p), c) for c, p in enumerate(pixels)]).astype(np.int64)
    pix_of = np.concatenate([np.asarray(p, dtype=np.int64) for p in pixels])
    if not reference and _compiled_tracer() is not None:
        return _render_compiled(cs, cameras, lp, li, settings, cam_of, pix_of, adjoint, jacobian_cols, hw)
    row_of = np.repeat(np.arange(len(pix_of)), settings.spp)
    cam_of = np.repeat(cam_of, settings.spp)
    pix_of = np.repeat(pix_of, settings.spp)
    img = np.zeros(len(cameras) * n_l * hw * 3)
    want_grad = adjoint is not None or jacobian_cols is not None
    adj = None if adjoint is None else np.asarray(adjoint, dtype=np.float64).reshape(len(cameras), n_l, hw, 3)
    grad = np.zeros(cs.layout.size) if adjoint is not None else None
    tr = _Tracer(cs, want_grad, jacobian_cols)
    jac = None
    if jacobian_cols is not None:
        n_rows = len(row_of) // settings.spp
        need = 8 * n_l * 3 * tr.n_j * (n_rows + 2 * min(settings.chunk, len(row_of)))  # result + chunk buffers
        n_workers = min(settings.workers, -(-len(row_of) // settings.chunk))
        if n_workers > 1:  # every worker fills a full Jacobian, pickles it, and the parent receives it
            need += 3 * n_workers * 8 * n_l * 3 * tr.n_j * n_rows
        if need > JACOBIAN_MAX_BYTES:
            raise UserError(f"the image Jacobian needs about {need / 2**30:.1f} GiB (limit "
                            f"{JACOBIAN_MAX_BYTES / 2**30:.0f} GiB): ask for fewer columns, lights or pixels")
        jac = np.zeros((n_rows, n_l, 3, tr.n_j))
    t0 = time.perf_counter()
    starts = list(range(0, len(pix_of), settings.chunk))

    def trace(chunk_ids, img, grad, jac) -> tuple[int, int, int, int]:
        """Trace these chunks into img / grad / jac; (path vertices, shadow rays, ray casts, paths stopped
        by ``MAX_PATH_VERTICES``) they added."""
        n_vertices, n_capped, shadow0, casts0 = 0, 0, tr.n_shadow, tr.n_casts
        for ci in chunk_ids:
            sl = slice(starts[ci], starts[ci] + settings.chunk)
            rng = np.random.Generator(np.random.PCG64([settings.seed, ci]))
            nv, nc = _trace_chunk(tr, cameras, cam_of[sl], pix_of[sl], rng, lp, li, settings, img, adj, grad,
                                  hw, jac, row_of[sl])
            n_vertices += nv
            n_capped += nc
        return n_vertices, tr.n_shadow - shadow0, tr.n_casts - casts0, n_capped

    if settings.workers > 1 and len(starts) > 1:
        n_vertices, n_shadow, n_casts, n_capped = _trace_forked(trace, len(starts), settings.workers, img, grad, jac)
    else:
        n_vertices, n_shadow, n_casts, n_capped = trace(range(len(starts)), img, grad, jac)
    stats = {"seconds": time.perf_counter() - t0, "path_vertices": int(n_vertices),
             "shadow_rays": int(n_shadow), "ray_casts": int(n_casts), "camera_paths": int(len(pix_of))}
    if settings.max_depth is None:
        stats["capped_paths"] = int(n_capped)
    images = img.reshape(len(cameras), n_l, h, w, 3)
    return RenderResult(images, grad, stats, jac)


def _compiled_tracer():
    """The compiled tracer module, or None where numba is not installed."""
    try:
        from . import path_tracer_compiled
    except ImportError:  # pragma: no cover - depends on the environment
        return None
    return path_tracer_compiled


def _render_compiled(cs: CompiledScene, cameras, lp, li, settings: RenderSettings, cam_of, pix_of, adjoint,
                     jacobian_cols, hw: int) -> RenderResult:
    """``render`` through ``path_tracer_compiled`` (rows = traced pixels, all their samples in one thread)."""
    ptc = _compiled_tracer()
    n_cam, n_l, n_rows = len(cameras), len(lp), len(pix_of)
    jmap, n_j = None, 0
    if jacobian_cols is not None:
        n_j = len(jacobian_cols)
        need = 8 * n_l * 3 * n_j * n_rows
        if need > JACOBIAN_MAX_BYTES:
            raise UserError(f"the image Jacobian needs about {need / 2**30:.1f} GiB (limit "
                            f"{JACOBIAN_MAX_BYTES / 2**30:.0f} GiB): ask for fewer columns, lights or pixels")
        jmap = np.full(cs.layout.size + 1, -1, dtype=np.int64)
        jmap[np.asarray(jacobian_cols, dtype=np.int64)] = np.arange(n_j)
    adj = None
    if adjoint is not None:
        adj = np.asarray(adjoint, dtype=np.float64).reshape(n_cam, n_l, hw, 3)
    packed = getattr(cs, "_packed", None)
    if packed is None:
        packed = cs._packed = ptc.pack_scene(cs)
    t0 = time.perf_counter()
    rows, grad, jac, counts, threads = ptc.trace(cs, packed, cameras, cam_of, pix_of, settings.spp, settings.seed,
                                                 settings.max_depth, settings.rr_depth, settings.jitter, lp, li, adj,
                                                 jmap, n_j)
    img = np.zeros((n_cam, n_l, hw, 3))
    np.add.at(img, (cam_of, slice(None), pix_of), rows)
    stats = {"seconds": time.perf_counter() - t0, "path_vertices": int(counts[0]), "shadow_rays": int(counts[1]),
             "ray_casts": int(counts[2]), "camera_paths": int(n_rows * settings.spp), "threads": int(threads)}
    if settings.max_depth is None:
        stats["capped_paths"] = int(counts[3])
    h = hw // cameras[0].width
    return RenderResult(img.reshape(n_cam, n_l, h, cameras[0].width, 3), grad, stats, jac)


def _trace_forked(trace, n_chunks: int, workers: int, img, grad, jac) -> tuple[int, int, int, int]:
    """Run ``trace`` over the chunks in ``workers`` forked processes (chunk i on worker i mod workers)
    and add their images, gradients and Jacobians into ``img``, ``grad``, ``jac`` in worker order."""
    workers = min(workers, n_chunks)
    parts = forked_map(_trace_chunk_set, (trace, (img, grad, jac)),
                       [list(range(k, n_chunks, workers)) for k in range(workers)], workers)
    totals = np.zeros(4, dtype=np.int64)
    for p_img, p_grad, p_jac, counts in parts:
        img += p_img
        if grad is not None:
            grad += p_grad
        if jac is not None:
            jac += p_jac
        totals += counts
    return tuple(int(t) for t in totals)


def _trace_chunk_set(job, chunk_ids: list[int]):
    """One worker's share: its chunks traced into zeroed copies of the image, gradient and Jacobian."""
    trace, arrays = job
    img, grad, jac = (None if a is None else np.zeros_like(a) for a in arrays)
    return img, grad, jac, trace(chunk_ids, img, grad, jac)


def _trace_chunk(tr: _Tracer, cameras, cam, pix, rng, lp, li, st: RenderSettings, img, adj, grad, hw,
                 jac=None, rows_j=None) -> tuple[int, int]:
    """Trace one wavefront batch; (path vertices, paths still alive at the roulette safety cap)."""
    cs = tr.cs
    n = len(pix)
    want = tr.want_grad
    # --- camera rays (pinhole, box filter, eq. 5.8)
    jit = rng.random((n, 2)) if st.jitter else np.full((n, 2), 0.5)
    o = np.zeros((n, 3))
    d = np.zeros((n, 3))
    for c in np.unique(cam):
        m = cam == c
        wcam = cameras[c].width
        o[m], d[m] = cameras[c].rays(pix[m] % wcam + jit[m, 0], pix[m] // wcam + jit[m, 1])
    hero = rng.integers(0, 3, n)
    pid = np.arange(n)
    med = np.zeros(n, dtype=np.int64)
    logf = np.zeros((n, 3))
    logp = np.zeros((n, 3))
    roulette = st.max_depth is None
    depth_cap = MAX_PATH_VERTICES if roulette else st.max_depth
    # log f at the sampling parameters theta_0 (roulette only): the throughput that sets q
    logfs = np.zeros((n, 3)) if roulette else None
    # adjoint-weighted contributions per path and vertex level; grown as paths get deeper (roulette)
    A = np.zeros((n, depth_cap + 2 if not roulette else 16, 3)) if grad is not None else None
    prefix = []  # (level, rows, cols, vals) for the reverse-mode gradient
    # forward mode: running per-path score (n, P, 3) and per-path image derivatives (n, L, 3, P)
    S = None if jac is None else np.zeros((n, tr.n_j, 3))
    JP = None if jac is None else np.zeros((n, len(lp), 3, tr.n_j))
    fwd = None if jac is None else (S, JP)

    def push(level, rows, cols, vals):
        """Record the d log f terms of an interaction that all vertices from ``level`` on share."""
        if grad is not None:
            prefix.append((level, rows, cols, vals))
        if S is not None:
            tr.add_scores(S, rows, cols, vals)
    n_vertices = 0
    inv_spp = 1.0 / st.spp

    for b in range(depth_cap):
        if len(pid) == 0:
            break
        if A is not None and A.shape[1] < b + 2:
            A = np.concatenate([A, np.zeros_like(A)], axis=1)
        m_ = len(pid)
        u = rng.random((m_, 6))
        tri_x, t_x, cnt, end_tri, end_t, _ = tr.through(o, d, None, shadow=False)
        mseq = tr.media_sequence(med, d, tri_x)
        k = tri_x.shape[1]
        # a flight from the air that crossed an index-matched surface entered a medium (only where volumes overlap:
        # a tooth's root inside the gums, entered and left through the gums' surface): it is a flight in a medium
        in_medium = (med != MED_AIR) | (np.any(tri_x >= 0, axis=1) if k else False)
        end_f = np.where(np.isfinite(end_t), end_t, 0.0)
        tb_s = np.concatenate([np.zeros((m_, 1)), np.where(tri_x >= 0, t_x, end_f[:, None]), end_f[:, None]], 1)
        lens_s = np.diff(tb_s, axis=1)
        sig_s = cs.sigma_s[mseq]  # (m, k+1, 3)
        tau_cum = np.cumsum(lens_s[:, :, None] * sig_s, axis=1)
        tau_star = -np.log1p(-u[:, 0])
        tau_h = tau_cum[np.arange(m_), :, hero]
        scatter = in_medium & (tau_star < tau_h[:, -1]) & (end_tri >= 0)
        kstar = np.where(scatter, np.argmax(tau_h > tau_star[:, None], axis=1), k)
        prev_tau = np.where(kstar > 0, tau_cum[np.arange(m_), np.maximum(kstar - 1, 0), :].T, 0.0).T
        prev_tau_h = prev_tau[np.arange(m_), hero]
        sig_k_s = sig_s[np.arange(m_), np.minimum(kstar, k)]
        s = np.where(scatter, tb_s[np.arange(m_), kstar] + (tau_star - prev_tau_h) /
                     np.maximum(sig_k_s[np.arange(m_), hero], 1e-300), end_f)
        # sampling pdf, all channels (balance heuristic over the hero channel)
        tau_at_s = prev_tau + sig_k_s * (s - tb_s[np.arange(m_), kstar])[:, None]
        logp += -tau_at_s
        logp[scatter] += np.log(sig_k_s[scatter])
        # evaluation: piece lengths on the evaluation geometry up to s
        t_e, clipped = tr.eval_crossings(o, d, tri_x, t_x, np.where(scatter, s, end_t))
        tb_e = np.concatenate([np.zeros((m_, 1)), np.where(tri_x >= 0, t_e, end_f[:, None]), end_f[:, None]], 1)
        jj = np.arange(k + 1)[None, :]
        upper = np.where(jj < kstar[:, None], tb_e[:, 1:], s[:, None])
        lens_e = np.where(jj <= kstar[:, None], upper - tb_e[:, :-1], 0.0)
        lens_e = np.where(in_medium[:, None], lens_e, 0.0)
        logf -= np.einsum("nk,nkc->nc", lens_e, cs.sigma_e[mseq])
        if roulette:
            logfs -= np.where(in_medium[:, None], tau_at_s, 0.0)
        if want:
            rec = tr.sigma_records(lens_e, mseq, pid)
            if rec is not None:
                push(b, *rec)
            rec = tr.crossing_records(o, d, tri_x, mseq, np.where(in_medium, kstar, 0), pid, clipped)
            if rec is not None:
                push(b, *rec)
        x = o + s[:, None] * d
        new_med = mseq[np.arange(m_), np.minimum(kstar, k)]
        alive = np.ones(m_, dtype=bool)
        new_d = d.copy()

        # ---------------- volume scattering vertices
        vs = np.flatnonzero(scatter)
        if len(vs):
            n_vertices += len(vs)
            mv = new_med[vs]
            xv = x[vs]
            lw_s = np.ones(len(vs))
            lw_e = np.ones(len(vs))
            dl = np.zeros(len(vs))
            dqdc = np.zeros((len(vs), 3))
            tooth = cs.med_tooth[mv]
            for i in np.unique(tooth[tooth >= 0]):
                mm = tooth == i
                sign = np.where(cs.med_kind[mv[mm]] == MED_DENTIN, -1.0, 1.0)
                q_s, q_e, dq = cs.dentin[i].query(xv[mm], sign)
                lw_s[mm] = blend_weight(q_s, cs.spread)
                lw_e[mm] = blend_weight(q_e, cs.spread)
                dl[mm] = blend_weight_dq(q_e, cs.spread)
                dqdc[mm] = dq
            # scattering coefficient sigma_s = albedo_mix * sigma_t at the vertex (eq. 5.17-5.21): the albedo is
            # blended, the extinction is the region's own (piecewise constant), so sigma_s <= sigma_t everywhere
            s_loc = cs.sigma_e[mv]
            aE, aD = cs.alb["Ee"][mv], cs.alb["De"][mv]
            a_mix = aE * lw_e[:, None] + aD * (1 - lw_e[:, None])
            logf[vs] += np.log(s_loc) + np.log(a_mix)
            if roulette:
                ls = lw_s[:, None]
                logfs[vs] += (np.log(cs.sigma_s[mv])
                              + np.log(cs.alb["Es"][mv] * ls + cs.alb["Ds"][mv] * (1 - ls)))
            if want:
                rows = pid[vs]
                push(b, rows, cs.col_sigma[mv][:, None] + np.arange(3), _diag(1.0 / s_loc))  # (N - 1) / sigma_t
                cols = np.concatenate([cs.col_alb["E"][mv][:, None] + np.arange(3),
                                       cs.col_alb["D"][mv][:, None] + np.arange(3)], axis=1)
                vals = np.concatenate([_diag(lw_e[:, None] / a_mix), _diag((1 - lw_e[:, None]) / a_mix)], axis=1)
                push(b, rows, cols, vals)  # eq. 5.20-5.21
                ht = tooth >= 0
                if np.any(ht):
                    cols = cs.c_col[tooth[ht]][:, None] + np.arange(3)
                    dlog = (aE - aD)[ht] / a_mix[ht]
                    vals = dlog[:, None, :] * (dl[ht, None] * dqdc[ht])[:, :, None]
                    push(b, rows[ht], cols, vals)  # eq. 5.21 via dl/dq dq/dc
            pe_e, pd_e, mix_e = tr.vertex_phase(mv, lw_e, "e")
            _, _, mix_s = tr.vertex_phase(mv, lw_s, "s")
            # next-event estimation to every light
            wv = np.exp(logf[vs] - _logmeanexp(logp[vs]))
            _nee(tr, vs, xv, d[vs], mv, wv, None, lp, li, cam, pix, pid, b, img, adj, grad, A, hw, inv_spp,
                 (lw_e, dl, dqdc, pe_e, pd_e, mix_e), fwd)
            # continue: sample the phase function with the sampling parameters
            first = u[vs, 1] < mix_s[:, 2]
            gsel = np.where(first, mix_s[:, 0], mix_s[:, 1])
            mu = sample_hg_mu(gsel, u[vs, 2])
            new_d[vs] = direction_from_mu(d[vs], mu, 2 * np.pi * u[vs, 3])
            f_e, _, _ = tr.phase_eval(mu[:, None], mix_e)
            f_s, _, _ = tr.phase_eval(mu[:, None], mix_s)
            logf[vs] += np.log(f_e[:, 0])[:, None]
            logp[vs] += np.log(f_s[:, 0])[:, None]
            if roulette:
                logfs[vs] += np.log(f_s[:, 0])[:, None]
            if want:
                cols, vals = tr.phase_scores(mu[:, None], mv, lw_e, dl, dqdc, pe_e, pd_e, mix_e)
                push(b + 1, pid[vs], cols[:, :], np.repeat(vals[:, 0, :, None], 3, axis=2))

        # ---------------- surface events
        sv = np.flatnonzero(~scatter & (end_tri >= 0))
        alive[np.flatnonzero(~scatter & (end_tri < 0))] = False
        if len(sv):
            tri = end_tri[sv]
            kind = cs.kind[tri]
            # thin dielectric boundary (eq. 5.1-5.2)
            dv = sv[kind == KIND_DIELECTRIC]
            if len(dv):
                n_vertices += len(dv)
                tri_d = end_tri[dv]
                nrm = cs.normal_s[tri_d]
                cosv = np.einsum("nx,nx->n", nrm, d[dv])
                F = fresnel_dielectric(cosv, cs.eta[tri_d])
                refl = u[dv, 4] < F
                rv, tv_ = dv[refl], dv[~refl]
                new_d[rv] = d[rv] - 2 * cosv[refl, None] * nrm[refl]
                if len(tv_):
                    tt = tri_d[~refl]
                    entering = cosv[~refl] < 0
                    new_med[tv_] = np.where(entering, cs.inside[tt], cs.outside[tt])
                    a, cols, w4 = tr.a_t_at(tt, o[tv_], d[tv_], end_t[tv_], "e")
                    logf[tv_] += np.log(a)
                    if roulette:
                        logfs[tv_] += np.log(tr.a_t_at(tt, o[tv_], d[tv_], end_t[tv_], "s")[0])
                    if want:
                        push(b, pid[tv_], cols, tr.a_t_vals(a, w4))
            # opaque Lambertian oral cavity
            ov = sv[kind == KIND_OPAQUE]
            if len(ov):
                n_vertices += len(ov)
                nrm = cs.normal_s[end_tri[ov]]
                nrm = nrm * -np.sign(np.einsum("nx,nx->n", nrm, d[ov]))[:, None]
                logf[ov] += np.log(cs.rho_e)[None, :]
                if roulette:
                    logfs[ov] += np.log(cs.rho_s)[None, :]
                if want:
                    push(b, pid[ov], np.broadcast_to(cs.col_rho + np.arange(3), (len(ov), 3)),
                         _diag(np.broadcast_to(1.0 / cs.rho_e, (len(ov), 3))))
                wv = np.exp(logf[ov] - _logmeanexp(logp[ov]))
                _nee(tr, ov, x[ov], d[ov], new_med[ov], wv, nrm, lp, li, cam, pix, pid, b, img, adj, grad, A, hw,
                     inv_spp, None, fwd)
                # cosine-weighted continuation: f / p = rho
                r1, r2 = u[ov, 4], u[ov, 5]
                mu = np.sqrt(1.0 - r1)
                new_d[ov] = direction_from_mu(nrm, mu, 2 * np.pi * r2)
                new_med[ov] = MED_AIR
            # anything else (should not happen): terminate
            bad = sv[(kind != KIND_DIELECTRIC) & (kind != KIND_OPAQUE)]
            alive[bad] = False
        # Russian roulette (see ``RenderSettings``): survival q from the theta_0 throughput, p *= q
        if roulette and b + 1 >= st.rr_depth:
            ur = rng.random(m_)
            ra = np.flatnonzero(alive)
            live, log_q = _roulette(ur[ra], logfs[ra], logp[ra])
            alive[ra[~live]] = False
            logp[ra[live]] += log_q[:, None]
        # compact
        keep = np.flatnonzero(alive)
        o, d, med = x[keep], new_d[keep], new_med[keep]
        logf, logp, hero, pid = logf[keep], logp[keep], hero[keep], pid[keep]
        if roulette:
            logfs = logfs[keep]
        cam, pix = cam[keep], pix[keep]
    n_capped = len(pid) if roulette else 0

    if grad is not None and prefix:
        R = np.cumsum(A[:, ::-1, :], axis=1)[:, ::-1, :]  # suffix sums over vertex levels
        for level, rows, cols, vals in prefix:
            _accumulate(grad, rows, np.asarray(cols), vals, R[:, level, :])
    if jac is not None:
        np.add.at(jac, rows_j, JP)  # rows repeat when spp > 1
    return n_vertices, n_capped


def _logmeanexp(a: np.ndarray) -> np.ndarray:
    m = a.max(axis=1, keepdims=True)
    return m + np.log(np.mean(np.exp(a - m), axis=1, keepdims=True))


def _roulette(u: np.ndarray, logfs: np.ndarray, logp: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Russian roulette for paths with uniform numbers ``u``, log f at theta_0 ``logfs`` and per-channel
    log pdfs ``logp`` (n, 3): (survives (n,), log q of the survivors). Survival probability
    q = min(1, max_c beta_c), beta_c = f_c / mean_k p_k (see ``RenderSettings``); a zero-throughput path
    (q = 0) never survives. The caller multiplies the survivors' pdfs by q (their weight by 1 / q)."""
    with np.errstate(invalid="ignore", over="ignore"):
        beta = np.exp(np.max(logfs, axis=1) - _logmeanexp(logp)[:, 0])
    q = np.minimum(np.nan_to_num(beta, nan=0.0, posinf=1.0), 1.0)
    live = u < q
    return live, np.log(q[live])


def _nee(tr: _Tracer, idx, xv, dv, mv, wv, normal, lp, li, cam, pix, pid, b, img, adj, grad, A, hw, inv_spp,
         phase_ctx, fwd=None):
    """Connect vertices to all lights; splat contributions; gradient terms of the connections."""
    n = len(idx)
    n_l = len(lp)
    xx = np.repeat(xv, n_l, axis=0)
    to = np.tile(lp, (n, 1)) - xx
    r = np.linalg.norm(to, axis=1)
    w = to / r[:, None]
    if phase_ctx is not None:
        lw_e, dl, dqdc, pe_e, pd_e, mix_e = phase_ctx
        mu = np.einsum("nlx,nx->nl", w.reshape(n, n_l, 3), dv)
        fp, _, _ = tr.phase_eval(mu, mix_e)
        geo = fp
    else:
        cosl = np.einsum("nlx,nx->nl", w.reshape(n, n_l, 3), normal)
        geo = np.maximum(cosl, 0.0) / np.pi
    T, recs = tr.shadow(xx, w, r, np.repeat(mv, n_l))
    contrib = (wv[:, None, :] * geo[:, :, None] * T.reshape(n, n_l, 3) * li[None, :, :]
               / (r * r).reshape(n, n_l)[:, :, None]) * inv_spp
    c_ = cam[idx]
    p_ = pix[idx]
    base = ((c_[:, None] * n_l + np.arange(n_l)[None, :]) * hw + p_[:, None]) * 3  # (n, L)
    flat = (base[:, :, None] + np.arange(3)).ravel()
    img += np.bincount(flat, contrib.ravel(), minlength=img.size)
    if fwd is None and grad is None:
        return
    # the connection's own d log f terms: shadow ray (eq. 5.10, 5.23, 5.29) and phase function at the vertex
    conn = list(recs)
    if phase_ctx is not None:
        cols, vals = tr.phase_scores(mu, mv, lw_e, dl, dqdc, pe_e, pd_e, mix_e)  # (n, L, 9)
        conn.append((np.arange(n * n_l), np.repeat(cols, n_l, axis=0),
                     np.repeat(vals.reshape(n * n_l, 9)[:, :, None], 3, axis=2)))
    if fwd is not None:
        S, JP = fwd
        score = np.repeat(S[pid[idx]], n_l, axis=0)  # (n L, P, 3): the path's terms so far ...
        for rows, cols, vals in conn:  # ... plus the connection's own
            tr.add_scores(score, rows, cols, vals)
        # each path has one vertex per level, so pid[idx] has no repeats
        JP[pid[idx]] += contrib[:, :, :, None] * score.reshape(n, n_l, -1, 3).transpose(0, 1, 3, 2)
    if grad is None:
        return
    a = adj.reshape(-1)[flat].reshape(n, n_l, 3) * contrib
    A[pid[idx], b, :] += a.sum(axis=1)
    a2 = a.reshape(n * n_l, 3)
    for rows, cols, vals in conn:
        _accumulate(grad, rows, cols, vals, a2)
