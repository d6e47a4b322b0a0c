"""``bench teeth-vs-mitsuba``: our teeth path tracer (``core.teeth.path_tracer.render``, compiled tracer, all
bounces with Russian roulette) against Mitsuba 3 (``llvm_ad_rgb``), side by side in one run on the same machine.

Scene: the 2-tooth acceptance scene (``make_scene(n_teeth=2)``, its materials, gums and oral cavity) made
index-matched (eta 1, a_t 1 for teeth and gums) with a sharp enamel/dentin boundary (blend spread 1e-5 mm), the
variant in which both renderers compute the same image (tests/core/test_teeth_mitsuba.py): Mitsuba ``null``
interfaces around homogeneous media with ``blendphase`` two-lobe HG phase functions, a two-sided diffuse cavity
and point lights. Rig: ``default_rig`` as in ``benchmarks/teeth.py::acceptance_setup`` (3 cameras 96 x 64,
54 lights). Times are wall-clock seconds after a warm-up call (numba's and Dr.Jit's compilation excluded), the
median of ``RUNS`` runs (``TEETH_MITSUBA_LONG_RUNS`` sets how often our whole capture and full gradient run, 0.5-1.5
minutes each on 2 cores), our runs and Mitsuba's interleaved; every run's time is reported; about 9 minutes in all
on 2 idle cores. The scene set-up of both (our ``CompiledScene``, Mitsuba's ``load_dict``) is outside the timings
and reported separately. Both use all cores (numba's threads, Dr.Jit's thread pool). The machine may be shared
with other work: every run's process CPU seconds are reported too, ``cpu_time_ratios`` gives the three ratios in
CPU seconds (medians), with the load averages at the start and the end, and ``source`` the commit and any
uncommitted teeth-core files measured.

Measured:

* ``forward_per_sample_ratio``: seconds per sample of one full image (camera 0, light 0, ``SPP`` spp), ours
  (``max_depth=None``) over Mitsuba ``volpath`` (``max_depth -1``, its default ``rr_depth``).
* ``capture_ratio``: the whole capture (3 cameras x 54 lights, ``SPP`` spp), ours in one ``render`` call whose paths
  are shared by all lights (as the thesis does) over Mitsuba's 162 separate renders (one scene; the light is
  moved through ``mi.traverse`` between renders, so its kernel is compiled once), images copied to numpy.
* ``gradient_ratio``: the gradient of sum(adjoint x image) over all 162 images at ``SPP`` spp (forward and
  backward, one random adjoint for both), ours in one ``render(..., adjoint=...)`` call (all physical parameters)
  over Mitsuba ``prbvolpath`` (``max_depth -1``) with the parameters that map to ours made differentiable (per
  medium sigma_t, albedo, both HG g and the lobe weight; the cavity's reflectance): one ``mi.render`` +
  ``dr.backward`` per (camera, light). Mitsuba is timed on ``GRADIENT_LIGHTS`` of the 54 lights (spread over the
  rig, all 3 cameras) and scaled linearly to 54 (``mitsuba_gradient_scaled_from`` says so; its renders are
  independent; the last run's seconds per measured light are reported); ``TEETH_MITSUBA_GRADIENT_LIGHTS=54`` times all.
* ``transport_max_rel_err``: tooth-pixel means (``tooth_masks``, camera 0) per channel for lights 0, 18 and 36,
  ours at defaults (``max_depth=None``, 256 spp) over Mitsuba ``volpath`` with all bounces (1024 spp per light):
  the worst |ours / mitsuba - 1| over lights and channels, per light/channel values, and the relative standard
  errors of both means from the per-pixel variance over ``TRANSPORT_BATCHES`` independent renders (about 0.1-0.4 %
  each at these spp).

Environment: TEETH_MITSUBA_LONG_RUNS, TEETH_MITSUBA_GRADIENT_LIGHTS, TEETH_MITSUBA_TRANSPORT_SPP (Mitsuba's spp per
light in the transport check), TEETH_MITSUBA_OUR_SPP (ours). Progress goes to stderr.
"""

from __future__ import annotations

import os
import statistics
import subprocess
import sys
import tempfile
import time

import numpy as np

from ..core.teeth.mitsuba_capture import import_mitsuba as _import_mitsuba
from ..core.teeth.mitsuba_capture import mitsuba_image, set_light
from ..core.teeth.mitsuba_capture import mitsuba_scene as _mitsuba_scene

VARIANT = "llvm_ad_rgb"
SPP = 16
RUNS = 3
WIDTH, HEIGHT = 96, 64
TRANSPORT_LIGHTS = (0, 18, 36)
TRANSPORT_BATCHES = 4
GRADIENT_LIGHTS = 6
TARGETS = {"forward_per_sample_ratio": 1.5, "capture_ratio": 0.5, "gradient_ratio": 1.0}


def _log(msg: str) -> None:
    print(f"bench teeth-vs-mitsuba: {msg}", file=sys.stderr, flush=True)


def import_mitsuba():
    """Mitsuba 3 with the ``llvm_ad_rgb`` variant (Dr.Jit's LLVM backend finds libLLVM 19 through
    DRJIT_LIBLLVM_PATH where Debian's libllvm19 is installed)."""
    return _import_mitsuba(VARIANT)[0]


def mitsuba_scene(mi, sc, cameras, folder: str):
    """``sc`` as a Mitsuba scene (``core.teeth.mitsuba_capture.mitsuba_scene``, sensors at ``SPP`` samples):
    (scene, the names of the parameters that map to ours)."""
    return _mitsuba_scene(mi, sc, cameras, folder, spp=SPP)


def bench_scene():
    """The index-matched 2-tooth acceptance scene and its rig: (scene, cameras, lights)."""
    from ..core.teeth.capture import default_rig
    from ..core.teeth.synthetic import make_scene, scene_target

    sc = make_scene(n_teeth=2)
    for t in sc.teeth:
        t.eta = 1.0
        t.a_t[:] = 1.0
    sc.gums.eta = 1.0
    sc.gums.a_t[:] = 1.0
    sc.blend_spread = 1e-5  # sharp enamel/dentin interface, as in Mitsuba
    cams, lights = default_rig(target=scene_target(sc), width=WIDTH, height=HEIGHT, fov_x_deg=4.8)
    return sc, cams, lights


def _median_times(fns: list, runs: list[int]) -> list[tuple[float, list[float], float, list[float], object]]:
    """Each ``fns[i](run)`` called ``runs[i]`` times, the functions' runs interleaved (run 0 of each, then run 1, ...)
    so that load from other processes on a shared machine falls on both sides alike. Per function: median wall
    seconds, every run's, median CPU seconds of this process (all its threads: numba's and Dr.Jit's; less disturbed
    by other processes than the wall time, a run that had both cores has CPU / wall near 2), every run's, and the
    last result."""
    times: list[list[float]] = [[] for _ in fns]
    cpu: list[list[float]] = [[] for _ in fns]
    last: list[object] = [None] * len(fns)
    for r in range(max(runs)):
        for i, fn in enumerate(fns):
            if r < runs[i]:
                t0, c0 = time.perf_counter(), time.process_time()
                last[i] = fn(r)
                times[i].append(time.perf_counter() - t0)
                cpu[i].append(time.process_time() - c0)
    return [(statistics.median(t), t, statistics.median(c), c, o) for t, c, o in zip(times, cpu, last, strict=True)]


def _source_state() -> dict:
    """The commit the benchmark ran on and the uncommitted changes to the teeth core (others may be editing it)."""
    root = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
    try:
        head = subprocess.run(["git", "rev-parse", "--short", "HEAD"], cwd=root, capture_output=True, text=True,
                              timeout=10).stdout.strip()
        dirty = subprocess.run(["git", "status", "--porcelain", "--", "core/teeth"], cwd=root, capture_output=True,
                               text=True, timeout=10).stdout.split("\n")
    except (OSError, subprocess.SubprocessError):
        return {}
    return {"git_head": head, "uncommitted_teeth_core_files": [line[3:] for line in dirty if line.strip()]}


def _tooth_mean(batches: np.ndarray, mask: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Per channel: the tooth-pixel mean of the batches' mean image and its standard error from the per-pixel
    variance over the independent batches (pixels are independent estimates)."""
    v = batches[:, mask]  # (batches, pixels, 3)
    return v.mean(axis=(0, 1)), np.sqrt(v.var(axis=0, ddof=1).sum(axis=0) / len(v)) / v.shape[1]


def bench_teeth_vs_mitsuba() -> dict:
    """Run the four comparisons of the module docstring; returns their ratios, the absolute seconds of both sides
    (every run), our tracer's ``RenderResult.stats`` and the set-up (spp, image size, threads, CPU count)."""
    import drjit as dr

    from ..core.teeth.compiled_scene import CompiledScene
    from ..core.teeth.path_tracer import RenderSettings, render
    from ..core.teeth.synthetic import tooth_masks

    t_start = time.perf_counter()
    mi = import_mitsuba()
    long_runs = int(os.environ.get("TEETH_MITSUBA_LONG_RUNS", RUNS))
    n_grad_lights = int(os.environ.get("TEETH_MITSUBA_GRADIENT_LIGHTS", GRADIENT_LIGHTS))
    mi_transport_spp = int(os.environ.get("TEETH_MITSUBA_TRANSPORT_SPP", "1024"))
    our_transport_spp = int(os.environ.get("TEETH_MITSUBA_OUR_SPP", "256"))
    sc, cams, lights = bench_scene()
    n_cam, n_l = len(cams), len(lights)
    out: dict = {"machine_cpu_count": os.cpu_count(), "spp": SPP, "image_size": [WIDTH, HEIGHT],
                 "cameras": n_cam, "lights": n_l, "runs_per_median": RUNS, "mitsuba_variant": VARIANT,
                 "mitsuba_version": mi.__version__, "drjit_version": dr.__version__,
                 "mitsuba_threads": int(dr.thread_count()), "mitsuba_integrators":
                 "volpath / prbvolpath, max_depth -1, default rr_depth (5)", "our_settings":
                 f"RenderSettings(max_depth=None) (Russian roulette from rr_depth {RenderSettings().rr_depth}), "
                 "compiled tracer",
                 "targets": TARGETS, "load_average_start": list(os.getloadavg()), "source": _source_state()}
    t0 = time.perf_counter()
    cs = CompiledScene(sc)
    out["our_scene_setup_seconds"] = time.perf_counter() - t0
    with tempfile.TemporaryDirectory() as folder:
        t0 = time.perf_counter()
        scene, diff_keys = mitsuba_scene(mi, sc, cams, folder)
        out["mitsuba_scene_setup_seconds"] = time.perf_counter() - t0
    params = mi.traverse(scene)
    volpath = mi.load_dict({"type": "volpath", "max_depth": -1})
    prb = mi.load_dict({"type": "prbvolpath", "max_depth": -1})

    def ours(cameras, spp: int, seed: int, adjoint=None, light_ids=None):
        return render(sc, cameras, lights, RenderSettings(spp=spp, max_depth=None, seed=seed), adjoint=adjoint,
                      compiled=cs, light_ids=light_ids)

    # ---- warm-up: numba compiles the tracer (forward and gradient), Dr.Jit the volpath kernel
    t0 = time.perf_counter()
    ours(cams[:1], SPP, 0, light_ids=[0])
    ours(cams[:1], 1, 0, adjoint=np.zeros((1, 1, HEIGHT, WIDTH, 3)), light_ids=[0])
    out["our_warmup_seconds"] = time.perf_counter() - t0
    t0 = time.perf_counter()
    set_light(mi, params, lights[0])
    for k in range(n_cam):
        mitsuba_image(mi, scene, k, SPP, 0, volpath)
    out["mitsuba_warmup_seconds"] = time.perf_counter() - t0

    # ---- forward: camera 0, light 0, SPP spp; seconds per sample of the image
    _log("forward (camera 0, light 0)")
    set_light(mi, params, lights[0])
    (t_our, our_times, c_our, our_cpu, res), (t_mi, mi_times, c_mi, mi_cpu, _) = _median_times(
        [lambda r: ours(cams[:1], SPP, 100 + r, light_ids=[0]),
         lambda r: mitsuba_image(mi, scene, 0, SPP, 100 + r, volpath)], [RUNS, RUNS])
    out["forward"] = {"our_seconds": t_our, "mitsuba_seconds": t_mi, "our_runs": our_times, "mitsuba_runs": mi_times,
                      "our_cpu_seconds_runs": our_cpu, "mitsuba_cpu_seconds_runs": mi_cpu,
                      "our_seconds_per_sample": t_our / SPP, "mitsuba_seconds_per_sample": t_mi / SPP,
                      "our_stats": res.stats}
    out["forward_per_sample_ratio"] = t_our / t_mi
    cpu_ratios = {"forward_per_sample_ratio": c_our / c_mi}
    _log(f"forward: ours {t_our:.3f} s, Mitsuba {t_mi:.3f} s")

    # ---- capture: all cameras and lights
    def mitsuba_capture(r: int) -> np.ndarray:
        imgs = np.zeros((n_cam, n_l, HEIGHT, WIDTH, 3), dtype=np.float32)
        for li, light in enumerate(lights):
            set_light(mi, params, light)
            for k in range(n_cam):
                imgs[k, li] = mitsuba_image(mi, scene, k, SPP, 10_000 * (r + 1) + n_cam * li + k, volpath)
        return imgs

    _log(f"capture: ours {long_runs} run(s) of one render call for all lights, Mitsuba {RUNS} runs of "
         f"{n_cam * n_l} renders, interleaved")
    (t_our, our_times, c_our, our_cpu, res), (t_mi, mi_times, c_mi, mi_cpu, _) = _median_times(
        [lambda r: ours(cams, SPP, 200 + r), mitsuba_capture], [long_runs, RUNS])
    out["capture"] = {"our_seconds": t_our, "mitsuba_seconds": t_mi, "our_runs": our_times, "mitsuba_runs": mi_times,
                      "our_cpu_seconds_runs": our_cpu, "mitsuba_cpu_seconds_runs": mi_cpu,
                      "mitsuba_renders": n_cam * n_l, "our_stats": res.stats}
    out["capture_ratio"] = t_our / t_mi
    cpu_ratios["capture_ratio"] = c_our / c_mi
    _log(f"capture: ours {t_our:.1f} s, Mitsuba {t_mi:.1f} s")

    # ---- gradient of sum(adjoint * images) over all cameras and lights
    adjoint = np.random.default_rng(7).standard_normal((n_cam, n_l, HEIGHT, WIDTH, 3))
    grad_lights = np.unique(np.round(np.linspace(0, n_l - 1, min(n_grad_lights, n_l))).astype(int))
    adj_mi = {(int(li), k): mi.TensorXf(adjoint[k, li].astype(np.float32)) for li in grad_lights for k in range(n_cam)}
    for key in diff_keys:
        dr.enable_grad(params[key])
    params.update()

    per_light: dict[str, float] = {}

    def mitsuba_gradient(r: int, ids=grad_lights, cam_ids=range(n_cam)) -> list[np.ndarray]:
        for key in diff_keys:
            dr.set_grad(params[key], 0.0)
        for li in ids:
            t_light = time.perf_counter()
            set_light(mi, params, lights[li])
            for k in cam_ids:
                seed = int(20_000 * (r + 1) + n_cam * li + k)
                img = mi.render(scene, params, sensor=k, integrator=prb, spp=SPP, seed=seed)
                dr.backward(dr.sum(adj_mi[int(li), k] * img, axis=None))
            dr.eval([dr.grad(params[key]) for key in diff_keys])
            dr.sync_thread()
            per_light[str(int(li))] = time.perf_counter() - t_light
        return [np.asarray(dr.grad(params[key])) for key in diff_keys]

    t0 = time.perf_counter()
    mitsuba_gradient(-1, ids=grad_lights[:1], cam_ids=range(1))  # warm-up: compiles prbvolpath's kernels
    out["mitsuba_gradient_warmup_seconds"] = time.perf_counter() - t0
    _log(f"gradient: ours {long_runs} run(s) of one render call for all lights, Mitsuba {RUNS} runs of "
         f"{len(grad_lights) * n_cam} renders + backward, interleaved")
    (t_our, our_times, c_our, our_cpu, res), (t_sub, mi_times, c_sub, mi_cpu, g_mi) = _median_times(
        [lambda r: ours(cams, SPP, 300 + r, adjoint=adjoint), mitsuba_gradient], [long_runs, RUNS])
    scale = n_l / len(grad_lights)
    out["gradient"] = {
        "our_seconds": t_our, "mitsuba_seconds": t_sub * scale, "our_runs": our_times,
        "mitsuba_runs_measured": mi_times, "our_cpu_seconds_runs": our_cpu, "mitsuba_cpu_seconds_runs_measured": mi_cpu,
        "mitsuba_gradient_scaled_from":
        f"{len(grad_lights)} lights {grad_lights.tolist()} x {n_cam} cameras = {len(grad_lights) * n_cam} renders "
        f"+ backward, median {t_sub:.2f} s, times {scale:.2f} for {n_l} lights", "mitsuba_seconds_per_render":
        t_sub / (len(grad_lights) * n_cam), "mitsuba_seconds_per_light_last_run": per_light,
        "our_parameters": int(cs.layout.size),
        "mitsuba_parameters": int(sum(np.size(g) for g in g_mi)), "mitsuba_differentiable": diff_keys,
        "our_parameters_without_mitsuba_counterpart": "a_t of each tooth and the gums (1 here, null interfaces), "
        "the dentin coefficients c (geometry)", "mitsuba_grad_finite": bool(all(np.all(np.isfinite(g)) for g in g_mi)),
        "our_grad_finite": bool(np.all(np.isfinite(res.grad))), "our_stats": res.stats}
    out["gradient_ratio"] = t_our / (t_sub * scale)
    cpu_ratios["gradient_ratio"] = c_our / (c_sub * scale)
    for key in diff_keys:
        dr.disable_grad(params[key])
    params.update()
    _log(f"gradient: ours {t_our:.1f} s, Mitsuba {t_sub * scale:.1f} s (scaled)")

    # ---- transport: tooth-pixel means, camera 0, three lights, all bounces
    _log(f"transport check (ours {our_transport_spp} spp, Mitsuba {mi_transport_spp} spp per light)")
    mask = tooth_masks(sc, cams[:1], cs)[0]
    ids = np.array(TRANSPORT_LIGHTS)
    nb = TRANSPORT_BATCHES
    t0 = time.perf_counter()
    mine = np.array([ours(cams[:1], our_transport_spp // nb, 400 + b, light_ids=ids).images[0] for b in range(nb)])
    t_our = time.perf_counter() - t0
    t0 = time.perf_counter()
    ref = np.zeros_like(mine)
    for j, li in enumerate(ids):
        set_light(mi, params, lights[li])
        for b in range(nb):
            ref[b, j] = mitsuba_image(mi, scene, 0, mi_transport_spp // nb, 500 + nb * j + b, volpath)
    t_mi = time.perf_counter() - t0
    rows = {}
    worst = 0.0
    for j, li in enumerate(ids):
        a, sa = _tooth_mean(mine[:, j], mask)
        b, sb = _tooth_mean(ref[:, j], mask)
        rel = a / b - 1
        worst = max(worst, float(np.abs(rel).max()))
        se = np.hypot(sa / a, sb / b)  # relative standard error of ours / mitsuba
        rows[str(int(li))] = {"ours": a.tolist(), "mitsuba": b.tolist(), "rel_err": rel.tolist(),
                              "our_rel_se": (sa / a).tolist(), "mitsuba_rel_se": (sb / b).tolist(),
                              "ratio_rel_se": se.tolist(), "rel_err_in_se": (rel / se).tolist()}
    out["transport"] = {"camera": 0, "lights": ids.tolist(), "tooth_pixels": int(mask.sum()),
                        "our_spp": our_transport_spp, "mitsuba_spp": mi_transport_spp, "batches": nb,
                        "our_seconds": t_our, "mitsuba_seconds": t_mi, "per_light": rows}
    out["transport_max_rel_err"] = worst
    out["targets_met"] = {k: bool(out[k] <= v) for k, v in TARGETS.items()}
    # the same ratios of process CPU seconds (medians), less disturbed by other processes on a shared machine
    out["cpu_time_ratios"] = cpu_ratios
    out["our_threads"] = int(res.stats["threads"]) if "threads" in res.stats else None
    out["load_average_end"] = list(os.getloadavg())
    out["total_seconds"] = time.perf_counter() - t_start
    return out


BENCHMARKS = {"teeth-vs-mitsuba": bench_teeth_vs_mitsuba}
