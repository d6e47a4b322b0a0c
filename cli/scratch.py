"""``scratch``: scratched-surface sets (thesis chapter 4): generate, inspect, evaluate.

    python -m material_structures scratch generate --kind wear --count 10000 --patch-mm 50 --out s.npz
    python -m material_structures scratch generate --kind curves --curves my_curves.json --out tables/
    python -m material_structures scratch info s.npz
    python -m material_structures scratch eval s.npz --size 256 --out patch.exr

An ``--out`` ending in ``.npz`` writes one file; anything else writes the EXR-table folder the OSL
shader reads (layout: ``core/scratch/scratch_io.py``). ``--curves`` takes a JSON list of curves,
each a list of [u, v] points in UV units (0-1 across the patch).
"""

from __future__ import annotations

import argparse
import json
import os

from ..core.errors import MissingFileError, UserError
from .checks import UsageError, between, check_memory, finite_float, refuse_output_over_inputs, seed

MAX_SCRATCHES = 2**24  # the grid index addresses at most 2^24 entries, each scratch has at least one
SCRATCH_BYTES = 4096  # memory per scratch while a set is generated and indexed (2.4 KB measured, rounded up)
PIXEL_BYTES = 256  # memory per pixel of ``scratch eval`` (about 120 bytes measured, rounded up)
COUNT = 500  # scratches of ``generate --count``: the Generate Scratches operator's default


def add_parser(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("scratch", help="scratched surfaces: generate, inspect and evaluate scratch sets")
    ss = p.add_subparsers(dest="scratch_command", metavar="ACTION", required=True)

    g = ss.add_parser("generate", help="generate a scratch set (.npz or EXR-table folder)")
    g.add_argument("--kind", choices=("wear", "polish", "hairline", "curves"), default="wear",
                   help="uniform wear, polishing circles, hairline brushing, or your own curves (--curves)")
    g.add_argument("--count", type=between(1, MAX_SCRATCHES, int), default=COUNT,
                   help="number of scratches (not for curves)")
    g.add_argument("--patch-mm", type=between(1e-3, 1e4), nargs="+", default=[20.0],
                   help="patch size in mm (1 or 2 values)")
    g.add_argument("--curves", default=None, help="JSON file: list of curves, each a list of [u, v] points")
    g.add_argument("--angle-deg", type=between(-360.0, 360.0), default=0.0,
                   help="hairline brushing direction in degrees")
    g.add_argument("--sigma-um", type=between(0.1, 1e4), default=60.0, help="coherence radius the index is built for")
    g.add_argument("--max-footprint-um", type=between(0.1, 1e5), default=500.0,
                   help="largest pixel footprint to index for")
    g.add_argument("--seed", type=seed, default=0, help="random seed of the scratches")
    g.add_argument("--out", required=True, help="output .npz file or EXR-table folder")
    g.set_defaults(func=run_generate)

    i = ss.add_parser("info", help="summarise a scratch set file or folder as JSON")
    i.add_argument("path", help="scratch set: .npz file or EXR-table folder")
    i.set_defaults(func=run_info)

    e = ss.add_parser("eval", help="evaluate the scratch radiance over the patch into an EXR image")
    e.add_argument("path", help="scratch set: .npz file or EXR-table folder")
    e.add_argument("--size", type=between(1, 16384, int), default=256, help="image width = height in pixels")
    e.add_argument("--view-deg", type=between(0.0, 89.9), default=30.0,
                   help="viewing angle from the normal in degrees (in the x-z plane)")
    e.add_argument("--light", type=finite_float, nargs=4, default=[-0.5, 0.2, 1.0, 0.05], metavar=("X", "Y", "Z", "R"),
                   help="sphere light centre (relative, local frame) and radius, same unit")
    e.add_argument("--spectral", choices=("rgb", "16"), default="rgb", help="3 wavelengths or 16 bands")
    e.add_argument("--si", choices=("series", "thesis", "exact"), default="series",
                   help="how the sine integral Si(x) is evaluated: a series (|error| < 2e-6), the thesis' eq. 4.29, "
                        "or exactly")
    e.add_argument("--footprint-rule", choices=("chords", "thesis"), default="chords",
                   help="a scratch's length in the pixel footprint: 12 chords across it, or the thesis' eq. 4.14-4.15")
    e.add_argument("--workers", type=between(1, 1024, int), default=1,
                   help="processes on this machine that share the pixels")
    e.add_argument("--out", required=True, help="output EXR (channels R, G, B, A = rho_P)")
    e.set_defaults(func=run_eval)


def _patch(values: list[float]) -> tuple[float, float]:
    if len(values) not in (1, 2) or min(values) <= 0:
        raise UsageError("--patch-mm takes one or two positive sizes")
    v = [x * 1000.0 for x in values]
    return (v[0], v[-1])


def _curve(path: str, k: int, points):
    """Curve ``k`` of a curves file as an (n, 2) array of finite (u, v) points, or a one-line refusal."""
    import numpy as np

    try:
        a = np.asarray(points, dtype=np.float64)
    except (TypeError, ValueError):
        a = None
    if a is None or isinstance(points, (str, dict)) or a.ndim != 2 or a.shape[1] != 2:
        raise UserError(f"{path}: curve {k} is not a list of [u, v] points of numbers")
    if not np.isfinite(a).all():
        raise UserError(f"{path}: curve {k} holds non-finite coordinates")
    return a


def run_generate(args: argparse.Namespace) -> int:
    import numpy as np

    from ..core import scratch as sc

    if args.curves:
        refuse_output_over_inputs(args.out, [args.curves])
    patch = _patch(args.patch_mm)
    if args.kind != "curves":
        check_memory(args.count * SCRATCH_BYTES, f"a set of {args.count} scratches")
    kw = dict(seed=args.seed, sigma_um=args.sigma_um, max_footprint_um=args.max_footprint_um)
    if args.kind == "curves":
        if not args.curves:
            raise UsageError("--kind curves needs --curves FILE.json")
        if not os.path.isfile(args.curves):
            raise MissingFileError(f"curves file not found: {args.curves}", args.curves)
        with open(args.curves) as f:
            try:
                curves = json.load(f)
            except json.JSONDecodeError as exc:
                raise UserError(f"{args.curves}: not valid JSON ({exc})") from exc
        from ..core.json_schema import check as check_schema

        check_schema(curves, "scratch-curves", args.curves)  # core/schemas/scratch-curves.schema.json
        s = sc.from_curves([_curve(args.curves, k, c) for k, c in enumerate(curves)], patch, uv=True, **kw)
        if s.n_segments == 0:  # an empty set would be written without a word
            raise UserError(f"{args.curves}: no curve adds a scratch (each lies outside the UV square [0, 1]^2 or "
                            "has no length)")
    elif args.kind == "wear":
        s = sc.uniform_wear(args.count, patch, **kw)
    elif args.kind == "polish":
        s = sc.circular_polish(args.count, patch, **kw)
    else:
        s = sc.hairline_brush(args.count, patch, angle_rad=np.deg2rad(args.angle_deg), **kw)
    sc.save_scratch_set(args.out, s)
    print(json.dumps(_summary(s, args.out)))
    return 0


def _summary(s, path: str) -> dict:
    return {
        "path": path,
        "scratches": s.n_scratches,
        "segments": s.n_segments,
        "patch_size_um": [float(v) for v in s.patch_size_um],
        "grid": {"nx": s.grid_shape[1], "ny": s.grid_shape[0], "cell_size_um": s.cell_size_um,
                 "query_radius_um": s.query_radius_um, "entries": int(s.cell_segments.size),
                 "max_per_cell": int(s.grid_count.max()) if s.grid_count.size else 0},
        "sigma_um": s.sigma_um,
        "width_um": [float(s.width_um.min()), float(s.width_um.max())] if s.n_segments else [],
        "depth_um": [float(s.depth_um.min()), float(s.depth_um.max())] if s.n_segments else [],
    }


def run_info(args: argparse.Namespace) -> int:
    from ..core.scratch import load_scratch_set

    print(json.dumps(_summary(load_scratch_set(args.path), args.path), indent=2))
    return 0


def run_eval(args: argparse.Namespace) -> int:
    import numpy as np

    from ..core.exr_io import write_exr
    from ..core.scratch import SphereLight, load_scratch_set, scratch_radiance

    refuse_output_over_inputs(args.out, [args.path])
    if not args.out.lower().endswith(".exr"):
        raise UsageError(f"--out {args.out!r}: the image is written as OpenEXR: give a .exr file name")
    if args.light[3] <= 0.0:
        raise UsageError(f"--light: the radius R must be > 0, got {args.light[3]:g}")
    if args.light[2] <= args.light[3]:
        raise UsageError(f"--light: the light must lie above the surface (Z > R), got Z {args.light[2]:g}, "
                         f"R {args.light[3]:g}")
    s = load_scratch_set(args.path)
    n = int(args.size)
    check_memory(n * n * PIXEL_BYTES, f"a {n} x {n} image")
    px = s.patch_size_um / n
    u = (np.arange(n) + 0.5) * px[0]
    v = (np.arange(n) + 0.5) * px[1]
    X, Y = np.meshgrid(u, v[::-1])  # row 0 = top = largest v
    pts = np.stack([X.ravel(), Y.ravel()], 1)
    J = np.diag(0.5 * px)
    th = np.deg2rad(args.view_deg)
    wo = np.array([np.sin(th), 0.0, np.cos(th)])
    light = SphereLight(center=np.array(args.light[:3]), radius=float(args.light[3]))
    res = scratch_radiance(pts, J, wo, light, s, args.spectral, si=args.si, footprint_rule=args.footprint_rule,
                           workers=args.workers)
    img = np.concatenate([res.rgb, res.rho_p[:, None]], 1).reshape(n, n, 4)
    write_exr(args.out, img, ("R", "G", "B", "A"))
    print(json.dumps({"out": args.out, "pixels": n * n, "max_rgb": float(res.rgb.max()),
                      "mean_rho_p": float(res.rho_p.mean()), "pairs": res.n_pairs}))
    return 0
