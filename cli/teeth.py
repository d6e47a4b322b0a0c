"""``teeth``: synthetic captures, appearance fitting and rendering of the teeth model (chapter 5).

    python -m material_structures teeth synth --out DIR [--teeth 2 | --smile] [--width 96 --height 64] [--samples 16]
    python -m material_structures teeth fit CAPTURE_DIR --out FIT_DIR [--iterations 300] [--resume]
    python -m material_structures teeth render SCENE_JSON CAPTURE_DIR --out DIR [--samples 16]
    python -m material_structures teeth sensitivity CAPTURE_DIR (--capture-samples N | --noise-variance V)

Old spellings, accepted until the next release with a note on stderr: ``teeth synth OUT`` (positional),
``--spp`` (``--samples``), ``--spp-background`` (``--samples-background``), ``teeth synth --resolution``
(``--mesh-resolution``), ``--capture-spp`` (``--capture-samples``), ``teeth sensitivity --json`` (``--out``).
"""

from __future__ import annotations

import argparse
import contextlib
import json
import math
import os
import sys

from ..core.errors import MissingFileError, UserError
from ..core.teeth.fit_checkpoint import TRIALS_DIR
from ..core.teeth.fit_settings import FitSettings
from .checks import (
    OLD_SPELLING_NOTE,
    UsageError,
    at_least,
    between,
    old_spelling,
    positive_float,
    refuse_output_over_inputs,
    refuse_unwritable_folder,
    seed,
)

FIT_DEFAULTS = FitSettings()  # the defaults of ``teeth fit``: the fit's own, no second table


def add_parser(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("teeth", help="teeth appearance model: synthetic captures, fitting, rendering")
    tsub = p.add_subparsers(dest="teeth_command", metavar="ACTION", required=True)

    s = tsub.add_parser("synth", help="render a synthetic capture of a known ground truth")
    s.add_argument("--out", default=None, help="output capture folder (capture.json, images/, masks/, scene.json)")
    s.add_argument("out_positional", nargs="?", default=None, metavar="OUT",
                   help="old spelling of --out (a positional folder), accepted until the next release (with a note)")
    s.add_argument("--scene", default=None,
                   help="render this scene JSON (your own ground truth) instead of the built-in jaw section")
    s.add_argument("--teeth", type=between(1, 32, int), default=2,
                   help="number of teeth of the built-in jaw section (incisor, canine, premolar, molar)")
    s.add_argument("--smile", action="store_true",
                   help="render the built-in smile instead of the jaw section: 8 upper and 8 lower front teeth, "
                        "gums and the oral cavity, every tooth with its own materials and dentin shape "
                        "(--truth-seed); the cameras frame the arches")
    s.add_argument("--truth-seed", type=seed, default=None,
                   help="with --smile: the seed the teeth's materials and dentin shapes are drawn from "
                        "(default 69)")
    s.add_argument("--width", type=between(4, 16384, int), default=None,
                   help="image width in pixels (default 96; with --smile 208, an upper central incisor about "
                        "31 pixels across)")
    s.add_argument("--height", type=between(4, 16384, int), default=None,
                   help="image height in pixels (default 64; with --smile 128)")
    s.add_argument("--lights", type=between(1, 4096, int), default=54, help="number of lights (one image each)")
    s.add_argument("--cameras", type=between(1, 256, int), default=3, help="number of cameras")
    s.add_argument("--samples", type=between(1, 1 << 24, int), default=16,
                   help="samples per masked (tooth) pixel; with --renderer mitsuba, per pixel")
    s.add_argument("--samples-background", type=between(0, 1 << 24, int), default=2,
                   help="samples per other pixel (0: black)")
    s.add_argument("--mesh-resolution", type=between(8, 1024, int), default=32,
                   help="tooth mesh resolution of the built-in jaw section (grid cells a side)")
    s.add_argument("--seed", type=seed, default=12345, help="random seed of the path samples")
    s.add_argument("--renderer", choices=("ours", "mitsuba"), default="ours",
                   help="ours (our path tracer) or mitsuba (Mitsuba 3 volpath, all bounces, every pixel at --samples; "
                        "llvm_ad_rgb where Dr.Jit's LLVM backend loads, else scalar_rgb; needs mitsuba, as .venv has): "
                        "for mitsuba the enamel/dentin boundary is made sharp (blend spread 1e-5 mm, as Mitsuba "
                        "renders it) and scene.json is that scene")
    old_spelling(s, "--spp", "--samples")
    old_spelling(s, "--spp-background", "--samples-background")
    old_spelling(s, "--resolution", "--mesh-resolution")
    s.set_defaults(func=run_synth)

    f = tsub.add_parser("fit", help="fit the appearance model to a capture folder",
                        description="Fit enamel, dentin and gums to a capture with the best measured settings "
                                    "(5-20 s per iteration for a 3-camera, 54-light capture of two teeth on 2 "
                                    "cores, longer while the materials are far off: 35-100 minutes for 300; it "
                                    "grows with the teeth: about 2 hours for a 16-tooth smile). Writes "
                                    "scene_fit.json (the result), fit_report.json and check.png (the result "
                                    "against lights the fit never used), loss.json, loss.png, scene_best.json "
                                    "and checkpoint.json.")
    f.add_argument("capture", help="capture folder with capture.json, images, masks and scene.json")
    f.add_argument("--out", required=True, help="fit folder (created if missing)")
    f.add_argument("--scene", default=None, help="scene JSON with geometry/start (default CAPTURE/scene.json)")
    f.add_argument("--init", choices=("literature", "scene", "perturbed"), default="literature",
                   help="start point: the teeth's materials from a literature-table search (default, as the "
                        "thesis; gums and cavity from the scene), the scene's values, or a perturbation of them")
    f.add_argument("--iterations", type=at_least(1), default=None,
                   help=f"iterations (default {FIT_DEFAULTS.iterations}; fewer: a quicker, rougher fit)")
    f.add_argument("--textured-iterations", type=at_least(0), default=None,
                   help="then this many iterations with the enamel transmittance as a texture (default "
                        f"{FIT_DEFAULTS.textured_iterations})")
    f.add_argument("--held-out-lights", type=at_least(0), default=None,
                   help="lights left out of the fit to check it by: those farthest off the capture's axis, so the "
                        "check predicts lights outside the cone the fit saw; at most a quarter of the capture's "
                        f"lights (default {FIT_DEFAULTS.held_out_lights})")
    f.add_argument("--held-out-camera", type=at_least(0), default=None, metavar="INDEX",
                   help="a camera (its index in capture.json) left out of the fit and rendered afterwards under "
                        "every light, to check new views by (default: none)")
    f.add_argument("--free", default=None,
                   help="comma-separated parameter name patterns to fit (default: every material, a_t and the "
                        "dentin shape)")
    f.add_argument("--seed", type=seed, default=None,
                   help="random seed of the perturbed start, the lights of each iteration and the path samples "
                        f"(default {FIT_DEFAULTS.seed}); another seed gives an independent fit")
    f.add_argument("--resume", action="store_true",
                   help="continue an interrupted fit from its --out folder, with the settings it started with")
    f.add_argument("--scheduler", default=None,
                   help="Dask scheduler address (tcp://host:8786): per-view gradient renders become tasks there")
    f.add_argument("--dask-workers", type=between(1, 1024, int), default=None,
                   help="render on a local Dask cluster of this many processes (on one machine the fit renders "
                        "faster in its own process, the default)")
    f.add_argument("--workers", type=between(1, 1024, int), default=FIT_DEFAULTS.workers,
                   help="processes on this machine that share each render pass (helps where numba is missing; "
                        "with Dask, --dask-workers or the scheduler's workers render instead)")
    f.add_argument("--no-progress", action="store_true", help="no progress bar")
    f.set_defaults(func=run_fit)

    r = tsub.add_parser("render", help="render a scene JSON with the cameras/lights of a capture")
    r.add_argument("scene", help="scene JSON (scene.json, a fit's scene_fit.json)")
    r.add_argument("capture", help="capture folder whose cameras and lights are rendered (capture.json)")
    r.add_argument("--out", required=True, help="output folder: one camC_lightL.exr per camera and light")
    r.add_argument("--samples", type=between(1, 1 << 24, int), default=16, help="samples per pixel")
    r.add_argument("--seed", type=seed, default=1, help="random seed of the path samples")
    old_spelling(r, "--spp", "--samples")
    r.set_defaults(func=run_render)

    v = tsub.add_parser("sensitivity",
                        help="how strongly a capture constrains sigma_s, sigma_a and the dentin coefficients")
    v.add_argument("capture", help="capture folder (capture.json, masks; images are not needed)")
    v.add_argument("--scene", default=None, help="scene JSON to evaluate at (default CAPTURE/scene.json)")
    noise = v.add_mutually_exclusive_group(required=True)
    noise.add_argument("--capture-samples", type=between(1, 1 << 24, int),
                       help="synthetic capture: its samples per pixel")
    noise.add_argument("--noise-variance", type=positive_float,
                       help="the photographs' noise variance per pixel value")
    old_spelling(noise, "--capture-spp", "--capture-samples")
    v.add_argument("--passes", type=between(2, 4096, int), default=6,
                   help="independent 1-sample-per-pixel Jacobian passes (>= 2)")
    v.add_argument("--block", type=between(1, 4096, int), default=8,
                   help="pixel tile size the image changes are pooled over")
    v.add_argument("--max-depth", type=between(1, 1 << 16, int), default=None,
                   help="stop every path after this many bounces (an experiment: biased dark); default all bounces")
    v.add_argument("--out", default=None, help="also write the table to this JSON file")
    old_spelling(v, "--json", "--out")
    v.set_defaults(func=run_sensitivity)


def run_synth(args: argparse.Namespace) -> int:
    from ..core.teeth.synthetic import render_capture

    if args.out_positional is not None:
        import sys

        if args.out is not None and args.out != args.out_positional:
            raise UsageError(f"two output folders: --out {args.out!r} and OUT {args.out_positional!r}; give --out")
        print(OLD_SPELLING_NOTE.format(old="the positional OUT", new="--out OUT"), file=sys.stderr)
        args.out = args.out_positional
    if args.out is None:
        raise UsageError("teeth synth: the following arguments are required: --out")
    refuse_unwritable_folder(args.out)
    if args.scene:
        refuse_output_over_inputs(args.out, [args.scene])
    scene, cams, lights = synth_truth(args)
    if args.renderer == "mitsuba":
        from ..core.teeth.mitsuba_capture import import_mitsuba, render_capture_mitsuba

        _, variant = import_mitsuba()
        with _bar(len(lights), "synth (mitsuba)", "light") as bar:
            cap = render_capture_mitsuba(scene, cams, lights, args.samples, args.seed, progress=bar.update,
                                         variant=variant)
        how = (f" rendered by Mitsuba 3 {variant} (volpath, all bounces, {args.samples} spp per pixel; blend spread "
               "1e-5 mm)")
    else:
        with _bar(2 * len(lights), "synth", "light-pass") as bar:
            cap = render_capture(scene, cams, lights, args.samples, args.samples_background, args.seed,
                                 progress=bar.update)
        how = ""
    cap.save(args.out, scene.to_dict())
    print(f"wrote {len(cams)} x {len(lights)} images and masks{how} to {args.out}")
    return 0


def synth_truth(args: argparse.Namespace):
    """``teeth synth``'s ground truth as it renders it and writes it to ``scene.json``, and its rig: (scene,
    cameras, lights). Mitsuba's enamel/dentin boundary is sharp, so its truth has the smallest blend spread."""
    scene, cams, lights = synth_scene_and_rig(args)
    if args.renderer == "mitsuba":
        scene = scene.copy()
        scene.blend_spread = 1e-5
    return scene, cams, lights


def synth_scene_and_rig(args: argparse.Namespace):
    """``teeth synth``'s ground truth and rig from its options: (scene, cameras, lights)."""
    from ..core.teeth.capture import default_rig
    from ..core.teeth.scene import load_scene
    from ..core.teeth.smile import SMILE_CAPTURE_SIZE, SMILE_TRUTH_SEED, smile_framing, smile_scene, smile_truth
    from ..core.teeth.synthetic import make_scene, scene_target

    if args.smile and args.scene is not None:
        raise UsageError("teeth synth: give --smile or --scene, not both")
    if args.truth_seed is not None and not args.smile:
        raise UsageError("teeth synth: --truth-seed chooses the teeth of --smile; add --smile")
    size = SMILE_CAPTURE_SIZE if args.smile else (96, 64)
    width, height = args.width or size[0], args.height or size[1]
    if args.smile:
        truth_seed = SMILE_TRUTH_SEED if args.truth_seed is None else args.truth_seed
        scene = smile_truth(smile_scene(resolution=args.mesh_resolution), seed=truth_seed)
        target, fov = smile_framing(scene)
    else:
        if args.scene is not None:
            scene = load_scene(args.scene)
            if not scene.teeth:
                raise UserError(f"{args.scene} has no teeth to render")
        else:
            scene = make_scene(n_teeth=args.teeth, resolution=args.mesh_resolution)
        span = max(12.0, 8.6 * len(scene.teeth) + 6.0)
        target, fov = scene_target(scene), 2.0 * math.degrees(math.atan(0.5 * span / 300.0))
    cams, lights = default_rig(target=target, width=width, height=height, n_lights=args.lights,
                               n_cameras=args.cameras, fov_x_deg=fov)
    return scene, cams, lights


PROGRESS_ENV = "MATERIAL_STRUCTURES_PROGRESS"  # "json": progress as JSON lines on stdout, no bars


def _event(**fields) -> None:
    print(json.dumps(fields), flush=True)


class _NoBar:
    """Stands in for a tqdm bar where bars are off or tqdm is not installed (a desktop Blender's Python)."""

    def __init__(self, *_, **__) -> None:
        pass

    def __enter__(self) -> _NoBar:
        return self

    def __exit__(self, *exc) -> None:
        pass

    def update(self, *_) -> None:
        pass

    def set_postfix(self, **_) -> None:
        pass

    def set_description_str(self, *_) -> None:
        pass

    def close(self) -> None:
        pass


def _bar(total: int, desc: str, unit: str, disable: bool = False):
    """A tqdm progress bar on stderr, or a stand-in that shows nothing."""
    if disable:
        return _NoBar()
    try:
        from tqdm import tqdm
    except ImportError:
        return _NoBar()
    return tqdm(total=total, desc=desc, unit=unit)


# the FitSettings that ``teeth fit`` flags set (the flag of each); --workers says only where the fit renders
FIT_FLAGS = {"iterations": "--iterations", "textured_iterations": "--textured-iterations",
             "held_out_lights": "--held-out-lights", "held_out_camera": "--held-out-camera", "seed": "--seed",
             "free": "--free"}


# flags a resumed fit takes: how many iterations it runs (its checkpoints continue to any length)
RESUME_SCHEDULE = ("iterations", "textured_iterations")


def _given_settings(args: argparse.Namespace) -> dict:
    """The settings given by flags on the command line (a flag left out is not among them)."""
    given = {name: getattr(args, name) for name in FIT_FLAGS if getattr(args, name) is not None}
    if "free" in given:
        given["free"] = tuple(p.strip() for p in given["free"].split(",") if p.strip()) or FIT_DEFAULTS.free
    return given


def fit_settings(args: argparse.Namespace) -> FitSettings:
    """The FitSettings of a ``teeth fit`` command line: FitSettings' defaults, with the flags given."""
    from dataclasses import replace

    return replace(FIT_DEFAULTS, **_given_settings(args), workers=args.workers)


def resumed_settings(args: argparse.Namespace, saved: dict | None, where: str) -> FitSettings:
    """The settings a resumed fit goes on with: those it started with (``saved``, read from ``where``; None
    from a fit of an earlier version, which saved none: the flags'), with this run's --workers and, where
    given, its --iterations and --textured-iterations (a fit may be resumed to run longer or shorter). Any
    other flag given with another value than the fit started with is refused, naming both."""
    from dataclasses import replace

    from ..core.errors import UserError
    from ..core.teeth.fit_settings import settings_from_dict

    if saved is None:
        return fit_settings(args)
    try:
        fs = settings_from_dict(saved)
    except UserError as exc:
        raise UserError(f"{where}: {exc}; start the fit again without --resume") from None

    def shown(v) -> str:
        return ",".join(v) if isinstance(v, tuple) else str(v)

    given = _given_settings(args)
    schedule = {k: given.pop(k) for k in RESUME_SCHEDULE if k in given}
    conflicts = [f"{FIT_FLAGS[k]} {shown(v)} (it started with {shown(getattr(fs, k))})"
                 for k, v in given.items() if getattr(fs, k) != v]
    if conflicts:
        raise UserError(f"--resume goes on with the settings the fit in {args.out!r} started with, not "
                        f"{'; '.join(conflicts)}: leave out the flag, or start a new fit without --resume")
    return replace(fs, **schedule, workers=args.workers)


def _saved_settings(out: str, state) -> dict | None:
    """The settings a stopped fit in ``out`` started with: its checkpoint's, or (a checkpoint of an earlier
    version) those of the loss.json written beside it; None where neither has them."""
    if state.settings is not None:
        return state.settings
    try:
        with open(os.path.join(out, "loss.json")) as f:
            saved = json.load(f).get("settings")
    except (OSError, ValueError, AttributeError):
        return None
    return saved if isinstance(saved, dict) else None


@contextlib.contextmanager
def _fit_backends(args: argparse.Namespace, cap, on_dask: bool):
    """(gradient, task_map) the fit's trials, iterations and intervals render with: (None, None) in this process;
    on Dask the cluster's, kept open from the start trials to the intervals."""
    if not on_dask:
        yield None, None
        return
    from ..scaleout.cluster import dask_client
    from ..scaleout.teeth import DaskGradient

    with dask_client(args.scheduler, args.dask_workers) as client:
        gradient = DaskGradient(client, cap)
        yield gradient, gradient.task_map


def _literature_start(scene, cap, fs, args: argparse.Namespace, as_json: bool, trials_path: str, gradient=None,
                      task_map=None, resume_trials: bool = False):
    """(start, whether the fit resumes): the literature search's start at g ``START_G`` (the default); with
    ``start_trials``, one start per g of the table, the fit's first iterations from each
    (``start_trials.best_start``), and the winner's checkpoint, log and scene files moved into ``--out``, where
    the fit resumes them. ``resume_trials``: an interrupted fit's trials go on from their checkpoints, from the
    starts its search saved (no search)."""
    import shutil
    from dataclasses import asdict

    from ..core.json_io import save_json
    from ..core.teeth.fit_checkpoint import load_state
    from ..core.teeth.literature_init import G_VALUES, START_G, literature_points, literature_starts
    from ..core.teeth.scene import TeethScene
    from ..core.teeth.start_trials import best_start, trial_dir

    work = os.path.join(args.out, TRIALS_DIR)
    starts_path = os.path.join(work, "starts.json")

    def saved_starts() -> list[TeethScene]:
        try:
            with open(starts_path) as f:
                return [TeethScene.from_dict(d) for d in json.load(f)["starts"]]
        except (ValueError, KeyError, TypeError, AttributeError, IndexError) as exc:
            raise UserError(f"{starts_path}: not the starts of a fit's trials ({exc}); run the fit again "
                            "without --resume") from None

    if resume_trials:
        starts = saved_starts()
    else:
        if as_json:
            _event(progress="init", message="searching the literature table for a start")
        total, searched = literature_points(), [0, 0]  # points done, twentieths announced

        with _bar(total, "init", "point", disable=args.no_progress or as_json) as init_bar:
            def point_done(n: int) -> None:  # the bar; as JSON (the add-on's panel) every 5 % of the points
                init_bar.update(n)
                searched[0] += n
                if as_json and 20 * searched[0] // total > searched[1]:
                    searched[1] = 20 * searched[0] // total
                    _event(progress="init", message=f"searching the literature table: {searched[0]} of {total} points")

            starts = literature_starts(scene, cap, progress=point_done)
        if fs.start_trials == 0:
            return starts[G_VALUES.index(START_G)], False
        shutil.rmtree(work, ignore_errors=True)  # an interrupted fit's trials
        os.makedirs(work)
        # the trials run from the starts as saved (a resumed trial starts from them read back, to the bit)
        save_json(starts_path, {"starts": [s.to_dict() for s in starts], "settings": asdict(fs)})
        starts = saved_starts()
    n_trial = min(fs.start_trials, fs.iterations)
    if as_json:
        _event(progress="init", message=f"trying {len(starts)} starts, {n_trial} iterations each")
    ran_before = 0  # the iterations an interrupted fit's trials had run
    for k in range(len(starts)):
        ckpt = os.path.join(trial_dir(work, k), "checkpoint.json")
        if os.path.isfile(ckpt):
            ran_before += len(load_state(ckpt).log)
    n_all, done = [len(starts) * n_trial], [ran_before]
    with _bar(n_all[0], "starts", "it", disable=args.no_progress or as_json) as trial_bar:
        trial_bar.update(ran_before)

        def trial_progress(entry: dict) -> None:
            done[0] += 1
            trial_bar.update(1)
            if as_json:
                _event(progress="init", message=f"trying {len(starts)} starts: {done[0]} of {n_all[0]} iterations")

        def trial_dropped(n: int) -> None:  # a start stopped at half its trial: fewer iterations to run
            n_all[0] -= n
            if hasattr(trial_bar, "total"):
                trial_bar.total = n_all[0]
                trial_bar.refresh()

        trials = best_start(starts, cap, fs, work, progress=trial_progress, dropped=trial_dropped,
                            gradient=gradient, task_map=task_map)
    if trials is None:
        shutil.rmtree(work)
        return starts[0], False
    save_json(trials_path, {"g1": [s.teeth[0].enamel.g1 for s in starts], "trial_loss": trials.scores,
                            "iterations": trials.iterations, "chosen": trials.chosen})
    _adopt_trial(work, trials.chosen, args.out)
    return starts[trials.chosen], True


def _check_free_patterns(patterns: tuple, scene, scene_path: str) -> None:
    """Refuse a --free pattern that names no parameter of the scene (a typo would silently fit less)."""
    import fnmatch

    from ..core.teeth.param_vector import ParamLayout

    names = [e.name for e in ParamLayout(scene).entries]
    unmatched = [p for p in patterns if not any(fnmatch.fnmatch(n, p) for n in names)]
    if unmatched:
        kinds = sorted({n.rsplit(".", 1)[-1] for n in names})
        raise UserError(f"--free {','.join(unmatched)}: no parameter of {scene_path} matches; the parameters are "
                        f"PART.NAME with NAME one of {', '.join(kinds)} (e.g. {names[0]})")


def _chosen_trial(trials_path: str) -> int:
    """The start that won the trials, as ``start_trials.json`` says."""
    try:
        with open(trials_path) as f:
            chosen = json.load(f)["chosen"]
        if isinstance(chosen, bool) or not isinstance(chosen, int) or chosen < 0:
            raise TypeError(f"'chosen' is {chosen!r}")
    except (ValueError, KeyError, TypeError) as exc:
        raise UserError(f"{trials_path}: not the result of a fit's start trials ({exc}); run the fit again "
                        "without --resume") from None
    return chosen


def _trials_settings(work: str) -> dict | None:
    """The settings saved with the starts of a fit stopped during its start trials (None: none saved)."""
    try:
        with open(os.path.join(work, "starts.json")) as f:
            saved = json.load(f).get("settings")
    except (OSError, ValueError, AttributeError):
        return None  # damaged starts are refused, naming the file, where they are read
    return saved if isinstance(saved, dict) else None


def _adopt_trial(work: str, chosen: int, out: str) -> None:
    """Move the winning trial's files into ``out`` (its checkpoint last: once it is there, so is the rest)
    and remove the trials' folder. Run again after an interruption, it finishes the move."""
    import shutil

    from ..core.teeth.start_trials import trial_dir

    won = trial_dir(work, chosen)
    names = [n for n in os.listdir(won) if n != ".fit.lock" and n != "checkpoint.json" and ".tmp" not in n] \
        if os.path.isdir(won) else []
    for name in [*names, "checkpoint.json"]:
        if os.path.exists(os.path.join(won, name)):
            os.replace(os.path.join(won, name), os.path.join(out, name))
    shutil.rmtree(work)


def run_fit(args: argparse.Namespace) -> int:
    import time

    import numpy as np

    from ..core.folder_lock import FolderLock
    from ..core.json_io import save_json
    from ..core.teeth.capture import Capture, split_camera
    from ..core.teeth.capture_outliers import clamp_bright_outliers
    from ..core.teeth.fit_checkpoint import load_state
    from ..core.teeth.fit_report import held_out_check, plot_loss
    from ..core.teeth.optimise import fit, held_out_light_ids, light_angles_deg
    from ..core.teeth.scene import load_scene
    from ..core.teeth.synthetic import perturbed_start, scene_target

    t_start = time.perf_counter()
    cap, outliers = clamp_bright_outliers(Capture.load(args.capture))  # the fit's capture model: no frozen spikes
    scene_path = args.scene or os.path.join(args.capture, "scene.json")
    scene = load_scene(scene_path)
    if len(cap.cameras) == 0 or len(cap.lights) == 0:
        raise UserError("the capture has no cameras or lights")
    lacks = [field for field, have in (("images", cap.images), ("masks", cap.masks)) if have is None]
    if lacks:  # before --out is made (a rig without photographs renders, it does not fit)
        raise UserError(f"{os.path.join(args.capture, 'capture.json')}: a fit needs the capture's images and masks; "
                        f"it has no {' and no '.join(lacks)}")
    fs = fit_settings(args)
    if args.free is not None:
        _check_free_patterns(fs.free, scene, scene_path)
    on_dask = args.scheduler is not None or args.dask_workers is not None
    if args.workers != 1 and on_dask:
        raise UsageError("--workers is for fits in this process; on Dask, the cluster's workers render")
    if args.scheduler is not None and args.dask_workers is not None:
        raise UsageError("--dask-workers starts a local cluster; --scheduler uses one that runs: give one of them")
    if args.scheduler is not None:
        from ..scaleout.cluster import check_scheduler

        check_scheduler(args.scheduler)  # before the start search and trials, minutes of work written to --out
    ckpt = os.path.join(args.out, "checkpoint.json")
    trials_path = os.path.join(args.out, "start_trials.json")
    trials_work = os.path.join(args.out, TRIALS_DIR)
    before: list = []  # the log of the iterations done before this run (resumed)
    # --resume of a fit stopped during its start trials (the search's starts were saved), or while the
    # winner's files moved into --out (the trials had ended: start_trials.json is written before the move)
    stopped_in_trials = args.resume and args.init == "literature" and os.path.isdir(trials_work) and (
        os.path.isfile(trials_path) or os.path.isfile(os.path.join(trials_work, "starts.json")))
    if args.resume and not stopped_in_trials:
        if not os.path.isfile(ckpt):
            raise MissingFileError(f"no checkpoint to resume from in {args.out!r} (the fit stopped before its "
                            "first one: run it again without --resume)", ckpt)
        state = load_state(ckpt)  # a malformed or foreign checkpoint is a one-line error here
        before = state.log
        fs = resumed_settings(args, _saved_settings(args.out, state), ckpt)
    elif stopped_in_trials:
        fs = resumed_settings(args, _trials_settings(trials_work), os.path.join(trials_work, "starts.json"))
    full_cap, cam_cap = cap, None
    if fs.held_out_camera >= 0:  # the fit, its search, trials, check and intervals see the other cameras only
        cap, cam_cap = split_camera(full_cap, fs.held_out_camera)
    if args.held_out_lights is not None and args.held_out_lights > len(cap.lights) // 4:
        print(f"note: --held-out-lights {args.held_out_lights}: a fit holds out at most a quarter of the capture's "
              f"{len(cap.lights)} lights; it holds out {len(cap.lights) // 4}", file=sys.stderr)
    as_json = os.environ.get(PROGRESS_ENV) == "json"  # the Blender add-on reads progress as JSON lines
    os.makedirs(args.out, exist_ok=True)  # before the cluster, the search and the trials: a bad --out fails at once
    with _fit_backends(args, cap, on_dask) as (gradient, task_map):
        resume = args.resume
        if stopped_in_trials:
            with FolderLock(args.out):
                if os.path.isfile(trials_path):
                    _adopt_trial(trials_work, _chosen_trial(trials_path), args.out)
                else:
                    scene, resume = _literature_start(scene, cap, fs, args, as_json, trials_path, gradient, task_map,
                                                      resume_trials=True)
        elif not args.resume:
            with FolderLock(args.out):  # the search and the trials write to --out/start_trials
                for earlier in (trials_path, ckpt):  # an earlier fit's, in this folder: this fit replaces it
                    if os.path.isfile(earlier):
                        os.remove(earlier)
                if args.init == "literature":
                    scene, resume = _literature_start(scene, cap, fs, args, as_json, trials_path, gradient,
                                                      task_map)
            if args.init == "perturbed":
                scene = perturbed_start(scene, seed=fs.seed)
        if resume and not before:  # the winning start's trial, moved into --out by this run
            before = load_state(ckpt).log
        total = fs.iterations + fs.textured_iterations
        bar = None if args.no_progress or as_json else _bar(total, "fit", "it")
        done = [0]

        def progress(entry):
            done[0] += 1
            if as_json:
                _event(progress="fit", iteration=done[0], iterations=total, loss=entry["loss"], phase=entry["phase"])
            if bar is not None:
                bar.update(1)
                bar.set_postfix(loss=f"{entry['loss']:.3e}", best=f"{entry['best_loss']:.3e}", phase=entry["phase"])

        def status(text: str) -> None:
            if as_json:
                _event(progress="status", message=text)
            if bar is not None:
                bar.set_description_str(f"fit: {text}" if text else "fit")

        done[0] = len(before)
        if bar is not None and before:
            bar.update(len(before))
        if as_json and before:  # the iterations done before (the winning start's trial, or an interrupted fit)
            _event(progress="fit", iteration=len(before), iterations=total, loss=before[-1]["loss"],
                   phase=before[-1]["phase"])
        os.makedirs(args.out, exist_ok=True)
        best, log = fit(scene, cap, fs, out_dir=args.out, resume=resume, progress=progress, status=status,
                        gradient=gradient, task_map=task_map)
        if bar is not None:
            bar.close()
        plot_loss(log, os.path.join(args.out, "loss.png"))
        target = scene_target(scene)
        angles = light_angles_deg(cap, target)
        held_out = held_out_light_ids(cap, target, fs.held_out_lights)
        if as_json:
            _event(progress="status", message=f"checking the fit on {len(held_out)} held-out lights")
        elif not args.no_progress and len(held_out):
            print(f"checking the fit on {len(held_out)} held-out lights", flush=True)
        check = held_out_check(best, cap, held_out, os.path.join(args.out, "check.png"), workers=fs.workers)
        if len(held_out):  # how far outside the training cone the check reaches
            check["light_angles_deg"] = [round(float(a), 2) for a in angles[held_out]]
            check["training_cone_deg"] = round(float(np.delete(angles, held_out).max()), 2)
        report = {"result": "scene_fit.json", "iterations": len(log), "final_loss": log[-1]["loss"] if log else None,
                  "held_out": check, "capture_outliers": outliers}
        if cam_cap is not None:
            if as_json:
                _event(progress="status", message=f"checking the fit from the held-out camera {fs.held_out_camera}")
            elif not args.no_progress:
                print(f"checking the fit from the held-out camera {fs.held_out_camera}", flush=True)
            cam_check = held_out_check(best, cam_cap, np.arange(len(cam_cap.lights)),
                                       os.path.join(args.out, "check_camera.png"), workers=fs.workers)
            report["held_out_camera"] = {"camera": fs.held_out_camera, **cam_check}
        if cap.masks is not None:
            from ..core.teeth.fit_intervals import parameter_intervals

            if as_json:
                _event(progress="status", message="estimating what the capture determines")
            elif not args.no_progress:
                print("estimating what the capture determines (intervals)", flush=True)
            trained = np.setdiff1d(np.arange(len(cap.lights)), held_out)
            try:
                report["intervals"] = parameter_intervals(best, cap, light_ids=trained, seed=fs.seed,
                                                             task_map=task_map)
            except UserError as e:  # a capture whose noise cannot be estimated: the fit stands, without intervals
                report["intervals"] = {"error": str(e)}
        report["seconds_this_run"] = time.perf_counter() - t_start
        if os.path.isfile(trials_path):
            with open(trials_path) as f:
                report["start_trials"] = json.load(f)
        save_json(os.path.join(args.out, "fit_report.json"), report)
        summary = (f"held-out lights: {check['rms_relative']:.1%} RMS per pixel, {check['rms_relative_tiles']:.1%} "
                   f"on 8 x 8 tiles (check.png)" if check["lights"] else "no held-out lights")
        if cam_cap is not None:
            cc = report["held_out_camera"]
            summary += (f"; held-out camera {fs.held_out_camera}: {cc['rms_relative']:.1%} RMS per pixel, "
                        f"{cc['rms_relative_tiles']:.1%} on 8 x 8 tiles (check_camera.png)")
        print(f"best loss {min(e['loss'] for e in log):.4e}; wrote {args.out}/scene_fit.json; {summary}; "
              "fit_report.json, loss.png, scene_best.json")
        return 0


def run_render(args: argparse.Namespace) -> int:
    import tempfile

    import numpy as np

    from ..core.exr_io import write_exr
    from ..core.teeth.capture import Capture
    from ..core.teeth.path_tracer import RenderSettings, render
    from ..core.teeth.scene import load_scene

    refuse_output_over_inputs(args.out, [args.capture, args.scene])
    scene = load_scene(args.scene)
    cap = Capture.load(args.capture)
    os.makedirs(args.out, exist_ok=True)
    names = [f"cam{c}_light{li}.exr" for c in range(len(cap.cameras)) for li in range(len(cap.lights))]
    blocked = next((n for n in names if os.path.isdir(os.path.join(args.out, n))), None)
    if blocked is not None:
        raise UserError(f"--out {args.out!r}: {blocked} is a folder there; choose another output")
    # every image into a folder of its own first, moved into --out only once all are rendered: a render that
    # fails or is stopped half-way leaves --out as it was, not half new and half old
    with tempfile.TemporaryDirectory(dir=args.out, prefix=".teeth-render-") as work:
        for l0 in range(0, len(cap.lights), 9):
            ids = np.arange(l0, min(l0 + 9, len(cap.lights)))
            res = render(scene, cap.cameras, cap.lights, RenderSettings(spp=args.samples, seed=args.seed + l0),
                         light_ids=ids)
            for c in range(len(cap.cameras)):
                for k, li in enumerate(ids):
                    write_exr(os.path.join(work, f"cam{c}_light{li}.exr"), res.images[c, k])
        for name in names:
            os.replace(os.path.join(work, name), os.path.join(args.out, name))
    print(f"wrote {len(names)} images to {args.out}")
    return 0


def run_sensitivity(args: argparse.Namespace) -> int:
    from ..core.teeth.capture import Capture
    from ..core.teeth.scene import load_scene
    from ..core.teeth.sensitivity import capture_sensitivity, cramer_rao_std, default_directions

    if args.out:  # before minutes of renders, not after
        if os.path.isdir(args.out):
            raise UserError(f"--out {args.out!r} is a folder; give a .json file name")
        refuse_unwritable_folder(os.path.dirname(os.path.abspath(args.out)))
    cap = Capture.load(args.capture)
    scene = load_scene(args.scene or os.path.join(args.capture, "scene.json"))
    names, directions = default_directions(scene)
    out = capture_sensitivity(scene, cap, directions, passes=args.passes, block=args.block,
                              noise_variance=args.noise_variance, capture_spp=args.capture_samples,
                              max_depth=args.max_depth)
    bound = cramer_rao_std(out["information"])
    rows = sorted(zip(names, out["chi2"].tolist(), bound.tolist(), strict=True), key=lambda r: -r[1])
    print(f"chi2 of each change against the capture noise (variance {out['noise_variance']:.3g} per value, "
          f"{out['tiles']} tiles of {args.block} x {args.block} px; sigma_s/sigma_a: +10 %, c: +0.05), and the "
          "smallest standard deviation of its size that any fit can reach with every parameter free, in units "
          "of the change (inf: other changes imitate it, or too few passes to tell)")
    print(f"  {'':32s} {'chi2':>12s} {'best std':>10s}")
    for name, c, b in rows:
        print(f"  {name:32s} {c:12.1f} {b:10.3g}")
    if args.out:
        from ..core.json_io import save_json

        save_json(args.out, {"chi2": {r[0]: r[1] for r in rows}, "best_std": {r[0]: r[2] for r in rows},
                              "noise_variance": out["noise_variance"], "tiles": out["tiles"],
                              "block": args.block, "passes": args.passes})
    return 0
