"""Compiled (numba) form of the volumetric path tracer of ``path_tracer``: the same estimator per path.

``path_tracer`` documents the estimator (eq. 5.1-5.32): hero-channel free flight with the balance
heuristic, thin non-bending boundaries (eq. 5.1-5.2), enamel/dentin blend by l(q) (eq. 5.15-5.21),
next-event estimation to every point light, Russian roulette at theta_0, and the per-path derivative
d/dtheta [f / p] = (f / p) d log f with the per-interaction terms of eq. 5.10-5.32. This module traces
that estimator one path at a time in compiled code (paths in parallel threads); ``path_tracer``'s
numpy wavefront implementation stays as the readable reference the tests compare against.

Differences that change no expectation: random numbers come from a counter-based generator per path
(splitmix64 seeded by (seed, path index)), so the result does not depend on the thread count but is
not the numpy tracer's sample for sample; ray queries use a float64 BVH (``bvh``) instead of embree;
the dentin distance q is the exact nearest triangle (the reference searches 8 nearest centroids).

Gradient (reverse mode) by path replay: a first pass traces a path and records the adjoint-weighted
contribution A_b of each vertex level b; a second pass replays the same random numbers and adds every
d log f term pushed at level L with the weight R_L = sum_{b >= L} A_b (the suffix sums of the
reference), and every connection term with its own connection's weight. Forward mode (the image
Jacobian) carries the running score d log f per path as the reference does.

Compiled with numba's numpy error model: a float division by zero gives inf or NaN as in numpy instead of
a test and a branch to raise ZeroDivisionError at every division (no division here has a zero divisor in
the scenes the tests trace: the images are bit-identical to the Python error model's). ``trace`` refuses a
result that is not finite, which is where such a division would show.

The kernels read named tuples (numba compiles a field access to the same load as a tuple index):
``Geometry``, ``Media`` and ``Textures`` (``pack_scene``), the cameras and settings of one call (``Job``), and
each thread's scratch arrays (``Scratch``, ``PacketScratch``, ``PathVectors``). The trees' arrays are fields of
``Geometry``, gathered into ``bvh.RayTree`` / ``bvh.BinaryNodes`` / the reach grid by
``_ray_tree``, ``_dentin_nodes``, ``_reach_grid`` where a query takes them. The physics is that of ``fresnel``,
``phase_function`` and ``sigmoid_blend``, whose functions compile into these kernels.
"""

from __future__ import annotations

import hashlib
import threading
from typing import NamedTuple

import numpy as np
from numba import get_num_threads, njit

from . import numba_kernels as _numba_kernels
from .bvh import (
    LANES,
    PACKET,
    WIDTH,
    BinaryNodes,
    RayTree,
    TriangleBVH,
    closest_point_triangle,
    closest_triangle,
    first_hit,
    first_hit_inlined,
    hits_until_stop,
    packet_hits,
    ray_triangle,
)
from .compiled_scene import KIND_DIELECTRIC, KIND_INDEX_MATCHED, KIND_OPAQUE, MED_AIR, MED_DENTIN, CompiledScene
from .dentin_reach_grid import dentin_reach_grid, may_be_within_reach
from .fresnel import fresnel_dielectric
from .path_tracer import MAX_CROSSINGS, MAX_PATH_VERTICES  # the reference's limits, the same estimator
from .phase_function import direction_from_mu_into, hg, hg_dlog_dg, sample_hg_mu_scalar, two_lobe
from .ray_queries import RAY_EPS
from .sigmoid_blend import blend_weight
from .work_queue import take_next

_numba_kernels.activate()  # before any cached njit: the kernel cache locator, then numba_callable's overloads

# l(q) = (1 + tanh(q / 2 s)) / 2 is 1 in float64 from q / s = 38.2 on (tanh rounds to 1 beyond 19.1):
# the dentin distance is searched only this many spreads far
BLEND_REACH = 40.0
PACKET_MIN = 4  # lights from which a vertex's shadow rays are traced as packets
HIT_BUFFER = 32  # hits gathered per traversal (more: one cast per crossing)
SAMPLE_HALVES = 2  # each row's samples traced in 2 halves in parallel (see ``_trace_rows``)
N_BLOCKS = 64  # row blocks traced in parallel; fixed so that sums do not depend on the thread count


class Geometry(NamedTuple):
    """The scene's triangles and trees (``pack_scene``). T triangles; sampling (s) and evaluation (e) geometry."""

    tris_s: np.ndarray  # (T, 3, 3) float64
    tris_e: np.ndarray  # (T, 3, 3) float64
    normal_s: np.ndarray  # (T, 3) unit normals of tris_s
    kind: np.ndarray  # (T,) int64: KIND_DIELECTRIC, KIND_INDEX_MATCHED or KIND_OPAQUE
    inside: np.ndarray  # (T,) int64: the medium on the side the normal points away from
    outside: np.ndarray  # (T,) int64: the medium the normal points into
    eta: np.ndarray  # (T,) float64: refractive index of a dielectric boundary
    tex_id: np.ndarray  # (T,) int64: a_t texture of a boundary (``Textures``), -1 where none
    corner_uv: np.ndarray  # (T, 3, 2) float64
    dentin_tooth: np.ndarray  # (T,) int64: tooth of a dentin triangle, -1 for the others
    tri_delta: np.ndarray  # (T, 3 modes, 3 corners, 3) float64: dentin blend-shape offsets d v / d c
    wbox: np.ndarray  # the scene's tree for ray queries (``bvh.RayTree``, ``_ray_tree``): wide boxes
    wchild: np.ndarray  # wide children
    tblk: np.ndarray  # leaf triangle blocks
    tord: np.ndarray  # their triangle ids
    dentin_lo: np.ndarray  # every tooth's dentin tree (``bvh.BinaryNodes``, ``_dentin_nodes``): boxes
    dentin_hi: np.ndarray
    dentin_left: np.ndarray
    dentin_start: np.ndarray
    dentin_count: np.ndarray
    dentin_order: np.ndarray
    dentin_roots: np.ndarray  # (teeth,) int64: each tooth's root among the dentin nodes
    stops_shadow: np.ndarray  # (T,) bool: blocks a shadow ray (opaque)
    stops_flight: np.ndarray  # (T,) bool: ends a path's flight (every kind but index-matched)
    same_geometry: bool  # tris_e equals tris_s
    same_textures: bool  # the evaluation a_t textures equal the sampling ones
    grid_lo: np.ndarray  # ``dentin_reach_grid``'s grids (``_reach_grid``): lower corners
    grid_inv: np.ndarray  # inverse cell sizes
    grid_cells: np.ndarray  # cells per axis
    grid_offsets: np.ndarray  # each tooth's first flag
    grid_flags: np.ndarray  # uint8
    stack_size: int  # entries of a traversal stack that serves the scene tree and the dentin trees


class Media(NamedTuple):
    """Per medium m (``compiled_scene``: 0 air, then enamel and dentin of each tooth, then the gums): the
    coefficients of the sampling (s) and evaluation (e) scenes, and the parameter columns (``col_*``) their
    derivatives go to. E / D: a medium's enamel-side and dentin-side albedo and phase function (the blend of
    eq. 5.15-5.21; sigma_t is the medium's own)."""

    sigma_s: np.ndarray  # (M, 3) sigma_t of the sampling scene
    sigma_e: np.ndarray  # (M, 3) sigma_t of the evaluation scene
    kind: np.ndarray  # (M,) int64 MED_*
    tooth: np.ndarray  # (M,) int64, -1 for air and gums
    col_sigma: np.ndarray  # (M,) int64
    alb_es: np.ndarray  # (M, 3) albedo, enamel side, sampling scene
    alb_ds: np.ndarray  # (M, 3) dentin side, sampling
    alb_ee: np.ndarray  # (M, 3) enamel side, evaluation
    alb_de: np.ndarray  # (M, 3) dentin side, evaluation
    ph_es: np.ndarray  # (M, 3) phase function (g1, g2, beta), as the albedos
    ph_ds: np.ndarray
    ph_ee: np.ndarray
    ph_de: np.ndarray
    col_alb_e: np.ndarray  # (M,) int64
    col_alb_d: np.ndarray  # (M,) int64
    col_ph_e: np.ndarray  # (M, 3) int64
    col_ph_d: np.ndarray  # (M, 3) int64
    c_col: np.ndarray  # (teeth,) int64: first column of each tooth's dentin coefficients c
    rho_s: np.ndarray  # (3,) oral cavity albedo, sampling (ones where there is no cavity)
    rho_e: np.ndarray  # (3,) evaluation
    col_rho: int  # -1 where there is no cavity
    spread: float  # the blend's spread s (eq. 5.15)
    ln_sigma_s: np.ndarray  # the logs of sigma_s, sigma_e, the albedos and rho, by the kernels' own log
    ln_sigma_e: np.ndarray
    ln_alb_es: np.ndarray
    ln_alb_ds: np.ndarray
    ln_alb_ee: np.ndarray
    ln_alb_de: np.ndarray
    ln_rho_s: np.ndarray
    ln_rho_e: np.ndarray


class Textures(NamedTuple):
    """The a_t textures (eq. 5.2), all in one table: texture k's texels are rows offset[k] .. offset[k] +
    height[k] width[k] of flat_s (sampling) and flat_e (evaluation), row by row."""

    flat_s: np.ndarray  # (texels, 3)
    flat_e: np.ndarray  # (texels, 3)
    offset: np.ndarray  # (textures,) int64
    height: np.ndarray  # (textures,) int64
    width: np.ndarray  # (textures,) int64
    col: np.ndarray  # (textures,) int64: first parameter column of each texture


class Job(NamedTuple):
    """What one ``trace`` call asks: rows (camera, flat pixel) x spp paths and what to compute from them."""

    fxy: np.ndarray  # (cameras, 4): focal lengths and principal point fx, fy, cx, cy
    rot: np.ndarray  # (cameras, 3, 3) the cameras' rotations (rows: image x, y and viewing axes in the world)
    center: np.ndarray  # (cameras, 3)
    width: np.ndarray  # (cameras,) int64: pixels per image row
    cam_of: np.ndarray  # (rows,) int64
    pix_of: np.ndarray  # (rows,) int64
    spp: int
    seed: int
    depth_cap: int  # path vertices at most
    roulette: bool  # all bounces with Russian roulette (depth_cap is then ``MAX_PATH_VERTICES``)
    rr_depth: int  # first vertex the roulette may stop a path at
    jitter: bool  # sample positions jittered in the pixel (else its centre)
    lp: np.ndarray  # (L, 3) light positions
    li: np.ndarray  # (L, 3) light intensities
    inv_spp: float
    adj: np.ndarray  # (cameras, L, H W, 3) the adjoint, or (0, 0, 0, 3) without a gradient
    want_grad: bool
    jmap: np.ndarray  # parameter column -> Jacobian column (-1: none); (1,) of -1 without a Jacobian


class PacketScratch(NamedTuple):
    """One thread's arrays for ``_light_packets`` (L lights)."""

    ldir: np.ndarray  # (L, 3) unit directions to the lights
    lr: np.ndarray  # (L,) distances
    lgeo: np.ndarray  # (L,) phase function or cosine / pi towards each light
    lmu: np.ndarray  # (L,) cosine to the path direction
    tri: np.ndarray  # (L, HIT_BUFFER) int64: each shadow ray's hits
    t: np.ndarray  # (L, HIT_BUFFER)
    n: np.ndarray  # (L,) int64: each shadow ray's number of hits
    pinv: np.ndarray  # (PACKET, 4) ``packet_hits``' scratch from here on
    pstack: np.ndarray  # (stack size, 2) int64
    cmask: np.ndarray  # (WIDTH,) int64
    pmask: np.ndarray  # (PACKET,) int64
    pt: np.ndarray  # (PACKET, LANES)


class Scratch(NamedTuple):
    """One thread's arrays for a path's walks and connections (C = ``MAX_CROSSINGS``)."""

    tri_x: np.ndarray  # (C + 1,) int64: triangles crossed along a ray
    t_x: np.ndarray  # (C + 1,) their distances
    meds: np.ndarray  # (C + 2,) int64: the medium of each piece
    t_e: np.ndarray  # (C + 1,) crossing distances on the evaluation geometry
    clipped: np.ndarray  # (C + 1,) bool
    a: np.ndarray  # (3,) a_t at a boundary
    idx: np.ndarray  # (4,) int64: its texels
    wts: np.ndarray  # (4,) their bilinear weights
    wgt: np.ndarray  # (3,) a connection's adjoint weight
    score: np.ndarray  # (n_j, 3) a connection's forward-mode score
    no_score: np.ndarray  # (0, 3): the score sink that records nothing
    no_grad: np.ndarray  # (0,): the gradient sink that records nothing
    stack: np.ndarray  # (stack size,) int64: traversal stack
    vec: np.ndarray  # (3, 3): a connection's direction, contribution and transmittance
    buf_tri: np.ndarray  # (HIT_BUFFER,) int64: hits gathered by one traversal
    buf_t: np.ndarray  # (HIT_BUFFER,)
    wdist: np.ndarray  # (WIDTH,) a wide node's entry distances
    packet: PacketScratch


class PathVectors(NamedTuple):
    """One thread's 3-vectors of a path (``_trace_path``) and its running score."""

    s_run: np.ndarray  # (n_j, 3) the path's running score d log f (forward mode)
    o: np.ndarray
    d: np.ndarray
    x: np.ndarray
    nd: np.ndarray
    nrm: np.ndarray
    logf: np.ndarray
    logp: np.ndarray
    logfs: np.ndarray
    wv: np.ndarray
    dqdc: np.ndarray
    mix_e: np.ndarray
    mix_s: np.ndarray
    tau_cum: np.ndarray
    tau_at: np.ndarray
    sig_k: np.ndarray
    tmp: np.ndarray
    ones: np.ndarray


@njit(cache=True, forceinline=True, error_model="numpy")
def _ray_tree(geo) -> RayTree:
    """The scene's ``bvh.RayTree`` from its fields of ``geo``."""
    return RayTree(geo.wbox, geo.wchild, geo.tblk, geo.tord, geo.stack_size)


@njit(cache=True, forceinline=True, error_model="numpy")
def _dentin_nodes(geo) -> BinaryNodes:
    """The dentin trees' ``bvh.BinaryNodes`` from their fields of ``geo``."""
    return BinaryNodes(geo.dentin_lo, geo.dentin_hi, geo.dentin_left, geo.dentin_start, geo.dentin_count,
                       geo.dentin_order)


@njit(cache=True, forceinline=True, error_model="numpy")
def _reach_grid(geo) -> tuple:
    """``dentin_reach_grid``'s (lo, inverse cell size, cells, offsets, flags) from their fields of ``geo``."""
    return geo.grid_lo, geo.grid_inv, geo.grid_cells, geo.grid_offsets, geo.grid_flags


_TREES: dict = {}  # (sampling geometry, dentin assignment, spread) digest -> BVH arrays; a fit re-packs every iteration
_TOPOLOGIES: dict = {}  # (geometry at c = 0, dentin assignment) digest -> (scene tree, dentin trees)


def _digest(*arrays: np.ndarray) -> str:
    return hashlib.sha1(b"".join(np.ascontiguousarray(a).tobytes() for a in arrays)).hexdigest()


def _remember(cache: dict, key: str, value, size: int = 8):
    if len(cache) >= size:
        cache.pop(next(iter(cache)))
    cache[key] = value
    return value


def _trees(cs: CompiledScene) -> tuple:
    """(scene ray tree, dentin nodes, dentin roots, dentin reach grid, stack size) of ``cs``'s sampling
    geometry, cached by content; the stack size serves the scene tree and every dentin tree. The trees'
    topology is built once per geometry at c = 0 (``cs.tris_rest``) and refitted to the coefficients' dentin
    (``TriangleBVH.refit``): a fit's every iteration, and its shape gradient's two renders, move the dentin,
    and a build cost about 0.2 s per tree."""
    key = _digest(cs.tris_s, cs.dentin_tooth, np.float64(cs.spread))
    if key in _TREES:
        return _TREES[key]
    topo_key = _digest(cs.tris_rest, cs.dentin_tooth)
    if topo_key not in _TOPOLOGIES:
        _remember(_TOPOLOGIES, topo_key, (
            TriangleBVH(cs.tris_rest),
            [TriangleBVH(cs.tris_rest, np.flatnonzero(cs.dentin_tooth == i)) for i in range(len(cs.dentin))]))
    scene_tree, dentin_trees = _TOPOLOGIES[topo_key]
    dnodes, droots = TriangleBVH.merge([t.refit(cs.tris_s) for t in dentin_trees])
    grid = dentin_reach_grid(cs.tris_s, cs.dentin_tooth, len(cs.dentin), BLEND_REACH * float(cs.spread))
    ray_tree = scene_tree.refit(cs.tris_s).ray_arrays(cs.tris_s)
    stack_size = max([ray_tree.stack_size] + [t.stack_size for t in dentin_trees])
    return _remember(_TREES, key, (ray_tree, dnodes, droots, grid, stack_size))


def pack_scene(cs: CompiledScene) -> tuple[Geometry, Media, Textures]:
    """The arrays of ``cs`` the kernels read."""
    tri_delta = np.zeros((len(cs.tris_s), 3, 3, 3))
    for i, dp in enumerate(cs.dentin):
        ids = np.flatnonzero(cs.dentin_tooth == i)
        tri_delta[ids] = np.transpose(dp.deltas[:, dp.faces[cs.dentin_face[ids]], :], (1, 0, 2, 3))
    offs, hs, ws, flat_s, flat_e = [], [], [], [], []
    n = 0
    for ts, te in zip(cs.tex_s, cs.tex_e, strict=True):
        ts, te = np.asarray(ts, dtype=np.float64), np.asarray(te, dtype=np.float64)
        offs.append(n)
        hs.append(te.shape[0])
        ws.append(te.shape[1])
        flat_s.append(ts.reshape(-1, 3))
        flat_e.append(te.reshape(-1, 3))
        n += te.shape[0] * te.shape[1]
    tex = Textures(np.concatenate(flat_s) if flat_s else np.ones((1, 3)),
                   np.concatenate(flat_e) if flat_e else np.ones((1, 3)), np.array(offs, dtype=np.int64),
                   np.array(hs, dtype=np.int64), np.array(ws, dtype=np.int64), np.array(cs.tex_col, dtype=np.int64))
    ray_tree, dnodes, droots, grid, stack_size = _trees(cs)
    geo = Geometry(np.ascontiguousarray(cs.tris_s), np.ascontiguousarray(cs.tris_e), np.ascontiguousarray(cs.normal_s),
                   cs.kind, cs.inside, cs.outside, cs.eta, cs.tex_id,
                   np.ascontiguousarray(cs.corner_uv, dtype=np.float64), cs.dentin_tooth, tri_delta, ray_tree.wbox,
                   ray_tree.wchild, ray_tree.tblk, ray_tree.tord, *dnodes, droots, cs.kind == KIND_OPAQUE,
                   cs.kind != KIND_INDEX_MATCHED, bool(np.array_equal(cs.tris_s, cs.tris_e)),
                   bool(np.array_equal(tex.flat_s, tex.flat_e)), *grid, int(stack_size))
    has_cavity = bool(cs.has_cavity)
    rho_s = cs.rho_s if has_cavity else np.ones(3)
    rho_e = cs.rho_e if has_cavity else np.ones(3)
    # the logs of the unblended coefficients (most vertices lie where l(q) is 0 or 1 to the last bit), computed by
    # the kernels' own log so that a table entry equals the log the vertex would compute
    logs = tuple(_log_table(np.ascontiguousarray(v, dtype=np.float64)) for v in (
        cs.sigma_s, cs.sigma_e, cs.alb["Es"], cs.alb["Ds"], cs.alb["Ee"], cs.alb["De"], rho_s, rho_e))
    med = Media(cs.sigma_s, cs.sigma_e, cs.med_kind, cs.med_tooth, cs.col_sigma, cs.alb["Es"],
                cs.alb["Ds"], cs.alb["Ee"], cs.alb["De"], cs.ph["Es"], cs.ph["Ds"], cs.ph["Ee"],
                cs.ph["De"], cs.col_alb["E"], cs.col_alb["D"], cs.col_ph["E"], cs.col_ph["D"], cs.c_col, rho_s, rho_e,
                int(cs.col_rho) if has_cavity else -1, float(cs.spread), *logs)
    return geo, med, tex


@njit(cache=True, error_model="numpy")
def _log_table(a):
    return np.log(a)


@njit(cache=True, forceinline=True, error_model="numpy")
def _log_mix(a, b, log_a, log_b, w) -> float:
    """log(w a + (1 - w) b), the log of a blended coefficient (eq. 5.17); from the tables where w is 0 or 1."""
    if w == 1.0:
        return log_a
    if w == 0.0:
        return log_b
    return np.log(a * w + b * (1 - w))


# ------------------------------------------------------------------------------------------ random numbers
@njit(cache=True, error_model="numpy")
def _mix64(z):
    z = (z ^ (z >> np.uint64(30))) * np.uint64(0xBF58476D1CE4E5B9)
    z = (z ^ (z >> np.uint64(27))) * np.uint64(0x94D049BB133111EB)
    return z ^ (z >> np.uint64(31))


@njit(cache=True, error_model="numpy")
def _rand(rs) -> float:
    """Next uniform in [0, 1) of the splitmix64 stream in rs[0]."""
    rs[0] += np.uint64(0x9E3779B97F4A7C15)
    return float(_mix64(rs[0]) >> np.uint64(11)) * (1.0 / 9007199254740992.0)


@njit(cache=True, error_model="numpy")
def _seed(rs, seed, path) -> None:
    rs[0] = _mix64(np.uint64(seed) * np.uint64(0x9E3779B97F4A7C15) + _mix64(np.uint64(path) + np.uint64(1)))


# ------------------------------------------------------------------------------------------ small math
@njit(cache=True, error_model="numpy")
def _logmeanexp3(a) -> float:
    m = max(a[0], max(a[1], a[2]))
    return m + np.log((np.exp(a[0] - m) + np.exp(a[1] - m) + np.exp(a[2] - m)) / 3.0)


@njit(cache=True, error_model="numpy")
def _blend(q, spread) -> float:
    """``sigmoid_blend.blend_weight`` l(q) (eq. 5.15) without its tanh where it is 0 or 1: beyond |q / (2 spread)|
    = 20, tanh is +-1 to the last bit (1 - tanh(20) < 1e-17), so l is exactly 1 or 0 (pinned by
    ``test_teeth_numba_kernels``)."""
    z = 0.5 * q / spread
    if z >= 20.0:
        return 1.0
    if z <= -20.0:
        return 0.0
    return blend_weight(q, spread)


# ------------------------------------------------------------------------------------------ score sinks
@njit(cache=True, forceinline=True, error_model="numpy")
def _emit(col, v0, v1, v2, w, g, sx, jmap) -> None:
    """One d log f record: g[col] += v . w (reverse mode), sx[jmap[col]] += v (forward mode)."""
    if col < 0:
        return
    if g.shape[0] > 0:
        g[col] += v0 * w[0] + v1 * w[1] + v2 * w[2]
    if sx.shape[0] > 0:
        j = jmap[col]
        if j >= 0:
            sx[j, 0] += v0
            sx[j, 1] += v1
            sx[j, 2] += v2


@njit(cache=True, forceinline=True, error_model="numpy")
def _emit_diag(col0, v, w, g, sx, jmap) -> None:
    """Records col0 + c with value v[c] on channel c only."""
    if col0 < 0:
        return
    _emit(col0, v[0], 0.0, 0.0, w, g, sx, jmap)
    _emit(col0 + 1, 0.0, v[1], 0.0, w, g, sx, jmap)
    _emit(col0 + 2, 0.0, 0.0, v[2], w, g, sx, jmap)


@njit(cache=True, forceinline=True, error_model="numpy")
def _emit_blend(col_e, col_d, v_e, row_e, v_d, row_d, w, tmp, ab_b, g, sx, jmap) -> None:
    """Derivatives of log(w a + (1 - w) b), the log of a blended coefficient (eq. 5.17-5.21), with
    a = v_e[row_e], b = v_d[row_d] per channel: w / mix by a (on columns ``col_e``), (1 - w) / mix by b
    (on ``col_d``)."""
    for c in range(3):
        tmp[c] = w / (v_e[row_e, c] * w + v_d[row_d, c] * (1 - w))
    _emit_diag(col_e, tmp, ab_b, g, sx, jmap)
    for c in range(3):
        tmp[c] = (1 - w) / (v_e[row_e, c] * w + v_d[row_d, c] * (1 - w))
    _emit_diag(col_d, tmp, ab_b, g, sx, jmap)


# ------------------------------------------------------------------------------------------ ray walks
@njit(cache=True, forceinline=True, error_model="numpy")
def _cross(tri, t, k, d, normal_s, inside, outside, tri_x, t_x, meds) -> int:
    """Record crossing k of triangle tri at t and the medium beyond it; returns k + 1."""
    tri_x[k] = tri
    t_x[k] = t
    cosv = normal_s[tri, 0] * d[0] + normal_s[tri, 1] * d[1] + normal_s[tri, 2] * d[2]
    meds[k + 1] = inside[tri] if cosv < 0.0 else outside[tri]
    return k + 1


@njit(cache=True, forceinline=True, error_model="numpy")
def _walk(geo, o, d, med0, shadow, tmax, tri_x, t_x, meds, stack, wdist, buf_tri, buf_t):
    """Crossings along o + t d (see ``path_tracer._Tracer.through``): path mode passes index-matched
    surfaces and stops at the first other one; shadow mode passes every non-opaque surface up to tmax.
    Each hit must lie RAY_EPS beyond the previous one, as when every crossing casts a new ray from there.
    Fills tri_x, t_x (crossings), meds (medium of each piece); returns (k, end_tri, end_t, blocked, casts).
    One traversal gathers the hits up to the first stopping surface; where that cannot decide (buffer
    overflow, a stopping hit within RAY_EPS of a crossing) the walk goes on one ray cast per crossing."""
    stops = geo.stops_shadow if shadow else geo.stops_flight
    n = hits_until_stop(_ray_tree(geo), stops, o, d, RAY_EPS, tmax, stack, wdist, buf_tri, buf_t, not shadow)
    return _walk_hits(geo, o, d, med0, shadow, tmax, n, buf_tri, buf_t, tri_x, t_x, meds, stack, wdist)


@njit(cache=True, forceinline=True, error_model="numpy")
def _walk_hits(geo, o, d, med0, shadow, tmax, n, buf_tri, buf_t, tri_x, t_x, meds, stack, wdist):
    """``_walk`` from the n hits gathered by ``hits_until_stop`` (or ``packet_hits``) in buf_tri, buf_t."""
    normal_s, kind, inside, outside = geo.normal_s, geo.kind, geo.inside, geo.outside
    nodes, stops = _ray_tree(geo), (geo.stops_shadow if shadow else geo.stops_flight)
    k = 0
    tcur = 0.0
    meds[0] = med0
    casts = 1
    if n <= buf_t.shape[0]:
        for i in range(1, n):  # insertion sort by distance
            ti, ki = buf_t[i], buf_tri[i]
            j = i - 1
            while j >= 0 and buf_t[j] > ti:
                buf_t[j + 1] = buf_t[j]
                buf_tri[j + 1] = buf_tri[j]
                j -= 1
            buf_t[j + 1] = ti
            buf_tri[j + 1] = ki
        decided = True
        for i in range(n):
            t, tri = buf_t[i], buf_tri[i]
            if t <= tcur + RAY_EPS and k > 0:
                if stops[tri]:  # a stopping hit the one-ray-per-crossing walk would step over
                    decided = False
                    break
                continue
            if stops[tri]:
                return k, tri, t, shadow, casts
            if k >= MAX_CROSSINGS:  # degenerate geometry: give up on this ray
                return k, -1, np.inf, True, casts
            k = _cross(tri, t, k, d, normal_s, inside, outside, tri_x, t_x, meds)
            tcur = t
        if decided:
            return k, -1, np.inf, False, casts
    while True:
        tri, t = first_hit(nodes, o, d, tcur + RAY_EPS, tmax, stack, wdist)
        casts += 1
        if tri < 0:
            return k, -1, np.inf, False, casts
        kd = kind[tri]
        if shadow:
            if kd == KIND_OPAQUE:
                return k, tri, t, True, casts
        elif kd != KIND_INDEX_MATCHED:
            return k, tri, t, False, casts
        if k >= MAX_CROSSINGS:  # degenerate geometry: give up on this ray
            return k, -1, np.inf, True, casts
        k = _cross(tri, t, k, d, normal_s, inside, outside, tri_x, t_x, meds)
        tcur = t


@njit(cache=True, forceinline=True, error_model="numpy")
def _walk_to_flight(geo, o, d, med0, sigma_s, hero, tau_star, tri_x, t_x, meds, tau_cum, stack, wdist):
    """The free flight of a path in a medium, walked lazily: the crossings of index-matched surfaces along
    o + t d up to the distance where the hero channel's optical depth reaches ``tau_star`` (a scattering
    vertex there) or the first other surface before it. Each ray cast reaches only as far as the optical
    depth left in the current piece, so a short flight costs a short traversal; the crossings, the vertex
    and the surface found are those of ``_walk`` followed by the free-flight search of ``_trace_path``
    (the same numbers up to rounding). Fills tri_x, t_x, meds and tau_cum (optical depth before the last
    piece); returns (k crossings, surface or -1, its distance, scatter, ray casts)."""
    normal_s, kind, inside, outside = geo.normal_s, geo.kind, geo.inside, geo.outside
    nodes = _ray_tree(geo)
    k = 0
    tcur = 0.0
    tmin = RAY_EPS
    meds[0] = med0
    for c in range(3):
        tau_cum[c] = 0.0
    casts = 0
    while True:
        sig = sigma_s[meds[k], hero]
        t_sc = tcur + (tau_star - tau_cum[hero]) / max(sig, 1e-300) if sig > 0.0 else np.inf
        tri, t = first_hit_inlined(nodes, o, d, tmin, t_sc, stack, wdist)
        casts += 1
        if tri < 0:
            return k, -1, np.inf, t_sc < np.inf, casts
        if kind[tri] != KIND_INDEX_MATCHED:
            return k, tri, t, False, casts
        if k >= MAX_CROSSINGS:  # degenerate geometry: give up on this ray
            return k, -1, np.inf, False, casts
        for c in range(3):
            tau_cum[c] += (t - tcur) * sigma_s[meds[k], c]
        k = _cross(tri, t, k, d, normal_s, inside, outside, tri_x, t_x, meds)
        tcur = t
        tmin = t + RAY_EPS


@njit(cache=True, _nrt=False, error_model="numpy")
def _eval_crossings(geo, o, d, k, tri_x, t_x, upper, t_e, clipped) -> None:
    """Crossing distances on the evaluation geometry, ordered and within [0, upper]; which were clipped
    (``path_tracer._Tracer.eval_crossings``)."""
    tris_e, kind = geo.tris_e, geo.kind
    if geo.same_geometry:  # evaluation geometry = sampling geometry: the distances are the sampled ones, and a
        for j in range(k):  # crossing beyond ``upper`` is never read
            t_e[j] = t_x[j]
            clipped[j] = False
        return
    any_matched = False
    for j in range(k):
        clipped[j] = False
        if kind[tri_x[j]] == KIND_INDEX_MATCHED:
            t_e[j] = ray_triangle(tris_e, tri_x[j], o, d)[0]
            any_matched = True
        else:
            t_e[j] = t_x[j]
    if not any_matched:
        return
    run = 0.0
    for j in range(k):
        run = max(run, max(t_e[j], 0.0))
        kept = min(run, upper)
        if kept != t_e[j]:
            clipped[j] = True
            t_e[j] = kept


@njit(cache=True, _nrt=False, error_model="numpy")
def _crossing_record(geo, med, o, d, tri, m_before, m_after, w, g, sx, jmap) -> None:
    """(S_i - S_e) dt/dc of one dentin crossing (eq. 5.29-5.32)."""
    tris_e, dtooth, tri_delta = geo.tris_e, geo.dentin_tooth, geo.tri_delta
    sigma_e, c_col = med.sigma_e, med.c_col
    _, u, v = ray_triangle(tris_e, tri, o, d)
    b0, b1, b2 = 1.0 - u - v, u, v
    a0, a1, a2 = tris_e[tri, 1, 0] - tris_e[tri, 0, 0], tris_e[tri, 1, 1] - tris_e[tri, 0, 1], \
        tris_e[tri, 1, 2] - tris_e[tri, 0, 2]
    c0, c1, c2 = tris_e[tri, 2, 0] - tris_e[tri, 0, 0], tris_e[tri, 2, 1] - tris_e[tri, 0, 1], \
        tris_e[tri, 2, 2] - tris_e[tri, 0, 2]
    n0 = a1 * c2 - a2 * c1
    n1 = a2 * c0 - a0 * c2
    n2 = a0 * c1 - a1 * c0
    nd = n0 * d[0] + n1 * d[1] + n2 * d[2]
    g0, g1, g2 = n0 / nd, n1 / nd, n2 / nd
    col0 = c_col[dtooth[tri]]
    for mode in range(3):
        dt = 0.0
        for vv in range(3):
            bw = b0 if vv == 0 else (b1 if vv == 1 else b2)
            dt += bw * (g0 * tri_delta[tri, mode, vv, 0] + g1 * tri_delta[tri, mode, vv, 1]
                        + g2 * tri_delta[tri, mode, vv, 2])
        _emit(col0 + mode, dt * (sigma_e[m_after, 0] - sigma_e[m_before, 0]),
              dt * (sigma_e[m_after, 1] - sigma_e[m_before, 1]), dt * (sigma_e[m_after, 2] - sigma_e[m_before, 2]),
              w, g, sx, jmap)


@njit(cache=True, _nrt=False, error_model="numpy")
def _a_t(geo, tex, tri, o, d, which_e, a, idx, wts) -> int:
    """Bilinear a_t at the boundary hit of o + t d on tri (eq. 5.2): values into a (3), texel indices and
    weights into idx, wts (4); returns the texture's first parameter column."""
    tris_s, tex_id, corner_uv = geo.tris_s, geo.tex_id, geo.corner_uv
    flat = tex.flat_e if which_e else tex.flat_s
    off, hh, ww, tex_col = tex.offset, tex.height, tex.width, tex.col
    _, u, v = ray_triangle(tris_s, tri, o, d)
    b0 = 1.0 - u - v
    uu = b0 * corner_uv[tri, 0, 0] + u * corner_uv[tri, 1, 0] + v * corner_uv[tri, 2, 0]
    vv = b0 * corner_uv[tri, 0, 1] + u * corner_uv[tri, 1, 1] + v * corner_uv[tri, 2, 1]
    k = tex_id[tri]
    h, w = hh[k], ww[k]
    x = uu * w - 0.5
    y = min(max(vv * h - 0.5, 0.0), h - 1.0)
    x0 = np.floor(x)
    y0 = min(np.floor(y), max(h - 2, 0))
    fx = x - x0
    fy = y - y0 if h > 1 else 0.0
    j0 = int(x0) % w
    j1 = (j0 + 1) % w
    i0 = int(y0)
    i1 = min(i0 + 1, h - 1)
    idx[0], idx[1], idx[2], idx[3] = i0 * w + j0, i0 * w + j1, i1 * w + j0, i1 * w + j1
    wts[0], wts[1], wts[2], wts[3] = (1 - fx) * (1 - fy), fx * (1 - fy), (1 - fx) * fy, fx * fy
    for c in range(3):
        a[c] = 0.0
        for i in range(4):
            a[c] += wts[i] * flat[off[k] + idx[i], c]
    return tex_col[k]


@njit(cache=True, _nrt=False, error_model="numpy")
def _a_t_records(col0, a, idx, wts, w, g, sx, jmap) -> None:
    """d log a_t / d texel = w_i / a_t per channel (eq. 5.10)."""
    for i in range(4):
        base = col0 + 3 * idx[i]
        _emit(base, wts[i] / a[0], 0.0, 0.0, w, g, sx, jmap)
        _emit(base + 1, 0.0, wts[i] / a[1], 0.0, w, g, sx, jmap)
        _emit(base + 2, 0.0, 0.0, wts[i] / a[2], w, g, sx, jmap)


@njit(cache=True, _nrt=False, error_model="numpy")
def _phase_records(med, mv, mu, mix, lw, dl, dqdc, w, g, sx, jmap) -> None:
    """d log f_p of the blended two-lobe phase function at one vertex and direction (eq. 5.11-5.19)."""
    ph_ee, ph_de, col_ph_e, col_ph_d, med_tooth, c_col = med.ph_ee, med.ph_de, med.col_ph_e, med.col_ph_d, \
        med.tooth, med.c_col
    g1, g2, beta = mix[0], mix[1], mix[2]
    h1, h2 = hg(mu, g1), hg(mu, g2)
    f = beta * h1 + (1.0 - beta) * h2
    d1 = beta * h1 * hg_dlog_dg(mu, g1) / f
    d2 = (1.0 - beta) * h2 * hg_dlog_dg(mu, g2) / f
    db = (h1 - h2) / f
    for i, val in ((0, d1), (1, d2), (2, db)):
        _emit(col_ph_e[mv, i], val * lw, val * lw, val * lw, w, g, sx, jmap)
        _emit(col_ph_d[mv, i], val * (1 - lw), val * (1 - lw), val * (1 - lw), w, g, sx, jmap)
    tooth = med_tooth[mv]
    if tooth >= 0:
        dmix = (d1 * (ph_ee[mv, 0] - ph_de[mv, 0]) + d2 * (ph_ee[mv, 1] - ph_de[mv, 1])
                + db * (ph_ee[mv, 2] - ph_de[mv, 2]))
        for m in range(3):
            val = dmix * dl * dqdc[m]
            _emit(c_col[tooth] + m, val, val, val, w, g, sx, jmap)


@njit(cache=True, _nrt=False, forceinline=True, error_model="numpy")
def _dentin_query(geo, tooth, p, sign, dqdc, stack, bary, reach):
    """Signed distance to the tooth's dentin on the sampling and evaluation geometry, dq_e/dc into dqdc
    (eq. 5.33-5.41): (q_s, q_e). Where no dentin triangle is nearer than ``reach`` (beyond which l(q) is
    0 or 1 to the last bit and dl/dq is 0), returns +-reach for both and dq/dc = 0."""
    tris_s, tris_e, tri_delta, dnodes, droots = geo.tris_s, geo.tris_e, geo.tri_delta, _dentin_nodes(geo), \
        geo.dentin_roots
    tri, dist = -1, reach  # where the reach grid rules dentin out, the search would find no triangle either
    if may_be_within_reach(_reach_grid(geo), tooth, p):
        tri, dist = closest_triangle(dnodes, droots[tooth], tris_s, p, stack, bary, reach)
    if tri < 0:
        dqdc[:] = 0.0
        return sign * reach, sign * reach
    dist_e = closest_point_triangle(tris_e, tri, p, bary)
    ux = p[0] - (bary[0] * tris_e[tri, 0, 0] + bary[1] * tris_e[tri, 1, 0] + bary[2] * tris_e[tri, 2, 0])
    uy = p[1] - (bary[0] * tris_e[tri, 0, 1] + bary[1] * tris_e[tri, 1, 1] + bary[2] * tris_e[tri, 2, 1])
    uz = p[2] - (bary[0] * tris_e[tri, 0, 2] + bary[1] * tris_e[tri, 1, 2] + bary[2] * tris_e[tri, 2, 2])
    inv = 1.0 / max(dist_e, 1e-300)
    for m in range(3):
        s = 0.0
        for vv in range(3):
            s += bary[vv] * (ux * tri_delta[tri, m, vv, 0] + uy * tri_delta[tri, m, vv, 1]
                             + uz * tri_delta[tri, m, vv, 2])
        dqdc[m] = -sign * s * inv
    return sign * dist, sign * dist_e


@njit(cache=True, _nrt=False, error_model="numpy")
def _light_packets(geo, x, d, lp, is_phase, mix_e, nrm, pk) -> None:
    """``_nee``'s shadow rays from x as packets (``bvh.packet_hits``): every light's direction, distance, mu and
    f (phase function or cosine / pi) into pk, and the hits of the rays with f > 0 (a function of its own,
    so that ``_nee``'s one-light code is compiled as before)."""
    ldir, lr, lgeo, lmu, pk_tri, pk_t, pk_n = pk.ldir, pk.lr, pk.lgeo, pk.lmu, pk.tri, pk.t, pk.n
    pinv, pstack, cmask, pmask, pt = pk.pinv, pk.pstack, pk.cmask, pk.pmask, pk.pt
    n_l = lp.shape[0]
    for lt in range(n_l):
        r2 = 0.0
        for c in range(3):
            ldir[lt, c] = lp[lt, c] - x[c]
            r2 += ldir[lt, c] * ldir[lt, c]
        r = np.sqrt(r2)
        lr[lt] = r
        for c in range(3):
            ldir[lt, c] /= r
        mu = ldir[lt, 0] * d[0] + ldir[lt, 1] * d[1] + ldir[lt, 2] * d[2]
        lmu[lt] = mu
        if is_phase:
            lgeo[lt] = two_lobe(mu, mix_e[0], mix_e[1], mix_e[2])
        else:
            lgeo[lt] = max(ldir[lt, 0] * nrm[0] + ldir[lt, 1] * nrm[1] + ldir[lt, 2] * nrm[2], 0.0) / np.pi
    for l0 in range(0, n_l, PACKET):
        mask = np.int64(0)
        for b in range(min(PACKET, n_l - l0)):
            if lgeo[l0 + b] > 0.0:
                mask |= np.int64(1) << b
        if mask != 0:
            packet_hits(_ray_tree(geo), geo.stops_shadow, x, ldir, lr, l0, mask, RAY_EPS, pinv, pstack, cmask, pmask,
                        pt, pk_tri, pk_t, pk_n)


# ------------------------------------------------------------------------------------------ one path
@njit(cache=True, _nrt=False, forceinline=True, error_model="numpy")
def _nee(geo, med, tex, job, x, d, mv, wv, nrm, is_phase, mix_e, lw, dl, dqdc, row, cam, pix, b, img_on, gradpass,
         out_rows, ab, grad, jac, s_run, scratch):
    """Connect vertex x to every light; splat, and the connection's own d log f terms (``path_tracer._nee``).
    Returns (shadow rays, ray casts)."""
    lp, li, inv_spp, adj, jmap = job.lp, job.li, job.inv_spp, job.adj, job.jmap
    sigma_e, col_sigma = med.sigma_e, med.col_sigma
    kind, normal_s, eta = geo.kind, geo.normal_s, geo.eta
    tri_x, t_x, meds, t_e, clipped = scratch.tri_x, scratch.t_x, scratch.meds, scratch.t_e, scratch.clipped
    a, idx, wts, wgt, score, emp2, emp1 = scratch.a, scratch.idx, scratch.wts, scratch.wgt, scratch.score, \
        scratch.no_score, scratch.no_grad
    stack, vec, buf_tri, buf_t, wdist, pk = scratch.stack, scratch.vec, scratch.buf_tri, scratch.buf_t, \
        scratch.wdist, scratch.packet
    ldir, lr, lgeo, lmu, pk_tri, pk_t, pk_n = pk.ldir, pk.lr, pk.lgeo, pk.lmu, pk.tri, pk.t, pk.n
    w, contrib, trans = vec[0], vec[1], vec[2]
    n_shadow = 0
    casts = 0
    n_l = lp.shape[0]
    packet = n_l >= PACKET_MIN
    if packet:
        _light_packets(geo, x, d, lp, is_phase, mix_e, nrm, pk)
    for lt in range(n_l):
        if packet:
            geo_f = lgeo[lt]
            r = lr[lt]
            r2 = r * r
            mu = lmu[lt]
            for c in range(3):
                w[c] = ldir[lt, c]
        else:
            r2 = 0.0
            for c in range(3):
                w[c] = lp[lt, c] - x[c]
                r2 += w[c] * w[c]
            r = np.sqrt(r2)
            for c in range(3):
                w[c] /= r
            mu = w[0] * d[0] + w[1] * d[1] + w[2] * d[2]
            if is_phase:
                geo_f = two_lobe(mu, mix_e[0], mix_e[1], mix_e[2])
            else:
                geo_f = max(w[0] * nrm[0] + w[1] * nrm[1] + w[2] * nrm[2], 0.0) / np.pi
        if geo_f <= 0.0:
            continue
        n_shadow += 1
        if packet:
            hb_n, hb_tri, hb_t = pk_n[lt], pk_tri[lt], pk_t[lt]
        else:
            hb_n = hits_until_stop(_ray_tree(geo), geo.stops_shadow, x, w, RAY_EPS, r, stack, wdist, buf_tri, buf_t,
                                   False)
            hb_tri, hb_t = buf_tri, buf_t
        k, _, _, blocked, nc = _walk_hits(geo, x, w, mv, True, r, hb_n, hb_tri, hb_t, tri_x, t_x, meds, stack, wdist)
        casts += nc
        if blocked:
            continue
        _eval_crossings(geo, x, w, k, tri_x, t_x, r, t_e, clipped)
        for c in range(3):
            trans[c] = 0.0
        prev = 0.0
        for j in range(k + 1):
            end = t_e[j] if j < k else r
            for c in range(3):
                trans[c] -= (end - prev) * sigma_e[meds[j], c]
            prev = end
        for c in range(3):
            trans[c] = np.exp(trans[c])  # Beer-Lambert, then the boundaries' a_t (1 - F)
        for j in range(k):
            tri = tri_x[j]
            if kind[tri] == KIND_DIELECTRIC:
                _a_t(geo, tex, tri, x, w, True, a, idx, wts)
                cosv = normal_s[tri, 0] * w[0] + normal_s[tri, 1] * w[1] + normal_s[tri, 2] * w[2]
                tf = 1.0 - fresnel_dielectric(cosv, eta[tri])
                for c in range(3):
                    trans[c] *= a[c] * tf
        for c in range(3):
            contrib[c] = wv[c] * geo_f * trans[c] * li[lt, c] / r2 * inv_spp
            if img_on:
                out_rows[row, lt, c] += contrib[c]
        if gradpass == 0 and jac.shape[0] == 0:
            continue
        if gradpass == 1:
            for c in range(3):
                ab[b, c] += adj[cam, lt, pix, c] * contrib[c]
        sinks = 0
        if gradpass == 2:
            for c in range(3):
                wgt[c] = adj[cam, lt, pix, c] * contrib[c]
            sinks = 1
        if jac.shape[0] > 0:
            for j in range(score.shape[0]):
                for c in range(3):
                    score[j, c] = s_run[j, c]
            sinks += 2
        for sink in (1, 2):
            if sinks & sink == 0:
                continue
            g = grad if sink == 1 else emp1
            sx = emp2 if sink == 1 else score
            prev = 0.0
            for j in range(k + 1):
                end = t_e[j] if j < k else r
                ln = end - prev
                prev = end
                if ln != 0.0 and meds[j] != MED_AIR:
                    _emit_diag(col_sigma[meds[j]], (-ln, -ln, -ln), wgt, g, sx, jmap)
            for j in range(k):
                tri = tri_x[j]
                if kind[tri] == KIND_DIELECTRIC:
                    col0 = _a_t(geo, tex, tri, x, w, True, a, idx, wts)
                    _a_t_records(col0, a, idx, wts, wgt, g, sx, jmap)
                elif not clipped[j]:
                    _crossing_record(geo, med, x, w, tri, meds[j], meds[j + 1], wgt, g, sx, jmap)
            if is_phase:
                _phase_records(med, mv, mu, mix_e, lw, dl, dqdc, wgt, g, sx, jmap)
        if sinks & 2:
            for c in range(3):
                for j in range(score.shape[0]):
                    jac[row, lt, c, j] += contrib[c] * score[j, c]
    return n_shadow, casts


@njit(cache=True, _nrt=False, forceinline=True, error_model="numpy")
def _trace_path(geo, med, tex, job, o0, d0, seed_path, row, cam, pix, img_on, gradpass, out_rows, ab, grad, jac,
                scratch, path_vecs, rs):
    """One camera path (``path_tracer._trace_chunk`` for a single path). Returns (vertices, shadow rays,
    casts, capped, levels used). Allocates nothing (its vectors are the caller's ``path_vecs``), so it runs
    without reference counting."""
    seed, depth_cap, roulette, rr_depth, jmap = job.seed, job.depth_cap, job.roulette, job.rr_depth, job.jmap
    sigma_s, sigma_e, med_kind, med_tooth, col_sigma = med.sigma_s, med.sigma_e, med.kind, med.tooth, med.col_sigma
    alb_es, alb_ds, alb_ee, alb_de = med.alb_es, med.alb_ds, med.alb_ee, med.alb_de
    ph_es, ph_ds, ph_ee, ph_de = med.ph_es, med.ph_ds, med.ph_ee, med.ph_de
    col_alb_e, col_alb_d, c_col, rho_e, col_rho, spread = med.col_alb_e, med.col_alb_d, med.c_col, med.rho_e, \
        med.col_rho, med.spread
    ln_sigma_s, ln_sigma_e, ln_alb_es, ln_alb_ds = med.ln_sigma_s, med.ln_sigma_e, med.ln_alb_es, med.ln_alb_ds
    ln_alb_ee, ln_alb_de, ln_rho_s, ln_rho_e = med.ln_alb_ee, med.ln_alb_de, med.ln_rho_s, med.ln_rho_e
    kind, normal_s, eta = geo.kind, geo.normal_s, geo.eta
    tri_x, t_x, meds, t_e, clipped = scratch.tri_x, scratch.t_x, scratch.meds, scratch.t_e, scratch.clipped
    a, idx, wts, emp2, emp1 = scratch.a, scratch.idx, scratch.wts, scratch.no_score, scratch.no_grad
    stack, buf_tri, buf_t, wdist = scratch.stack, scratch.buf_tri, scratch.buf_t, scratch.wdist
    pv = path_vecs
    s_run, o, d, x, nd, nrm = pv.s_run, pv.o, pv.d, pv.x, pv.nd, pv.nrm
    logf, logp, logfs, wv, dqdc, mix_e, mix_s = pv.logf, pv.logp, pv.logfs, pv.wv, pv.dqdc, pv.mix_e, pv.mix_s
    tau_cum, tau_at, sig_k, tmp, ones = pv.tau_cum, pv.tau_at, pv.sig_k, pv.tmp, pv.ones
    s_run[:] = 0.0
    use_g = gradpass == 2
    use_s = jac.shape[0] > 0
    g_lvl = grad if use_g else emp1
    sx_lvl = s_run if use_s else emp2
    for c in range(3):
        o[c] = o0[c]
        d[c] = d0[c]
        logf[c] = logp[c] = logfs[c] = dqdc[c] = 0.0
        ones[c] = 1.0
    _seed(rs, seed, seed_path)
    _rand(rs)  # the camera jitter (drawn by the caller's formula): keep the stream aligned
    _rand(rs)
    hero = min(int(_rand(rs) * 3.0), 2)
    m = MED_AIR
    n_vert = n_shadow = casts = 0
    capped = 0
    levels = 0
    for b in range(depth_cap):
        levels = b + 1
        u0, u1, u2, u3, u4, u5 = _rand(rs), _rand(rs), _rand(rs), _rand(rs), _rand(rs), _rand(rs)
        in_medium = m != MED_AIR
        # ---- free flight on the sampling scene (hero channel, balance heuristic over channels)
        tau_star = -np.log1p(-u0)
        scatter = False
        nc = 0
        if not in_medium:
            k, end_tri, end_t, _, nc = _walk(geo, o, d, m, False, np.inf, tri_x, t_x, meds, stack, wdist, buf_tri,
                                             buf_t)
            for c in range(3):
                tau_cum[c] = 0.0
            # an index-matched surface crossed from the air: only where volumes overlap (a tooth's root inside
            # the gums, entered and left through the gums' surface), the flight entered a medium and is one
            in_medium = k > 0
        if in_medium:  # tau_cum: the optical depth before piece kstar
            k, end_tri, end_t, scatter, nc_f = _walk_to_flight(geo, o, d, m, sigma_s, hero, tau_star, tri_x, t_x,
                                                               meds, tau_cum, stack, wdist)
            nc += nc_f
        casts += nc
        end_f = end_t if end_t < np.inf else 0.0
        kstar = k
        tb_k = 0.0 if kstar == 0 else t_x[kstar - 1]
        mk = meds[min(kstar, k)]
        for c in range(3):
            sig_k[c] = sigma_s[mk, c]
        if scatter:
            s = tb_k + (tau_star - tau_cum[hero]) / max(sig_k[hero], 1e-300)
        else:
            s = end_f
        for c in range(3):
            tau_at[c] = tau_cum[c] + sig_k[c] * (s - tb_k)
            logp[c] -= tau_at[c]
            if scatter:
                logp[c] += ln_sigma_s[mk, c]
        # ---- evaluation: piece lengths on the evaluation geometry up to s
        _eval_crossings(geo, o, d, k, tri_x, t_x, s if scatter else end_t, t_e, clipped)
        if in_medium:
            prev = 0.0
            for j in range(kstar + 1):
                end = (t_e[j] if j < k else end_f) if j < kstar else s
                ln = end - prev
                prev = end
                for c in range(3):
                    logf[c] -= ln * sigma_e[meds[j], c]
                if (use_g or use_s) and ln != 0.0 and meds[j] != MED_AIR:
                    _emit_diag(col_sigma[meds[j]], (-ln, -ln, -ln), ab[b], g_lvl, sx_lvl, jmap)
            if roulette:
                for c in range(3):
                    logfs[c] -= tau_at[c]
            if use_g or use_s:
                for j in range(kstar):
                    if kind[tri_x[j]] == KIND_INDEX_MATCHED and not clipped[j]:
                        _crossing_record(geo, med, o, d, tri_x[j], meds[j], meds[j + 1], ab[b], g_lvl, sx_lvl, jmap)
        for c in range(3):
            x[c] = o[c] + s * d[c]
            nd[c] = d[c]
        new_m = mk
        alive = True
        lme_rr = np.nan  # log mean_c exp(logp_c) at the end of this vertex where already known (the roulette's)
        connect = False  # a scattering or an opaque vertex: connected to the lights
        nee_m, nee_mix, nee_lw, nee_dl = mk, ones, 1.0, 0.0  # the opaque vertex's; a scattering vertex sets its own
        if scatter:
            # ---- volume scattering vertex
            n_vert += 1
            mv = new_m
            lw_s = lw_e = 1.0
            dl = 0.0
            dqdc[:] = 0.0
            tooth = med_tooth[mv]
            if tooth >= 0:
                sign = -1.0 if med_kind[mv] == MED_DENTIN else 1.0
                q_s, q_e = _dentin_query(geo, tooth, x, sign, dqdc, stack, tmp, BLEND_REACH * spread)
                lw_s = _blend(q_s, spread)
                lw_e = _blend(q_e, spread)
                dl = lw_e * (1.0 - lw_e) / spread
            # sigma_s = albedo_mix * sigma_t (eq. 5.17-5.21): the albedo blended, the extinction the region's own
            for c in range(3):
                logf[c] += ln_sigma_e[mv, c] + _log_mix(alb_ee[mv, c], alb_de[mv, c], ln_alb_ee[mv, c],
                                                        ln_alb_de[mv, c], lw_e)
                if roulette:
                    logfs[c] += ln_sigma_s[mv, c] + _log_mix(alb_es[mv, c], alb_ds[mv, c], ln_alb_es[mv, c],
                                                             ln_alb_ds[mv, c], lw_s)
            if use_g or use_s:
                for c in range(3):
                    tmp[c] = 1.0 / sigma_e[mv, c]
                _emit_diag(col_sigma[mv], tmp, ab[b], g_lvl, sx_lvl, jmap)
                _emit_blend(col_alb_e[mv], col_alb_d[mv], alb_ee, mv, alb_de, mv, lw_e, tmp, ab[b], g_lvl, sx_lvl, jmap)
                if tooth >= 0:
                    for c in range(3):
                        a_mix = alb_ee[mv, c] * lw_e + alb_de[mv, c] * (1 - lw_e)
                        tmp[c] = (alb_ee[mv, c] - alb_de[mv, c]) / a_mix
                    for mm in range(3):
                        f_ = dl * dqdc[mm]
                        _emit(c_col[tooth] + mm, tmp[0] * f_, tmp[1] * f_, tmp[2] * f_, ab[b], g_lvl, sx_lvl,
                              jmap)
            for i in range(3):
                mix_e[i] = ph_ee[mv, i] * lw_e + ph_de[mv, i] * (1 - lw_e)
                mix_s[i] = ph_es[mv, i] * lw_s + ph_ds[mv, i] * (1 - lw_s)
            lme = _logmeanexp3(logp)
            for c in range(3):
                wv[c] = np.exp(logf[c] - lme)
            nee_m, nee_mix, nee_lw, nee_dl = mv, mix_e, lw_e, dl
            connect = True
        elif end_tri >= 0:
            kd = kind[end_tri]
            if kd == KIND_DIELECTRIC:
                # ---- thin dielectric boundary (eq. 5.1-5.2)
                n_vert += 1
                cosv = normal_s[end_tri, 0] * d[0] + normal_s[end_tri, 1] * d[1] + normal_s[end_tri, 2] * d[2]
                if u4 < fresnel_dielectric(cosv, eta[end_tri]):  # reflected: stays in the medium of the last piece (mk)
                    for c in range(3):
                        nd[c] = d[c] - 2.0 * cosv * normal_s[end_tri, c]
                else:
                    new_m = geo.inside[end_tri] if cosv < 0.0 else geo.outside[end_tri]
                    col0 = _a_t(geo, tex, end_tri, o, d, True, a, idx, wts)
                    la0, la1, la2 = np.log(a[0]), np.log(a[1]), np.log(a[2])
                    logf[0] += la0
                    logf[1] += la1
                    logf[2] += la2
                    if use_g or use_s:
                        _a_t_records(col0, a, idx, wts, ab[b], g_lvl, sx_lvl, jmap)
                    if roulette:
                        if not geo.same_textures:  # the sampling scene's a_t differs from the evaluation scene's
                            _a_t(geo, tex, end_tri, o, d, False, a, idx, wts)
                            la0, la1, la2 = np.log(a[0]), np.log(a[1]), np.log(a[2])
                        logfs[0] += la0
                        logfs[1] += la1
                        logfs[2] += la2
            elif kd == KIND_OPAQUE:
                # ---- opaque Lambertian oral cavity
                n_vert += 1
                dn = normal_s[end_tri, 0] * d[0] + normal_s[end_tri, 1] * d[1] + normal_s[end_tri, 2] * d[2]
                sg = -1.0 if dn > 0.0 else (1.0 if dn < 0.0 else 0.0)
                for c in range(3):
                    nrm[c] = normal_s[end_tri, c] * sg
                    logf[c] += ln_rho_e[c]
                    if roulette:
                        logfs[c] += ln_rho_s[c]
                if use_g or use_s:
                    for c in range(3):
                        tmp[c] = 1.0 / rho_e[c]
                    _emit_diag(col_rho, tmp, ab[b], g_lvl, sx_lvl, jmap)
                lme = _logmeanexp3(logp)
                lme_rr = lme
                for c in range(3):
                    wv[c] = np.exp(logf[c] - lme)
                connect = True  # with the connection's defaults set above: medium mk, no phase function
            else:
                alive = False
        else:
            alive = False
        if connect:
            # ---- next-event estimation from the vertex (one call site: ``_nee`` is inlined here)
            ns, nc = _nee(geo, med, tex, job, x, d, nee_m, wv, nrm, scatter, nee_mix, nee_lw, nee_dl, dqdc, row, cam,
                          pix, b, img_on, gradpass, out_rows, ab, grad, jac, s_run, scratch)
            n_shadow += ns
            casts += nc
            if scatter:
                # continue: sample the phase function with the sampling parameters
                gsel = mix_s[0] if u1 < mix_s[2] else mix_s[1]
                mu = sample_hg_mu_scalar(gsel, u2)
                direction_from_mu_into(d, mu, 2.0 * np.pi * u3, nd)
                f_e = two_lobe(mu, mix_e[0], mix_e[1], mix_e[2])
                if mix_s[0] == mix_e[0] and mix_s[1] == mix_e[1] and mix_s[2] == mix_e[2]:
                    f_s = f_e  # sampling and evaluation phase functions agree (every forward render)
                else:
                    f_s = two_lobe(mu, mix_s[0], mix_s[1], mix_s[2])
                lf_e = np.log(f_e)
                lf_s = lf_e if f_s == f_e else np.log(f_s)
                for c in range(3):
                    logf[c] += lf_e
                    logp[c] += lf_s
                    if roulette:
                        logfs[c] += lf_s
                lme_rr = lme + lf_s  # log mean_c p_c after the phase term, which every channel shares
                if use_g or use_s:  # pushed at level b + 1: weight R_{b+1}
                    _phase_records(med, mv, mu, mix_e, lw_e, dl, dqdc, ab[b + 1], g_lvl, sx_lvl, jmap)
            else:  # the oral cavity: cosine-weighted about the normal facing the path
                mu = np.sqrt(1.0 - u4)
                direction_from_mu_into(nrm, mu, 2.0 * np.pi * u5, nd)
                new_m = MED_AIR
        # ---- Russian roulette at theta_0 (see ``path_tracer.RenderSettings``)
        if alive and roulette and b + 1 >= rr_depth:
            ur = _rand(rs)
            if lme_rr != lme_rr:  # not set at this vertex (a boundary): NaN
                lme_rr = _logmeanexp3(logp)
            beta = np.exp(max(logfs[0], max(logfs[1], logfs[2])) - lme_rr)
            q = 0.0 if np.isnan(beta) else min(beta, 1.0)
            if ur < q:
                lq = np.log(q)
                for c in range(3):
                    logp[c] += lq
            else:
                alive = False
        if not alive:
            return n_vert, n_shadow, casts, 0, levels
        for c in range(3):
            o[c] = x[c]
            d[c] = nd[c]
        m = new_m
    if roulette:
        capped = 1
    return n_vert, n_shadow, casts, capped, levels


@njit(cache=True, _nrt=False, error_model="numpy")
def _trace_part(geo, med, tex, job, r0, r1, s0, s1, out_rows, g, jac, jac_off, ab, mode, scratch, path_vecs, rs, o, d,
                counts) -> None:
    """One part of ``_trace_rows``: rows r0..r1, samples s0..s1 of each, counters into ``counts``. Allocates
    nothing (runs without reference counting) and holds the only call of ``_trace_path``, which LLVM inlines
    here (``forceinline``): a call would pass every field of every array of the scene's tuples on the stack,
    per path."""
    fxy, rot, center, width = job.fxy, job.rot, job.center, job.width
    cam_of, pix_of, spp, seed, jitter, want_grad = job.cam_of, job.pix_of, job.spp, job.seed, job.jitter, job.want_grad
    yes, no = mode[0] == 0, mode[0] == 1
    for row in range(r0, r1):
        cam = cam_of[row]
        pix = pix_of[row]
        for smp in range(s0, s1):
            path = row * spp + smp
            _seed(rs, seed, path)
            jx = _rand(rs) if jitter else 0.5
            jy = _rand(rs) if jitter else 0.5
            px = pix % width[cam] + jx
            py = pix // width[cam] + jy
            dcx = (px - fxy[cam, 2]) / fxy[cam, 0]
            dcy = (py - fxy[cam, 3]) / fxy[cam, 1]
            nn = 0.0
            for c in range(3):
                d[c] = dcx * rot[cam, 0, c] + dcy * rot[cam, 1, c] + rot[cam, 2, c]
                nn += d[c] * d[c]
            nn = np.sqrt(nn)
            for c in range(3):
                d[c] /= nn
                o[c] = center[cam, c]
            # one call site (LLVM inlines ``_trace_path`` here): the image, or the gradient's two passes
            nv = ns = nc = cap = lv = 0
            for ps in range(2 if want_grad else 1):
                if not want_grad:
                    gp, img, jj = mode[0], yes, jac
                elif ps == 0:  # ab is zero here: zeroed once, and after each replay as far as it was used
                    gp, img, jj = mode[1], yes, jac
                else:
                    gp, img, jj = mode[2], no, jac_off
                nv_, ns_, nc_, cap_, lv_ = _trace_path(geo, med, tex, job, o, d, path, row, cam, pix, img, gp,
                                                       out_rows, ab, g, jj, scratch, path_vecs, rs)
                if ps == 0:
                    nv, ns, nc, cap, lv = nv_, ns_, nc_, cap_, lv_
                    if want_grad:
                        for lvl in range(lv, -1, -1):  # suffix sums R_L = sum_{b >= L} A_b
                            for c in range(3):
                                ab[lvl, c] += ab[lvl + 1, c]
            if want_grad:
                for lvl in range(lv + 1):
                    for c in range(3):
                        ab[lvl, c] = 0.0
            counts[0] += nv
            counts[1] += ns
            counts[2] += nc
            counts[3] += cap


@njit(cache=True, nogil=True, error_model="numpy")
def _trace_worker(geo, med, tex, job, n_j, out_parts, grad_blocks, jac, counters, next_part):
    """One thread's work (``_trace_rows`` runs it on each thread; ``next_part`` is the shared queue): trace every
    row (traced pixel) x spp in parts: part = (sample half, row block),
    n_halves = out_parts.shape[0] (1 or 2) halves of the samples of each of the row blocks; half h adds
    into out_parts[h]. Each thread takes the next untaken part until none is left (``work_queue``), so a thread
    slowed by other work takes fewer parts; a part's result and where it goes do not depend on which thread
    traced it, so neither do the sums. The halves keep the parts alike where row blocks differ (on the forward
    scene the first half of the rows holds 43 % of the work)."""
    n_rows = job.cam_of.shape[0]
    n_l = job.lp.shape[0]
    spp, depth_cap, want_grad, stack_size = job.spp, job.depth_cap, job.want_grad, geo.stack_size
    n_halves = out_parts.shape[0]
    n_blocks = counters.shape[0] // n_halves
    n_parts = counters.shape[0]
    packet = PacketScratch(np.empty((n_l, 3)), np.empty(n_l), np.empty(n_l), np.empty(n_l),
                           np.empty((n_l, HIT_BUFFER), dtype=np.int64), np.empty((n_l, HIT_BUFFER)),
                           np.empty(n_l, dtype=np.int64), np.empty((PACKET, 4)),
                           np.empty((stack_size, 2), dtype=np.int64), np.empty(WIDTH, dtype=np.int64),
                           np.empty(PACKET, dtype=np.int64), np.empty((PACKET, LANES)))
    scratch = Scratch(np.empty(MAX_CROSSINGS + 1, dtype=np.int64), np.empty(MAX_CROSSINGS + 1),
                      np.empty(MAX_CROSSINGS + 2, dtype=np.int64), np.empty(MAX_CROSSINGS + 1),
                      np.empty(MAX_CROSSINGS + 1, dtype=np.bool_), np.empty(3), np.empty(4, dtype=np.int64),
                      np.empty(4), np.empty(3), np.empty((n_j, 3)), np.empty((0, 3)), np.empty(0),
                      np.empty(stack_size, dtype=np.int64), np.empty((3, 3)), np.empty(HIT_BUFFER, dtype=np.int64),
                      np.empty(HIT_BUFFER), np.empty(WIDTH), packet)
    vecs = np.empty((17, 3))
    path_vecs = PathVectors(np.empty((n_j, 3)), vecs[0], vecs[1], vecs[2], vecs[3], vecs[4], vecs[5], vecs[6],
                            vecs[7], vecs[8], vecs[9], vecs[10], vecs[11], vecs[12], vecs[13], vecs[14], vecs[15],
                            vecs[16])
    jac_off = np.empty((0, 1, 3, 1))
    # the passes (0 image, 1 image + vertex contributions, 2 replay) as run-time values: literal
    # arguments would compile a copy of _trace_path for each
    mode = np.arange(3)
    ab = np.zeros((depth_cap + 2, 3))
    rs = np.empty(1, dtype=np.uint64)
    o = np.empty(3)
    d = np.empty(3)
    while True:
        part = take_next(next_part)
        if part >= n_parts:
            break
        half = part // n_blocks
        blk = part - half * n_blocks
        r0 = blk * n_rows // n_blocks
        r1 = (blk + 1) * n_rows // n_blocks
        s0 = half * spp // n_halves
        s1 = (half + 1) * spp // n_halves
        g = grad_blocks[part] if want_grad else np.empty(0)
        _trace_part(geo, med, tex, job, r0, r1, s0, s1, out_parts[half], g, jac, jac_off, ab, mode, scratch,
                    path_vecs, rs, o, d, counters[part])


def _trace_rows(geo, med, tex, job, n_j: int, out_parts: np.ndarray, grad_blocks: np.ndarray, jac: np.ndarray,
                counters: np.ndarray, n_workers: int) -> None:
    """Run ``_trace_worker`` on ``n_workers`` threads (it releases the GIL) sharing one queue of parts. Python
    threads rather than a numba parfor: the parfor's compile optimises the whole inlined tracer once more (a cold
    compile 61 s with it, 52-56 s without), and numba's workqueue threading layer refuses parfors launched from two
    threads at once (a Dask worker's threads)."""
    next_part = np.zeros(1, dtype=np.int64)
    args = (geo, med, tex, job, n_j, out_parts, grad_blocks, jac, counters, next_part)
    if n_workers <= 1:
        _trace_worker(*args)
        return
    errors: list[BaseException] = []

    def work() -> None:
        try:
            _trace_worker(*args)
        except BaseException as exc:  # re-raised in the caller's thread
            errors.append(exc)

    threads = [threading.Thread(target=work, name=f"teeth-tracer-{i}", daemon=True) for i in range(n_workers)]
    for t in threads:
        t.start()
    for t in threads:
        t.join()
    if errors:
        raise errors[0]


def trace(cs: CompiledScene, packed: tuple, cameras: list, cam_of: np.ndarray, pix_of: np.ndarray, spp: int,
          seed: int, max_depth: int | None, rr_depth: int, jitter: bool, lp: np.ndarray, li: np.ndarray,
          adj: np.ndarray | None, jmap: np.ndarray | None, n_j: int):
    """Trace rows (camera, flat pixel) x spp; (per-row images (n_rows, L, 3), grad or None, per-row
    Jacobian (n_rows, L, 3, n_j) or None, counters (vertices, shadow rays, casts, capped))."""
    geo, med, tex = packed
    n_rows, n_l = len(cam_of), len(lp)
    roulette = max_depth is None
    depth_cap = MAX_PATH_VERTICES if roulette else int(max_depth)
    want_grad = adj is not None
    n_blocks = max(1, min(N_BLOCKS, n_rows))
    # two halves of the samples (see _trace_rows), fixed so that sums do not depend on the thread count; one
    # where the per-row Jacobian is accumulated (it would need a copy per half)
    n_halves = SAMPLE_HALVES if jmap is None else 1
    out_parts = np.zeros((n_halves, n_rows, n_l, 3))
    grad_blocks = np.zeros((n_halves * n_blocks if want_grad else 0, cs.layout.size))
    jac = np.zeros((n_rows, n_l, 3, n_j)) if jmap is not None else np.zeros((0, n_l, 3, 0))
    counters = np.zeros((n_halves * n_blocks, 4), dtype=np.int64)
    n_threads = get_num_threads()
    fxy = np.array([[c.K[0, 0], c.K[1, 1], c.K[0, 2], c.K[1, 2]] for c in cameras], dtype=np.float64)
    rot = np.array([c.R for c in cameras], dtype=np.float64)
    center = np.array([c.center for c in cameras], dtype=np.float64)
    job = Job(fxy, rot, center, np.array([c.width for c in cameras], dtype=np.int64),
              np.asarray(cam_of, dtype=np.int64), np.asarray(pix_of, dtype=np.int64), int(spp), int(seed),
              int(depth_cap), bool(roulette), int(rr_depth), bool(jitter), np.ascontiguousarray(lp, dtype=np.float64),
              np.ascontiguousarray(li, dtype=np.float64), 1.0 / int(spp),
              np.zeros((0, 0, 0, 3)) if adj is None else np.ascontiguousarray(adj, dtype=np.float64), bool(want_grad),
              np.full(1, -1, dtype=np.int64) if jmap is None else jmap)
    _trace_rows(geo, med, tex, job, max(n_j, 0), out_parts, grad_blocks, jac, counters, n_threads)
    out_rows = out_parts[0] if n_halves == 1 else out_parts[0] + out_parts[1]
    grad = grad_blocks.sum(axis=0) if want_grad else None
    if not (np.isfinite(out_rows).all() and (grad is None or np.isfinite(grad).all())
            and (jmap is None or np.isfinite(jac).all())):
        raise ValueError("the teeth tracer computed a value that is not finite: degenerate geometry (a triangle of "
                         "zero area, a light on a surface) or parameters out of range")
    return out_rows, grad, (jac if jmap is not None else None), counters.sum(axis=0), n_threads
