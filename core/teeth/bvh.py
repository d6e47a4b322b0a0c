"""Bounding-volume hierarchy over triangles for the compiled tracer: first ray hit and closest point.

Build (numpy, once per scene): binary tree of axis-aligned boxes, split by the binned surface-area
heuristic (Wald 2007), a node becoming a leaf where that is cheaper. Nodes are stored flat: node i has
box ``lo[i]``, ``hi[i]``; an inner node's children are ``left[i]`` and ``left[i] + 1``; a leaf has
``count[i] > 0`` triangles ``order[start[i]:start[i] + count[i]]``.

Ray queries read the tree in a second layout (``ray_arrays``): the binary tree collapsed into an
8-wide one (each wide node holds up to ``WIDTH`` child boxes as six rows of ``WIDTH`` floats, so one
visit tests all children at once), each leaf's triangles in leaf order in blocks of ``LANES`` (v0, e1, e2
rows, one lane per triangle). The box and triangle tests are AVX vector code written as LLVM IR through
numba intrinsics (``_slab_mask``, ``_packet_box_masks``, ``_leaf_hits``, ``_packet_leaf_hits``; numba does not
vectorise these loops itself), each lane doing the scalar references' operations in their order
(``_wide_slabs``, ``packet_box_masks_scalar``, ``leaf_hits_scalar``). Every triangle a ray hits is tested with
the same float64 arithmetic as in a binary traversal (the padded float32 boxes only let a few more be tested), so
hits and distances are the same numbers; only fewer nodes are visited.

Queries (numba, per ray / point; float64 except the box tests, which run in float32 on padded boxes):
* ``first_hit``: nearest triangle with tmin < t < tmax (Moeller-Trumbore; the distance is the plane
  distance of eq. 5.28, smooth in the vertices), children visited near-first, boxes by the slab test.
* ``hits_until_stop``: every hit up to the first stopping triangle, unsorted (the shadow rays' and
  index-matched walks' query); ``packet_hits``: the same for up to ``PACKET`` rays that share their
  origin (a vertex's shadow rays to all lights), in one traversal of the rays still inside each box.
* ``closest_triangle``: triangle nearest to a point (point-triangle distance after Ericson 2005, the
  region tests of ``distance_derivatives.closest_point_on_triangle``), boxes pruned by their
  distance to the point: the exact minimiser, as the dentin distance q of eq. 5.15 asks.

Several trees can share one node array (``merge``): each keeps its own root index.

Depth and stacks: the build refuses a tree deeper than ``MAX_DEPTH`` (a ``ValueError`` naming the depth), and
each tree knows the stack its traversals need (``TriangleBVH.stack_size`` for ``closest_triangle``,
``RayTree.stack_size`` for the ray queries: the most entries a depth-first traversal that pushes every child
it enters can hold). The tracer sizes its stacks from these, so no traversal ever finds its stack full; the
pushes still stop at the stack's end, which only a caller passing a smaller stack than the tree's
``stack_size`` can reach.

A wide child that is a leaf is stored as the negative code ``encode_leaf(first block, triangle count)``
(``leaf_blocks`` reads it back).
"""

from __future__ import annotations

from typing import NamedTuple

import numpy as np
from llvmlite import ir
from numba import njit, types
from numba.core import cgutils
from numba.cpython.unsafe.numbers import trailing_zeros
from numba.extending import intrinsic

from . import numba_kernels as _numba_kernels  # noqa: E402
from .numba_kernels import numba_callable

_numba_kernels.activate()  # before any cached njit: the kernel cache locator, then numba_callable's overloads

LEAF_SIZE = 4  # at most, for the median fallback; the SAH decides below
SAH_BINS = 16
STACK_SIZE = 64  # a traversal stack that serves every tree whose ``stack_size`` is at most this (the tests' trees)
MAX_DEPTH = 64  # deepest binary tree the build accepts (a SAH tree over a million triangles is about 40 deep)
LEAF_COUNT_BITS = 5  # a wide leaf code holds its triangle count in its low bits ...
MAX_LEAF_COUNT = (1 << LEAF_COUNT_BITS) - 1  # ... so a leaf holds at most 31 triangles
PACKET = 63  # rays per packet of ``packet_hits`` (bits of an int64 mask)
WIDTH = 8  # children per node of the ray-query tree (one AVX register of float32 per box plane)
LANES = 4  # triangles per leaf block of the ray-query layout (one AVX register of float64)
SLACK32 = np.float32(1.0 + 2.0**-18)  # a box is hit where t0 <= t1 * SLACK32 (float32 rounding of the distances)
BOX_PAD = 2.0**-16  # the ray-query boxes' padding, relative to the scene's largest coordinate (float32 tests)


class BinaryNodes(NamedTuple):
    """The flat node arrays of one or more binary trees (``TriangleBVH.merge``), as ``closest_triangle`` reads
    them: node i has box lo[i], hi[i]; an inner node's children are left[i] and left[i] + 1; a leaf (count[i] >
    0) holds the triangles order[start[i]:start[i] + count[i]]."""

    lo: np.ndarray  # (N, 3) float64
    hi: np.ndarray  # (N, 3) float64
    left: np.ndarray  # (N,) int64, -1 at a leaf
    start: np.ndarray  # (N,) int64
    count: np.ndarray  # (N,) int64, 0 at an inner node
    order: np.ndarray  # (T,) int64 triangle ids in leaf order


class RayTree(NamedTuple):
    """The layout the ray queries read (``TriangleBVH.ray_arrays``)."""

    wbox: np.ndarray  # (M, 6, WIDTH) float32: wide nodes' child boxes, rows lo x, y, z, hi x, y, z
    wchild: np.ndarray  # (M, WIDTH) int64: a wide node index (>= 0) or a leaf code (``encode_leaf``, < 0)
    tblk: np.ndarray  # (B, 9, LANES) float64: leaf triangles, rows v0, v1 - v0, v2 - v0, one lane each
    tord: np.ndarray  # (B, LANES) int64: the lanes' triangle ids, -1 where unused
    stack_size: int  # the most stack entries a traversal of this tree holds


@numba_callable(inline=True)
def encode_leaf(first, count):
    """The wide-child code of a leaf whose triangles start at block (or slot) ``first``, ``count`` of them:
    ~(first 2^LEAF_COUNT_BITS + count), negative (an inner child is its node index, >= 0). count <=
    ``MAX_LEAF_COUNT``. Integers or int64 arrays; callable from numba code."""
    return ~((first << LEAF_COUNT_BITS) | count)


@numba_callable(inline=True)
def decode_leaf(code):
    """(first, count) of the leaf code ``code`` (``encode_leaf``'s inverse). Integers or int64 arrays; callable
    from numba code."""
    s = ~code
    return s >> LEAF_COUNT_BITS, s & MAX_LEAF_COUNT


@numba_callable(inline=True)
def leaf_blocks(code):
    """(first block, end block) of the leaf code ``code`` of a ray tree: its count triangles fill the blocks
    first .. first + ceil(count / LANES) - 1. Callable from numba code."""
    first, count = decode_leaf(code)
    return first, first + (count + LANES - 1) // LANES


class TriangleBVH:
    """Flat BVH over ``triangles`` (T, 3, 3) restricted to the triangle ids ``ids`` (default: all).

    ``depth``: edges from the root to the deepest leaf (at most ``MAX_DEPTH``, else the build raises a
    ``ValueError``); ``stack_size = depth + 1``: the stack ``closest_triangle`` needs on this tree."""

    def __init__(self, triangles: np.ndarray, ids: np.ndarray | None = None):
        tris = np.asarray(triangles, dtype=np.float64)
        ids = np.arange(len(tris), dtype=np.int64) if ids is None else np.asarray(ids, dtype=np.int64)
        cen = tris[ids].mean(axis=1)
        tlo, thi = tris[ids].min(axis=1), tris[ids].max(axis=1)
        lo, hi, left, start, count = [], [], [], [], []
        order = ids.copy()
        perm = np.arange(len(ids))

        def new_node():
            lo.append(None)
            hi.append(None)
            left.append(-1)
            start.append(0)
            count.append(0)
            return len(lo) - 1

        root = new_node()
        stack = [(root, 0, len(ids), 0)]
        depth = 0
        while stack:
            node, a, b, level = stack.pop()
            depth = max(depth, level)
            if depth > MAX_DEPTH:
                raise ValueError(f"the BVH over {len(ids)} triangles grows deeper than MAX_DEPTH = {MAX_DEPTH} levels "
                                 "(its traversal stacks are sized from the depth): degenerate geometry, such as "
                                 "triangles of widely different sizes nested in one another")
            sel = perm[a:b]
            lo[node], hi[node] = tlo[sel].min(axis=0), thi[sel].max(axis=0)
            split = None if b - a <= LEAF_SIZE else _sah_split(cen[sel], tlo[sel], thi[sel])
            if split is None:
                start[node], count[node] = a, b - a
                continue
            left_mask = split
            perm[a:b] = np.concatenate([sel[left_mask], sel[~left_mask]])
            mid = int(left_mask.sum())
            l_ = new_node()
            new_node()
            left[node] = l_
            stack.append((l_, a, a + mid, level + 1))
            stack.append((l_ + 1, a + mid, b, level + 1))
        self.lo = np.array(lo)
        self.hi = np.array(hi)
        self.left = np.array(left, dtype=np.int64)
        self.start = np.array(start, dtype=np.int64)
        self.count = np.array(count, dtype=np.int64)
        self.order = order[perm]
        self.root = 0
        self.depth = depth

    @property
    def stack_size(self) -> int:
        """Entries ``closest_triangle``'s stack needs on this tree: it pops a node and pushes both children of an
        inner one, so at most one sibling waits per level above the node it holds, + 2 at the deepest inner
        node: depth + 1."""
        return self.depth + 1

    def refit(self, triangles: np.ndarray) -> TriangleBVH:
        """This tree's topology (node structure, leaf triangles) with every box recomputed from
        ``triangles``, the same triangles at new positions: each leaf's box bounds its triangles, each
        inner node's its two children. Queries stay exact (a box still bounds everything below it); only
        the tree's quality follows the topology's geometry. A fit moves the dentin vertices every
        iteration (eq. 5.5), and a refit costs 2-3 % of a build."""
        tris = np.asarray(triangles, dtype=np.float64)
        out = object.__new__(TriangleBVH)
        out.left, out.start, out.count, out.order, out.root = self.left, self.start, self.count, self.order, self.root
        out.depth = self.depth
        lo, hi = np.empty_like(self.lo), np.empty_like(self.hi)
        leaves = np.flatnonzero(self.count > 0)
        leaves = leaves[np.argsort(self.start[leaves], kind="stable")]  # their ranges tile ``order`` in this order
        if len(leaves):
            tlo, thi = tris[self.order].min(axis=1), tris[self.order].max(axis=1)  # in leaf order
            lo[leaves] = np.minimum.reduceat(tlo, self.start[leaves], axis=0)
            hi[leaves] = np.maximum.reduceat(thi, self.start[leaves], axis=0)
        # children come after their parent (the build appends them), so a reverse sweep sees them first
        for node in np.flatnonzero(self.count == 0)[::-1]:
            a = self.left[node]
            lo[node] = np.minimum(lo[a], lo[a + 1])
            hi[node] = np.maximum(hi[a], hi[a + 1])
        out.lo, out.hi = lo, hi
        return out

    @staticmethod
    def merge(trees: list[TriangleBVH]) -> tuple[BinaryNodes, np.ndarray]:
        """One node array holding ``trees``: (``BinaryNodes``, roots)."""
        parts = [[] for _ in range(6)]
        roots = []
        n_nodes = n_tris = 0
        for t in trees:
            roots.append(n_nodes)
            parts[0].append(t.lo)
            parts[1].append(t.hi)
            parts[2].append(np.where(t.left >= 0, t.left + n_nodes, -1))
            parts[3].append(t.start + n_tris)
            parts[4].append(t.count)
            parts[5].append(t.order)
            n_nodes += len(t.lo)
            n_tris += len(t.order)
        if not trees:
            empty = (np.zeros((0, 3)), np.zeros((0, 3))) + tuple(np.zeros(0, dtype=np.int64) for _ in range(4))
            return BinaryNodes(*empty), np.zeros(0, dtype=np.int64)
        return BinaryNodes(*(np.concatenate(p) for p in parts)), np.array(roots, dtype=np.int64)

    def arrays(self) -> BinaryNodes:
        return BinaryNodes(self.lo, self.hi, self.left, self.start, self.count, self.order)

    def ray_arrays(self, triangles: np.ndarray) -> RayTree:
        """The layout ``first_hit`` and ``hits_until_stop`` read: the binary tree collapsed into a
        ``WIDTH``-wide one (wide box (M, 6, WIDTH) float32: rows lo x, y, z, hi x, y, z, one column per child,
        each box padded by ``BOX_PAD`` times the largest coordinate and rounded outwards, so that the float32
        slab test of ``_slab_mask`` never misses a box the ray enters (see there); empty children with every
        plane at +inf; wide child (M, WIDTH): a wide node index (>= 0), or a
        leaf ``encode_leaf(first block, triangle count)``; leaf triangles in blocks of ``LANES`` (B, 9, LANES): rows
        v0, v1 - v0, v2 - v0 (x, y, z each), one lane per triangle, a leaf's triangles in leaf order over
        ceil(count / LANES) consecutive blocks, unused lanes NaN (no comparison holds for them); order
        (B, LANES): the lanes' triangle ids, -1 where unused); the stack size its traversals need (``_collapse``)."""
        tv = np.asarray(triangles, dtype=np.float64)
        wbox, wchild, stack_size = self._collapse()
        wbox = _outward_float32(wbox, BOX_PAD * max(1.0, float(np.abs(tv).max(initial=0.0))))
        leaves = np.flatnonzero(self.count > 0)
        leaves = leaves[np.argsort(self.start[leaves], kind="stable")]
        n_blk = (self.count[leaves] + LANES - 1) // LANES
        first = np.concatenate([[0], np.cumsum(n_blk)[:-1]]).astype(np.int64)
        tblk = np.full((int(n_blk.sum()), 9, LANES), np.nan)
        tord = np.full((len(tblk), LANES), -1, dtype=np.int64)
        block_of = dict(zip(self.start[leaves].tolist(), first.tolist(), strict=True))
        for leaf, b0 in zip(leaves, first, strict=True):
            ids = self.order[self.start[leaf]:self.start[leaf] + self.count[leaf]]
            for k, tri in enumerate(ids):
                b, lane = b0 + k // LANES, k % LANES
                v0 = tv[tri, 0]
                tblk[b, :, lane] = np.concatenate([v0, tv[tri, 1] - v0, tv[tri, 2] - v0])
                tord[b, lane] = tri
        leaf = wchild < 0
        slot, cnt = decode_leaf(wchild[leaf])
        wchild[leaf] = encode_leaf(np.array([block_of.get(int(x), 0) for x in slot], dtype=np.int64), cnt)
        return RayTree(wbox, wchild, np.ascontiguousarray(tblk), tord, stack_size)

    def _collapse(self) -> tuple[np.ndarray, np.ndarray, int]:
        """Wide nodes from the binary tree: each takes a binary node's children and keeps opening its
        largest-area inner child until it has ``WIDTH`` children (Wald et al. 2008's collapse). Returns (boxes,
        children with leaves coded by their slot in ``order``, stack size). The stack size: a traversal pops a
        node and pushes (at most) its k children, so below wide nodes a_0 (the root) .. a_n it holds at most
        sum_{i < n} (k_{a_i} - 1) + k_{a_n} entries; the largest over all wide nodes, at least 1."""
        ext = np.maximum(self.hi - self.lo, 0.0)
        area = ext[:, 0] * ext[:, 1] + ext[:, 1] * ext[:, 2] + ext[:, 2] * ext[:, 0]
        boxes: list[np.ndarray] = []
        childs: list[np.ndarray] = []
        pending = [(0, -1, 0, 0)]  # (binary node, parent wide node, column, sum of (k - 1) over the wide ancestors)
        stack_size = 1
        while pending:
            b, parent, col, above = pending.pop()
            w = len(boxes)
            if parent >= 0:
                childs[parent][col] = w
            kids = [b] if self.count[b] > 0 else [self.left[b], self.left[b] + 1]
            while len(kids) < WIDTH:
                inner = [k for k in kids if self.count[k] == 0]
                if not inner:
                    break
                k = max(inner, key=lambda n: area[n])
                kids.remove(k)
                kids += [self.left[k], self.left[k] + 1]
            box = np.full((6, WIDTH), np.inf)  # an empty child: every plane at +inf, missed by any ray
            child = np.full(WIDTH, encode_leaf(0, 0), dtype=np.int64)  # an empty leaf, never entered (infinite box)
            stack_size = max(stack_size, above + len(kids))
            for c, k in enumerate(kids):
                box[:3, c], box[3:, c] = self.lo[k], self.hi[k]
                if self.count[k] > 0:
                    if self.count[k] > MAX_LEAF_COUNT:
                        raise ValueError(f"BVH leaf larger than the wide layout's {MAX_LEAF_COUNT} triangles")
                    child[c] = encode_leaf(int(self.start[k]), int(self.count[k]))
                else:
                    pending.append((k, w, c, above + len(kids) - 1))
            boxes.append(box)
            childs.append(child)
        return np.ascontiguousarray(np.array(boxes)), np.ascontiguousarray(np.array(childs)), stack_size


def _outward_float32(wbox: np.ndarray, pad: float) -> np.ndarray:
    """Wide boxes (M, 6, WIDTH) as float32, lo rows moved down and hi rows up by ``pad`` and then to the next
    float32 outwards where rounding moved them in; empty children (+inf) stay +inf."""
    lo = (wbox[:, :3] - pad).astype(np.float32)
    hi = (wbox[:, 3:] + pad).astype(np.float32)
    lo = np.where(lo.astype(np.float64) > wbox[:, :3] - pad, np.nextafter(lo, np.float32(-np.inf)), lo)
    hi = np.where(hi.astype(np.float64) < wbox[:, 3:] + pad, np.nextafter(hi, np.float32(np.inf)), hi)
    return np.ascontiguousarray(np.concatenate([lo, hi], axis=1), dtype=np.float32)


def _area(lo: np.ndarray, hi: np.ndarray) -> np.ndarray:
    e = np.maximum(hi - lo, 0.0)
    return e[..., 0] * e[..., 1] + e[..., 1] * e[..., 2] + e[..., 2] * e[..., 0]


def _sah_split(cen: np.ndarray, tlo: np.ndarray, thi: np.ndarray) -> np.ndarray | None:
    """Left-side mask of the binned surface-area-heuristic split (``SAH_BINS`` bins per axis, traversal
    cost 1, triangle cost 1), or None when a leaf is cheaper (or all centroids coincide)."""
    n = len(cen)
    node_area = _area(tlo.min(axis=0), thi.max(axis=0))
    best = (float(n), None)  # leaf cost in units of the node's area
    for axis in range(3):
        c0, c1 = cen[:, axis].min(), cen[:, axis].max()
        if c1 - c0 < 1e-12:
            continue
        bins = np.minimum(((cen[:, axis] - c0) / (c1 - c0) * SAH_BINS).astype(np.int64), SAH_BINS - 1)
        cnt = np.bincount(bins, minlength=SAH_BINS)
        blo = np.full((SAH_BINS, 3), np.inf)
        bhi = np.full((SAH_BINS, 3), -np.inf)
        np.minimum.at(blo, bins, tlo)
        np.maximum.at(bhi, bins, thi)
        llo, lhi = np.minimum.accumulate(blo, axis=0), np.maximum.accumulate(bhi, axis=0)
        rlo, rhi = np.minimum.accumulate(blo[::-1], axis=0)[::-1], np.maximum.accumulate(bhi[::-1], axis=0)[::-1]
        nl, nr = np.cumsum(cnt)[:-1], np.cumsum(cnt[::-1])[::-1][1:]
        cost = 1.0 + (nl * _area(llo[:-1], lhi[:-1]) + nr * _area(rlo[1:], rhi[1:])) / max(node_area, 1e-300)
        cost = np.where((nl > 0) & (nr > 0), cost, np.inf)
        k = int(np.argmin(cost))
        if cost[k] < best[0]:
            best = (float(cost[k]), bins <= k)
    if best[1] is None and n > 4 * LEAF_SIZE:  # no useful SAH split: median split keeps the tree shallow
        axis = int(np.argmax(np.ptp(cen, axis=0)))
        order = np.argsort(cen[:, axis], kind="stable")
        mask = np.zeros(n, dtype=bool)
        mask[order[: n // 2]] = True
        return mask
    return best[1]


@njit(cache=True, forceinline=True, error_model="numpy")
def _inverse(d) -> tuple[float, float, float, int, int, int]:
    """Inverse direction of a ray and, per axis, the box row of its near plane (0-2: lo where the direction is
    positive, 3-5: hi), the far plane being the other one."""
    ix = 1.0 / d[0] if d[0] != 0.0 else 1e300
    iy = 1.0 / d[1] if d[1] != 0.0 else 1e300
    iz = 1.0 / d[2] if d[2] != 0.0 else 1e300
    return ix, iy, iz, 0 if ix >= 0.0 else 3, 1 if iy >= 0.0 else 4, 2 if iz >= 0.0 else 5


@njit(cache=True, forceinline=True, error_model="numpy")
def _leaf_triangle(tblk, blk, lane, o, d) -> tuple[float, float, float]:
    """(t, u, v) of the ray with the plane of the triangle in lane ``lane`` of leaf block ``blk``, as
    ``ray_triangle`` (the same operations on the stored edges, so the same numbers); u is returned as 2
    where it already rules the hit out. The scalar reference of ``_leaf_hits``."""
    e1x, e1y, e1z = tblk[blk, 3, lane], tblk[blk, 4, lane], tblk[blk, 5, lane]
    e2x, e2y, e2z = tblk[blk, 6, lane], tblk[blk, 7, lane], tblk[blk, 8, lane]
    px, py, pz = d[1] * e2z - d[2] * e2y, d[2] * e2x - d[0] * e2z, d[0] * e2y - d[1] * e2x
    det = e1x * px + e1y * py + e1z * pz
    if abs(det) < 1e-300:
        det = 1e-300
    inv = 1.0 / det
    sx, sy, sz = o[0] - tblk[blk, 0, lane], o[1] - tblk[blk, 1, lane], o[2] - tblk[blk, 2, lane]
    u = (sx * px + sy * py + sz * pz) * inv
    if u < 0.0 or u > 1.0:
        return 0.0, 2.0, 0.0
    qx, qy, qz = sy * e1z - sz * e1y, sz * e1x - sx * e1z, sx * e1y - sy * e1x
    v = (d[0] * qx + d[1] * qy + d[2] * qz) * inv
    t = (e2x * qx + e2y * qy + e2z * qz) * inv
    return t, u, v


@njit(cache=True, _nrt=False, error_model="numpy")
def leaf_hits_scalar(tblk, blk, o, d, tmin, tout) -> int:
    """Scalar reference of ``_leaf_hits``: bit l set where lane l's triangle is hit with tmin < t (u, v >= 0,
    u + v <= 1), its t in tout[l] (t of every lane with u in [0, 1]; the others' entries are not used)."""
    m = 0
    for lane in range(LANES):
        t, u, v = _leaf_triangle(tblk, blk, lane, o, d)
        tout[lane] = t
        if u >= 0.0 and v >= 0.0 and u + v <= 1.0 and tmin < t:
            m |= 1 << lane
    return m


# ------------------------------------------------------------------------ SIMD box tests (LLVM vector IR)
# One wide-node visit as a handful of vector instructions: numba does not vectorise the loop over the WIDTH
# children (docs/teeth-tracer.md), so the slab test is written as LLVM vector IR through numba intrinsics.
# Each scalar operation of ``_wide_slabs`` / the packet's box loop has its lane-wise twin with the same
# rounding and the same NaN behaviour (numba's ``max(a, b)`` is ``b if b > a else a``, ordered compare).
_V = ir.VectorType(ir.DoubleType(), WIDTH)
_I64 = ir.IntType(64)


def _splat(builder: ir.IRBuilder, x: ir.Value, vt: ir.VectorType) -> ir.Value:
    v = builder.insert_element(ir.Constant(vt, ir.Undefined), x, ir.Constant(ir.IntType(32), 0))
    return builder.shuffle_vector(v, ir.Constant(vt, ir.Undefined),
                                  ir.Constant(ir.VectorType(ir.IntType(32), vt.count), [0] * vt.count))


def _vmax(builder: ir.IRBuilder, acc: ir.Value, v: ir.Value) -> ir.Value:
    """Lane-wise numba ``max(acc, v)``: v where v > acc (ordered), else acc."""
    return builder.select(builder.fcmp_ordered(">", v, acc), v, acc)


def _vmin(builder: ir.IRBuilder, acc: ir.Value, v: ir.Value) -> ir.Value:
    """Lane-wise numba ``min(acc, v)``: v where v < acc (ordered), else acc."""
    return builder.select(builder.fcmp_ordered("<", v, acc), v, acc)


def _row_ptr(context, builder: ir.IRBuilder, aty, ary: ir.Value, inds: list, vt: ir.Type) -> ir.Value:
    """Pointer to ary[inds] cast to ``vt`` (a row of WIDTH float64 or a packet scratch row)."""
    a = context.make_array(aty)(context, builder, ary)
    p = cgutils.get_item_pointer(context, builder, aty, a, inds, wraparound=False)
    return builder.bitcast(p, vt.as_pointer())


def _c_array(ty, dtype, ndim: int) -> bool:
    """Whether numba type ``ty`` is a C-contiguous array of ``dtype`` and ``ndim`` (the vector loads and stores
    of the intrinsics below address rows as contiguous WIDTH-element blocks)."""
    return isinstance(ty, types.Array) and ty.layout == "C" and ty.dtype == dtype and ty.ndim == ndim


def _over_set_bits(builder: ir.IRBuilder, mask: ir.Value, init: ir.Value, step, name: str) -> ir.Value:
    """A loop over the set bits b of the i64 ``mask``, lowest first, carrying one value: acc = init, then
    acc = step(b, acc) per bit (``step`` emits its IR at the builder's position). Returns the final acc, with the
    builder after the loop."""
    zero = ir.Constant(_I64, 0)
    pre = builder.block
    head = builder.append_basic_block(name + "_head")
    body = builder.append_basic_block(name + "_body")
    done = builder.append_basic_block(name + "_done")
    builder.branch(head)
    builder.position_at_end(head)
    m = builder.phi(_I64)
    acc = builder.phi(init.type)
    m.add_incoming(mask, pre)
    acc.add_incoming(init, pre)
    builder.cbranch(builder.icmp_unsigned("!=", m, zero), body, done)
    builder.position_at_end(body)
    b = builder.cttz(m, ir.Constant(ir.IntType(1), 0))
    m_next = builder.and_(m, builder.sub(m, ir.Constant(_I64, 1)))
    acc_next = step(b, acc)
    m.add_incoming(m_next, builder.block)
    acc.add_incoming(acc_next, builder.block)
    builder.branch(head)
    builder.position_at_end(done)
    return acc


def _by_width(context, builder: ir.IRBuilder, wty, wb: ir.Value, i: ir.Value, test) -> ir.Value:
    """``test(WIDTH // 2)`` where wide node i has at most WIDTH / 2 children (its children come first, an empty
    one has every plane at +inf: the box of column WIDTH / 2 is empty), else ``test(WIDTH)``; the i64 result.
    Most nodes near the leaves have 2-4 children, so half the vector work is skipped there. Where the narrow
    test runs, outputs beyond column WIDTH / 2 are left as they were and their mask bits are 0 (the full test
    may report a ray with tmax = inf as entering an empty child, t0 = t1 = inf: an empty leaf either way)."""
    half = WIDTH // 2
    p = _row_ptr(context, builder, wty, wb, [i, ir.Constant(_I64, 0), ir.Constant(_I64, half)], ir.FloatType())
    narrow = builder.fcmp_ordered("==", builder.load(p, align=4), ir.Constant(ir.FloatType(), float("inf")))
    with builder.if_else(narrow) as (then, otherwise):
        with then:
            m_narrow = test(half)
            bb_narrow = builder.block
        with otherwise:
            m_wide = test(WIDTH)
            bb_wide = builder.block
    res = builder.phi(_I64)
    res.add_incoming(m_narrow, bb_narrow)
    res.add_incoming(m_wide, bb_wide)
    return res


def _slab_intrinsic(wbox, dist, store_dist: bool):
    """Signature and code of ``_slab_mask`` (with ``store_dist``) and ``_slab_hit_mask``."""
    if not (_c_array(wbox, types.float32, 3) and _c_array(dist, types.float64, 1)):
        return None
    i64, f64 = types.int64, types.float64  # the arguments are cast to these at the call
    sig = i64(wbox, i64, i64, i64, i64, f64, f64, f64, f64, f64, f64, f64, f64, dist)

    def codegen(context, builder, signature, args):
        wb, i, nx, ny, nz, ox, oy, oz, ix, iy, iz, tmin, tmax, dist = args
        wty, dty = signature.args[0], signature.args[13]
        zero, three = ir.Constant(_I64, 0), ir.Constant(_I64, 3)
        f32 = ir.FloatType()
        ox, oy, oz, ix, iy, iz, tmin, tmax = (builder.fptrunc(v, f32) for v in (ox, oy, oz, ix, iy, iz, tmin, tmax))

        def far(n):
            return builder.select(builder.icmp_signed("<", n, three), builder.add(n, three), builder.sub(n, three))

        vt = ir.VectorType(f32, WIDTH)

        def plane(r, o, inv):
            row = builder.load(_row_ptr(context, builder, wty, wb, [i, r, zero], vt), align=4)
            return builder.fmul(builder.fsub(row, _splat(builder, o, vt)), _splat(builder, inv, vt))

        ax, ay, az = plane(nx, ox, ix), plane(ny, oy, iy), plane(nz, oz, iz)
        bx, by, bz = plane(far(nx), ox, ix), plane(far(ny), oy, iy), plane(far(nz), oz, iz)
        t0 = _vmax(builder, _splat(builder, tmin, vt), _vmax(builder, ax, _vmax(builder, ay, az)))
        t1 = _vmin(builder, _splat(builder, tmax, vt), _vmin(builder, bx, _vmin(builder, by, bz)))
        hit = builder.fcmp_ordered("<=", t0, builder.fmul(t1, ir.Constant(vt, [float(SLACK32)] * WIDTH)))
        fin = builder.fcmp_ordered("<", t0, ir.Constant(vt, [float("inf")] * WIDTH))
        if store_dist:
            t0d = builder.fpext(t0, ir.VectorType(ir.DoubleType(), WIDTH))
            builder.store(t0d, _row_ptr(context, builder, dty, dist, [zero], t0d.type), align=8)
        return builder.zext(builder.bitcast(builder.and_(hit, fin), ir.IntType(WIDTH)), _I64)

    return sig, codegen


@intrinsic
def _slab_mask(typingctx, wbox, i, nx, ny, nz, ox, oy, oz, ix, iy, iz, tmin, tmax, dist):
    """``_wide_slabs`` in vector form, in float32 (one AVX register holds a plane of all WIDTH children): the
    WIDTH entry distances t0 go into ``dist`` (all of them, also of the missed boxes), the return value has bit c
    set where the ray enters child c: t0 <= t1 SLACK32 and t0 < inf (exactly the children ``_wide_slabs`` gives a
    finite distance). The origin, inverse direction and limits are rounded to float32; the boxes' padding
    (``ray_arrays``) covers the origin's rounding and SLACK32 the relative rounding of the distances, so a box the
    ray enters within (tmin, tmax) is never missed (a few more may be visited; the triangles decide the hits)."""
    return _slab_intrinsic(wbox, dist, True)


@intrinsic
def _slab_hit_mask(typingctx, wbox, i, nx, ny, nz, ox, oy, oz, ix, iy, iz, tmin, tmax, dist):
    """``_slab_mask`` without storing the entry distances (``dist`` is left as it was): for traversals that
    visit the children in any order."""
    return _slab_intrinsic(wbox, dist, False)


@intrinsic
def _packet_box_masks(typingctx, wbox, i, ox, oy, oz, pinv, live, tmin, cmask):
    """The packet's box test of wide node i, in float32 as ``_slab_mask``: for every ray b of ``live`` (inverse
    direction and current limit in pinv[b]) and child c, the slab test of ``packet_hits`` (t0 <= t1 SLACK32, near
    and far plane by min / max, planes offset by the shared origin once per node); cmask[c] gets the rays that
    enter child c, the return value has bit c set where cmask[c] != 0."""
    if not (_c_array(wbox, types.float32, 3) and _c_array(pinv, types.float64, 2)
            and _c_array(cmask, types.int64, 1)):
        return None
    i64, f64 = types.int64, types.float64
    sig = i64(wbox, i64, f64, f64, f64, pinv, i64, f64, cmask)

    def codegen(context, builder, signature, args):
        wb, i, ox, oy, oz, pinv, live, tmin, cmask = args
        wty, pty, cty = signature.args[0], signature.args[5], signature.args[8]
        zero = ir.Constant(_I64, 0)
        f32 = ir.FloatType()
        ox, oy, oz, tmin = (builder.fptrunc(v, f32) for v in (ox, oy, oz, tmin))

        def test(w):  # the first w children (the others empty)
            vt, vi = ir.VectorType(f32, w), ir.VectorType(_I64, w)
            diff = []
            for r, o in enumerate((ox, oy, oz, ox, oy, oz)):
                row = builder.load(_row_ptr(context, builder, wty, wb, [i, ir.Constant(_I64, r), zero], vt), align=4)
                diff.append(builder.fsub(row, _splat(builder, o, vt)))
            vtmin = _splat(builder, tmin, vt)
            slack = ir.Constant(vt, [float(SLACK32)] * w)

            def ray(b, acc):  # ray b of the packet against the w children
                p = _row_ptr(context, builder, pty, pinv, [b, zero], ir.DoubleType())
                inv = [_splat(builder, builder.fptrunc(builder.load(builder.gep(p, [ir.Constant(_I64, k)]), align=8),
                                                       f32), vt) for k in range(4)]
                lo = [builder.fmul(diff[k], inv[k]) for k in range(3)]
                hi = [builder.fmul(diff[k + 3], inv[k]) for k in range(3)]
                near = [_vmin(builder, lo[k], hi[k]) for k in range(3)]
                far = [_vmax(builder, lo[k], hi[k]) for k in range(3)]
                t0 = _vmax(builder, vtmin, _vmax(builder, near[0], _vmax(builder, near[1], near[2])))
                t1 = _vmin(builder, inv[3], _vmin(builder, far[0], _vmin(builder, far[1], far[2])))
                hit = builder.fcmp_ordered("<=", t0, builder.fmul(t1, slack))
                bit = _splat(builder, builder.shl(ir.Constant(_I64, 1), b), vi)
                return builder.or_(acc, builder.select(hit, bit, ir.Constant(vi, [0] * w)))

            acc = _over_set_bits(builder, live, ir.Constant(vi, [0] * w), ray, "pk")
            builder.store(acc, _row_ptr(context, builder, cty, cmask, [zero], vi), align=8)
            nz = builder.icmp_unsigned("!=", acc, ir.Constant(vi, [0] * w))
            return builder.zext(builder.bitcast(nz, ir.IntType(w)), _I64)

        return _by_width(context, builder, wty, wb, i, test)

    return sig, codegen


_VL = ir.VectorType(ir.DoubleType(), LANES)


def _leaf_o_terms(builder: ir.IRBuilder, tri: list, o: tuple) -> tuple:
    """Lane-wise o-terms of the triangle test: s = o - v0, q = s x e1, tq = e2 . q (``_leaf_triangle``'s
    operations in its order). ``tri``: the 9 rows (v0, e1, e2) as vectors, ``o``: the origin's 3 scalars."""
    sx, sy, sz = (builder.fsub(_splat(builder, o[k], _VL), tri[k]) for k in range(3))
    e1x, e1y, e1z = tri[3:6]
    e2x, e2y, e2z = tri[6:9]
    fm, fs, fa = builder.fmul, builder.fsub, builder.fadd
    qx = fs(fm(sy, e1z), fm(sz, e1y))
    qy = fs(fm(sz, e1x), fm(sx, e1z))
    qz = fs(fm(sx, e1y), fm(sy, e1x))
    tq = fa(fa(fm(e2x, qx), fm(e2y, qy)), fm(e2z, qz))
    return (sx, sy, sz), (qx, qy, qz), tq


def _leaf_ray(builder: ir.IRBuilder, tri: list, s_: tuple, q: tuple, tq: ir.Value, d: tuple, tmin: ir.Value):
    """Lane-wise ray-triangle test (``_leaf_triangle`` with its operations in its order, the o-terms given):
    (mask of u >= 0, u <= 1, v >= 0, u + v <= 1, tmin < t as <LANES x i1>, t)."""
    fm, fs, fa = builder.fmul, builder.fsub, builder.fadd
    dx, dy, dz = (_splat(builder, x, _VL) for x in d)
    e1x, e1y, e1z = tri[3:6]
    e2x, e2y, e2z = tri[6:9]
    px = fs(fm(dy, e2z), fm(dz, e2y))
    py = fs(fm(dz, e2x), fm(dx, e2z))
    pz = fs(fm(dx, e2y), fm(dy, e2x))
    det = fa(fa(fm(e1x, px), fm(e1y, py)), fm(e1z, pz))
    fabs = cgutils.get_or_insert_function(builder.module, ir.FunctionType(_VL, [_VL]), f"llvm.fabs.v{LANES}f64")
    tiny = ir.Constant(_VL, [1e-300] * LANES)
    det = builder.select(builder.fcmp_ordered("<", builder.call(fabs, [det]), tiny), tiny, det)
    inv = builder.fdiv(ir.Constant(_VL, [1.0] * LANES), det)
    u = fm(fa(fa(fm(s_[0], px), fm(s_[1], py)), fm(s_[2], pz)), inv)
    v = fm(fa(fa(fm(dx, q[0]), fm(dy, q[1])), fm(dz, q[2])), inv)
    t = fm(tq, inv)
    zero, one = ir.Constant(_VL, [0.0] * LANES), ir.Constant(_VL, [1.0] * LANES)
    ok = builder.and_(builder.fcmp_ordered(">=", u, zero), builder.fcmp_ordered("<=", u, one))
    ok = builder.and_(ok, builder.fcmp_ordered(">=", v, zero))
    ok = builder.and_(ok, builder.fcmp_ordered("<=", fa(u, v), one))
    ok = builder.and_(ok, builder.fcmp_ordered("<", _splat(builder, tmin, _VL), t))
    return ok, t


def _load_block(context, builder: ir.IRBuilder, bty, tblk: ir.Value, blk: ir.Value) -> list:
    return [builder.load(_row_ptr(context, builder, bty, tblk, [blk, ir.Constant(_I64, r), ir.Constant(_I64, 0)],
                                  _VL), align=8) for r in range(9)]


def _mask_bits(builder: ir.IRBuilder, m: ir.Value, n: int) -> ir.Value:
    return builder.zext(builder.bitcast(m, ir.IntType(n)), _I64)


@intrinsic
def _leaf_hits(typingctx, tblk, blk, ox, oy, oz, dx, dy, dz, tmin, tout):
    """The ray o + t d against the LANES triangles of leaf block ``blk`` at once: bit l set where lane l's
    triangle is hit with tmin < t (barycentrics u, v >= 0, u + v <= 1), every lane's t into tout[:LANES]
    (``leaf_hits_scalar`` in vector form, the same operations per lane, so the same t)."""
    if not (_c_array(tblk, types.float64, 3) and _c_array(tout, types.float64, 1)):
        return None
    i64, f64 = types.int64, types.float64
    sig = i64(tblk, i64, f64, f64, f64, f64, f64, f64, f64, tout)

    def codegen(context, builder, signature, args):
        tb, blk, ox, oy, oz, dx, dy, dz, tmin, tout = args
        tri = _load_block(context, builder, signature.args[0], tb, blk)
        s_, q, tq = _leaf_o_terms(builder, tri, (ox, oy, oz))
        ok, t = _leaf_ray(builder, tri, s_, q, tq, (dx, dy, dz), tmin)
        builder.store(t, _row_ptr(context, builder, signature.args[9], tout, [ir.Constant(_I64, 0)], _VL), align=8)
        return _mask_bits(builder, ok, LANES)

    return sig, codegen


@intrinsic
def _packet_leaf_hits(typingctx, tblk, blk, ox, oy, oz, dirs, r0, rays, tmin, pmask, pt):
    """``_leaf_hits`` for every ray b of the bit mask ``rays`` (direction dirs[r0 + b], origin o shared, so the
    o-terms are computed once per block): lane mask into pmask[b], the lanes' t into pt[b, :LANES]. Returns
    the rays with a nonzero lane mask."""
    if not (_c_array(tblk, types.float64, 3) and _c_array(dirs, types.float64, 2)
            and _c_array(pmask, types.int64, 1) and _c_array(pt, types.float64, 2)):
        return None
    i64, f64 = types.int64, types.float64
    sig = i64(tblk, i64, f64, f64, f64, dirs, i64, i64, f64, pmask, pt)

    def codegen(context, builder, signature, args):
        tb, blk, ox, oy, oz, dirs, r0, rays, tmin, pmask, pt = args
        bty, dty, mty, tty = (signature.args[k] for k in (0, 5, 9, 10))
        zero = ir.Constant(_I64, 0)
        tri = _load_block(context, builder, bty, tb, blk)
        s_, q, tq = _leaf_o_terms(builder, tri, (ox, oy, oz))

        def ray(b, anyhit):  # ray b of the packet against the block's 4 triangles
            dp = _row_ptr(context, builder, dty, dirs, [builder.add(r0, b), zero], ir.DoubleType())
            d = tuple(builder.load(builder.gep(dp, [ir.Constant(_I64, k)]), align=8) for k in range(3))
            ok, t = _leaf_ray(builder, tri, s_, q, tq, d, tmin)
            bits = _mask_bits(builder, ok, LANES)
            builder.store(bits, _row_ptr(context, builder, mty, pmask, [b], _I64), align=8)
            builder.store(t, _row_ptr(context, builder, tty, pt, [b, zero], _VL), align=8)
            hit = builder.zext(builder.icmp_unsigned("!=", bits, zero), _I64)
            return builder.or_(anyhit, builder.shl(hit, b))

        return _over_set_bits(builder, rays, zero, ray, "lf")

    return sig, codegen


@njit(cache=True, forceinline=True, error_model="numpy")
def _wide_slabs(wbox, i, nx, ny, nz, ox, oy, oz, ix, iy, iz, tmin, tmax, dist) -> None:
    """Slab test of the ray against the WIDTH child boxes of wide node i (nx, ny, nz: near-plane rows from
    ``_inverse``): entry distances into dist, inf where the ray misses a box within (tmin, tmax). With
    t_a = (plane_a - o_a) / d_a: t0 = max(tmin, t_near x, t_near y, t_near z), t1 = min(tmax, t_far x, y, z),
    hit where t0 <= t1 SLACK32, all in float32 (the float64 arguments rounded once). The scalar reference of
    ``_slab_mask``, which the queries use."""
    fx, fy, fz = (nx + 3) % 6, (ny + 3) % 6, (nz + 3) % 6
    ox, oy, oz = np.float32(ox), np.float32(oy), np.float32(oz)
    ix, iy, iz = np.float32(ix), np.float32(iy), np.float32(iz)
    tmin, tmax = np.float32(tmin), np.float32(tmax)
    for c in range(WIDTH):
        t0 = max(tmin, max((wbox[i, nx, c] - ox) * ix, max((wbox[i, ny, c] - oy) * iy, (wbox[i, nz, c] - oz) * iz)))
        t1 = min(tmax, min((wbox[i, fx, c] - ox) * ix, min((wbox[i, fy, c] - oy) * iy, (wbox[i, fz, c] - oz) * iz)))
        dist[c] = t0 if t0 <= t1 * SLACK32 else np.inf


@njit(cache=True, _nrt=False, error_model="numpy")
def packet_box_masks_scalar(wbox, i, ox, oy, oz, pinv, live, tmin, diff, cmask) -> int:
    """Scalar reference of ``_packet_box_masks`` (the packet's box loop before it was written as vector IR), in
    float32 as ``_wide_slabs``: with d = box plane - origin and a = d ix (per axis, both planes), t0 = max(tmin,
    max_axes min(a_lo, a_hi)), t1 = min(tlim, min_axes max(a_lo, a_hi)); ray b enters child c where t0 <= t1
    SLACK32. ``diff``: (6, WIDTH) scratch (its float64 entries hold the float32 differences exactly)."""
    o32 = (np.float32(ox), np.float32(oy), np.float32(oz))
    tmin = np.float32(tmin)
    for c in range(WIDTH):
        for r in range(6):
            diff[r, c] = wbox[i, r, c] - o32[r % 3]
        cmask[c] = 0
    m = live
    while m != 0:
        b = trailing_zeros(m)
        m &= m - 1
        ix, iy, iz, tlim = np.float32(pinv[b, 0]), np.float32(pinv[b, 1]), np.float32(pinv[b, 2]), \
            np.float32(pinv[b, 3])
        bit = np.int64(1) << b
        for c in range(WIDTH):
            ax, bx = np.float32(diff[0, c]) * ix, np.float32(diff[3, c]) * ix
            ay, by = np.float32(diff[1, c]) * iy, np.float32(diff[4, c]) * iy
            az, bz = np.float32(diff[2, c]) * iz, np.float32(diff[5, c]) * iz
            t0 = max(tmin, max(min(ax, bx), max(min(ay, by), min(az, bz))))
            t1 = min(tlim, min(max(ax, bx), min(max(ay, by), max(az, bz))))
            cmask[c] |= bit & -np.int64(t0 <= t1 * SLACK32)
    kids = 0
    for c in range(WIDTH):
        if cmask[c] != 0:
            kids |= 1 << c
    return kids


# The traversal loops index their stacks with np.uint64: numba then leaves out the negative-index wraparound
# (a sign test and an add per access), which a signed index gets even where it is never negative (2.5 % of the
# forward work, paired)
@njit(cache=True, forceinline=True, error_model="numpy")
def _push_masked(wchild, i, mask, dist, stack, sp) -> int:
    """Push the children of wide node i in the bit mask ``mask`` (from ``_slab_mask``), the nearest by entry
    distance ``dist`` on top; new sp. A stack of the tree's ``RayTree.stack_size`` holds them all; the test
    against its end only keeps a smaller stack's caller from writing past it."""
    base = sp
    cap = stack.shape[0]
    m = mask
    while m != 0 and sp < cap:
        c = trailing_zeros(m)
        m &= m - 1
        tc = dist[np.uint64(c)]
        k = sp
        while k > base and dist[stack[np.uint64(k - 1)]] < tc:
            stack[np.uint64(k)] = stack[np.uint64(k - 1)]
            k -= 1
        stack[np.uint64(k)] = c
        sp += 1
    for k in range(base, sp):
        stack[np.uint64(k)] = wchild[np.uint64(i), np.uint64(stack[np.uint64(k)])]
    return sp


@njit(cache=True, forceinline=True, error_model="numpy")
def _push_unsorted(wchild, i, mask, stack, sp) -> int:
    """Push the children of wide node i in the bit mask ``mask`` in column order; new sp (stack size as
    ``_push_masked``)."""
    cap = stack.shape[0]
    m = mask
    while m != 0 and sp < cap:
        c = trailing_zeros(m)
        m &= m - 1
        stack[np.uint64(sp)] = wchild[np.uint64(i), np.uint64(c)]
        sp += 1
    return sp


@njit(cache=True, forceinline=True, error_model="numpy")
def ray_triangle(tris, k, o, d) -> tuple[float, float, float]:
    """(t, u, v) of the ray o + t d with the plane of triangle k; barycentrics (1 - u - v, u, v)."""
    e1x, e1y, e1z = tris[k, 1, 0] - tris[k, 0, 0], tris[k, 1, 1] - tris[k, 0, 1], tris[k, 1, 2] - tris[k, 0, 2]
    e2x, e2y, e2z = tris[k, 2, 0] - tris[k, 0, 0], tris[k, 2, 1] - tris[k, 0, 1], tris[k, 2, 2] - tris[k, 0, 2]
    px, py, pz = d[1] * e2z - d[2] * e2y, d[2] * e2x - d[0] * e2z, d[0] * e2y - d[1] * e2x
    det = e1x * px + e1y * py + e1z * pz
    if abs(det) < 1e-300:
        det = 1e-300
    inv = 1.0 / det
    sx, sy, sz = o[0] - tris[k, 0, 0], o[1] - tris[k, 0, 1], o[2] - tris[k, 0, 2]
    u = (sx * px + sy * py + sz * pz) * inv
    qx, qy, qz = sy * e1z - sz * e1y, sz * e1x - sx * e1z, sx * e1y - sy * e1x
    v = (d[0] * qx + d[1] * qy + d[2] * qz) * inv
    t = (e2x * qx + e2y * qy + e2z * qz) * inv
    return t, u, v


@njit(cache=True, _nrt=False, error_model="numpy")
def first_hit(ray_nodes, o, d, tmin, tmax, stack, dist) -> tuple[int, float]:
    """Nearest triangle hit by o + t d with tmin < t < tmax: (triangle or -1, t). ``ray_nodes``: a tree's
    ``RayTree``; ``stack``: int64 scratch of at least its ``stack_size``, ``dist``: float64 scratch of ``WIDTH``."""
    wbox, wchild, tblk, tord = ray_nodes.wbox, ray_nodes.wchild, ray_nodes.tblk, ray_nodes.tord
    ix, iy, iz, nx, ny, nz = _inverse(d)
    ox, oy, oz = o[0], o[1], o[2]
    dx, dy, dz = d[0], d[1], d[2]
    best, best_t = -1, tmax
    stack[0] = 0
    sp = 1
    while sp > 0:
        sp -= 1
        i = stack[np.uint64(sp)]
        if i < 0:
            b0, b1 = leaf_blocks(i)
            for blk in range(b0, b1):
                hm = _leaf_hits(tblk, blk, ox, oy, oz, dx, dy, dz, tmin, dist)
                while hm != 0:  # lanes in order: ties go to the first triangle, as one at a time
                    lane = trailing_zeros(hm)
                    hm &= hm - 1
                    if dist[np.uint64(lane)] < best_t:
                        best, best_t = tord[np.uint64(blk), np.uint64(lane)], dist[np.uint64(lane)]
            continue
        mask = _slab_mask(wbox, i, nx, ny, nz, ox, oy, oz, ix, iy, iz, tmin, best_t, dist)
        sp = _push_masked(wchild, i, mask, dist, stack, sp)
    return best, best_t


# ``first_hit`` compiled into its caller: for the free flights, one call per path vertex, where a call passes every
# field of the tree's arrays on the stack. Not cached itself (it would share ``first_hit``'s cache file); its cached
# callers are recompiled after an edit of this module (``numba_kernels``: the cache stamp covers every kernel module)
first_hit_inlined = njit(cache=False, forceinline=True, error_model="numpy")(first_hit.py_func)


@njit(cache=True, _nrt=False, error_model="numpy")
def closest_point_triangle(tris, k, p, out) -> float:
    """Closest point on triangle k to p: barycentrics into ``out`` (3,), returns the distance."""
    ax, ay, az = tris[k, 0, 0], tris[k, 0, 1], tris[k, 0, 2]
    abx, aby, abz = tris[k, 1, 0] - ax, tris[k, 1, 1] - ay, tris[k, 1, 2] - az
    acx, acy, acz = tris[k, 2, 0] - ax, tris[k, 2, 1] - ay, tris[k, 2, 2] - az
    apx, apy, apz = p[0] - ax, p[1] - ay, p[2] - az
    d1 = abx * apx + aby * apy + abz * apz
    d2 = acx * apx + acy * apy + acz * apz
    bpx, bpy, bpz = apx - abx, apy - aby, apz - abz
    d3 = abx * bpx + aby * bpy + abz * bpz
    d4 = acx * bpx + acy * bpy + acz * bpz
    cpx, cpy, cpz = apx - acx, apy - acy, apz - acz
    d5 = abx * cpx + aby * cpy + abz * cpz
    d6 = acx * cpx + acy * cpy + acz * cpz
    va = d3 * d6 - d5 * d4
    vb = d5 * d2 - d1 * d6
    vc = d1 * d4 - d3 * d2
    if d1 <= 0.0 and d2 <= 0.0:
        w0, w1, w2 = 1.0, 0.0, 0.0
    elif d3 >= 0.0 and d4 <= d3:
        w0, w1, w2 = 0.0, 1.0, 0.0
    elif d6 >= 0.0 and d5 <= d6:
        w0, w1, w2 = 0.0, 0.0, 1.0
    elif vc <= 0.0 and d1 >= 0.0 and d3 <= 0.0:
        s = d1 / (d1 - d3)
        w0, w1, w2 = 1.0 - s, s, 0.0
    elif vb <= 0.0 and d2 >= 0.0 and d6 <= 0.0:
        s = d2 / (d2 - d6)
        w0, w1, w2 = 1.0 - s, 0.0, s
    elif va <= 0.0 and d4 - d3 >= 0.0 and d5 - d6 >= 0.0:
        s = (d4 - d3) / ((d4 - d3) + (d5 - d6))
        w0, w1, w2 = 0.0, 1.0 - s, s
    else:
        den = 1.0 / (va + vb + vc)
        w1, w2 = vb * den, vc * den
        w0 = 1.0 - w1 - w2
    out[0], out[1], out[2] = w0, w1, w2
    dx = p[0] - (ax + w1 * abx + w2 * acx)
    dy = p[1] - (ay + w1 * aby + w2 * acy)
    dz = p[2] - (az + w1 * abz + w2 * acz)
    return np.sqrt(dx * dx + dy * dy + dz * dz)


@njit(cache=True, forceinline=True, error_model="numpy")
def _box_dist2(lo, hi, i, p) -> float:
    s = 0.0
    for a in range(3):
        if p[a] < lo[i, a]:
            s += (lo[i, a] - p[a]) ** 2
        elif p[a] > hi[i, a]:
            s += (p[a] - hi[i, a]) ** 2
    return s


@njit(cache=True, _nrt=False, error_model="numpy")
def closest_triangle(nodes, root, tris, p, stack, bary, max_dist=np.inf) -> tuple[int, float]:
    """Triangle of the tree at ``root`` nearest to point p, (triangle, distance), or (-1, max_dist) when
    none is closer than ``max_dist``. ``nodes``: ``BinaryNodes``; ``stack``, ``bary``: scratch (int64 of at least
    the tree's ``TriangleBVH.stack_size``, 3 float64)."""
    lo, hi, left, start, count, order = nodes.lo, nodes.hi, nodes.left, nodes.start, nodes.count, nodes.order
    best, best_d = -1, max_dist
    stack[0] = root
    sp = 1
    while sp > 0:
        sp -= 1
        i = stack[sp]
        if _box_dist2(lo, hi, i, p) >= best_d * best_d:
            continue
        if count[i] > 0:
            for j in range(start[i], start[i] + count[i]):
                k = order[j]
                dist = closest_point_triangle(tris, k, p, bary)
                if dist < best_d:
                    best, best_d = k, dist
            continue
        a, b = left[i], left[i] + 1
        da, db = _box_dist2(lo, hi, a, p), _box_dist2(lo, hi, b, p)
        if da > db:
            a, b, da, db = b, a, db, da
        if sp + 2 <= stack.shape[0]:  # always, with a stack of the tree's stack_size
            stack[sp] = b
            stack[sp + 1] = a
            sp += 2
    return best, best_d


@njit(cache=True, forceinline=True, error_model="numpy")
def hits_until_stop(ray_nodes, stops, o, d, tmin, tmax, stack, dist, buf_tri, buf_t, nearest_first) -> int:
    """Every triangle hit by o + t d with tmin < t < tmax up to the nearest one with ``stops[k]``, in one
    traversal (boxes beyond the nearest stopping hit found so far are skipped). Hits go unsorted into
    ``buf_tri``, ``buf_t``; some beyond the final stopping hit may be among them. Returns the number
    of hits, which exceeds the buffer when it overflowed (the extra ones are not stored). ``nearest_first``:
    visit a node's children nearest first, so that a stopping hit found early culls the boxes behind it (a
    path's flight through air, which usually stops at the nearest tooth); else in column order, for shadow
    rays: most reach their light unblocked and visit every box they cross in any order, and sorting cost more
    than the culling it bought."""
    wbox, wchild, tblk, tord = ray_nodes.wbox, ray_nodes.wchild, ray_nodes.tblk, ray_nodes.tord
    ix, iy, iz, nx, ny, nz = _inverse(d)
    ox, oy, oz = o[0], o[1], o[2]
    dx, dy, dz = d[0], d[1], d[2]
    cap = buf_t.shape[0]
    n = 0
    tlim = tmax
    stack[0] = 0
    sp = 1
    while sp > 0:
        sp -= 1
        i = stack[np.uint64(sp)]
        if i < 0:
            b0, b1 = leaf_blocks(i)
            for blk in range(b0, b1):
                hm = _leaf_hits(tblk, blk, ox, oy, oz, dx, dy, dz, tmin, dist)
                while hm != 0:
                    lane = trailing_zeros(hm)
                    hm &= hm - 1
                    t = dist[lane]
                    if t <= tlim and t < tmax:
                        k = tord[blk, lane]
                        if n < cap:
                            buf_tri[n] = k
                            buf_t[n] = t
                        n += 1
                        if stops[k]:
                            tlim = t
            continue
        if nearest_first:
            mask = _slab_mask(wbox, i, nx, ny, nz, ox, oy, oz, ix, iy, iz, tmin, tlim, dist)
            sp = _push_masked(wchild, i, mask, dist, stack, sp)
        else:
            mask = _slab_hit_mask(wbox, i, nx, ny, nz, ox, oy, oz, ix, iy, iz, tmin, tlim, dist)
            sp = _push_unsorted(wchild, i, mask, stack, sp)
    return n


@njit(cache=True, _nrt=False, error_model="numpy")
def packet_hits(ray_nodes, stops, o, dirs, tmaxs, r0, mask, tmin, pinv, pstack, cmask, pmask, pt, buf_tri, buf_t,
                counts):
    """``hits_until_stop`` for the rays o + t dirs[r0 + b] with tmin < t < tmaxs[r0 + b], for every bit b
    set in ``mask`` (b < ``PACKET``), in one traversal: the rays share their origin, so each node's box
    planes are offset by o once for the packet and each triangle's o-terms once (the same per-ray
    arithmetic as ``hits_until_stop``, hence the same hits). Ray r's hits go into buf_tri[r], buf_t[r],
    their number (which may exceed the buffer) into counts[r]. Scratch: pinv (PACKET, 4) float64, pstack (the
    tree's stack_size, 2) int64, cmask (WIDTH,) int64, pmask (PACKET,) int64, pt (PACKET, LANES) float64. The box
    and triangle tests run as vector code (``_packet_box_masks``, ``_packet_leaf_hits``; scalar references
    ``packet_box_masks_scalar``, ``leaf_hits_scalar``)."""
    wbox, wchild, tblk, tord = ray_nodes.wbox, ray_nodes.wchild, ray_nodes.tblk, ray_nodes.tord
    cap = buf_t.shape[1]
    m = mask
    while m != 0:
        b = trailing_zeros(m)
        m &= m - 1
        r = r0 + b
        ix, iy, iz, _, _, _ = _inverse(dirs[r])
        pinv[b, 0], pinv[b, 1], pinv[b, 2], pinv[b, 3] = ix, iy, iz, tmaxs[r]
        counts[r] = 0
    ox, oy, oz = o[0], o[1], o[2]
    pstack[0, 0], pstack[0, 1] = 0, mask
    sp = 1
    while sp > 0:
        sp -= 1
        i, live = pstack[sp, 0], pstack[sp, 1]
        kids = _packet_box_masks(wbox, i, ox, oy, oz, pinv, live, tmin, cmask)
        while kids != 0:
            c = trailing_zeros(kids)
            kids &= kids - 1
            cm = cmask[c]
            ch = wchild[i, c]
            if ch >= 0:
                if sp < pstack.shape[0]:
                    pstack[sp, 0], pstack[sp, 1] = ch, cm
                    sp += 1
                continue
            b0, b1 = leaf_blocks(ch)
            for blk in range(b0, b1):
                mm = _packet_leaf_hits(tblk, blk, ox, oy, oz, dirs, r0, cm, tmin, pmask, pt)
                while mm != 0:
                    b = trailing_zeros(mm)
                    mm &= mm - 1
                    r = r0 + b
                    hm = pmask[b]
                    while hm != 0:  # lanes in order, the ray's limit updated as one triangle at a time
                        lane = trailing_zeros(hm)
                        hm &= hm - 1
                        t = pt[b, lane]
                        if t <= pinv[b, 3] and t < tmaxs[r]:
                            k = tord[blk, lane]
                            n = counts[r]
                            if n < cap:
                                buf_tri[r, n] = k
                                buf_t[r, n] = t
                            counts[r] = n + 1
                            if stops[k]:
                                pinv[b, 3] = t
    return 0
