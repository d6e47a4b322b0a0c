"""``bench teeth-start-trials``: does the fit's choice among its starts decide what it predicts?

With ``FitSettings.start_trials`` the fit runs its first iterations from each literature start (one per
phase-function g, ``start_trials.best_start``) and goes on from the lowest trial loss (the default before the fit
started at g 0.6 instead, ``literature_init``). For each truth of ``bench teeth-extrapolation`` (its Mitsuba capture:
3 cameras x 54 lights, 128 spp), every start's trial is run to the end (none dropped) and, at
``TEETH_START_TRIALS_ITERATIONS`` (default: 30, the trials' length, then 80: where Gauss-Newton steps begin),
three figures of its iterate are reported side by side:

* ``trial_loss``: the trial's score (the mean loss of its last half), what the fit chooses by;
* ``held_out_tiles``: the fit's own check, rms relative error of 8 x 8 tiles on the capture's held-out lights
  (the 3 farthest off axis), ``fit_report.held_out_check`` at its 64 spp;
* ``novel_*``: tooth-mean errors against the truth under the extrapolation benchmark's novel camera and lights
  (``teeth_extrapolation.novel_rig``), both rendered by this project's tracer at ``NOVEL_SPP`` with the same
  seed (common random numbers: the median is meaningful at this sample count, the worst value is noisy).

A selection rule is worth having when the start with the lowest ``trial_loss`` or ``held_out_tiles`` is the one
with the lowest ``novel_tooth_mean_median``. Environment: TEETH_START_TRIALS_TRUTHS (comma-separated names),
TEETH_START_TRIALS_ITERATIONS (comma-separated iteration counts), TEETH_EXTRAPOLATION_KEEP (the folder of kept
captures, shared with ``bench teeth-extrapolation``). About 15 minutes per truth on 2 cores.
"""

from __future__ import annotations

import contextlib
import json
import os
import sys
import tempfile

import numpy as np

NOVEL_SPP = 64
TRIAL_ITERATIONS = 30  # the trials' length when the fit ran them by default (FitSettings.start_trials)


def _log(msg: str) -> None:
    print(f"[teeth-start-trials] {msg}", file=sys.stderr, flush=True)


def _capture(name: str, work: str):
    """The truth's capture as ``bench teeth-extrapolation`` renders it (reused from a kept folder)."""
    from ..core.teeth.capture import Capture, default_rig
    from ..core.teeth.capture_outliers import clamp_bright_outliers
    from ..core.teeth.mitsuba_capture import render_capture_mitsuba
    from ..core.teeth.synthetic import scene_target
    from . import teeth_extrapolation as T

    truth = T.truth_scene(name)
    cap_dir = os.path.join(work, name, "capture")
    identity = {"truth": T.TRUTHS[name], "spp": T.CAPTURE_SPP, "size": [96, 64], "seed": T.CAPTURE_SEED}
    if T._kept_capture(cap_dir) != json.loads(json.dumps(identity)):
        _log(f"{name}: Mitsuba capture at {T.CAPTURE_SPP} spp")
        cams, lights = default_rig(scene_target(truth), width=96, height=64)
        cap = render_capture_mitsuba(truth, cams, lights, spp=T.CAPTURE_SPP, seed=T.CAPTURE_SEED)
        cap.save(cap_dir, truth.to_dict())
        with open(os.path.join(cap_dir, T.CAPTURE_IDENTITY), "w") as f:
            json.dump(identity, f)
    return truth, clamp_bright_outliers(Capture.load(cap_dir))[0]  # the capture as ``teeth fit`` reads it


def teeth_start_trials() -> dict:
    from ..core.teeth.fit_report import held_out_check
    from ..core.teeth.fit_settings import FitSettings
    from ..core.teeth.literature_init import literature_starts
    from ..core.teeth.optimise import fit, held_out_light_ids
    from ..core.teeth.path_tracer import RenderSettings, render
    from ..core.teeth.start_trials import trial_score
    from ..core.teeth.synthetic import scene_target, tooth_masks
    from . import teeth_extrapolation as T

    fs = FitSettings()
    names = [n for n in os.environ.get("TEETH_START_TRIALS_TRUTHS", "translucent-forward,dense-diffuse").split(",")
             if n]
    unknown = [n for n in names if n not in T.TRUTHS]
    if unknown:
        raise ValueError(f"unknown truth(s) {unknown}; the truths are {list(T.TRUTHS)}")
    lengths = sorted(int(v) for v in os.environ.get("TEETH_START_TRIALS_ITERATIONS", f"{TRIAL_ITERATIONS},80")
                     .split(","))
    out: dict = {"iterations": lengths, "novel_spp": NOVEL_SPP, "truths": {}}
    keep = os.environ.get("TEETH_EXTRAPOLATION_KEEP")
    with contextlib.nullcontext(keep) if keep else tempfile.TemporaryDirectory() as work:
        for name in names:
            truth, cap = _capture(name, work)
            starts = literature_starts(truth, cap)  # the geometry only: the search's materials are its own
            ncams, nlights = T.novel_rig(truth, 96, 64)
            masks = tooth_masks(truth, ncams)
            pixels = [np.flatnonzero(m.ravel()) for m in masks]
            rs = RenderSettings(spp=NOVEL_SPP, seed=5)
            truth_img = render(truth, ncams, nlights, rs, pixels=pixels).images
            held = held_out_light_ids(cap, scene_target(truth), fs.held_out_lights)
            rows = []
            with tempfile.TemporaryDirectory() as trials:
                for n in lengths:
                    for k, start in enumerate(starts):
                        folder = os.path.join(trials, f"start{k}")
                        resumed = os.path.isfile(os.path.join(folder, "checkpoint.json"))
                        scene, log = fit(start, cap, fs, out_dir=folder, resume=resumed, until=n)
                        check = held_out_check(scene, cap, held)
                        img = render(scene, ncams, nlights, rs, pixels=pixels).images
                        novel = T.compare(img, truth_img, masks)
                        rows.append({"iterations": n, "g": start.teeth[0].enamel.g1, "trial_loss": trial_score(log),
                                     "held_out_tiles": check["rms_relative_tiles"],
                                     "novel_tooth_mean_worst": novel["tooth_mean_rel_err_worst"],
                                     "novel_tooth_mean_median": novel["tooth_mean_rel_err_median"]})
                        _log(f"{name}: {rows[-1]}")
            out["truths"][name] = rows
    return out


BENCHMARKS = {"teeth-start-trials": teeth_start_trials}
