"""Fabric fitting on a real local Dask cluster (2 worker processes): identical to the local fitter,
also when a worker is killed during the fit; finished tiles are not recomputed."""

from __future__ import annotations

import json
import os
import signal
import threading
import time

import numpy as np
import pytest

pytest.importorskip("distributed")

from material_structures.core.fabric.btf_fitter import fit_btf  # noqa: E402
from material_structures.core.fabric.btf_io import save_btf  # noqa: E402
from material_structures.core.fabric.parameter_maps import load_params  # noqa: E402
from material_structures.core.fabric.synthetic_btf import light_view_pairs, render_btf, synthetic_maps  # noqa: E402
from material_structures.scaleout.cluster import dask_client  # noqa: E402
from material_structures.scaleout.fabric import fit_btf_dask  # noqa: E402


@pytest.fixture(scope="module")
def btf(tmp_path_factory):
    folder = tmp_path_factory.mktemp("btf")
    maps = synthetic_maps(12, 12, seed=4)
    wi, wo = light_view_pairs(8, 8)
    path = save_btf(str(folder / "btf.npz"), render_btf(maps, wi, wo), wi, wo)
    local = folder / "local"
    fit_btf(path, local, tile=4, workers=1, progress=False)
    return path, load_params(local)


@pytest.fixture(scope="module")
def client():
    with dask_client(n_workers=2) as c:
        yield c


def _assert_identical(a, b):
    for key in ("kd", "ks", "sigma", "basis"):
        np.testing.assert_array_equal(getattr(a, key), getattr(b, key))


def test_distributed_equals_local(btf, client, tmp_path):
    path, local = btf
    maps, stats = fit_btf_dask(path, tmp_path / "dask", client=client, tile=4, progress=False)
    assert stats["tiles_fitted_this_run"] == 9
    _assert_identical(maps, local)
    _assert_identical(load_params(tmp_path / "dask"), local)
    # params.json holds the cluster's figures (it held the assembly's: 1 worker, 0 tiles, 0.002 s, no iterations)
    stored = json.loads((tmp_path / "dask" / "params.json").read_text())["fit"]
    assert stored == stats
    assert stored["workers"] == 2 and stored["tiles_fitted_this_run"] == 9 and stored["scheduler"] == "client"
    assert stored["mean_lm_iterations_per_tile"] >= 1 and stored["seconds_fit"] > 0.01 and stored["seconds_load"] > 0
    # a rerun finds every tile checkpointed and recomputes none
    _, again = fit_btf_dask(path, tmp_path / "dask", client=client, tile=4, progress=False)
    assert again["tiles_fitted_this_run"] == 0
    # an interrupted fit (three checkpoints missing) resumes with exactly those tiles
    for tile_file in sorted((tmp_path / "dask" / ".fit_cache" / "tiles").glob("tile_*.npz"))[:3]:
        tile_file.unlink()
    resumed, stats = fit_btf_dask(path, tmp_path / "dask", client=client, tile=4, progress=False)
    assert stats["tiles_fitted_this_run"] == 3
    _assert_identical(resumed, local)


def test_a_second_btf_fitted_into_the_same_folder_on_the_same_cluster_is_fitted_with_its_own_directions(
        btf, client, tmp_path):
    """A long-lived cluster's workers keep the directions and NDF operator they loaded for a fit: another BTF (other
    light/view pairs) fitted into the same folder afterwards must not be fitted with the first one's (the workers
    keyed them on the cache's path alone). The fixture's maps under other pairs: the closure fit then has the few
    distinct texel keys of the fixture's (the 8 x 8 maps of seed 6 had 64, 8 s of closure fits in each fit)."""
    path, local = btf
    out = tmp_path / "same"
    fit_btf_dask(path, out, client=client, tile=4, progress=False)
    maps = synthetic_maps(12, 12, seed=4)
    wi, wo = light_view_pairs(7, 9)
    other = save_btf(str(tmp_path / "other.npz"), render_btf(maps, wi, wo), wi, wo)
    got, _ = fit_btf_dask(other, out, client=client, tile=4, progress=False)
    want, _ = fit_btf(other, tmp_path / "other-local", tile=4, workers=1, progress=False)
    _assert_identical(got, want)


def test_killed_worker_still_gives_identical_result(btf, client, tmp_path):
    path, local = btf
    out = tmp_path / "killed"
    tiles_dir = out / ".fit_cache" / "tiles"
    killed = {}
    pids = client.run(os.getpid)  # worker address -> process id (local cluster)

    def kill_one_worker_mid_fit():
        deadline = time.monotonic() + 120
        while time.monotonic() < deadline:
            if tiles_dir.is_dir() and len(list(tiles_dir.glob("tile_*.npz"))) >= 1:
                addr = sorted(pids)[0]
                killed["tiles_done"] = len(list(tiles_dir.glob("tile_*.npz")))
                os.kill(pids[addr], signal.SIGKILL)
                killed["pid"] = pids[addr]
                return
            time.sleep(0.005)

    killer = threading.Thread(target=kill_one_worker_mid_fit)
    killer.start()
    maps, stats = fit_btf_dask(path, out, client=client, tile=4, progress=False)
    killer.join()
    assert "pid" in killed, "the fit finished before a worker could be killed"
    assert killed["tiles_done"] < 9
    with pytest.raises(ProcessLookupError):
        os.kill(killed["pid"], 0)  # that worker process is gone
    _assert_identical(maps, local)
