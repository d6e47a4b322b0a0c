"""``bench teeth``: path throughput, time per optimisation iteration, gradient FD check and the
parameter-recovery acceptance fit (2 teeth, 3 cameras at 96 x 64, 54 lights, perturbed start).

Environment: TEETH_BENCH_ITERATIONS (default: the acceptance preset's) and TEETH_BENCH_SYNTH_SPP (default 128) size the
recovery fit (about 60 minutes on 2 cores; progress on stderr); TEETH_BENCH_RECOVERY=0 skips it. The synthetic
capture stands in for photographs, whose noise is far below a Monte Carlo image's; near the optimum the residual's
noise is pass A's plus the capture's (at the truth a 64-spp capture instead of 32 lowered the dentin coefficients'
gradient standard deviation by 12 %, geometric mean; that model predicts 13 %).
"""

from __future__ import annotations

import os
import sys
import time
from dataclasses import asdict

import numpy as np

from ..core.teeth.fit_settings import FitSettings

RECOVERY_FREE = ("*.enamel.sigma_t", "*.enamel.albedo", "*.dentin.sigma_t", "*.dentin.albedo", "tooth*.c")
# the fit's default settings (besides free; docs/teeth-fit.md has the measurements): 6 random lights
# per iteration; pass A (the image in the adjoint 2 (C_A - C_ref)) at 32 spp, pass B (the gradient) at 4 spp,
# both traced by 2 processes. Near the optimum the gradient's variance is mostly pass A's per-pixel noise times
# the pixel's derivative: at the stall point of the earlier anchored fits (8-spp anchor image of all
# lights every 10 iterations, 4-spp brackets), a fresh 32-spp pass A has about 2x lower gradient
# variance per iteration even before counting the anchor's own noise, which the anchored gradients
# shared for 10 iterations; it costs about 2.6x the CPU time per iteration (16.4 s in 2 processes
# against 12.6 s in one). From iteration 80 the materials step along the damped inverse Gauss-Newton
# matrix (estimated every 40 iterations; gauss_newton.py), which follows the valley where enamel and
# dentin absorption trade off; Adam alone crept along it (docs/teeth-fit.md). The loss is the L2
# loss of 8 x 8 box-filtered images (loss_block 8): near the optimum most of the gradient's noise is the
# product of the residual's per-pixel noise and pass B's per-pixel derivative noise, which averages over
# a tile while the smooth signal does not; measured at the truth with c moved by 0.1 (8 gradients each),
# the dentin coefficients' gradient sd is 7-18x lower than per pixel, the materials' 1.3-4.3x (median 1.9x).
# The Gauss-Newton matrix is the pooled estimate of 8 passes (its Monte Carlo bias, extra curvature that
# made the steps along the valley's flattest directions 3-10 % of Newton's, divided by 8), damped by
# 0.01; the guard reacts to a doubled loss only (windows vary by +-10 % from noise). The dentin
# coefficients keep Adam, on a gradient by central differences with common random numbers
# (dentin_shape_gradient: the path-space one is noise, and biased at a sharp boundary); the result is the
# mean of the last 30 % of 300 iterations (average_tail)
RECOVERY_SETTINGS = {**asdict(FitSettings()), "workers": 2}


def recovery_errors(fit_scene, truth) -> dict:
    s_err, a_err, c_err = [], [], []
    for t, g in zip(fit_scene.teeth, truth.teeth, strict=True):
        for part in ("enamel", "dentin"):
            mf, mg = getattr(t, part), getattr(g, part)
            s_err.append(np.abs(mf.sigma_t / mg.sigma_t - 1).max())
            a_err.append(np.abs(mf.albedo / mg.albedo - 1).max())
        c_err.append(np.abs(t.c - g.c).max())
    return {"recovery_sigma_t_rel_err": float(max(s_err)), "recovery_albedo_rel_err": float(max(a_err)),
            "recovery_dentin_abs_err": float(max(c_err))}


def acceptance_setup(synth_spp: int = 8, seed: int = 12345, workers: int = 1):
    from material_structures.core.teeth.capture import default_rig
    from material_structures.core.teeth.synthetic import make_scene, render_capture, scene_target

    truth = make_scene(n_teeth=2)
    cams, lights = default_rig(target=scene_target(truth), width=96, height=64, fov_x_deg=4.8)
    capture = render_capture(truth, cams, lights, spp=synth_spp, spp_background=0, seed=seed, workers=workers)
    return truth, capture


def run_recovery(iterations: int | None = None, synth_spp: int | None = None, seed: int = 1) -> dict:
    """The acceptance fit: synthetic capture, perturbed start, fit of sigma_t, albedo and c (Adam for 80
    iterations, then Gauss-Newton steps for the materials while c keeps Adam; RECOVERY_SETTINGS).

    Reports the errors of the fit's result (the preset averages the last iterates, ``average_tail``)
    and of its best-loss parameters (the thesis' choice).
    """
    from material_structures.core.teeth.optimise import FitSettings, fit
    from material_structures.core.teeth.synthetic import perturbed_start

    iterations = iterations or int(os.environ.get("TEETH_BENCH_ITERATIONS", RECOVERY_SETTINGS["iterations"]))
    synth_spp = synth_spp or int(os.environ.get("TEETH_BENCH_SYNTH_SPP", "128"))
    t0 = time.perf_counter()
    truth, capture = acceptance_setup(synth_spp, workers=RECOVERY_SETTINGS["workers"])
    out: dict = {"synth_seconds": time.perf_counter() - t0}
    start = perturbed_start(truth, seed=seed, sigma_factor=0.25, kappa_shift=0.2)
    settings = FitSettings(**{**RECOVERY_SETTINGS, "iterations": iterations, "free": RECOVERY_FREE})
    n_done, best = 0, start
    t0 = time.perf_counter()

    def record(entry: dict, scene) -> None:
        nonlocal n_done, best
        n_done += 1
        if entry["loss"] == entry["best_loss"]:  # this iterate became the fit's best-loss scene
            best = scene.copy()
        if n_done % 10 == 0:  # progress on stderr (stdout is the JSON result)
            err = recovery_errors(scene, truth)
            print(f"bench teeth: recovery iteration {n_done}/{iterations}, loss {entry['loss']:.3e}, "
                  f"{(time.perf_counter() - t0) / n_done:.1f} s per iteration; this iterate's sigma_t / albedo / c "
                  f"errors {err['recovery_sigma_t_rel_err']:.3f} / {err['recovery_albedo_rel_err']:.3f} / "
                  f"{err['recovery_dentin_abs_err']:.3f}"
                  + (f"; Gauss-Newton damping {entry['gauss_newton_damping']:.3g}"
                     if "gauss_newton_damping" in entry else ""), file=sys.stderr, flush=True)
        if entry.get("gauss_newton_rollback"):
            print(f"bench teeth: iteration {entry['iteration']}: the loss rose, Gauss-Newton went back to its best "
                  f"window (damping now {entry['gauss_newton_damping']:.3g})", file=sys.stderr, flush=True)

    result, log = fit(start, capture, settings, callback=record)
    out["recovery_seconds"] = time.perf_counter() - t0
    out["recovery_iterations"] = len(log)
    out["recovery_seconds_per_iteration"] = out["recovery_seconds"] / max(len(log), 1)
    out.update(recovery_errors(result, truth))
    out["recovery_best_loss_params"] = recovery_errors(best, truth)
    out["recovery_start"] = recovery_errors(start, truth)
    settings_text = {k: v for k, v in RECOVERY_SETTINGS.items() if k not in ("iterations", "free")}
    out["recovery_config"] = (f"capture {synth_spp} spp; perturbed start (sigma_t x exp(+-0.25), kappa +-0.2, "
                              "c = 0); free: enamel/dentin sigma_t, albedo, c of both teeth; "
                              f"{iterations} iterations ({RECOVERY_SETTINGS.get('optimiser', 'adam')}), "
                              f"{settings_text}; errors of the fit's result (the mean of the last average_tail "
                              "of the iterates)")
    return out


def bench_teeth() -> dict:
    from material_structures.core.teeth.gradient_check import fd_check
    from material_structures.core.teeth.optimise import FitSettings, iteration_gradient
    from material_structures.core.teeth.param_vector import ParamLayout
    from material_structures.core.teeth.path_tracer import RenderSettings
    from material_structures.core.teeth.synthetic import perturbed_start

    out: dict = {}
    layout, g, fd = fd_check()
    out["fd_max_rel_err"] = float(np.max(np.abs(g - fd) / np.abs(fd)))
    out["fd_components"] = int(layout.size)
    truth, capture = acceptance_setup(2)
    start = perturbed_start(truth, seed=1)
    settings = FitSettings()
    lay = ParamLayout(start)
    # path throughput: 4 spp in both passes
    st = RenderSettings(spp=RECOVERY_SETTINGS["spp"], max_depth=settings.max_depth)
    ids = np.sort(np.random.default_rng(0).choice(54, RECOVERY_SETTINGS["lights_per_iteration"], replace=False))
    _, _, stats = iteration_gradient(start, capture, ids, st, 0, lay)
    # the acceptance fit's iteration (RECOVERY_SETTINGS: 32-spp pass A, 4-spp pass B; 2 processes where the
    # numpy tracer traces)
    st_fit = RenderSettings(spp=RECOVERY_SETTINGS["spp"], max_depth=settings.max_depth,
                            workers=RECOVERY_SETTINGS["workers"])
    t0 = time.perf_counter()
    iteration_gradient(start, capture, ids, st_fit, 0, lay, image_spp=RECOVERY_SETTINGS["image_spp"],
                       loss_block=RECOVERY_SETTINGS["loss_block"])
    out["seconds_per_iteration"] = time.perf_counter() - t0
    from material_structures.core.teeth.path_tracer import _compiled_tracer

    tracer = ("compiled tracer, one thread per core" if _compiled_tracer() is not None
              else f"numpy tracer, {RECOVERY_SETTINGS['workers']} processes")
    depth = "all bounces" if settings.max_depth is None else f"max_depth {settings.max_depth}"
    out["iteration_config"] = (f"2 teeth, 3 cameras 96x64 (masked pixels), {len(ids)} of 54 lights, pass A "
                               f"{RECOVERY_SETTINGS['image_spp']} spp, pass B {st.spp} spp, {depth}, {tracer}")
    half = stats["path_vertices"] / 2
    out["path_vertices_per_second"] = {"forward": half / stats["render_seconds"],
                                       "forward_and_gradient": half / stats["gradient_seconds"]}
    out["lights_per_path_vertex"] = len(ids)
    if os.environ.get("TEETH_BENCH_RECOVERY", "1") != "0":
        out.update(run_recovery())
    return out


BENCHMARKS = {"teeth": bench_teeth}
