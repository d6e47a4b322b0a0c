"""``TriangleBVH.refit``: a tree built on the dentin at c = 0 and refitted to moved dentin triangles must
answer every query as a tree built on the moved triangles (first hit: same triangle and distance; closest
triangle: same triangle and distance, no tolerance), its boxes must be the tight bounds of what lies
below them, and the compiled tracer, which refits (``path_tracer_compiled._trees``), must render the same
image and gradient as with trees built on the moved geometry."""

from __future__ import annotations

import numpy as np
import pytest

pytest.importorskip("numba")

from numba import njit  # noqa: E402

from material_structures.core.teeth import bvh  # noqa: E402
from material_structures.core.teeth.bvh import TriangleBVH  # noqa: E402
from material_structures.core.teeth.compiled_scene import CompiledScene  # noqa: E402
from material_structures.core.teeth.synthetic import make_scene  # noqa: E402

pytestmark = pytest.mark.heavy  # compiles the queries (about 10 s): outside `make test-fast`

C_MOVED = np.array([0.6, -0.5, 0.4])  # far across the coefficients' range (-0.8, 0.8)


@njit(cache=False)
def _first_hits(ray_nodes, o, d):
    stack = np.empty(bvh.STACK_SIZE, dtype=np.int64)
    dist = np.empty(bvh.WIDTH)
    tri = np.empty(len(o), dtype=np.int64)
    t = np.empty(len(o))
    for i in range(len(o)):
        tri[i], t[i] = bvh.first_hit(ray_nodes, o[i], d[i], 0.0, np.inf, stack, dist)
    return tri, t


@njit(cache=False)
def _closest(nodes, root, tris, pts):
    stack = np.empty(bvh.STACK_SIZE, dtype=np.int64)
    bary = np.empty(3)
    tri = np.empty(len(pts), dtype=np.int64)
    q = np.empty(len(pts))
    for i in range(len(pts)):
        tri[i], q[i] = bvh.closest_triangle(nodes, root, tris, pts[i], stack, bary, np.inf)
    return tri, q


def _rest_and_moved() -> tuple[CompiledScene, CompiledScene]:
    sc = make_scene(n_teeth=2)
    moved = sc.copy()
    for t in moved.teeth:
        t.c = C_MOVED.copy()
    rest = sc.copy()
    for t in rest.teeth:
        t.c = np.zeros(3)
    return CompiledScene(rest), CompiledScene(moved)


def test_refit_boxes_are_the_tight_bounds_of_what_lies_below():
    rest, moved = _rest_and_moved()
    assert np.abs(moved.tris_s - rest.tris_s).max() > 0.05  # the dentin did move
    np.testing.assert_array_equal(moved.tris_rest, rest.tris_s)
    tree = TriangleBVH(rest.tris_s).refit(moved.tris_s)
    below: dict[int, np.ndarray] = {}
    for node in range(len(tree.lo))[::-1]:
        if tree.count[node] > 0:
            below[node] = tree.order[tree.start[node]:tree.start[node] + tree.count[node]]
        else:
            below[node] = np.concatenate([below[tree.left[node]], below[tree.left[node] + 1]])
        pts = moved.tris_s[below[node]].reshape(-1, 3)
        np.testing.assert_array_equal(tree.lo[node], pts.min(axis=0))
        np.testing.assert_array_equal(tree.hi[node], pts.max(axis=0))
    assert sorted(below[0].tolist()) == list(range(len(moved.tris_s)))


def test_refitted_tree_answers_queries_as_a_fresh_build():
    rest, moved = _rest_and_moved()
    rng = np.random.default_rng(11)
    lo, hi = moved.tris_s.reshape(-1, 3).min(axis=0), moved.tris_s.reshape(-1, 3).max(axis=0)
    # rays from around the teeth through points inside their bounds; points near the dentin
    o = rng.uniform(lo - 2.0, hi + 2.0, (20000, 3))
    d = rng.uniform(lo, hi, (20000, 3)) - o
    d /= np.linalg.norm(d, axis=1, keepdims=True)
    refit = TriangleBVH(rest.tris_s).refit(moved.tris_s).ray_arrays(moved.tris_s)
    fresh = TriangleBVH(moved.tris_s).ray_arrays(moved.tris_s)
    tri_r, t_r = _first_hits(refit, o, d)
    tri_f, t_f = _first_hits(fresh, o, d)
    assert (tri_f >= 0).sum() > 5000
    np.testing.assert_array_equal(tri_r, tri_f)
    np.testing.assert_array_equal(t_r, t_f)
    for tooth in range(len(moved.dentin)):
        ids = np.flatnonzero(moved.dentin_tooth == tooth)
        k = rng.choice(ids, 20000)
        pts = np.einsum("nv,nva->na", rng.dirichlet(np.ones(3), 20000), moved.tris_s[k])
        pts += rng.uniform(-0.3, 0.3, pts.shape)
        nodes_r, roots_r = TriangleBVH.merge([TriangleBVH(rest.tris_s, ids).refit(moved.tris_s)])
        nodes_f, roots_f = TriangleBVH.merge([TriangleBVH(moved.tris_s, ids)])
        tri_r, q_r = _closest(nodes_r, roots_r[0], moved.tris_s, pts)
        tri_f, q_f = _closest(nodes_f, roots_f[0], moved.tris_s, pts)
        np.testing.assert_array_equal(q_r, q_f)
        same = tri_r == tri_f  # a tie (a point nearest to a shared edge) may name either triangle
        assert same.mean() > 0.99
        np.testing.assert_array_equal(q_r[~same], q_f[~same])


def test_tracer_renders_the_same_with_refitted_trees(monkeypatch):
    from material_structures.core.teeth import path_tracer_compiled as ptc
    from material_structures.core.teeth.capture import default_rig
    from material_structures.core.teeth.path_tracer import RenderSettings, render
    from material_structures.core.teeth.synthetic import scene_target

    sc = make_scene(n_teeth=2)
    for t in sc.teeth:
        t.c = C_MOVED.copy()
    sc.blend_spread = 0.05
    cams, lights = default_rig(target=scene_target(sc), width=24, height=16, fov_x_deg=4.8)
    cams, lights = cams[:1], lights[:2]
    adj = np.random.default_rng(1).standard_normal((1, 2, 16, 24, 3))

    def run():
        ptc._TREES.clear()
        ptc._TOPOLOGIES.clear()
        img = render(sc, cams, lights, RenderSettings(spp=8, max_depth=None, seed=5))
        grad = render(sc, cams, lights, RenderSettings(spp=2, max_depth=None, seed=6), adjoint=adj)
        return img, grad

    calls = []
    real_refit = TriangleBVH.refit

    def counted(self, tris):
        calls.append(1)
        return real_refit(self, tris)

    monkeypatch.setattr(TriangleBVH, "refit", counted)
    img, grad = run()
    assert len(calls) == 3  # the scene tree and both teeth's dentin trees
    # the trees built on the moved geometry itself, as before refitting
    monkeypatch.setattr(TriangleBVH, "refit", lambda self, tris: TriangleBVH(tris, np.sort(self.order)))
    img0, grad0 = run()
    ptc._TREES.clear()
    ptc._TOPOLOGIES.clear()
    assert img.stats["path_vertices"] > 1000
    # the same hits in another traversal order: sums over a vertex's hits may round differently
    np.testing.assert_allclose(img.images, img0.images, rtol=1e-12, atol=1e-15)
    np.testing.assert_allclose(grad.grad, grad0.grad, rtol=1e-10, atol=1e-14 * np.abs(grad0.grad).max())
