"""``fabric``: fit / evaluate / synthesize pile-fabric SVBRDFs (thesis chapter 3).

    python -m material_structures fabric fit BTF --out PARAMS_DIR
    python -m material_structures fabric eval PARAMS_DIR --directions btf.json --out DIR
    python -m material_structures fabric synth --out BTF_DIR [--gt-out PARAMS_DIR] [--noise 0.05]
    python -m material_structures fabric score PRED_BTF REF_BTF
    python -m material_structures fabric ndf BTF --texel X Y --out ndf.exr
    python -m material_structures fabric material PARAMS_DIR [--out fabric.blend] [--render preview.png]

Angles are in degrees (options ending in -deg). Old spellings, accepted until the next release with a note on
stderr: ``fabric synth --theta-max`` / ``--max-tilt`` (``--theta-max-deg`` / ``--max-tilt-deg``), ``fabric synth
--rotation`` in radians (``--rotation-deg``), ``fabric ndf --resolution`` (``--size``).
"""

from __future__ import annotations

import argparse
import json
import math
import os

from ..core.errors import UserError
from .checks import (
    UsageError,
    at_least,
    between,
    check_memory,
    old_spelling,
    refuse_output_over_inputs,
    refuse_unwritable_folder,
    seed,
)


def add_parser(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("fabric", help="pile fabric: fit a BTF, evaluate parameters, synthetic BTFs")
    fsub = p.add_subparsers(dest="fabric_command", metavar="ACTION", required=True)

    f = fsub.add_parser("fit", help="fit the SGGX fabric model (eq. 3.9) to a BTF")
    f.add_argument("btf", help="BTF folder (btf.json + EXRs), btf.json, or .npz")
    f.add_argument("--out", required=True,
                   help="parameter folder to write (kd/ks/sigma/basis.exr, params.json)")
    f.add_argument("--tile", type=between(1, 4096, int), default=20, help="tile edge in texels (default 20)")
    f.add_argument("--workers", type=between(1, 1024, int), default=None,
                   help="processes on this machine that share the tiles: the local process pool or local Dask "
                        "cluster (default: CPU count)")
    f.add_argument("--weighting", choices=("radiance", "brdf"), default="radiance",
                   help="residuals in f_r cos(theta_i) (default) or in f_r (eq. 3.17 as printed)")
    f.add_argument("--no-progress", action="store_true", help="no progress bar")
    f.add_argument("--drop-cache", action="store_true", help="delete OUT/.fit_cache when done")
    f.add_argument("--scheduler", default=None,
                   help="Dask scheduler address (tcp://host:8786); tiles become tasks on that cluster. "
                        "Default: a local Dask cluster with --workers processes")
    f.add_argument("--no-dask", action="store_true", help="use a plain local process pool instead of Dask")
    f.set_defaults(func=run_fit)

    e = fsub.add_parser("eval", help="write the model's prediction for given directions as a BTF")
    e.add_argument("params", help="parameter folder written by 'fabric fit'")
    e.add_argument("--directions", required=True, help="btf.json (images need not exist) or .npz with wi, wo")
    e.add_argument("--out", required=True, help="output BTF folder, or a path ending in .npz")
    e.set_defaults(func=run_eval)

    s = fsub.add_parser("synth", help="synthetic BTF of a known spatially varying model")
    s.add_argument("--out", required=True, help="BTF folder, or a path ending in .npz")
    s.add_argument("--width", type=between(1, 16384, int), default=32, help="BTF width in texels")
    s.add_argument("--height", type=between(1, 16384, int), default=32, help="BTF height in texels")
    s.add_argument("--lights", type=between(1, 1024, int), default=16, help="number of light directions")
    s.add_argument("--views", type=between(1, 1024, int), default=16, help="number of view directions")
    s.add_argument("--theta-max-deg", type=between(1.0, 89.0), default=75.0,
                   help="largest light/view zenith angle in degrees")
    s.add_argument("--rotation-deg", type=between(-360.0, 360.0), default=0.0,
                   help="azimuth offset of the direction sets in degrees")
    s.add_argument("--noise", type=between(0.0, 1.0), default=0.0, help="Gaussian noise level (0.05 = 5 %%)")
    s.add_argument("--noise-kind", choices=("relative", "peak"), default="relative",
                   help="multiplicative noise, or additive noise scaled by each texel's peak value")
    s.add_argument("--max-tilt-deg", type=between(0.0, 89.0), default=30.0, help="largest fibre tilt in degrees")
    s.add_argument("--seed", type=seed, default=0, help="random seed of the maps (and, plus 1, of the noise)")
    s.add_argument("--gt-out", default=None, help="also write the ground-truth parameter folder here")
    old_spelling(s, "--theta-max", "--theta-max-deg")
    old_spelling(s, "--max-tilt", "--max-tilt-deg")
    old_spelling(s, "--rotation", "--rotation-deg", convert=math.degrees, unit="radians",
                 type=between(-2 * math.pi, 2 * math.pi))
    s.set_defaults(func=run_synth)

    n = fsub.add_parser("ndf", help="write one texel's extracted NDF (eq. 3.11) as a parabolic map EXR (eq. 3.12)")
    n.add_argument("btf", help="BTF folder, btf.json or .npz")
    n.add_argument("--texel", type=at_least(0), nargs=2, metavar=("X", "Y"), default=(0, 0),
                   help="the texel's column and row (from 0)")
    n.add_argument("--size", type=between(4, 4096, int), default=64,
                   help="image width = height of the parabolic map in pixels")
    n.add_argument("--out", required=True, help="output .exr")
    old_spelling(n, "--resolution", "--size")
    n.set_defaults(func=run_ndf)

    from .fabric_material import add_material_parser

    add_material_parser(fsub)

    c = fsub.add_parser("score", help="PSNR of a predicted BTF against a reference BTF")
    c.add_argument("pred", help="the predicted BTF (folder, btf.json or .npz), e.g. from 'fabric eval'")
    c.add_argument("ref", help="the reference BTF with the same directions")
    c.set_defaults(func=run_score)


PROGRESS_ENV = "MATERIAL_STRUCTURES_PROGRESS"  # "json": progress as JSON lines on stdout, no bars


def _event(**fields) -> None:
    print(json.dumps(fields), flush=True)


def run_fit(args: argparse.Namespace) -> int:
    if args.no_dask and args.scheduler:
        raise UsageError("--no-dask and --scheduler exclude each other")
    refuse_output_over_inputs(args.out, [args.btf])
    made_out = not os.path.exists(args.out)
    try:
        return _fit(args)
    except BaseException:  # a fit that fails or is stopped before writing anything leaves no empty --out behind
        if made_out and os.path.isdir(args.out) and not os.listdir(args.out):
            os.rmdir(args.out)
        raise


def _fit(args: argparse.Namespace) -> int:
    from ..core.fabric.btf_fitter import check_btf, fit_btf
    from ..core.fabric.tile_fit import FitOptions

    options = FitOptions(weighting=args.weighting)
    if args.scheduler and os.environ.get(PROGRESS_ENV) != "json":
        from ..scaleout.cluster import check_scheduler

        check_btf(args.btf)  # a BTF that cannot be fitted is said first
        check_scheduler(args.scheduler)  # before anything is written
    if os.environ.get(PROGRESS_ENV) == "json":  # the Blender add-on: progress as JSON lines, a local process pool
        if args.scheduler:
            raise UserError(f"{PROGRESS_ENV}=json fits in local processes: leave out --scheduler")
        _event(progress="status", message="reading the BTF")

        def tiles_done(done: int, total: int) -> None:
            _event(progress="fit", iteration=done, iterations=total, phase="tiles",
                   message="fitting the world-light closures" if done == total else "")

        _, stats = fit_btf(args.btf, args.out, tile=args.tile, workers=args.workers, options=options,
                           progress=tiles_done, keep_cache=not args.drop_cache)
    elif args.no_dask:
        _, stats = fit_btf(args.btf, args.out, tile=args.tile, workers=args.workers, options=options,
                           progress=not args.no_progress, keep_cache=not args.drop_cache)
    else:
        from ..scaleout.fabric import fit_btf_dask

        _, stats = fit_btf_dask(args.btf, args.out, scheduler=args.scheduler, n_workers=args.workers,
                                tile=args.tile, options=options, progress=not args.no_progress,
                                keep_cache=not args.drop_cache)
    print(json.dumps(stats))
    return 0


def run_eval(args: argparse.Namespace) -> int:
    from ..core.fabric.btf_io import read_directions, save_btf
    from ..core.fabric.btf_prediction import predict_btf
    from ..core.fabric.parameter_maps import load_params

    refuse_output_over_inputs(args.out, [args.params, args.directions])
    maps = load_params(args.params)
    wi, wo = read_directions(args.directions)
    save_btf(args.out, predict_btf(maps, wi, wo), wi, wo)
    print(args.out)
    return 0


def run_synth(args: argparse.Namespace) -> int:
    from ..core.fabric.btf_io import save_btf
    from ..core.fabric.parameter_maps import save_params
    from ..core.fabric.synthetic_btf import light_view_pairs, render_btf, synthetic_maps

    for flag, out in (("--out", args.out), ("--gt-out", args.gt_out)):
        if out:  # both before either is written
            refuse_unwritable_folder(out if not out.lower().endswith(".npz") else os.path.dirname(out) or ".", flag)
    # the BTF is rendered in memory (float64 while rendering) before it is written
    check_memory(args.width * args.height * args.lights * args.views * 3 * 8 * 2,
                 f"a {args.width} x {args.height} BTF of {args.lights * args.views} light/view pairs")
    maps = synthetic_maps(args.height, args.width, seed=args.seed, max_tilt_deg=args.max_tilt_deg)
    wi, wo = light_view_pairs(args.lights, args.views, args.theta_max_deg, math.radians(args.rotation_deg))
    save_btf(args.out, render_btf(maps, wi, wo, noise=args.noise, seed=args.seed + 1,
                                        noise_kind=args.noise_kind), wi, wo)
    if args.gt_out:
        save_params(args.gt_out, maps, extra={"synthetic": vars(args) | {"func": None}})
    print(args.out)
    return 0


def run_ndf(args: argparse.Namespace) -> int:
    import numpy as np

    from ..core.exr_io import write_exr
    from ..core.fabric.btf_io import iter_btf_blocks, read_btf_header
    from ..core.fabric.ndf_extraction import ndf_operator

    refuse_output_over_inputs(args.out, [args.btf])
    if not args.out.lower().endswith(".exr"):
        raise UsageError(f"--out {args.out!r}: the NDF map is written as OpenEXR: give a .exr file name")
    hdr = read_btf_header(args.btf)
    x, y = args.texel
    if not (0 <= x < hdr.width and 0 <= y < hdr.height):
        raise UserError(f"texel ({x}, {y}) is outside the {hdr.width}x{hdr.height} BTF")
    f = np.concatenate([vals[:, y, x].mean(axis=1) for _, vals in iter_btf_blocks(args.btf)])
    op = ndf_operator(hdr.wi, hdr.wo, resolution=args.size)
    write_exr(args.out, op.to_image(op.apply(f / hdr.wi[:, 2])[:, 0]).astype(np.float32))
    print(args.out)
    return 0


def run_score(args: argparse.Namespace) -> int:
    from ..core.fabric.btf_io import load_btf
    from ..core.fabric.btf_prediction import psnr, texel_psnr

    pred, ref = load_btf(args.pred), load_btf(args.ref)
    if pred.values.shape != ref.values.shape:
        raise UserError(f"shapes differ: {pred.values.shape} vs {ref.values.shape}")
    import numpy as np

    if not (np.allclose(pred.wi, ref.wi, atol=1e-5) and np.allclose(pred.wo, ref.wo, atol=1e-5)):
        raise UserError("the two BTFs have different directions")
    tp = texel_psnr(pred.values, ref.values)

    def db(x: float) -> float | None:  # JSON has no Infinity: identical values (no error) are null
        return float(x) if np.isfinite(x) else None

    print(json.dumps({"psnr_db": db(psnr(pred.values, ref.values)), "texel_psnr_db_median": db(np.median(tp)),
                      "texel_psnr_db_p5": db(np.percentile(tp, 5)),
                      "identical": bool(np.array_equal(pred.values, ref.values))}, allow_nan=False))
    return 0
