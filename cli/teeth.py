"""``teeth``: synthetic captures, appearance fitting and rendering of the teeth model (chapter 5).

    python -m material_structures teeth synth OUT [--teeth 2] [--width 96 --height 64] [--spp 16] [--renderer mitsuba]
    python -m material_structures teeth fit CAPTURE_DIR --out FIT_DIR [--iterations 100] [--resume]
    python -m material_structures teeth render SCENE_JSON CAPTURE_DIR --out DIR
    python -m material_structures teeth sensitivity CAPTURE_DIR (--capture-spp N | --noise-variance V)
"""

from __future__ import annotations

import argparse
import json
import os

from ..core.teeth.fit_presets import FIT_PRESETS

# ``teeth fit``'s defaults for the settings a --preset may set (flag None = not given on the command line)
FIT_CLI_DEFAULTS = {"iterations": 100, "lr": 0.05, "lr_decay": 0.02, "spp": 1, "image_spp": 0,
                    "lights_per_iteration": 18, "loss_block": 1, "optimiser": "adam", "gn_lr": 0.3,
                    "gn_start": 0, "gn_every": 50, "gn_passes": 4, "gn_damping": 0.03, "gn_estimator": "per-pass",
                    "gn_c_lr": 1.0, "gn_guard_rise": 0.25, "average_tail": 0.0}


def add_parser(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("teeth", help="teeth appearance model: synthetic captures, fitting, rendering")
    tsub = p.add_subparsers(dest="teeth_command", metavar="ACTION", required=True)

    s = tsub.add_parser("synth", help="render a synthetic capture of a known ground truth")
    s.add_argument("out", help="output capture folder (capture.json, images/, masks/, scene.json)")
    s.add_argument("--teeth", type=int, default=2, help="number of teeth (incisor, canine, premolar, molar)")
    s.add_argument("--width", type=int, default=96)
    s.add_argument("--height", type=int, default=64)
    s.add_argument("--lights", type=int, default=54)
    s.add_argument("--cameras", type=int, default=3)
    s.add_argument("--spp", type=int, default=16, help="samples per masked (tooth) pixel")
    s.add_argument("--spp-background", type=int, default=2, help="samples per other pixel")
    s.add_argument("--resolution", type=int, default=32, help="tooth mesh resolution")
    s.add_argument("--seed", type=int, default=12345)
    s.add_argument("--renderer", choices=("ours", "mitsuba"), default="ours",
                   help="ours (our path tracer) or mitsuba (Mitsuba 3 volpath, all bounces, every pixel at --spp; "
                        "llvm_ad_rgb where Dr.Jit's LLVM backend loads, else scalar_rgb; needs mitsuba==3.9.1): "
                        "Mitsuba's boundaries are index-matched, so for mitsuba the scene is made index-matched "
                        "(eta 1, a_t 1, sharp enamel/dentin blend spread 1e-5 mm) and scene.json is that scene")
    s.set_defaults(func=run_synth)

    f = tsub.add_parser("fit", help="fit the appearance model to a capture folder")
    f.add_argument("capture", help="capture folder with capture.json, images, masks and scene.json")
    f.add_argument("--out", required=True,
                   help="fit folder: checkpoint.json, loss.json, loss.png, scene_fit.json, scene_best.json")
    f.add_argument("--scene", default=None, help="scene JSON with geometry/start (default CAPTURE/scene.json)")
    f.add_argument("--init", choices=("literature", "scene", "perturbed"), default="literature",
                   help="start point: literature-table search (thesis), the scene's values, or a "
                        "perturbation of them (recovery tests)")
    f.add_argument("--init-error", choices=("scale-invariant", "absolute"), default="scale-invariant",
                   help="literature search error: scale-invariant (thesis; uncalibrated exposure) or absolute "
                        "(calibrated light intensities and camera)")
    acceptance = " ".join(f"--{k.replace('_', '-')} {v}" for k, v in FIT_PRESETS["acceptance"].items())
    f.add_argument("--preset", choices=tuple(FIT_PRESETS), default="thesis",
                   help="named settings: thesis (the defaults below: Adam, 1 spp, 18 lights) or acceptance (the "
                        f"recovery acceptance fit's: {acceptance}); flags given explicitly win over the preset")
    f.add_argument("--iterations", type=int, default=None,
                   help=f'"homogeneous" phase iterations (default {FIT_CLI_DEFAULTS["iterations"]})')
    f.add_argument("--textured-iterations", type=int, default=0, help='"textured" phase iterations')
    f.add_argument("--texture-size", type=int, default=8)
    f.add_argument("--lr", type=float, default=None,
                   help=f"Adam's learning rate (default {FIT_CLI_DEFAULTS['lr']})")
    f.add_argument("--lr-decay", type=float, default=None,
                   help=f"lr_n = lr / (1 + decay n) (default {FIT_CLI_DEFAULTS['lr_decay']})")
    f.add_argument("--spp", type=int, default=None,
                   help=f"samples per pixel of the gradient pass (default {FIT_CLI_DEFAULTS['spp']})")
    f.add_argument("--image-spp", type=int, default=None,
                   help="samples per pixel of pass A, the image in the loss gradient's adjoint (default 0 = --spp); "
                        "near the optimum its noise dominates the gradient's (the acceptance fit uses 32 with --spp 4)")
    f.add_argument("--lights-per-iteration", type=int, default=None,
                   help=f"random lights per iteration (default {FIT_CLI_DEFAULTS['lights_per_iteration']})")
    f.add_argument("--max-depth", type=int, default=None,
                   help="stop every path after this many bounces (an experiment: biased dark); default all bounces")
    f.add_argument("--anchor-spp", type=int, default=0,
                   help="image control variate: spp of an anchor image of all lights (0 = off); cuts the "
                        "gradient noise of pass A, see core/teeth/optimise.py Anchor")
    f.add_argument("--anchor-every", type=int, default=20, help="iterations between anchor re-renders")
    f.add_argument("--loss-block", type=int, default=None,
                   help="L2 loss of box-filtered images over N x N pixel tiles (default 1 = per pixel, as in the "
                        "thesis); averages the gradient's pass A x pass B noise over each tile (8: 7-18x lower "
                        "noise in the dentin coefficients' gradient on the acceptance capture)")
    f.add_argument("--domain", choices=("thesis", "absorption"), default="thesis",
                   help="optimiser variables of sigma_t/albedo: thesis (log sigma_t, log10(1 - albedo)) or "
                        "absorption (log sigma_s, log sigma_a)")
    f.add_argument("--optimiser", choices=("adam", "gauss-newton"), default=None,
                   help="adam (thesis, the default) or gauss-newton: the material parameters step along the damped "
                        "inverse Gauss-Newton matrix (estimated from 1-spp Jacobian passes of all lights; the dentin "
                        "coefficients keep Adam), which follows the valley where enamel and dentin absorption "
                        "trade off; the acceptance fit (--preset acceptance) runs Adam first, then gauss-newton "
                        "(README, 'Why Adam stalls'); see core/teeth/gauss_newton.py")
    f.add_argument("--gn-lr", type=float, default=None,
                   help=f"gauss-newton: fraction of the Gauss-Newton step (default {FIT_CLI_DEFAULTS['gn_lr']})")
    f.add_argument("--gn-start", type=int, default=None,
                   help="gauss-newton: Adam iterations before Gauss-Newton takes over (far from the optimum the "
                        "linearised model misleads; default 0)")
    f.add_argument("--gn-every", type=int, default=None,
                   help=f"gauss-newton: iterations between matrix estimates (default {FIT_CLI_DEFAULTS['gn_every']})")
    f.add_argument("--gn-passes", type=int, default=None,
                   help=f"gauss-newton: 1-spp Jacobian passes per estimate (default {FIT_CLI_DEFAULTS['gn_passes']})")
    f.add_argument("--gn-damping", type=float, default=None,
                   help="gauss-newton: Levenberg-Marquardt damping, relative to the matrix diagonal (default "
                        f"{FIT_CLI_DEFAULTS['gn_damping']})")
    f.add_argument("--gn-estimator", choices=("per-pass", "pooled"), default=None,
                   help="gauss-newton: per-pass (the mean of the passes' J^T J; its Monte Carlo bias adds curvature "
                        "and shortens the steps along the flattest directions 6-16x on the acceptance capture) or "
                        "pooled ((mean J)^T (mean J), that bias divided by the passes; default "
                        f"{FIT_CLI_DEFAULTS['gn_estimator']})")
    f.add_argument("--gn-c-lr", type=float, default=None,
                   help="gauss-newton: factor on the dentin coefficients' Adam learning rate while Gauss-Newton steps "
                        f"the materials (default {FIT_CLI_DEFAULTS['gn_c_lr']})")
    f.add_argument("--gn-guard-window", type=int, default=10,
                   help="gauss-newton: iterations per loss window of the divergence guard (a window whose mean loss "
                        "rises more than --gn-guard-rise above the best one's goes back to the best window's mean "
                        "iterate and raises the damping 4x); 0 = no guard")
    f.add_argument("--gn-guard-rise", type=float, default=None,
                   help="gauss-newton: relative loss rise that counts as a divergence (default "
                        f"{FIT_CLI_DEFAULTS['gn_guard_rise']})")
    f.add_argument("--average-tail", type=float, default=None,
                   help="result = the mean of the iterates of this last fraction of the iterations (Polyak "
                        "averaging; near the optimum it is closer than any one iterate or the best-loss one); 0 = "
                        f"the best-loss parameters as in the thesis (default {FIT_CLI_DEFAULTS['average_tail']}; "
                        "scene_best.json has the best-loss parameters either way)")
    f.add_argument("--free", default=None,
                   help="comma-separated parameter name patterns to optimise (default: all volume, a_t, c)")
    f.add_argument("--seed", type=int, default=0)
    f.add_argument("--resume", action="store_true", help="continue from FIT_DIR/checkpoint.json")
    f.add_argument("--scheduler", default=None,
                   help="Dask scheduler address (tcp://host:8786): per-view gradient renders become tasks there")
    f.add_argument("--dask-workers", type=int, default=None,
                   help="processes of the local Dask cluster (default: CPU count)")
    f.add_argument("--no-dask", action="store_true", help="render in this process instead of on Dask")
    f.add_argument("--workers", type=int, default=1,
                   help="with --no-dask and no numba installed: forked processes that trace each pass (the "
                        "compiled tracer uses every core by itself)")
    f.add_argument("--no-progress", action="store_true")
    f.set_defaults(func=run_fit)

    r = tsub.add_parser("render", help="render a scene JSON with the cameras/lights of a capture")
    r.add_argument("scene")
    r.add_argument("capture")
    r.add_argument("--out", required=True)
    r.add_argument("--spp", type=int, default=16)
    r.add_argument("--seed", type=int, default=1)
    r.set_defaults(func=run_render)

    v = tsub.add_parser("sensitivity",
                        help="how strongly a capture constrains sigma_s, sigma_a and the dentin coefficients")
    v.add_argument("capture", help="capture folder (capture.json, masks; images are not needed)")
    v.add_argument("--scene", default=None, help="scene JSON to evaluate at (default CAPTURE/scene.json)")
    noise = v.add_mutually_exclusive_group(required=True)
    noise.add_argument("--capture-spp", type=int, help="synthetic capture: its samples per pixel")
    noise.add_argument("--noise-variance", type=float, help="the photographs' noise variance per pixel value")
    v.add_argument("--passes", type=int, default=6, help="independent 1-spp Jacobian passes (>= 2)")
    v.add_argument("--block", type=int, default=8, help="pixel tile size the image changes are pooled over")
    v.add_argument("--max-depth", type=int, default=None,
                   help="stop every path after this many bounces (an experiment: biased dark); default all bounces")
    v.add_argument("--json", default=None, help="also write the table to this JSON file")
    v.set_defaults(func=run_sensitivity)


def run_synth(args: argparse.Namespace) -> int:
    from tqdm import tqdm

    from ..core.teeth.capture import default_rig
    from ..core.teeth.synthetic import make_scene, render_capture, scene_target

    if args.teeth < 1 or args.width < 4 or args.height < 4 or args.spp < 1:
        raise ValueError("need --teeth >= 1, --width/--height >= 4 and --spp >= 1")
    scene = make_scene(n_teeth=args.teeth, resolution=args.resolution)
    span = max(12.0, 8.6 * args.teeth + 6.0)
    fov = 2.0 * __import__("math").degrees(__import__("math").atan(0.5 * span / 300.0))
    cams, lights = default_rig(target=scene_target(scene), width=args.width, height=args.height,
                               n_lights=args.lights, n_cameras=args.cameras, fov_x_deg=fov)
    if args.renderer == "mitsuba":
        from ..core.teeth.mitsuba_capture import import_mitsuba, index_matched, render_capture_mitsuba

        scene = index_matched(scene)
        _, variant = import_mitsuba()
        with tqdm(total=len(lights), desc="synth (mitsuba)", unit="light") as bar:
            cap = render_capture_mitsuba(scene, cams, lights, args.spp, args.seed, progress=bar.update,
                                         variant=variant)
        how = (f" rendered by Mitsuba 3 {variant} (volpath, all bounces, {args.spp} spp per pixel) of the "
               "index-matched scene (eta 1, a_t 1, blend spread 1e-5 mm)")
    else:
        with tqdm(total=2 * len(lights), desc="synth", unit="light-pass") as bar:
            cap = render_capture(scene, cams, lights, args.spp, args.spp_background, args.seed,
                                 progress=bar.update)
        how = ""
    cap.save(args.out, scene.to_dict())
    print(f"wrote {len(cams)} x {len(lights)} images and masks{how} to {args.out}")
    return 0


def fit_preset_settings(args: argparse.Namespace) -> dict:
    """FitSettings values of FIT_CLI_DEFAULTS' keys: the flag where given, else the preset's, else the default."""
    preset = FIT_PRESETS[args.preset]
    return {k: getattr(args, k) if getattr(args, k) is not None else preset.get(k, default)
            for k, default in FIT_CLI_DEFAULTS.items()}


def run_fit(args: argparse.Namespace) -> int:
    from tqdm import tqdm

    from ..core.teeth.capture import Capture
    from ..core.teeth.literature_init import literature_start, literature_table
    from ..core.teeth.optimise import DEFAULT_FREE, FitSettings, fit, plot_loss
    from ..core.teeth.scene import load_scene
    from ..core.teeth.synthetic import perturbed_start

    cap = Capture.load(args.capture)
    scene_path = args.scene or os.path.join(args.capture, "scene.json")
    scene = load_scene(scene_path)
    if len(cap.cameras) == 0 or len(cap.lights) == 0:
        raise ValueError("the capture has no cameras or lights")
    free = tuple(p.strip() for p in args.free.split(",")) if args.free else DEFAULT_FREE
    preset = fit_preset_settings(args)
    fs = FitSettings(textured_iterations=args.textured_iterations,
                     texture_size=args.texture_size, max_depth=args.max_depth, seed=args.seed,
                     free=free, anchor_spp=args.anchor_spp, anchor_every=args.anchor_every,
                     domain=args.domain, workers=args.workers, gn_guard_window=args.gn_guard_window, **preset)
    if args.workers != 1 and not args.no_dask:
        raise ValueError("--workers is for --no-dask; on Dask, --dask-workers sets the parallelism")
    if not args.resume:
        if args.init == "literature":
            table, gs = literature_table()
            n_points = len(table) * len(gs)
            with tqdm(total=n_points, desc="init", unit="point", disable=args.no_progress) as init_bar:
                scene = literature_start(scene, cap, scale_invariant=args.init_error == "scale-invariant",
                                         progress=init_bar.update)
        elif args.init == "perturbed":
            scene = perturbed_start(scene, seed=args.seed)
    total = fs.iterations + fs.textured_iterations
    bar = None if args.no_progress else tqdm(total=total, desc="fit", unit="it")

    def progress(entry):
        if bar is not None:
            bar.update(1)
            bar.set_postfix(loss=f"{entry['loss']:.3e}", best=f"{entry['best_loss']:.3e}", phase=entry["phase"])

    def status(text: str) -> None:
        if bar is not None:
            bar.set_description_str(f"fit: {text}" if text else "fit")

    os.makedirs(args.out, exist_ok=True)
    if args.resume and bar is not None:
        with open(os.path.join(args.out, "checkpoint.json")) as f:
            bar.update(len(json.load(f)["log"]))
    if args.no_dask and args.scheduler:
        raise ValueError("--no-dask and --scheduler exclude each other")
    if not args.no_dask:
        from ..scaleout.cluster import dask_client
        from ..scaleout.teeth import DaskGradient

        with dask_client(args.scheduler, args.dask_workers) as client:
            best, log = fit(scene, cap, fs, out_dir=args.out, resume=args.resume, progress=progress,
                            gradient=DaskGradient(client, cap), status=status)
    else:
        best, log = fit(scene, cap, fs, out_dir=args.out, resume=args.resume, progress=progress, status=status)
    if bar is not None:
        bar.close()
    plot_loss(log, os.path.join(args.out, "loss.png"))
    result = (f"mean of the last {fs.average_tail:.0%} of the iterates" if fs.average_tail > 0
              else "the best-loss parameters")
    print(f"best loss {min(e['loss'] for e in log):.4e}; wrote {args.out}/scene_fit.json ({result}), "
          "scene_best.json, loss.json, loss.png")
    return 0


def run_render(args: argparse.Namespace) -> int:
    import numpy as np

    from ..core.exr_io import write_exr
    from ..core.teeth.capture import Capture
    from ..core.teeth.path_tracer import RenderSettings, render
    from ..core.teeth.scene import load_scene

    scene = load_scene(args.scene)
    cap = Capture.load(args.capture)
    os.makedirs(args.out, exist_ok=True)
    for l0 in range(0, len(cap.lights), 9):
        ids = np.arange(l0, min(l0 + 9, len(cap.lights)))
        res = render(scene, cap.cameras, cap.lights, RenderSettings(spp=args.spp, seed=args.seed + l0),
                     light_ids=ids)
        for c in range(len(cap.cameras)):
            for k, li in enumerate(ids):
                write_exr(os.path.join(args.out, f"cam{c}_light{li}.exr"), res.images[c, k])
    print(f"wrote {len(cap.cameras) * len(cap.lights)} images to {args.out}")
    return 0


def run_sensitivity(args: argparse.Namespace) -> int:
    from ..core.teeth.capture import Capture
    from ..core.teeth.scene import load_scene
    from ..core.teeth.sensitivity import capture_sensitivity, default_directions

    cap = Capture.load(args.capture)
    scene = load_scene(args.scene or os.path.join(args.capture, "scene.json"))
    names, directions = default_directions(scene)
    out = capture_sensitivity(scene, cap, directions, passes=args.passes, block=args.block,
                              noise_variance=args.noise_variance, capture_spp=args.capture_spp,
                              max_depth=args.max_depth)
    rows = sorted(zip(names, out["chi2"].tolist(), strict=True), key=lambda r: -r[1])
    print(f"chi2 of each change against the capture noise (variance {out['noise_variance']:.3g} per value, "
          f"{out['tiles']} tiles of {args.block} x {args.block} px; sigma_s/sigma_a: +10 %, c: +0.05)")
    for name, c in rows:
        print(f"  {name:32s} {c:12.1f}")
    if args.json:
        with open(args.json, "w") as f:
            json.dump({"chi2": dict(rows), "noise_variance": out["noise_variance"], "tiles": out["tiles"],
                       "block": args.block, "passes": args.passes}, f, indent=1)
    return 0
