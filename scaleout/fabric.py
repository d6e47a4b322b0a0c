"""Fabric BTF fitting on Dask: one task per texel tile.

The client prepares the fit cache (``core.fabric.btf_fitter``) in the output folder, which must be on storage the
workers share, and reads the BTF a band of tile rows at a time into the cache's band files
(``core.fabric.btf_bands``); each task maps its tile from its band file, fits it and writes the tile's checkpoint
atomically. Finished tiles are never recomputed (a rerun or a resumed client skips them), a task lost with a killed
worker is rerun elsewhere, and every tile fit is deterministic, so the result equals a local run bit for bit. The
final assembly and post-processing are the local fitter's own (``fit_btf`` with every tile already done).
"""

from __future__ import annotations

import os
import sys
import threading
import time

import numpy as np

from ..core.fabric import btf_fitter
from ..core.fabric.tile_fit import FitOptions
from ..core.folder_lock import FolderLock

_INIT_LOCK = threading.Lock()


def _fit_tile_task(tile: tuple[int, int, int, int], cache: str, band, init_args: tuple) -> tuple:
    """Runs on a worker: load the shared inputs once per worker process and fit (a long-lived cluster's worker
    loads them again for another fit: another folder, BTF directions or options), fit one tile from its band file."""
    key = (init_args[0], btf_fitter._directions_hash(init_args[1], init_args[2]), repr(init_args[3]))
    with _INIT_LOCK:
        if btf_fitter._WORKER.get("_init_key") != key:
            btf_fitter._init_worker(*init_args)
            btf_fitter._WORKER["_init_key"] = key
    return btf_fitter._fit_one(tile, cache, band)


def fit_btf_dask(
    btf_path: str | os.PathLike,
    out_dir: str | os.PathLike,
    client=None,
    scheduler: str | None = None,
    n_workers: int | None = None,
    tile: int = 20,
    options: FitOptions | None = None,
    progress: bool = True,
    keep_cache: bool = True,
):
    """Fit a BTF with tiles as Dask tasks; returns ``(maps, stats)`` like ``fit_btf``.

    ``client``: an existing ``distributed.Client``; else ``scheduler`` (address) or a local
    cluster of ``n_workers`` processes.
    """
    from ..scaleout.cluster import dask_client

    btf_path, out_dir = os.path.abspath(os.fspath(btf_path)), os.path.abspath(os.fspath(out_dir))
    options = options or FitOptions()
    t_start = time.perf_counter()
    checked = btf_fitter.check_btf(btf_path)
    os.makedirs(out_dir, exist_ok=True)
    with FolderLock(out_dir):  # the tiles; fit_btf below takes the lock again for the assembly
        hdr, cache, values = btf_fitter._prepare_cache(btf_path, out_dir, tile, options, progress, checked)
        t_load = time.perf_counter() - t_start
        tiles = btf_fitter._tiles(hdr.height, hdr.width, tile)
        btf_fitter.check_tiles(cache, tiles)
        todo = [t for t in tiles if not os.path.isfile(btf_fitter._tile_path(cache, t))]
        init_args = (os.path.join(cache, "ndf_operator.npz"), hdr.wi, hdr.wo, _asdict(options))
        iterations: list[int] = []
        workers = 0
        t_fit = time.perf_counter()
        if todo:
            # workers of a cluster this call did not start may be on other machines: the bands go to storage
            if client is not None:
                workers = _run_tiles(client, values, hdr, todo, cache, init_args, progress, len(tiles), iterations,
                                     durable=True)
            else:
                with dask_client(scheduler, n_workers) as own:
                    workers = _run_tiles(own, values, hdr, todo, cache, init_args, progress, len(tiles), iterations,
                                         durable=scheduler is not None)
        t_fit = time.perf_counter() - t_fit
    # Every tile is checkpointed now: the local fitter only assembles and post-processes; the fit's figures in
    # params.json are the cluster's (the assembly would give its own: 1 worker, 0 tiles, no time)
    run_stats = {"workers": workers, "tiles_fitted_this_run": len(todo), "seconds_load": round(t_load, 3),
                 "seconds_fit": round(t_fit, 3),
                 "mean_lm_iterations_per_tile": float(np.mean(iterations)) if iterations else None,
                 "scheduler": scheduler or ("client" if client is not None else "local")}
    return btf_fitter.fit_btf(btf_path, out_dir, tile=tile, workers=1, options=options, progress=False,
                              keep_cache=keep_cache, run_stats=run_stats)


def _asdict(options: FitOptions) -> dict:
    from dataclasses import asdict

    return asdict(options)


class _DaskRunner:
    """Tiles as Dask tasks (``btf_bands.TileRunner``)."""

    def __init__(self, client, cache: str, shared):
        self.client, self.cache, self.shared = client, cache, shared
        self.submitted: list = []

    def submit(self, t, band):
        # key per tile and fit folder; retries: a task lost with a killed worker runs elsewhere
        future = self.client.submit(_fit_tile_task, t, self.cache, band, init_args=self.shared, retries=3,
                                  key=f"fabric-tile-{t[0]}-{t[2]}-{os.path.basename(os.path.dirname(self.cache))}")
        self.submitted.append(future)
        return future

    def wait_some(self, running):
        from distributed import wait

        return wait(list(running), return_when="FIRST_COMPLETED").done

    def result(self, handle):
        return handle.result()  # raises the task's error, if any


def _run_tiles(client, values, hdr, todo, cache, init_args, progress, total, iterations: list, durable: bool) -> int:
    """Fit the tiles ``todo`` as tasks of ``client``'s cluster (each tile's LM iterations appended to
    ``iterations``); returns how many workers the cluster had."""
    # sent once, not per task; hash=False: no key shared with an earlier fit (dask/distributed#3703)
    [shared] = client.scatter([init_args], broadcast=True, hash=False)
    runner = _DaskRunner(client, cache, shared)
    bar = None
    if progress:
        from tqdm import tqdm

        bar = tqdm(total=total, initial=total - len(todo), desc="fit tiles (dask)", unit="tile", file=sys.stderr)

    def done(result: tuple) -> None:
        iterations.append(int(result[2]))
        if bar:
            bar.update(1)

    try:
        btf_fitter.fit_all_bands(values, hdr, cache, todo, runner, done, durable)
    except BaseException:  # Ctrl-C, SIGTERM or a failed tile: the finished tiles stay checkpointed, the others
        client.cancel(runner.submitted)  # are dropped from the cluster instead of running on
        raise
    finally:
        if bar:
            bar.close()
    return len(client.scheduler_info().get("workers", {}))
