"""Benchmarks of the fabric's Blender side: shader accuracy vs eq. 3.9, viewport brushing latency."""

from __future__ import annotations

import time

import numpy as np

from ._blender import blender_with_addon

TILTS = (0.0, 10.0, 20.0, 30.0)
EXACT_CASES = [
    # sigma, tilt, azimuth, view, lamp position
    ((0.3, 0.8), 0.0, 0.0, (30.0, 200.0), (0.4, -0.3, 1.2)),
    ((0.3, 0.8), 15.0, 40.0, (30.0, 200.0), (0.4, -0.3, 1.2)),
    ((0.3, 0.8), 30.0, 40.0, (50.0, 120.0), (-0.6, 0.2, 0.9)),
    ((1.2, 0.25), 30.0, 250.0, (10.0, 0.0), (0.0, 0.8, 0.6)),
    ((2.5, 2.5), 30.0, 90.0, (60.0, 300.0), (0.9, 0.9, 0.5)),
]


KD, KS = (0.05, 0.03, 0.02), (0.7, 0.4, 0.3)  # render_patch_vs_core's defaults
FLAKES = (("surface_like_sigma_0.3_0.8", (0.3, 0.8)), ("fibre_like_sigma_2.5_2.5", (2.5, 2.5)))


def closure_accuracy() -> dict:
    """Closure representations vs eq. 3.9 in numpy (Cycles' closures as ported in
    core.fabric.cycles_closures): the previous fixed approximation ("before") and the per-texel fitted
    mix ("after"), per flake type and fibre tilt (azimuth 40 degrees): relative error median / p90
    over the patch pixels under the benchmark's point lamp, and over 72 cosine-stratified views under
    each procedural HDRI (numpy quadrature of eq. 3.9 x radiance over the hemisphere). RGB, k_d/k_s
    as in the render benchmark."""
    from ..core.fabric import closure_accuracy as A
    from ..core.fabric.closure_fit import closure_eval, fit_closure_maps, legacy_closure_eval
    from ..core.fabric.preset_maps import tilted_quat

    envs = {"sky": A.env_lights(A.sky_hdri()), "interior": A.env_lights(A.interior_hdri())}
    points, wo_patch = A.patch_points()
    views = A.view_set()
    kd, ks = np.asarray(KD), np.asarray(KS)
    out: dict = {}
    fit_s = 0.0
    for label, sigma in FLAKES:
        for tilt in TILTS:
            quat = tilted_quat(tilt, 40.0)
            sg = np.asarray(sigma, float)
            start = time.perf_counter()
            fit = fit_closure_maps(sg[None, None], quat[None, None])
            fit_s += time.perf_counter() - start
            params = (fit.weights[0, 0], fit.shape[0, 0], fit.ggx_scale[0, 0])
            fns = {
                "reference": A.reference_eval(kd, ks, sg, quat),
                "before": lambda wi, wo, q=quat, s=sg: legacy_closure_eval(wi, wo, kd, ks, s, q),
                "after": lambda wi, wo, q=quat, s=sg, p=params: closure_eval(wi, wo, kd, ks, s, q, p),
            }
            case = {}
            ref_pt = A.point_light_radiance(fns["reference"], points, wo_patch)
            ref_env = {k: A.env_radiance(fns["reference"], views, e) for k, e in envs.items()}
            for which in ("before", "after"):
                res = {"point_light": A.rel_stats(A.point_light_radiance(fns[which], points, wo_patch), ref_pt)}
                for k, e in envs.items():
                    res[f"hdri_{k}"] = A.rel_stats(A.env_radiance(fns[which], views, e), ref_env[k])
                case[which] = res
            case["fit"] = {"weight_coeffs": np.round(params[0].astype(float), 4).tolist(),
                           "shape": [round(float(v), 3) for v in params[1]], "ggx_scale": float(params[2][0])}
            out[f"{label}/tilt_{int(tilt)}"] = case
    worst = {w: {m: max(c[w][k][m] for c in out.values() for k in c[w]) for m in ("median", "p90")}
             for w in ("before", "after")}
    return {"cases": out, "worst": worst, "targets": {"median": 0.05, "p90": 0.10},
            "fit_seconds_8_single_texel_fits": fit_s}


HDRI_VIEWS = (3, 4)  # cosine-stratified view set of the Cycles HDRI renders (theta rings, azimuths)


def cycles_hdri_accuracy(samples: int = 64, views: tuple[int, int] = HDRI_VIEWS) -> dict:
    """The fabric under each procedural HDRI in Cycles (world light only), a flat patch seen along
    cosine-stratified views with an orthographic camera, both ways the world can reach it: the exact
    world light (the default: the shader samples the environment against eq. 3.9) and the fitted
    closures (``ExactWorld`` off, or a world the shader cannot sample). Relative error median / p90
    (over views and RGB) against eq. 3.9 and, for the closures, against the numpy closure model
    (``closure_fit.closure_eval``), all as quadratures over the same environment. Per flake type and
    fibre tilt (azimuth 40 degrees), k_d/k_s as above; seconds per mode."""
    import os
    import tempfile

    blender_with_addon()
    from ..addon.fabric.presets import tilted_quat
    from ..addon.fabric.verify import render_hdri_patch_vs_core
    from ..core.fabric import closure_accuracy as A
    from ..core.fabric.closure_fit import hemisphere_grid

    wo = hemisphere_grid(*views, offset=0.125)
    out: dict = {}
    seconds = {"exact_world": 0.0, "fitted_closures": 0.0}
    with tempfile.TemporaryDirectory() as tmp:
        for env_name, env in (("sky", A.sky_hdri()), ("interior", A.interior_hdri())):
            path = os.path.join(tmp, f"{env_name}.exr")
            for label, sigma in FLAKES:
                for tilt in TILTS:
                    case = {}
                    for mode in ("exact_world", "fitted_closures"):
                        start = time.perf_counter()
                        rgb, ref, model = render_hdri_patch_vs_core(
                            env, path, wo, kd=KD, ks=KS, sigma=sigma, quat=tilted_quat(tilt, 40.0), samples=samples,
                            exact_world=mode == "exact_world",
                        )
                        seconds[mode] += time.perf_counter() - start
                        case[mode] = {"vs_eq_3_9": A.rel_stats(rgb, ref)}
                        if mode == "fitted_closures":
                            case[mode]["vs_numpy_closures"] = A.rel_stats(rgb, model)
                            case[mode]["numpy_closures_vs_eq_3_9"] = A.rel_stats(model, ref)
                    out[f"hdri_{env_name}/{label}/tilt_{int(tilt)}"] = case
    worst = {f"{mode}/{k}": {m: max(c[mode][k][m] for c in out.values()) for m in ("median", "p90")}
             for mode, k in (("exact_world", "vs_eq_3_9"), ("fitted_closures", "vs_eq_3_9"),
                             ("fitted_closures", "vs_numpy_closures"))}
    return {"cases": out, "worst": worst, "views": len(wo), "samples": samples, "pixels_per_view": 64,
            "targets_vs_eq_3_9": {"median": 0.05, "p90": 0.10},
            "seconds": {k: round(v, 1) for k, v in seconds.items()}}


def fabric_shader() -> dict:
    numpy_part = closure_accuracy()
    cycles_hdri = cycles_hdri_accuracy()
    blender_with_addon()
    from ..addon.fabric.presets import tilted_quat
    from ..addon.fabric.verify import render_patch_vs_core

    rel = []
    for sigma, tilt, az, view, lamp in EXACT_CASES:
        rgb, ref, mask = render_patch_vs_core(sigma=sigma, quat=tilted_quat(tilt, az), view=view, lamp_position=lamp)
        rel.append((np.abs(rgb[mask] - ref[mask]) / ref[mask]).ravel())
    rel = np.concatenate(rel)
    closure, fitted = {}, {}
    for label, sigma in FLAKES:
        per_tilt, per_tilt_fit = {}, {}
        for tilt in TILTS:
            rgb, ref, mask = render_patch_vs_core(sigma=sigma, quat=tilted_quat(tilt, 40.0), fast_preview=True)
            per_tilt[f"tilt_{int(tilt)}"] = float(np.median(np.abs(rgb[mask] - ref[mask]) / ref[mask]))
            rgb, ref, mask = render_patch_vs_core(sigma=sigma, quat=tilted_quat(tilt, 40.0), fast_preview=True,
                                                  fitted_closures=True)
            rel_fit = np.abs(rgb[mask] - ref[mask]) / ref[mask]
            per_tilt_fit[f"tilt_{int(tilt)}"] = {"median": float(np.median(rel_fit)),
                                                 "p90": float(np.percentile(rel_fit, 90))}
        closure[label] = per_tilt
        fitted[label] = per_tilt_fit
    return {
        "median_rel_err": float(np.median(rel)),
        "p99_rel_err": float(np.percentile(rel, 99)),
        "closure_approx_median_rel_err": closure,
        "fitted_closures_fast_preview_rel_err": fitted,
        "pixels": int(rel.size),
        "closure_numpy": numpy_part,
        "closure_cycles_hdri": cycles_hdri,
    }


def fabric_brush_viewport(size: int = 2048, points: int = 200, repeats: int = 3) -> dict:
    """Per-segment update of a 2048 x 2048 map in Blender: core edit, closure lookup of the changed
    texels (core.fabric.closure_table) and upload of the changed images; and the stroke's end (upload
    and pack)."""
    bpy = blender_with_addon()
    from ..addon.fabric.brushing import BrushSession, BrushSettings
    from ..addon.fabric.maps import maps_to_images
    from ..core.fabric.parameter_maps import make_maps

    rng = np.random.default_rng(0)
    maps = make_maps(
        kd=np.full((size, size, 3), 0.05),
        ks=np.full((size, size, 3), 0.5),
        sigma=np.full((size, size, 2), 0.8),
        basis=np.tile([1.0, 0.0, 0.0, 0.0], (size, size, 1)),
    )
    bpy.ops.wm.read_homefile(use_empty=True)
    from ..addon.fabric.maps import closure_maps_to_images
    from ..core.fabric.closure_fit import ClosureMaps, fit_closure_maps
    from ..core.fabric.closure_table import load_table

    one = fit_closure_maps(maps.sigma[:1, :1], maps.basis[:1, :1])  # uniform map: one geometry
    cm = ClosureMaps(*(np.ascontiguousarray(np.broadcast_to(a, (size, size) + a.shape[2:]))
                       for a in (one.weights, one.shape, one.ggx_scale)))
    session = BrushSession(maps_to_images(maps, "Bench"), closure_maps_to_images(cm, "Bench"))
    load_table()  # once per Blender session
    end_s = []
    t = np.linspace(0.0, 1.0, points)
    uv = np.stack([0.1 + 0.8 * t, 0.5 + 0.3 * np.sin(6.0 * t)], axis=-1) + rng.normal(scale=1e-4, size=(points, 2))
    timings: dict = {"COMB": [], "RECOLOR": []}
    for mode in ("COMB", "RECOLOR"):
        settings = BrushSettings(mode=mode, radius=0.02, strength=0.8, kd=(0.8, 0.1, 0.1))
        for _ in range(repeats):
            session.begin_stroke()
            for a, b in zip(uv[:-1], uv[1:], strict=True):
                start = time.perf_counter()
                session.segment(a, b, settings)
                session.flush()
                timings[mode].append(time.perf_counter() - start)
            start = time.perf_counter()
            session.end_stroke()
            end_s.append(time.perf_counter() - start)
    ms = {k: 1000.0 * np.asarray(v) for k, v in timings.items()}
    all_ms = np.concatenate(list(ms.values()))
    return {
        "ms_per_update": float(np.median(all_ms)),
        "p95_ms_per_update": float(np.percentile(all_ms, 95)),
        "comb_ms_per_update": float(np.median(ms["COMB"])),
        "comb_p95_ms_per_update": float(np.percentile(ms["COMB"], 95)),
        "recolor_ms_per_update": float(np.median(ms["RECOLOR"])),
        "map_size": size,
        "segments": len(all_ms),
        "closures": "looked up per segment for the changed texels (closure_table); uploaded every 0.5 s and at the end",
        "stroke_end_s": [round(t, 3) for t in end_s],
    }


BENCHMARKS = {
    "fabric-shader": fabric_shader,
    "fabric-closure-accuracy": closure_accuracy,
    "fabric-closure-hdri": cycles_hdri_accuracy,
    "fabric-brush-viewport": fabric_brush_viewport,
}
