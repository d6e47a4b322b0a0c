"""``bench fabric-fit-dask``: the Dask fabric fit with 2 workers vs 1, and equality with the local fitter."""

from __future__ import annotations

import os
import tempfile
import time

import numpy as np


def _warm_up(client) -> None:
    """Import the fitter's modules in every worker before timing (process start-up is not fitting)."""

    def imports():
        import material_structures.core.fabric.tile_fit  # noqa: F401
        import material_structures.scaleout.fabric  # noqa: F401

    client.run(imports)


def fabric_fit_dask(size: int = 64, lights: int = 16, views: int = 16, tile: int = 8) -> dict:
    from ..core.fabric.btf_fitter import fit_btf
    from ..core.fabric.btf_io import save_btf
    from ..core.fabric.synthetic_btf import light_view_pairs, render_btf, synthetic_maps
    from ..scaleout.cluster import dask_client
    from ..scaleout.fabric import fit_btf_dask

    work = tempfile.mkdtemp(prefix="ms-bench-dask-")
    maps = synthetic_maps(size, size, seed=5)
    wi, wo = light_view_pairs(lights, views)
    path = save_btf(os.path.join(work, "btf.npz"), render_btf(maps, wi, wo), wi, wo)
    local, _ = fit_btf(path, os.path.join(work, "local"), tile=tile, workers=1, progress=False)

    seconds = {}
    results = {}
    for n in (1, 2):
        with dask_client(n_workers=n) as client:
            client.wait_for_workers(n)
            _warm_up(client)
            start = time.perf_counter()
            results[n], _ = fit_btf_dask(path, os.path.join(work, f"dask{n}"), client=client, tile=tile, progress=False)
            seconds[n] = time.perf_counter() - start
    identical = all(
        np.array_equal(getattr(results[n], k), getattr(local, k))
        for n in (1, 2)
        for k in ("kd", "ks", "sigma", "basis")
    )
    return {
        "speedup_2_workers_vs_1": seconds[1] / seconds[2],
        "identical_to_local": bool(identical),
        "seconds_1_worker": seconds[1],
        "seconds_2_workers": seconds[2],
        "texels": size * size,
        "directions": lights * views,
        "tiles": (size // tile) ** 2,
        "cpu_count": os.cpu_count(),
    }


BENCHMARKS = {"fabric-fit-dask": fabric_fit_dask}
