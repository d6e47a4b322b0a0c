"""``bench teeth-extrapolation``: does the default teeth fit predict what it never saw? (thesis Figs. 5.8, 5.10,
5.13: novel viewpoints and light directions.)

For each of ``TRUTHS`` (two teeth on gums before the cavity, each truth with its own enamel, dentin and phase
functions, none of them the project's defaults): Mitsuba 3 (``volpath``, all bounces) renders the capture, the
thesis' rig (``default_rig``: 3 cameras of 96 x 64 pixels, 54 lights within 75 degrees of the mouth axis) at
``CAPTURE_SPP``; ``teeth fit CAPTURE --out FIT`` runs with every default (the literature start); then Mitsuba
renders the fitted scene and the truth, twice (two seeds: the truth's own noise), under conditions no capture
image had: a camera 45 degrees to the side and the centre camera, each under ``NOVEL_LIGHTS`` lights 56-84
degrees off the mouth axis (the capture's reach 75), at ``NOVEL_SPP``.

Figures, over every (truth, novel camera, novel light, channel):

* ``tooth_mean_rel_err_worst`` / ``_median``: |fit / truth - 1| of the mean over the tooth pixels (the truth's
  ``tooth_masks``);
* ``tiles_median_rel_err``: the median over 8 x 8 pixel tiles (at least half tooth pixels) of the same on tile
  means, in the unit of the issue's "points" (per cent);
* ``truth_*``: the same figures between the truth's two seeds (the floor any fit meets);
* per truth: the fit's wall time and its parameters against the truth's;
* ``calibration_inside_share``: the share of all fitted parameters (over every truth) whose truth lies inside the
  fit report's 2-sigma interval; of those outside it, ``calibration_outside_determined`` the ones the report names
  as determined (each a defect of the report) and ``calibration_outside_undetermined`` the ones it names as left
  open (``fit_intervals.calibration``); ``calibration_determined`` how many the reports name as determined.

Environment (a shorter run for checking the benchmark itself): TEETH_EXTRAPOLATION_TRUTHS (how many of the
truths), TEETH_EXTRAPOLATION_CAPTURE_SPP, TEETH_EXTRAPOLATION_NOVEL_SPP, TEETH_EXTRAPOLATION_FIT_ARGS (extra
``teeth fit`` arguments, e.g. "--iterations 2"), TEETH_EXTRAPOLATION_SIZE ("W,H" of every camera),
TEETH_EXTRAPOLATION_KEEP (a folder that keeps every truth's capture and fit, instead of a temporary one; a later
run with the same folder reuses a capture rendered from the same truth, samples, size and seed, and fits again).
Progress goes to stderr. The full run takes about 2 hours on 2 cores (three default fits of 20-30 minutes, the
Mitsuba renders).
"""

from __future__ import annotations

import contextlib
import json
import os
import shlex
import shutil
import subprocess
import sys
import tempfile
import time

import numpy as np

CAPTURE_SPP = 128
NOVEL_SPP = 512
NOVEL_LIGHTS = 12
NOVEL_CAMERA_AZIMUTH_DEG = 45.0
NOVEL_LIGHT_OFF_AXIS_DEG = (56.0, 84.0)
TILE = 8

# Three truths, each unlike the project's synthetic defaults (core/teeth/synthetic.py GROUND_TRUTH) in every
# tissue and in the phase functions: per tissue (sigma_t 1/mm, albedo, g1, g2, beta).
TRUTHS = {
    "translucent-forward": {
        "enamel": ((0.55, 0.7, 0.95), (0.985, 0.975, 0.96), 0.78, -0.1, 0.9),
        "dentin": ((1.6, 2.0, 2.6), (0.95, 0.88, 0.75), 0.65, -0.2, 0.85),
    },
    "dense-diffuse": {
        "enamel": ((1.5, 1.8, 2.2), (0.96, 0.95, 0.93), 0.35, -0.3, 0.7),
        "dentin": ((3.0, 3.4, 4.0), (0.9, 0.8, 0.62), 0.3, 0.0, 0.75),
    },
    "yellow-dentin": {
        "enamel": ((0.8, 0.95, 1.2), (0.975, 0.97, 0.955), 0.55, -0.25, 0.8),
        "dentin": ((2.6, 3.0, 3.6), (0.94, 0.82, 0.6), 0.45, 0.1, 0.6),
    },
}


def _log(msg: str) -> None:
    print(f"[teeth-extrapolation] {msg}", file=sys.stderr, flush=True)


def truth_scene(name: str, resolution: int = 32):
    """The two-tooth scene of ``make_scene`` with the truth ``name``'s materials."""
    from ..core.teeth.scene import VolumeMaterial
    from ..core.teeth.synthetic import make_scene

    scene = make_scene(n_teeth=2, resolution=resolution)
    spec = TRUTHS[name]
    for tooth in scene.teeth:
        for tissue in ("enamel", "dentin"):
            st, al, g1, g2, beta = spec[tissue]
            setattr(tooth, tissue, VolumeMaterial(np.array(st), np.array(al), g1, g2, beta))
    scene.blend_spread = 1e-5  # Mitsuba renders a sharp enamel/dentin boundary
    return scene


def novel_rig(scene, width: int, height: int):
    """A camera ``NOVEL_CAMERA_AZIMUTH_DEG`` to the side (the capture's reach 30) and the centre camera, and
    ``NOVEL_LIGHTS`` lights ``NOVEL_LIGHT_OFF_AXIS_DEG`` off the mouth axis (+y), around it."""
    from ..core.teeth.capture import Camera, PointLight, default_rig
    from ..core.teeth.synthetic import scene_target

    target = scene_target(scene)
    cams, lights = default_rig(target, width=width, height=height)
    side = np.radians(NOVEL_CAMERA_AZIMUTH_DEG)
    eye = target + 300.0 * np.array([np.sin(side), np.cos(side), 0.12])
    novel_cams = [Camera.look_at(eye, target, (0, 0, 1), 5.0, width, height, "side45"), cams[1]]
    lo, hi = np.radians(NOVEL_LIGHT_OFF_AXIS_DEG)
    off = np.linspace(lo, hi, NOVEL_LIGHTS)
    around = np.linspace(0.0, 2.0 * np.pi, NOVEL_LIGHTS, endpoint=False) + 0.3
    novel_lights = [PointLight(target + 1000.0 * np.array([np.sin(a) * np.cos(b), np.cos(a), np.sin(a) * np.sin(b)]),
                               lights[0].intensity.copy()) for a, b in zip(off, around, strict=True)]
    return novel_cams, novel_lights


def _tile_means(img: np.ndarray, mask: np.ndarray) -> np.ndarray:
    h, w = mask.shape
    th, tw = h // TILE, w // TILE
    m = mask[: th * TILE, : tw * TILE].reshape(th, TILE, tw, TILE)
    x = img[..., : th * TILE, : tw * TILE, :].reshape(*img.shape[:-3], th, TILE, tw, TILE, 3)
    count = m.sum(axis=(1, 3))
    keep = count >= TILE * TILE // 2
    sums = (x * m[..., None]).sum(axis=(-4, -2))  # (..., th, tw, 3)
    return sums[..., keep, :] / count[keep][:, None]


def compare(pred: np.ndarray, ref: np.ndarray, masks: np.ndarray) -> dict:
    """Tooth-mean and tile figures of ``pred`` against ``ref`` (n_cam, n_light, H, W, 3) over ``masks``."""
    mean_err, tile_err = [], []
    for c in range(ref.shape[0]):
        m = masks[c]
        if not m.any():
            continue
        a = pred[c][:, m].mean(axis=1)  # (n_light, 3)
        b = ref[c][:, m].mean(axis=1)
        mean_err.append(np.abs(a / b - 1.0).ravel())
        ta, tb = _tile_means(pred[c], m), _tile_means(ref[c], m)
        tile_err.append(np.abs(ta / np.maximum(tb, 1e-12) - 1.0).ravel())
    e, t = np.concatenate(mean_err), np.concatenate(tile_err)
    return {"tooth_mean_rel_err_worst": float(e.max()), "tooth_mean_rel_err_median": float(np.median(e)),
            "tiles_median_rel_err": float(np.median(t))}


CAPTURE_SEED = 101
CAPTURE_IDENTITY = "bench_capture.json"  # what a kept capture was rendered from: truth, spp, size, seed


def _kept_capture(cap_dir: str) -> dict | None:
    """The identity of the capture kept in ``cap_dir`` (None: none, or an unreadable one)."""
    try:
        with open(os.path.join(cap_dir, CAPTURE_IDENTITY)) as f:
            return json.load(f)
    except (OSError, ValueError):
        return None


def teeth_extrapolation() -> dict:
    from ..core.teeth.capture import default_rig
    from ..core.teeth.fit_intervals import calibration
    from ..core.teeth.mitsuba_capture import render_capture_mitsuba
    from ..core.teeth.scene import load_scene
    from ..core.teeth.synthetic import scene_target, tooth_masks

    names = list(TRUTHS)[: int(os.environ.get("TEETH_EXTRAPOLATION_TRUTHS", len(TRUTHS)))]
    capture_spp = int(os.environ.get("TEETH_EXTRAPOLATION_CAPTURE_SPP", CAPTURE_SPP))
    novel_spp = int(os.environ.get("TEETH_EXTRAPOLATION_NOVEL_SPP", NOVEL_SPP))
    fit_args = shlex.split(os.environ.get("TEETH_EXTRAPOLATION_FIT_ARGS", ""))
    width, height = (int(v) for v in os.environ.get("TEETH_EXTRAPOLATION_SIZE", "96,64").split(","))
    out = {"truths": {}, "capture_spp": capture_spp, "novel_spp": novel_spp, "fit_args": fit_args,
           "size": [width, height], "novel_camera_azimuth_deg": NOVEL_CAMERA_AZIMUTH_DEG,
           "novel_light_off_axis_deg": list(NOVEL_LIGHT_OFF_AXIS_DEG), "novel_lights": NOVEL_LIGHTS}
    fits, floors, calibrations = [], [], []
    keep = os.environ.get("TEETH_EXTRAPOLATION_KEEP")
    if keep:
        os.makedirs(keep, exist_ok=True)
    with contextlib.nullcontext(keep) if keep else tempfile.TemporaryDirectory() as work:
        for name in names:
            truth = truth_scene(name)
            cams, lights = default_rig(scene_target(truth), width=width, height=height)
            cap_dir, fit_dir = os.path.join(work, name, "capture"), os.path.join(work, name, "fit")
            identity = {"truth": TRUTHS[name], "spp": capture_spp, "size": [width, height], "seed": CAPTURE_SEED}
            if keep and _kept_capture(cap_dir) == json.loads(json.dumps(identity)):
                _log(f"{name}: the kept Mitsuba capture in {cap_dir}")
            else:
                _log(f"{name}: Mitsuba capture, {len(cams)} cameras x {len(lights)} lights at {capture_spp} spp")
                cap = render_capture_mitsuba(truth, cams, lights, spp=capture_spp, seed=CAPTURE_SEED)
                cap.save(cap_dir, truth.to_dict())
                with open(os.path.join(cap_dir, CAPTURE_IDENTITY), "w") as f:
                    json.dump(identity, f)
            if os.path.isdir(fit_dir):  # a kept folder's earlier fit: this run fits afresh
                shutil.rmtree(fit_dir)
            _log(f"{name}: teeth fit with its defaults {' '.join(fit_args)}")
            t0 = time.perf_counter()
            proc = subprocess.run([sys.executable, "-m", "material_structures", "teeth", "fit", cap_dir, "--out",
                                   fit_dir, "--no-progress", *fit_args], capture_output=True, text=True)
            fit_s = time.perf_counter() - t0
            if proc.returncode != 0:
                raise RuntimeError(f"teeth fit of {name} failed: {proc.stderr.strip()[-2000:]}")
            fitted = load_scene(os.path.join(fit_dir, "scene_fit.json"))
            with open(os.path.join(fit_dir, "fit_report.json")) as f:
                report = json.load(f)
            ncams, nlights = novel_rig(truth, width, height)
            masks = tooth_masks(truth, ncams)
            _log(f"{name}: Mitsuba renders of truth (2 seeds) and fit, {len(ncams)} novel cameras x "
                 f"{len(nlights)} novel lights at {novel_spp} spp")
            ta = render_capture_mitsuba(truth, ncams, nlights, spp=novel_spp, seed=7).images
            tb = render_capture_mitsuba(truth, ncams, nlights, spp=novel_spp, seed=8).images
            fa = render_capture_mitsuba(fitted, ncams, nlights, spp=novel_spp, seed=9).images
            fit_fig, floor_fig = compare(fa, ta, masks), compare(tb, ta, masks)
            fits.append(fit_fig)
            floors.append(floor_fig)
            intervals = report.get("intervals", {})
            calib = calibration(intervals, truth) if "parameters" in intervals else {"error": intervals.get("error")}
            calibrations.append(calib)
            out["truths"][name] = {
                "fit": fit_fig, "truth_seed_to_seed": floor_fig, "fit_seconds": fit_s, "calibration": calib,
                "held_out_lights": report.get("held_out", {}).get("rms_relative_tiles"),
                "fitted": {t.name: {"enamel": t.enamel.to_dict(), "dentin": t.dentin.to_dict(), "c": t.c.tolist()}
                           for t in fitted.teeth},
                "truth": {t.name: {"enamel": t.enamel.to_dict(), "dentin": t.dentin.to_dict(), "c": t.c.tolist()}
                          for t in truth.teeth}}
            _log(f"{name}: {fit_fig} (truth's own: {floor_fig}); fit {fit_s:.0f} s")
    for key in ("tooth_mean_rel_err_worst", "tiles_median_rel_err"):
        out[key] = max(f[key] for f in fits)
        out[f"truth_{key}"] = max(f[key] for f in floors)
    out["tooth_mean_rel_err_median"] = float(np.median([f["tooth_mean_rel_err_median"] for f in fits]))
    out["truth_tooth_mean_rel_err_median"] = float(np.median([f["tooth_mean_rel_err_median"] for f in floors]))
    out["fit_seconds_max"] = max(v["fit_seconds"] for v in out["truths"].values())
    # calibration over every truth's parameters: inside their 2-sigma interval, and the determined ones outside
    counted = [c for c in calibrations if "parameters" in c]
    if counted:
        out["calibration_inside_share"] = sum(c["inside"] for c in counted) / sum(c["parameters"] for c in counted)
        out["calibration_outside_determined"] = [n for c in counted for n in c["outside_determined"]]
        out["calibration_outside_undetermined"] = [n for c in counted for n in c.get("outside_undetermined", [])]
        out["calibration_determined"] = sum(c["parameters"] - len(c["undetermined"]) for c in counted)
    return out


BENCHMARKS = {"teeth-extrapolation": teeth_extrapolation}
