"""Fabric benchmarks (issue 4).

``fabric-fit``: synthetic 200 x 200 texel BTF with 64 x 64 light-view pairs (tilted fibres, no
noise), fitted by ``python -m material_structures fabric fit`` in a subprocess (its process tree's
memory is sampled from /proc); scored on 16 x 16 held-out pairs; compared with a plain per-texel
``scipy.optimize.least_squares`` loop on a sub-tile, measured in the same run.
``fabric-fit-large``: the same fit streamed over a 1024 x 1024 texel BTF with 64 x 64 pairs (51 GB of float32
values, 13x the machine's memory), beside a 256 x 256 one in the same run: time per texel and the peak memory of
the fit's process tree at both sizes (memory flat in the texel count: the fit maps only a tile of the BTF at a
time). Rendering all of its 4 billion values would take about 20 minutes, so the BTF repeats a synthetic
1024 x 128 texel band down its rows (the fit does not know: every texel is fitted on its own); scored on the
first band against 16 x 16 held-out pairs of its ground truth.
``fabric-brush``: 200-point stroke on 2048 x 2048 maps, time per stroke-segment update.

Environment knobs for quick runs: ``FABRIC_BENCH_SIZE`` (texels per side, default 200),
``FABRIC_BENCH_DIRS`` (lights = views, default 64), ``FABRIC_BENCH_WORKERS`` (default 2); for
``fabric-fit-large``: ``FABRIC_LARGE_SIZES`` (default ``256,1024``), ``FABRIC_LARGE_BAND`` (rows rendered,
default 128) and ``FABRIC_LARGE_KEEP`` (a folder that keeps the generated BTFs for a later run).
"""

from __future__ import annotations

import glob
import json
import os
import shutil
import subprocess
import sys
import tempfile
import threading
import time
import zipfile

import numpy as np


def _tree_memory(root: int) -> tuple[float, float]:
    """(sum of RSS, sum of PSS) in bytes over ``root`` and its descendants (Linux /proc), children of every thread."""
    pids, frontier = {root}, [root]
    while frontier:
        pid = frontier.pop()
        kids = []
        for path in glob.glob(f"/proc/{pid}/task/*/children"):  # every thread's: Dask starts its workers from one
            try:
                with open(path) as f:
                    kids += [int(k) for k in f.read().split()]
            except OSError:
                pass
        for k in kids:
            if k not in pids:
                pids.add(k)
                frontier.append(k)
    rss = pss = 0.0
    for pid in pids:
        try:
            with open(f"/proc/{pid}/smaps_rollup") as f:
                for line in f:
                    if line.startswith("Rss:"):
                        rss += float(line.split()[1]) * 1024
                    elif line.startswith("Pss:"):
                        pss += float(line.split()[1]) * 1024
        except OSError:
            pass
    return rss, pss


def _run_sampled(cmd: list[str]) -> tuple[float, float, float, int]:
    """Run ``cmd``; return (seconds, peak RSS sum, peak PSS sum, returncode)."""
    start = time.perf_counter()
    proc = subprocess.Popen(cmd)
    peak = [0.0, 0.0]
    stop = threading.Event()

    def sample():
        while not stop.is_set():
            rss, pss = _tree_memory(proc.pid)
            peak[0], peak[1] = max(peak[0], rss), max(peak[1], pss)
            stop.wait(0.25)

    th = threading.Thread(target=sample, daemon=True)
    th.start()
    rc = proc.wait()
    seconds = time.perf_counter() - start
    stop.set()
    th.join()
    return seconds, peak[0], peak[1], rc


def _per_texel_lsq_seconds(values: np.ndarray, wi: np.ndarray, wo: np.ndarray, q0, s0) -> tuple[float, float]:
    """Plain loop: scipy.optimize.least_squares (Levenberg-Marquardt, finite-difference Jacobian)
    per texel on the same residuals and initial guess. Returns (seconds per texel, median cost)."""
    from scipy.optimize import least_squares

    from ..core.fabric.quaternion import quat_from_rotvec, quat_multiply
    from ..core.fabric.sggx_brdf import sggx_btf_value

    costs = []
    start = time.perf_counter()
    for t in range(values.shape[0]):
        y = values[t]

        def resid(p, t=t, y=y):
            q = quat_multiply(q0[t], quat_from_rotvec(p[2:5]))
            return (sggx_btf_value(wi, wo, p[8:11], p[5:8], np.exp(p[:2]), q) - y).ravel()

        p0 = np.concatenate([np.log(s0[t]), np.zeros(3), np.full(3, 0.4), np.full(3, 0.1)])
        res = least_squares(resid, p0, method="lm")
        costs.append(res.cost)
    return (time.perf_counter() - start) / values.shape[0], float(np.median(costs))


def bench_fit() -> dict:
    from ..core.fabric.btf_io import save_btf
    from ..core.fabric.btf_prediction import predict_btf, psnr, texel_psnr
    from ..core.fabric.initial_guess import initial_basis
    from ..core.fabric.ndf_extraction import ndf_operator
    from ..core.fabric.parameter_maps import load_params
    from ..core.fabric.quaternion import quat_to_matrix
    from ..core.fabric.synthetic_btf import light_view_pairs, render_btf, synthetic_maps

    size = int(os.environ.get("FABRIC_BENCH_SIZE", 200))
    ndir = int(os.environ.get("FABRIC_BENCH_DIRS", 64))
    workers = int(os.environ.get("FABRIC_BENCH_WORKERS", 2))
    with tempfile.TemporaryDirectory(prefix="fabric-bench-") as tmp:
        maps = synthetic_maps(size, size, seed=11)
        wi, wo = light_view_pairs(ndir, ndir)
        t0 = time.perf_counter()
        values = render_btf(maps, wi, wo)
        sub = np.ascontiguousarray(values[:, :2, :4]).reshape(len(wi), -1, 3).transpose(1, 0, 2)
        btf = os.path.join(tmp, "btf.npz")
        save_btf(btf, values, wi, wo)
        del values
        t_gen = time.perf_counter() - t0
        out = os.path.join(tmp, "fit")
        cmd = [sys.executable, "-m", "material_structures", "fabric", "fit", btf, "--out", out,
               "--workers", str(workers), "--drop-cache"]
        seconds, rss, pss, rc = _run_sampled(cmd)
        if rc != 0:
            raise RuntimeError(f"fabric fit exited with {rc}")
        fit = load_params(out)
        with open(os.path.join(out, "params.json")) as f:
            fit_cost = json.load(f)["fit"]["median_cost"]
        hwi, hwo = light_view_pairs(16, 16, rotation=0.9)
        ref = render_btf(maps, hwi, hwo)
        pred = predict_btf(fit, hwi, hwo)
        tp = texel_psnr(pred, ref)
        rt = quat_to_matrix(maps.basis.reshape(-1, 4).astype(np.float64))
        rf = quat_to_matrix(fit.basis.reshape(-1, 4).astype(np.float64))
        st, sf = maps.sigma.reshape(-1, 2), fit.sigma.reshape(-1, 2)

        def small(r, s):
            return np.where((s[:, 0] <= s[:, 1])[:, None], r[:, :, 0], r[:, :, 1])

        ang = np.degrees(np.arccos(np.clip(np.abs(np.sum(small(rt, st) * small(rf, sf), -1)), 0, 1)))
        aniso = st.max(1) / st.min(1) > 1.5
        # per-texel reference loop on a 2 x 4 sub-tile, same initial guess as the batched fitter
        op = ndf_operator(wi, wo)
        q0, s0 = initial_basis(op.apply((sub.mean(2) / wi[None, :, 2]).T), op)
        lsq_s, lsq_cost = _per_texel_lsq_seconds(sub.astype(np.float64), wi, wo, q0, s0)
        loop_total = lsq_s * size * size
    return {
        "seconds": round(seconds, 2),
        "psnr_db_holdout": round(psnr(pred, ref), 2),
        "texel_psnr_db_median": round(float(np.median(tp)), 2),
        "texel_psnr_db_p1": round(float(np.percentile(tp, 1)), 2),
        "axis_err_deg_median": round(float(np.median(ang[aniso])), 4),
        "axis_err_deg_p99": round(float(np.percentile(ang[aniso], 99)), 4),
        "axis_err_deg_max": round(float(np.max(ang[aniso])), 3),
        "axis_frac_within_5deg": round(float(np.mean(ang[aniso] <= 5.0)), 5),
        "speedup_vs_per_texel_lsq": round(loop_total / seconds, 1),
        "per_texel_lsq_seconds_per_texel": round(lsq_s, 3),
        "per_texel_lsq_extrapolated_seconds": round(loop_total, 1),
        "per_texel_lsq_median_cost": lsq_cost,
        "fit_median_cost": fit_cost,
        "peak_rss_gb": round(rss / 2**30, 3),
        "peak_pss_gb": round(pss / 2**30, 3),
        "texels": size * size,
        "pairs": ndir * ndir,
        "workers": workers,
        "generate_seconds": round(t_gen, 1),
    }


def _write_banded_npz(path: str, band, wi: np.ndarray, wo: np.ndarray, size: int) -> None:
    """An uncompressed BTF ``.npz`` of ``size x size`` texels whose rows repeat the rendered ``band``'s, written
    16 images at a time (memory flat in the BTF's size)."""
    from ..core.fabric.synthetic_btf import render_btf

    rows = band.shape[0]
    tmp = path + ".tmp"
    with zipfile.ZipFile(tmp, "w", compression=zipfile.ZIP_STORED, allowZip64=True) as zf:
        for key, arr in (("wi", wi), ("wo", wo)):
            with zf.open(f"{key}.npy", "w", force_zip64=True) as f:
                np.lib.format.write_array(f, np.asarray(arr, dtype=np.float64))
        with zf.open("values.npy", "w", force_zip64=True) as f:
            np.lib.format.write_array_header_2_0(
                f, {"descr": "<f4", "fortran_order": False, "shape": (len(wi), size, size, 3)})
            for k0 in range(0, len(wi), 16):
                vals = render_btf(band, wi[k0:k0 + 16], wo[k0:k0 + 16])  # (m, rows, size, 3)
                f.write(np.tile(vals, (1, -(-size // rows), 1, 1))[:, :size].tobytes())
    os.replace(tmp, path)


def bench_fit_large() -> dict:
    from ..core.fabric.btf_prediction import psnr
    from ..core.fabric.parameter_maps import load_params, make_maps
    from ..core.fabric.synthetic_btf import light_view_pairs, render_btf, synthetic_maps

    sizes = [int(v) for v in os.environ.get("FABRIC_LARGE_SIZES", "256,1024").split(",")]
    rows = int(os.environ.get("FABRIC_LARGE_BAND", 128))
    ndir, workers = 64, int(os.environ.get("FABRIC_BENCH_WORKERS", 2))
    keep = os.environ.get("FABRIC_LARGE_KEEP")
    wi, wo = light_view_pairs(ndir, ndir)
    hwi, hwo = light_view_pairs(16, 16, rotation=0.9)
    runs = {}
    with tempfile.TemporaryDirectory(prefix="fabric-large-") as tmp:
        folder = keep or tmp
        os.makedirs(folder, exist_ok=True)
        for size in sizes:
            band = synthetic_maps(min(rows, size), size, seed=11)
            btf = os.path.join(folder, f"btf-{size}x{size}-band{band.shape[0]}-{ndir}x{ndir}.npz")
            t0 = time.perf_counter()
            if not os.path.isfile(btf):
                _write_banded_npz(btf, band, wi, wo, size)
            t_gen = time.perf_counter() - t0
            out = os.path.join(tmp, f"fit-{size}")
            cmd = [sys.executable, "-m", "material_structures", "fabric", "fit", btf, "--out", out,
                   "--workers", str(workers), "--drop-cache", "--no-progress"]
            seconds, rss, pss, rc = _run_sampled(cmd)
            if rc != 0:
                raise RuntimeError(f"fabric fit exited with {rc}")
            fit = load_params(out)
            r = band.shape[0]
            first = make_maps(fit.kd[:r], fit.ks[:r], fit.sigma[:r], fit.basis[:r])
            with open(os.path.join(out, "params.json")) as f:
                stats = json.load(f)["fit"]
            runs[str(size)] = {
                "texels": size * size,
                "seconds": round(seconds, 1),
                "seconds_per_megatexel": round(seconds / (size * size) * 1e6, 1),
                "median_cost": stats["median_cost"],
                "peak_rss_gb": round(rss / 2**30, 3),
                "peak_pss_gb": round(pss / 2**30, 3),
                "btf_gb": round(os.path.getsize(btf) / 2**30, 2),
                "psnr_db_holdout_first_band": round(psnr(render_btf(first, hwi, hwo), render_btf(band, hwi, hwo)), 2),
                "generate_seconds": round(t_gen, 1),
            }
            shutil.rmtree(out, ignore_errors=True)
            if not keep:
                os.remove(btf)
    big, small = runs[str(max(sizes))], runs[str(min(sizes))]
    return {
        "sizes": runs,
        "pairs": ndir * ndir,
        "workers": workers,
        "band_rows": rows,
        "largest_fit_minutes": round(big["seconds"] / 60, 2),
        "peak_pss_ratio_largest_vs_smallest": round(big["peak_pss_gb"] / small["peak_pss_gb"], 2),
        "texel_ratio_largest_vs_smallest": big["texels"] / small["texels"],
    }


def bench_brush() -> dict:
    from ..core.fabric.brushing import BrushStates, brush_data_driven, brush_edit, brush_fibres, capsule_window
    from ..core.fabric.closure_table import load_table, lookup_closure_texels
    from ..core.fabric.parameter_maps import make_maps
    from ..core.fabric.synthetic_btf import synthetic_maps

    n = 2048
    rng = np.random.default_rng(0)
    maps = make_maps(np.full((n, n, 3), 0.2), np.full((n, n, 3), 0.5), np.full((n, n, 2), 0.3),
                     np.tile([1.0, 0.0, 0.0, 0.0], (n, n, 1)))
    t = np.linspace(0.0, 1.0, 200)
    pts = np.stack([200 + 1600 * t, 1000 + 400 * np.sin(5 * t) + rng.normal(0, 1, 200)], -1)
    radius = 48.0

    def timed(fn):
        m, times = maps, []
        for a, b in zip(pts[:-1], pts[1:], strict=True):
            s = time.perf_counter()
            m = fn(m, a, b)
            times.append(time.perf_counter() - s)
        return np.array(times) * 1e3

    fib = timed(lambda m, a, b: brush_fibres(m, a, b, radius, fibre_length=1.2))
    grid = load_table()

    def fibres_and_closures(m, a, b):
        """A combing segment plus the closure lookup of the texels it changed (what the brush does)."""
        new = brush_fibres(m, a, b, radius, fibre_length=1.2)
        win = capsule_window(m.shape, a, b, radius, 1.0)
        if win is not None:
            sl = win.slices
            changed = np.any(new.basis[sl] != m.basis[sl], axis=-1)
            lookup_closure_texels(new.sigma[sl][changed], new.basis[sl][changed], grid)
        return new

    fib_closures = timed(fibres_and_closures)
    states = BrushStates(tuple(synthetic_maps(64, 64, seed=k) for k in range(8)))
    dd = timed(lambda m, a, b: brush_data_driven(m, a, b, radius, states))
    ed = timed(lambda m, a, b: brush_edit(m, a, b, radius, kd=(0.1, 0.5, 0.1), anisotropy_factor=0.7))
    return {
        "ms_per_update": round(float(fib.mean()), 2),
        "ms_per_update_p95": round(float(np.percentile(fib, 95)), 2),
        "ms_per_update_max": round(float(fib.max()), 2),
        "with_closures_ms_per_update_median": round(float(np.median(fib_closures)), 2),
        "with_closures_ms_per_update_p95": round(float(np.percentile(fib_closures, 95)), 2),
        "data_driven_ms_per_update": round(float(dd.mean()), 2),
        "edit_ms_per_update": round(float(ed.mean()), 2),
        "map_size": n,
        "stroke_points": len(pts),
        "radius_px": radius,
    }


BENCHMARKS = {"fabric-fit": bench_fit, "fabric-fit-large": bench_fit_large, "fabric-brush": bench_brush}
