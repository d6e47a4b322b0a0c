"""Fit the fabric SVBRDF to a whole BTF: tiles in parallel processes, checkpoint per tile, resume.

Pipeline per tile (see :mod:`tile_fit`): NDF extraction (eq. 3.11) into a parabolic map (3.12),
PCA basis (3.13-3.15), ``S_v`` (3.16), batched Levenberg-Marquardt (3.17-3.19); then, for the
whole map, the post-processing of section 3.4.3. Output: :func:`parameter_maps.save_params`.

The BTF streams through the fit a band of tile rows at a time (:mod:`btf_bands`), so memory and the cache do not
grow with the texel count. An ``.npz`` saved uncompressed (``np.savez``, as ``save_btf`` writes one) is read where
it lies; a folder of EXR images or a compressed ``.npz`` is first copied, image after image, into
``OUT/.fit_cache/values.npy`` (float32).

On-disk work state in ``OUT/.fit_cache``: that copy where one is needed, the NDF operator, the two band files while
the fit runs, ``meta.json`` (what it was built from) and ``tiles/*.npz`` (one checkpoint per finished tile). An
interrupted fit run again with the same inputs resumes.
"""

from __future__ import annotations

import hashlib
import json
import multiprocessing
import os
import queue
import shutil
import sys
import time
import zipfile
from collections.abc import Callable
from concurrent.futures import ProcessPoolExecutor
from dataclasses import asdict

import numpy as np

from ..errors import BadFileError, UserError
from ..folder_lock import FolderLock
from ..forked_map import fork_warning_silenced
from ..json_io import save_json
from .btf_bands import BandFile, fit_in_bands
from .btf_io import ArrayInFile, iter_btf_blocks, npz_stored_array, read_btf_header
from .closure_fit import FIT_KEY_BUDGET, fit_closure_maps, save_closure_maps
from .levenberg_marquardt import Samples
from .ndf_extraction import NdfOperator, check_ndf_coverage, ndf_operator
from .parameter_maps import FabricMaps, make_maps, save_params
from .postprocess import postprocess_basis
from .tile_fit import FitOptions, fit_tile

CACHE = ".fit_cache"


def _tiles(height: int, width: int, tile: int) -> list[tuple[int, int, int, int]]:
    return [(y, min(y + tile, height), x, min(x + tile, width))
            for y in range(0, height, tile) for x in range(0, width, tile)]


def _tile_path(cache: str, t: tuple[int, int, int, int]) -> str:
    return os.path.join(cache, "tiles", f"tile_{t[0]:05d}_{t[2]:05d}.npz")


_WORKER: dict = {}


def _init_worker(op_path: str, wi: np.ndarray, wo: np.ndarray, options: dict) -> None:
    with np.load(op_path) as z:
        _WORKER["op"] = NdfOperator(A=z["A"], directions=z["directions"], solid_angle=z["solid_angle"],
                                    valid=z["valid"], resolution=int(z["resolution"]))
    _WORKER["options"] = FitOptions(**options)
    _WORKER["samples"] = Samples.make(wi, wo, _WORKER["options"].weighting)


def _fit_one(t: tuple[int, int, int, int], cache: str, band: BandFile) -> tuple[tuple[int, int, int, int], float, int]:
    """Fit one tile (in a worker) from its band and write its checkpoint atomically."""
    start = time.perf_counter()
    res = fit_tile(band.tile_values(t), _WORKER["samples"], _WORKER["op"], _WORKER["options"])
    path = _tile_path(cache, t)
    tmp = path + f".tmp-{os.getpid()}.npz"
    np.savez(tmp, quat=res.quat, sigma=res.sigma, ks=res.ks, kd=res.kd, cost=res.cost,
             iterations=res.iterations)
    os.replace(tmp, path)
    return t, time.perf_counter() - start, res.iterations


class _InProcess:
    """Tiles fitted here, one after the other (one worker)."""

    def __init__(self, cache):
        self.cache = cache

    def submit(self, t, band):
        return _Finished(_fit_one(t, self.cache, band))

    def wait_some(self, running):
        return running

    def result(self, handle):
        return handle.result


class _Finished:
    def __init__(self, result):
        self.result = result


class _Pool:
    """Tiles fitted in a process pool. Finished tiles arrive on a queue (a done-callback puts them there): the main
    thread waits on the queue, never inside the pool's locks, so Ctrl-C or SIGTERM while it waits cannot leave one
    held and the pool's shutdown waiting on it."""

    def __init__(self, pool, cache):
        self.pool, self.cache = pool, cache
        self.finished: queue.SimpleQueue = queue.SimpleQueue()

    def submit(self, t, band):
        future = self.pool.submit(_fit_one, t, self.cache, band)
        future.add_done_callback(self.finished.put)
        return future

    def wait_some(self, running):
        done = [self.finished.get()]
        while not self.finished.empty():
            done.append(self.finished.get())
        return done

    def result(self, handle):
        return handle.result()


TILE_ARRAYS = {"quat": 4, "sigma": 2, "ks": 3, "kd": 3, "cost": 0}


def read_tile(cache: str, t: tuple[int, int, int, int]) -> dict[str, np.ndarray]:
    """A tile's checkpoint as ``name -> (th, tw[, C])`` arrays; a damaged one (truncated, not a .npz, arrays
    missing or of the wrong size) is refused by name, with what to do about it."""
    path = _tile_path(cache, t)
    shp = (t[1] - t[0], t[3] - t[2])
    try:
        with np.load(path) as z:
            return {k: z[k].reshape(shp + ((c,) if c else ())) for k, c in TILE_ARRAYS.items()}
    except (OSError, ValueError, KeyError, EOFError, zipfile.BadZipFile) as exc:
        raise BadFileError(f"{path}: a damaged tile checkpoint ({type(exc).__name__}: {exc}); delete it and run "
                           "the fit again to fit that tile anew") from None


def check_tiles(cache: str, tiles: list[tuple[int, int, int, int]]) -> None:
    """Read every tile checkpoint there is before any work, so that a damaged one stops the fit at once."""
    for t in tiles:
        if os.path.isfile(_tile_path(cache, t)):
            read_tile(cache, t)


def _directions_hash(wi: np.ndarray, wo: np.ndarray) -> str:
    return hashlib.sha1(np.ascontiguousarray(np.concatenate([wi, wo], 1)).tobytes()).hexdigest()


def _content_stamp(hdr) -> list:
    """(path, size, mtime in ns) of every file the BTF's values come from: its .npz, or its folder's
    btf.json and every image, so rewriting one image in place invalidates the cache."""
    files = [hdr.source] if not os.path.isdir(hdr.source) else \
        [os.path.join(hdr.source, "btf.json"), *(hdr.images or [])]
    stamp = []
    for f in files:
        st = os.stat(f)
        stamp.append([os.path.abspath(f), st.st_size, st.st_mtime_ns])
    return stamp


def check_btf(btf_path: str) -> tuple:
    """Read a BTF's header and refuse it, before anything is written, where its directions cannot be
    fitted (``check_ndf_coverage``): (header, NDF operator)."""
    hdr = read_btf_header(btf_path)
    op = ndf_operator(hdr.wi, hdr.wo)
    check_ndf_coverage(op, hdr.source, hdr.count)
    return hdr, op


def _prepare_cache(btf_path: str, out_dir: str, tile: int, options: FitOptions, progress: bool,
                   checked: tuple) -> tuple:
    """The fit cache of ``out_dir`` for the BTF that ``check_btf`` accepted (``checked``: its result):
    (header, cache folder, the BTF's images as an :class:`ArrayInFile`). A BTF that is copied is checked (values
    finite, >= 0) as it is copied; one read where it lies is checked a band at a time, before the band is fitted."""
    hdr, op = checked
    cache = os.path.join(out_dir, CACHE)
    stored = npz_stored_array(hdr.source, "values") if hdr.images is None else None
    if stored is not None and np.dtype(stored.dtype).kind != "f":
        stored = None  # iter_btf_blocks says what is wrong with it
    meta = {
        "source": os.path.abspath(hdr.source),
        "files": _content_stamp(hdr),
        "shape": [hdr.count, hdr.height, hdr.width, 3],
        "directions": _directions_hash(hdr.wi, hdr.wo),
        "tile": tile,
        "layout": "NHW3",
        "values": "btf" if stored is not None else "values.npy",
        "options": asdict(options),
    }
    meta_path = os.path.join(cache, "meta.json")
    values_path = os.path.join(cache, "values.npy")
    shape = tuple(meta["shape"])
    old = None
    if os.path.isfile(meta_path):
        try:
            with open(meta_path) as f:
                old = json.load(f)
        except (ValueError, UnicodeDecodeError):  # damaged: the cache is built anew, as for another BTF
            old = None
    same = old == meta
    if not same or not _cache_readable(cache, meta["shape"], stored is None):
        if same:  # this BTF's copy or operator damaged: they are made again, the tiles fitted so far stay
            for name in ("meta.json", "values.npy", "ndf_operator.npz"):
                if os.path.exists(os.path.join(cache, name)):
                    os.remove(os.path.join(cache, name))
        else:
            shutil.rmtree(cache, ignore_errors=True)
        os.makedirs(os.path.join(cache, "tiles"), exist_ok=True)
        try:
            if stored is not None:  # read where it lies, a band at a time; its values are checked by band
                if os.path.getsize(stored.path) < stored.offset + int(np.prod(stored.shape)) * np.dtype(
                        stored.dtype).itemsize:
                    raise UserError(f"{hdr.source}: values is truncated")
            else:  # image after image into an (N, H, W, 3) float32 copy: written in order, read by tile
                tmp = values_path + ".tmp.npy"
                mm = np.lib.format.open_memmap(tmp, mode="w+", dtype=np.float32, shape=shape)
                for k0, vals in iter_btf_blocks(btf_path, progress=progress):
                    mm[k0:k0 + vals.shape[0]] = vals
                mm.flush()
                del mm
                os.replace(tmp, values_path)
        except BaseException:  # an unreadable image or value, Ctrl-C: no BTF-sized leftover
            shutil.rmtree(cache, ignore_errors=True)
            raise
        np.savez(os.path.join(cache, "ndf_operator.npz"), A=op.A, directions=op.directions,
                 solid_angle=op.solid_angle, valid=op.valid, resolution=op.resolution)
        save_json(meta_path, meta)
    if stored is not None:
        return hdr, cache, stored
    values = np.load(values_path, mmap_mode="r")
    offset = values.offset
    del values
    return hdr, cache, ArrayInFile(path=os.path.abspath(values_path), offset=offset, dtype="<f4", shape=shape)


def _cache_readable(cache: str, shape: list, copied: bool) -> bool:
    """Whether the cache's BTF copy (where the fit needs one) and NDF operator can be read (a damaged one is built
    anew: it is derived from the BTF, so nothing is lost)."""
    try:
        ok = True
        if copied:
            values = np.load(os.path.join(cache, "values.npy"), mmap_mode="r")
            ok = values.shape == tuple(shape) and values.dtype == np.float32
            del values
        with np.load(os.path.join(cache, "ndf_operator.npz")) as z:
            ok = ok and {"A", "directions", "solid_angle", "valid", "resolution"} <= set(z.files)
            ok = ok and all(z[k] is not None for k in z.files)
        return ok
    except (OSError, ValueError, EOFError, zipfile.BadZipFile):
        return False


class _CallbackBar:
    """A progress bar that calls ``callback(done, total)`` on each update."""

    def __init__(self, callback, total: int, initial: int = 0):
        self.callback, self.total, self.n = callback, total, initial
        callback(self.n, total)

    def update(self, k: int = 1) -> None:
        self.n += k
        self.callback(self.n, self.total)

    def close(self) -> None:
        pass


def fit_all_bands(values: ArrayInFile, hdr, cache: str, todo: list, runner, done, durable: bool = False) -> None:
    """Fit the tiles ``todo`` band by band (:func:`btf_bands.fit_in_bands`; ``durable`` where workers on other
    machines read the bands). A value the BTF cannot hold, found in a band read from the BTF where it lies, refuses
    the BTF: the cache goes with it (its tiles came from that BTF), as when the BTF is copied."""
    try:
        fit_in_bands(values, hdr.source, cache, todo, runner, done, durable)
    except UserError:
        shutil.rmtree(cache, ignore_errors=True)
        raise


def fit_btf(btf_path: str | os.PathLike, out_dir: str | os.PathLike, tile: int = 20,
            workers: int | None = None, options: FitOptions | None = None,
            progress: bool | Callable[[int, int], None] = True, preferred=(1.0, 0.0, 0.0),
            keep_cache: bool = True, run_stats: dict | None = None) -> tuple[FabricMaps, dict]:
    """Fit eq. 3.9 to every texel of a BTF and write the parameter folder ``out_dir``.

    ``workers`` processes (default: CPU count) fit ``tile x tile`` texel tiles (``progress``: a tqdm bar,
    or a callable ``(tiles done, tiles)``); finished tiles are checkpointed, so calling again after an
    interruption only fits the missing tiles. Returns the post-processed maps and a stats dict (also stored
    in ``params.json`` under ``"fit"``); ``run_stats`` replaces its entries of the run (a caller that fitted the
    tiles elsewhere, e.g. on Dask, and only assembles them here).
    """
    btf_path, out_dir = os.fspath(btf_path), os.fspath(out_dir)
    checked = check_btf(btf_path)
    os.makedirs(out_dir, exist_ok=True)
    with FolderLock(out_dir):  # a second fit into the folder would mix its tiles with this one's
        return _fit_btf(btf_path, out_dir, tile, workers, options or FitOptions(), progress, preferred, keep_cache,
                        checked, run_stats or {})


def _fit_btf(btf_path: str, out_dir: str, tile: int, workers: int | None, options: FitOptions, progress: bool,
             preferred, keep_cache: bool, checked: tuple, run_stats: dict) -> tuple[FabricMaps, dict]:
    workers = workers or os.cpu_count() or 1
    t_start = time.perf_counter()
    hdr, cache, values = _prepare_cache(btf_path, out_dir, tile, options, progress is True, checked)
    t_loaded = time.perf_counter()
    tiles = _tiles(hdr.height, hdr.width, tile)
    check_tiles(cache, tiles)
    todo = [t for t in tiles if not os.path.isfile(_tile_path(cache, t))]
    init_args = (os.path.join(cache, "ndf_operator.npz"), hdr.wi, hdr.wo, asdict(options))
    bar = None
    if callable(progress):  # progress(tiles done, tiles): e.g. JSON lines for the Blender add-on
        bar = _CallbackBar(progress, len(tiles), len(tiles) - len(todo))
    elif progress:
        from tqdm import tqdm

        bar = tqdm(total=len(tiles), initial=len(tiles) - len(todo), desc="fit tiles", unit="tile",
                   file=sys.stderr)
    iters = []

    def done(result: tuple) -> None:
        iters.append(result[2])
        if bar:
            bar.update(1)

    if todo:
        if workers <= 1:
            _init_worker(*init_args)
            fit_all_bands(values, hdr, cache, todo, _InProcess(cache), done)
        else:
            method = "fork" if "fork" in multiprocessing.get_all_start_methods() else "spawn"
            ctx = multiprocessing.get_context(method)
            with fork_warning_silenced(), ProcessPoolExecutor(max_workers=min(workers, len(todo)), mp_context=ctx,
                                                              initializer=_init_worker, initargs=init_args) as pool:
                try:
                    fit_all_bands(values, hdr, cache, todo, _Pool(pool, cache), done)
                except BaseException:  # Ctrl-C, SIGTERM or a failed tile: drop the queued tiles, let the
                    pool.shutdown(wait=True, cancel_futures=True)  # running ones finish, leave no worker
                    raise
    if bar:
        bar.close()
    t_fit = time.perf_counter()
    h, w = hdr.height, hdr.width
    quat, sigma = np.zeros((h, w, 4)), np.zeros((h, w, 2))
    ks, kd, cost = np.zeros((h, w, 3)), np.zeros((h, w, 3)), np.zeros((h, w))
    for t in tiles:
        y0, y1, x0, x1 = t
        z = read_tile(cache, t)
        quat[y0:y1, x0:x1], sigma[y0:y1, x0:x1] = z["quat"], z["sigma"]
        ks[y0:y1, x0:x1], kd[y0:y1, x0:x1], cost[y0:y1, x0:x1] = z["ks"], z["kd"], z["cost"]
    pref = None if preferred is None else np.asarray(preferred, dtype=np.float64)
    quat, sigma, labels = postprocess_basis(quat, sigma, pref)
    maps = make_maps(kd, ks, sigma, quat)
    stats = {
        "btf": os.path.abspath(btf_path), "samples": hdr.count, "tile": tile, "workers": workers,
        "tiles": len(tiles), "tiles_fitted_this_run": len(todo), "options": asdict(options),
        "seconds_load": round(t_loaded - t_start, 3), "seconds_fit": round(t_fit - t_loaded, 3),
        "mean_lm_iterations_per_tile": float(np.mean(iters)) if iters else None,  # all stages
        "median_cost": float(np.median(cost)), "flip_regions": int(labels.max()),
    } | run_stats
    save_params(out_dir, maps, extra={"fit": stats})
    # The closure mix world and indirect light see in Cycles, beside the maps (issue 38): an import
    # then reads it instead of fitting it. A fitted map's geometry varies per texel: beyond
    # FIT_KEY_BUDGET distinct geometries every texel comes from the closure table (3 us each, where
    # fitting each would take minutes).
    save_closure_maps(out_dir, fit_closure_maps(maps.sigma, maps.basis, max_keys=FIT_KEY_BUDGET))
    if not keep_cache:
        shutil.rmtree(cache, ignore_errors=True)
    return maps, stats
