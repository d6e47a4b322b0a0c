"""``bench teeth``: path throughput, time per optimisation iteration, gradient FD check and the
parameter-recovery acceptance fit (2 teeth, 3 cameras at 96 x 64, 54 lights, perturbed start).

Environment: TEETH_BENCH_ITERATIONS (default 200) and TEETH_BENCH_SYNTH_SPP (default 32) size the
recovery fit (about 35 minutes on 2 cores); TEETH_BENCH_RECOVERY=0 skips it.
"""

from __future__ import annotations

import os
import time

import numpy as np

RECOVERY_FREE = ("*.enamel.sigma_t", "*.enamel.albedo", "*.dentin.sigma_t", "*.dentin.albedo", "tooth*.c")
# the acceptance fit's settings (besides iterations and free): 6 random lights at 4 spp per iteration
# (per second of rendering, gradient variance about 2x lower than 27 lights at 1 spp, measured at the
# stall point of the earlier fits), the anchor image control variate (8 spp of all lights, re-rendered
# every 10 iterations)
RECOVERY_SETTINGS = {"lr": 0.04, "lr_decay": 0.01, "spp": 4, "lights_per_iteration": 6, "anchor_spp": 8,
                     "anchor_every": 10}


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


def acceptance_setup(synth_spp: int = 8, seed: int = 12345):
    from material_structures.core.teeth.capture import default_rig
    from material_structures.core.teeth.synthetic import make_scene, render_capture, scene_target

    truth = make_scene(n_teeth=2)
    cams, lights = default_rig(target=scene_target(truth), width=96, height=64, fov_x_deg=4.8)
    capture = render_capture(truth, cams, lights, spp=synth_spp, spp_background=0, seed=seed)
    return truth, capture


def run_recovery(iterations: int | None = None, synth_spp: int | None = None, seed: int = 1) -> dict:
    """The acceptance fit: synthetic capture, perturbed start, Adam fit of sigma_t, albedo and c.

    Reports the errors of the best-loss parameters (the thesis' choice) and of the average of the
    last quarter of the iterates (Polyak averaging, less sensitive to the Monte Carlo noise).
    """
    from material_structures.core.teeth.optimise import FitSettings, fit
    from material_structures.core.teeth.param_vector import (
        ParamLayout,
        from_optimiser,
        scene_to_vector,
        to_optimiser,
        vector_to_scene,
    )
    from material_structures.core.teeth.synthetic import perturbed_start

    iterations = iterations or int(os.environ.get("TEETH_BENCH_ITERATIONS", "200"))
    synth_spp = synth_spp or int(os.environ.get("TEETH_BENCH_SYNTH_SPP", "32"))
    t0 = time.perf_counter()
    truth, capture = acceptance_setup(synth_spp)
    out: dict = {"synth_seconds": time.perf_counter() - t0}
    start = perturbed_start(truth, seed=seed, sigma_factor=0.25, kappa_shift=0.2)
    settings = FitSettings(iterations=iterations, free=RECOVERY_FREE, **RECOVERY_SETTINGS)
    layout = ParamLayout(truth)
    ys: list = []
    t0 = time.perf_counter()
    best, log = fit(start, capture, settings,
                    callback=lambda e, s: ys.append(to_optimiser(scene_to_vector(s, layout), layout)))
    out["recovery_seconds"] = time.perf_counter() - t0
    out["recovery_iterations"] = len(log)
    out["recovery_seconds_per_iteration"] = out["recovery_seconds"] / max(len(log), 1)
    avg = vector_to_scene(truth, from_optimiser(np.mean(ys[len(ys) * 3 // 4:], axis=0), layout), layout)
    out.update(recovery_errors(avg, truth))
    out["recovery_best_loss_params"] = recovery_errors(best, truth)
    out["recovery_start"] = recovery_errors(start, truth)
    out["recovery_config"] = ("perturbed start (sigma_t x exp(+-0.25), kappa +-0.2, c = 0); free: enamel/dentin "
                              f"sigma_t, albedo, c of both teeth; {iterations} Adam iterations, "
                              f"{RECOVERY_SETTINGS}; errors of the tail-averaged iterate")
    return out


def bench_teeth() -> dict:
    from material_structures.core.teeth.gradient_check import fd_check
    from material_structures.core.teeth.optimise import FitSettings, anchor_image, iteration_gradient
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
    st = RenderSettings(spp=RECOVERY_SETTINGS["spp"], max_depth=settings.max_depth)
    ids = np.sort(np.random.default_rng(0).choice(54, RECOVERY_SETTINGS["lights_per_iteration"], replace=False))
    t0 = time.perf_counter()
    _, _, stats = iteration_gradient(start, capture, ids, st, 0, lay)
    out["seconds_per_iteration"] = time.perf_counter() - t0
    out["iteration_config"] = (f"2 teeth, 3 cameras 96x64 (masked pixels), {len(ids)} of 54 lights, {st.spp} spp, "
                               "2 passes")
    # the acceptance fit's iteration: anchored pass A (two CRN renders) + the anchor's amortised cost
    t0 = time.perf_counter()
    anchor = anchor_image(start, capture, RECOVERY_SETTINGS["anchor_spp"], settings.max_depth, 11, lay)
    anchor_seconds = time.perf_counter() - t0
    t0 = time.perf_counter()
    iteration_gradient(start, capture, ids, st, 0, lay, anchor=anchor)
    out["seconds_per_iteration_anchored"] = (time.perf_counter() - t0
                                             + anchor_seconds / RECOVERY_SETTINGS["anchor_every"])
    half = stats["path_vertices"] / 2
    out["path_vertices_per_second"] = {"forward": half / stats["render_seconds"],
                                       "forward_and_gradient": half / stats["gradient_seconds"]}
    out["lights_per_path_vertex"] = len(ids)
    if os.environ.get("TEETH_BENCH_RECOVERY", "1") != "0":
        out.update(run_recovery())
    return out


BENCHMARKS = {"teeth": bench_teeth}
