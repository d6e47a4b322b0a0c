"""Compile the teeth tracer's numba kernels into their on-disk cache (tests/conftest.py runs this in the
background when a test session starts; by hand: ``.venv/bin/python tests/warm_numba.py``).

It calls what the tests call, on a tiny scene: the compiled tracer (forward with roulette and with a depth cap,
gradient, Jacobian), the BVH queries the tests call directly and the dentin reach grid. A kernel it misses
compiles in the first test that needs it, as without the warm-up. With a warm cache this takes a few seconds
(loading). Writes ``DONE`` (argv[1]) when finished, ``DONE.failed`` with the error if something raised.
"""

from __future__ import annotations

import sys
import time
import traceback


def warm() -> None:
    import numpy as np

    from material_structures.core.teeth import bvh
    from material_structures.core.teeth.compiled_scene import CompiledScene
    from material_structures.core.teeth.dentin_reach_grid import dentin_reach_grid, may_be_within_reach
    from material_structures.core.teeth.gradient_check import fd_test_scene
    from material_structures.core.teeth.path_tracer import RenderSettings, render

    scene, cams, lights = fd_test_scene()
    cs = CompiledScene(scene)
    h, w = cams[0].height, cams[0].width
    render(scene, cams, lights, RenderSettings(1, None, 0), compiled=cs)
    render(scene, cams, lights, RenderSettings(1, 6, 1), compiled=cs)
    adjoint = np.ones((1, len(lights), h, w, 3))
    render(scene, cams, lights, RenderSettings(1, None, 2), compiled=cs, adjoint=adjoint)
    render(scene, cams, lights, RenderSettings(1, None, 3), compiled=cs, pixels=[np.arange(4)],
           jacobian_cols=np.arange(2))
    tris = cs.tris_s
    nodes = bvh.TriangleBVH(tris).ray_arrays(tris)
    stack, dist = np.empty(64, dtype=np.int64), np.empty(8)
    o, d = tris.reshape(-1, 3).mean(axis=0) + [0.0, 0.0, 50.0], np.array([0.0, 0.0, -1.0])
    bvh.first_hit(nodes, o, d, 0.0, np.inf, stack, dist)
    stops = np.ones(len(tris), dtype=bool)
    buf_tri, buf_t = np.empty(64, dtype=np.int64), np.empty(64)
    bvh.hits_until_stop(nodes, stops, o, d, 0.0, np.inf, stack, dist, buf_tri, buf_t, True)
    tree = bvh.TriangleBVH(tris)
    tnodes, roots = bvh.TriangleBVH.merge([tree.refit(tris)])
    bary = np.empty(3)
    bvh.closest_triangle(tnodes, roots[0], tris, o, stack, bary, np.inf)
    dentin_tooth = np.zeros(len(tris), dtype=np.int64)
    grid = dentin_reach_grid(tris, dentin_tooth, 1, 0.1)
    may_be_within_reach(grid, 0, o)


def main(done: str | None) -> int:
    t0 = time.perf_counter()
    try:
        warm()
    except Exception:  # a kernel the warm-up could not reach compiles in its test instead
        traceback.print_exc()
        if done:
            with open(done + ".failed", "w") as fh:
                fh.write(traceback.format_exc())
        return 1
    print(f"numba warm-up: {time.perf_counter() - t0:.1f} s")
    if done:
        with open(done, "w") as fh:
            fh.write(f"{time.perf_counter() - t0:.1f}\n")
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1] if len(sys.argv) > 1 else None))
