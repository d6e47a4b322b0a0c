"""The dentin reach grid (``core.teeth.dentin_reach_grid``) against the closest-point search it lets the tracer
skip (``bvh.closest_triangle``): every point for which the search finds a dentin triangle within the reach must be
flagged by the grid (no tolerance: a miss would change an image), on points crowded around the dentin surface at
distances of the order of the reach and of a cell, and the grid must let most points of the tooth skip the search.
The compiled tracer's images and gradient with and without the grid must be bit-identical."""

from __future__ import annotations

import numpy as np
import pytest

pytest.importorskip("numba")

from numba import njit  # noqa: E402

from material_structures.core.teeth import bvh  # noqa: E402
from material_structures.core.teeth.compiled_scene import CompiledScene  # noqa: E402
from material_structures.core.teeth.dentin_reach_grid import (  # noqa: E402
    CELLS_LONGEST_AXIS,
    dentin_reach_grid,
    may_be_within_reach,
)
from material_structures.core.teeth.synthetic import make_scene  # noqa: E402

pytestmark = pytest.mark.heavy  # compiles the grid and the search (about 10 s): outside `make test-fast`


@njit(cache=False)
def _compare(grid, dnodes, droots, tris, tooth, pts, reach):
    """Per point: (search found a triangle within reach, grid flags the point)."""
    stack = np.empty(bvh.STACK_SIZE, dtype=np.int64)
    bary = np.empty(3)
    found = np.zeros(len(pts), dtype=np.bool_)
    flagged = np.zeros(len(pts), dtype=np.bool_)
    for i in range(len(pts)):
        tri, _ = bvh.closest_triangle(dnodes, droots[tooth], tris, pts[i], stack, bary, reach)
        found[i] = tri >= 0
        flagged[i] = may_be_within_reach(grid, tooth, pts[i])
    return found, flagged


def _scene():
    sc = make_scene(n_teeth=2)
    sc.blend_spread = 1e-5
    return CompiledScene(sc)


def _trees_and_grid(cs: CompiledScene, reach: float) -> tuple:
    """The dentin trees the tracer searches (nodes, roots) and the reach grid, built on ``cs``'s geometry itself
    (``path_tracer_compiled._trees`` refits trees built at c = 0, which answer the same: test_teeth_bvh_refit)."""
    from material_structures.core.teeth.bvh import TriangleBVH

    trees = [TriangleBVH(cs.tris_s, np.flatnonzero(cs.dentin_tooth == i)) for i in range(len(cs.dentin))]
    dnodes, droots = TriangleBVH.merge(trees)
    return dnodes, droots, dentin_reach_grid(cs.tris_s, cs.dentin_tooth, len(cs.dentin), reach)


def _points_near_dentin(cs: CompiledScene, tooth: int, scale: float, n: int, rng) -> np.ndarray:
    """Points on random dentin triangles of ``tooth`` pushed off by a random offset of up to ``scale`` per axis."""
    ids = np.flatnonzero(cs.dentin_tooth == tooth)
    k = rng.choice(ids, n)
    w = rng.dirichlet(np.ones(3), n)
    on = np.einsum("nv,nva->na", w, cs.tris_s[k])
    return on + rng.uniform(-scale, scale, (n, 3))


@pytest.mark.parametrize("reach", [4e-4, 0.01, 0.08])
def test_grid_flags_every_point_the_search_finds_dentin_near(reach):
    cs = _scene()
    dnodes, droots, grid = _trees_and_grid(cs, reach)
    rng = np.random.default_rng(7)
    for tooth in range(len(cs.dentin)):
        assert grid[2][tooth, 0] > 0  # a grid was built at this reach
        size = float(np.ptp(cs.tris_s[cs.dentin_tooth == tooth].reshape(-1, 3), axis=0).max())
        cell = size / CELLS_LONGEST_AXIS
        pts = np.concatenate([_points_near_dentin(cs, tooth, s, 20000, rng) for s in (reach, 2 * reach, cell,
                                                                                     2 * cell)])
        found, flagged = _compare(grid, dnodes, droots, cs.tris_s, tooth, pts, reach)
        assert found.sum() > 1000  # the points do reach the dentin
        missed = found & ~flagged
        assert not missed.any(), f"tooth {tooth}: {missed.sum()} points with dentin within reach not flagged"


def test_grid_lets_most_of_the_tooth_skip_the_search():
    cs = _scene()
    reach = 40.0 * 1e-5
    dnodes, droots, grid = _trees_and_grid(cs, reach)
    rng = np.random.default_rng(3)
    pts_all = cs.tris_s[cs.dentin_tooth == 0].reshape(-1, 3)
    pts = rng.uniform(pts_all.min(axis=0) - 1.0, pts_all.max(axis=0) + 1.0, (50000, 3))
    found, flagged = _compare(grid, dnodes, droots, cs.tris_s, 0, pts, reach)
    assert not (found & ~flagged).any()
    assert flagged.mean() < 0.1, f"{flagged.mean():.3f} of the points would still be searched"


def test_no_grid_where_the_reach_spans_many_cells():
    cs = _scene()
    lo, inv, dims, offs, flags = dentin_reach_grid(cs.tris_s, cs.dentin_tooth, len(cs.dentin), 40.0 * 0.34)
    assert (dims == 0).all()  # the model's default spread: every point is searched, as before the grid


def test_tracer_gives_the_same_image_and_gradient_without_the_grid(monkeypatch):
    from material_structures.core.teeth import path_tracer_compiled as ptc
    from material_structures.core.teeth.capture import default_rig
    from material_structures.core.teeth.path_tracer import RenderSettings, render
    from material_structures.core.teeth.synthetic import scene_target

    sc = make_scene(n_teeth=2)
    # a blend whose reach (0.08 mm) still gets a grid (under two cells) but holds enough vertices to matter
    sc.blend_spread = 2e-3
    cams, lights = default_rig(target=scene_target(sc), width=24, height=16, fov_x_deg=4.8)
    cams, lights = cams[:1], lights[:2]
    adj = np.random.default_rng(1).standard_normal((1, 2, 16, 24, 3))

    def run():
        ptc._TREES.clear()
        s = RenderSettings(spp=8, max_depth=None, seed=5)
        return render(sc, cams, lights, s), render(sc, cams, lights, RenderSettings(spp=2, max_depth=None, seed=6),
                                                   adjoint=adj)

    img, grad = run()
    real = ptc.dentin_reach_grid
    cs = CompiledScene(sc)
    assert real(cs.tris_s, cs.dentin_tooth, 2, 40.0 * 2e-3)[2][0, 0] > 0
    monkeypatch.setattr(ptc, "dentin_reach_grid", lambda *a: (lambda g: g[:2] + (0 * g[2],) + g[3:])(real(*a)))
    img0, grad0 = run()  # no grid: every vertex searched
    # negative control: a grid that marks nothing (every search skipped) changes the image, so the blend is seen
    monkeypatch.setattr(ptc, "dentin_reach_grid", lambda *a: (lambda g: g[:4] + (0 * g[4],))(real(*a)))
    img_skip, _ = run()
    ptc._TREES.clear()
    assert img.stats["path_vertices"] > 1000
    np.testing.assert_array_equal(img.images, img0.images)
    np.testing.assert_array_equal(grad.grad, grad0.grad)
    assert not np.array_equal(img.images, img_skip.images)
