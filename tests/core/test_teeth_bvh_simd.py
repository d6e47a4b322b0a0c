"""The BVH's vector box tests (``bvh._slab_mask``, ``bvh._packet_box_masks``: LLVM vector IR through numba
intrinsics) against their scalar references (``bvh._wide_slabs``, ``bvh.packet_box_masks_scalar``) on random
rays and boxes, including the awkward cases: axis-parallel rays (inverse 1e300), empty children (+inf
planes), origins on a box plane, flat boxes, finite and infinite tmax, NaN slab distances. Tolerance: none;
the hit masks must be equal and every entry distance equal to the last bit. The single ray's float32 test is
also checked to be conservative: with the boxes padded as ``ray_arrays`` pads them it enters every box the
exact float64 slab test enters."""

from __future__ import annotations

import numpy as np
import pytest

numba = pytest.importorskip("numba")

from numba import njit  # noqa: E402

from material_structures.core.teeth import bvh  # noqa: E402

pytestmark = pytest.mark.heavy  # compiles the vector kernels (about 15 s): outside `make test-fast`


@njit(cache=False)
def _vector_slabs(wbox, i, nx, ny, nz, ox, oy, oz, ix, iy, iz, tmin, tmax, dist):
    return bvh._slab_mask(wbox, i, nx, ny, nz, ox, oy, oz, ix, iy, iz, tmin, tmax, dist)


@njit(cache=False)
def _scalar_slabs(wbox, i, nx, ny, nz, ox, oy, oz, ix, iy, iz, tmin, tmax, dist):
    bvh._wide_slabs(wbox, i, nx, ny, nz, ox, oy, oz, ix, iy, iz, tmin, tmax, dist)


@njit(cache=False)
def _vector_packet(wbox, i, ox, oy, oz, pinv, live, tmin, cmask):
    return bvh._packet_box_masks(wbox, i, ox, oy, oz, pinv, live, tmin, cmask)


def _boxes(rng: np.random.Generator, n: int) -> np.ndarray:
    """(n, 6, WIDTH) float32 wide-node boxes: random, some flat along an axis; node k has 1 + k % WIDTH children, then
    empty ones (+inf), as ``ray_arrays`` stores them (``_packet_box_masks`` relies on it); node 0 is empty."""
    w = bvh.WIDTH
    lo = rng.normal(size=(n, 3, w))
    hi = lo + np.abs(rng.normal(size=(n, 3, w))) * (rng.random((n, 3, w)) > 0.1)  # ~10 % flat extents
    box = np.concatenate([lo, hi], axis=1)
    for node in range(n):
        box[node, :, 1 + node % w:] = np.inf
    box[0, :, :] = np.inf
    return np.ascontiguousarray(box, dtype=np.float32)


def _ray(rng: np.random.Generator, box: np.ndarray, k: int, origin: np.ndarray | None = None) -> tuple:
    """Origin (``origin`` if given), inverse direction, near rows and tmax of a random ray, 3 in 4 aimed at a
    point inside a child box; every 7th axis-parallel (inverse 1e300), every 11th starting on a box plane,
    every 13th on a box plane with a subnormal direction component along its normal (inverse inf, distance
    0 x inf = NaN)."""
    o = rng.normal(size=3) if origin is None else origin.copy()
    finite = np.flatnonzero(np.isfinite(box[0]))
    d = rng.normal(size=3)
    if len(finite) and k % 4:
        c = rng.choice(finite)
        d = box[:3, c] + rng.random(3) * (box[3:, c] - box[:3, c]) - o
    if k % 7 == 0:
        d[k % 3] = 0.0
    if len(finite) and (k % 11 == 0 or k % 13 == 0):
        c = rng.choice(finite)
        o[0] = box[0, c] if k % 2 else box[3, c]
        if k % 13 == 0:
            d[0] = 5e-324 if k % 3 else -5e-324
    with np.errstate(over="ignore"):
        inv = [1.0 / x if x != 0.0 else 1e300 for x in d]
    near = [a if v >= 0.0 else a + 3 for a, v in enumerate(inv)]
    tmax = np.inf if k % 2 else float(rng.exponential(2.0))
    return o, inv, near, tmax


def test_slab_mask_equals_the_scalar_slab_test():
    rng = np.random.default_rng(11)
    wbox = _boxes(rng, 16)
    vd, sd = np.empty(bvh.WIDTH), np.empty(bvh.WIDTH)
    n_hit = n_miss = n_nan = 0
    for k in range(20000):
        i = k % len(wbox)
        o, inv, near, tmax = _ray(rng, wbox[i], k)
        tmin = 0.0 if k % 3 else 1e-4
        args = (wbox, i, *near, *o, *inv, tmin, tmax)
        mask = _vector_slabs(*args, vd)
        _scalar_slabs(*args, sd)
        for c in range(bvh.WIDTH):
            hit = bool((mask >> c) & 1)
            assert hit == (sd[c] < np.inf), (k, c, vd[c], sd[c])
            if hit:
                assert vd[c] == sd[c], (k, c, vd[c], sd[c])
                n_hit += 1
            else:
                n_miss += 1
        with np.errstate(invalid="ignore"):
            n_nan += int(np.isnan((wbox[i, near[0]] - o[0]) * inv[0]).any())
    assert n_hit > 10000 and n_miss > 10000 and n_nan > 500  # both outcomes and NaN distances were exercised


def test_packet_box_masks_equal_the_scalar_packet_loop():
    rng = np.random.default_rng(12)
    wbox = _boxes(rng, 16)
    pinv = np.empty((bvh.PACKET, 4))
    diff = np.empty((6, bvh.WIDTH))
    vc, sc = np.empty(bvh.WIDTH, dtype=np.int64), np.empty(bvh.WIDTH, dtype=np.int64)
    n_bits = n_nan = 0
    for k in range(3000):
        i = k % len(wbox)
        o = rng.normal(size=3)
        finite = np.flatnonzero(np.isfinite(wbox[i, 0]))
        if k % 3 == 0 and len(finite):  # the shared origin on a box plane: NaN distances for subnormal d x
            o[0] = wbox[i, rng.choice([0, 3]), rng.choice(finite)]
        for b in range(bvh.PACKET):
            _, inv, _, tmax = _ray(rng, wbox[i], k * bvh.PACKET + b, o)
            pinv[b] = (*inv, tmax)
            with np.errstate(invalid="ignore"):
                n_nan += int(np.isnan((wbox[i, [0, 3]] - o[0]) * inv[0]).any())
        live = np.int64(0)
        for b in rng.choice(bvh.PACKET, size=rng.integers(0, bvh.PACKET + 1), replace=False):
            live |= np.int64(1) << np.int64(b)
        tmin = 1e-4 if k % 2 else 0.0
        kv = _vector_packet(wbox, i, *o, pinv, live, tmin, vc)
        ks = bvh.packet_box_masks_scalar(wbox, i, *o, pinv, live, tmin, diff, sc)
        # empty children (every plane +inf) are empty leaves: the scalar loop lets a ray with tmax = inf "enter"
        # them (t0 = t1 = inf), the vector test of a narrow node skips them; only the real children are compared
        real = sum(1 << c for c in range(bvh.WIDTH) if np.isfinite(wbox[i, 0, c]))
        assert kv & real == ks & real, k
        for c in range(bvh.WIDTH):  # the rays entering each child (columns of no entered child are not used)
            if (real >> c) & (ks >> c) & 1:
                assert vc[c] == sc[c], (k, c)
        n_bits += sum(bin(int(x) & ((1 << 64) - 1)).count("1") for x in vc)
    assert n_bits > 40000 and n_nan > 1000  # ray-child hits (of about 750,000 pairs), NaN distances


def test_vector_box_tests_reject_non_contiguous_arrays():
    """The intrinsics load and store whole rows, so they only type for C-contiguous arrays."""
    wbox = np.zeros((2, 6, 2 * bvh.WIDTH), dtype=np.float32)[:, :, ::2]
    with pytest.raises(numba.core.errors.TypingError):
        _vector_slabs(wbox, 0, 0, 1, 2, 0.0, 0.0, 0.0, 1.0, 1.0, 1.0, 0.0, 1.0, np.empty(bvh.WIDTH))


def test_float32_slab_test_enters_every_box_the_exact_test_enters():
    """Boxes in a scene of coordinates up to 40 (the teeth scenes' millimetres), padded and rounded as
    ``ray_arrays`` does; rays from inside the scene, from its boxes' faces and corners and from far away (a
    camera 400 away), short and long, some grazing a face: every child whose exact slab interval (float64, no
    slack) meets (tmin, tmax) must be in the float32 test's mask. A test without the padding misses some."""
    rng = np.random.default_rng(21)
    n, w = 64, bvh.WIDTH
    lo = rng.uniform(-40.0, 40.0, size=(n, 3, w))
    hi = lo + rng.exponential(0.3, size=(n, 3, w)) * (rng.random((n, 3, w)) > 0.1)
    exact = np.concatenate([lo, hi], axis=1)
    pad = bvh.BOX_PAD * 40.0
    padded = bvh._outward_float32(exact, pad)
    unpadded = bvh._outward_float32(exact, 0.0)
    assert padded.dtype == np.float32 and (padded[:, :3] <= exact[:, :3] - pad).all()
    assert (padded[:, 3:] >= exact[:, 3:] + pad).all()
    vd = np.empty(w)
    missed = missed_unpadded = entered = 0
    for k in range(40000):
        i = k % n
        c = rng.integers(w)
        target = exact[i, :3, c] + rng.random(3) * (exact[i, 3:, c] - exact[i, :3, c])
        if k % 4 == 0:
            o = rng.uniform(-400.0, 400.0, size=3)
        elif k % 4 == 1:  # from a face or a corner of the box
            o = np.where(rng.random(3) < 0.5, exact[i, :3, c], exact[i, 3:, c])
            o[k % 3] = target[k % 3]
        else:
            o = target + rng.normal(size=3) * 10.0 ** rng.uniform(-4, 1)
        d = target - o if k % 5 else rng.normal(size=3)
        if k % 7 == 0:  # grazing: along a face
            d[k % 3] = 0.0
        nrm = np.linalg.norm(d)
        if nrm == 0.0:
            continue
        d /= nrm
        with np.errstate(divide="ignore"):
            inv = [1.0 / x if x != 0.0 else 1e300 for x in d]
        near = [a if v >= 0.0 else a + 3 for a, v in enumerate(inv)]
        tmin = 1e-6 if k % 2 else 0.0
        tmax = np.inf if k % 3 == 0 else float(rng.exponential(20.0))
        with np.errstate(invalid="ignore", over="ignore"):
            ta = (exact[i, :3] - o[:, None]) * np.array(inv)[:, None]
            tb = (exact[i, 3:] - o[:, None]) * np.array(inv)[:, None]
            t0 = np.maximum(np.nanmax(np.minimum(ta, tb), axis=0), tmin)
            t1 = np.minimum(np.nanmin(np.maximum(ta, tb), axis=0), tmax)
        want = t0 <= t1
        mask = _vector_slabs(padded, i, *near, *o, *inv, tmin, tmax, vd)
        mask0 = _vector_slabs(unpadded, i, *near, *o, *inv, tmin, tmax, vd)
        for cc in np.flatnonzero(want):
            entered += 1
            missed += not (mask >> cc) & 1
            missed_unpadded += not (mask0 >> cc) & 1
    assert entered > 20000
    assert missed == 0
    assert missed_unpadded > 0  # the check can fail: without the padding, float32 rounding loses boxes


@njit(cache=False)
def _vector_leaf(tblk, blk, o, d, tmin, tout):
    return bvh._leaf_hits(tblk, blk, o[0], o[1], o[2], d[0], d[1], d[2], tmin, tout)


@njit(cache=False)
def _vector_packet_leaf(tblk, blk, o, dirs, r0, rays, tmin, pmask, pt):
    return bvh._packet_leaf_hits(tblk, blk, o[0], o[1], o[2], dirs, r0, rays, tmin, pmask, pt)


def _leaf_blocks(rng: np.random.Generator, n: int) -> np.ndarray:
    """(n, 9, LANES) leaf blocks as ``ray_arrays`` stores them (v0, e1, e2 per lane), some lanes unused
    (NaN), some triangles degenerate (e2 = 0, e2 parallel to e1: det 0 -> 1e-300)."""
    v = rng.normal(size=(n, 3, 3, bvh.LANES))
    v[:, 1:] = 0.6 * v[:, 1:]  # edges
    v[::5, 2, :, 1] = 0.0
    v[::7, 2, :, 2] = 2.0 * v[::7, 1, :, 2]
    blk = v.reshape(n, 9, bvh.LANES).copy()
    blk[::3, :, 3] = np.nan
    return np.ascontiguousarray(blk)


def _point_on(rng: np.random.Generator, tblk: np.ndarray, blk: int, lane: int, w: float) -> np.ndarray:
    """A random point v0 + a e1 + b e2 (a, b in [0, w)) of the triangle in ``lane`` of block ``blk``."""
    return tblk[blk, :3, lane] + w * rng.random() * tblk[blk, 3:6, lane] + w * rng.random() * tblk[blk, 6:, lane]


def test_leaf_hits_equal_the_scalar_triangle_test():
    """Lane masks equal, and t equal to the last bit in every lane the scalar test keeps (u in [0, 1])."""
    rng = np.random.default_rng(13)
    tblk = _leaf_blocks(rng, 64)
    vt, st = np.empty(bvh.WIDTH), np.empty(bvh.LANES)
    n_hit = 0
    for k in range(20000):
        blk = k % len(tblk)
        lane = k % bvh.LANES
        o = rng.normal(size=3) * 2.0
        target = _point_on(rng, tblk, blk, lane, 0.5)
        d = target - o if np.all(np.isfinite(target)) and k % 4 else rng.normal(size=3)
        if k % 9 == 0:
            d[k % 3] = 0.0
        d /= np.linalg.norm(d)
        tmin = 0.0 if k % 2 else 1e-4
        mv = _vector_leaf(tblk, blk, o, d, tmin, vt)
        ms = bvh.leaf_hits_scalar(tblk, blk, o, d, tmin, st)
        assert mv == ms, k
        for lane_ in range(bvh.LANES):
            if (ms >> lane_) & 1:
                assert vt[lane_] == st[lane_], (k, lane_)
        n_hit += bin(int(ms)).count("1")
    assert n_hit > 5000


def test_packet_leaf_hits_equal_one_ray_at_a_time():
    rng = np.random.default_rng(14)
    tblk = _leaf_blocks(rng, 32)
    n_l = 50
    pmask, pt = np.empty(bvh.PACKET, dtype=np.int64), np.empty((bvh.PACKET, bvh.LANES))
    st = np.empty(bvh.LANES)
    n_hit = 0
    for k in range(400):
        blk = k % len(tblk)
        o = rng.normal(size=3) * 2.0
        dirs = np.empty((n_l + 3, 3))
        for r in range(len(dirs)):
            lane = rng.integers(bvh.LANES)
            target = _point_on(rng, tblk, blk, lane, 0.4)
            d = target - o if np.all(np.isfinite(target)) else rng.normal(size=3)
            dirs[r] = d / np.linalg.norm(d)
        r0 = 3
        rays = np.int64(0)
        for b in rng.choice(n_l, size=rng.integers(0, n_l + 1), replace=False):
            rays |= np.int64(1) << np.int64(b)
        tmin = 1e-4
        anyhit = _vector_packet_leaf(tblk, blk, o, dirs, r0, rays, tmin, pmask, pt)
        want_any = 0
        for b in range(n_l):
            if not (int(rays) >> b) & 1:
                continue
            ms = bvh.leaf_hits_scalar(tblk, blk, o, dirs[r0 + b], tmin, st)
            assert pmask[b] == ms, (k, b)
            for lane_ in range(bvh.LANES):
                if (ms >> lane_) & 1:
                    assert pt[b, lane_] == st[lane_], (k, b, lane_)
            want_any |= (ms != 0) << b
            n_hit += bin(int(ms)).count("1")
        assert anyhit == want_any, k
    assert n_hit > 2000
