"""``bench NAME``: run one benchmark and print one JSON object; ``bench --all`` writes them all."""

from __future__ import annotations

import argparse
import contextlib
import json
import os
import sys

from .checks import UsageError


def add_parser(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("bench", help="run a benchmark and print one JSON object")
    p.add_argument("name", nargs="?", help="benchmark name (see --list)")
    p.add_argument("--list", action="store_true", help="list benchmark names")
    p.add_argument("--all", action="store_true", help="run every benchmark")
    p.add_argument("--out", default=None, help="with --all: folder for NAME.json (default: bench/results)")
    p.set_defaults(func=run)


@contextlib.contextmanager
def _stdout_to_stderr():
    """Send what the benchmark writes to standard output, Blender's own C-level log lines included, to
    standard error, so that standard output holds only the JSON."""
    sys.stdout.flush()
    saved = os.dup(1)
    try:
        os.dup2(2, 1)
        with contextlib.redirect_stdout(sys.stderr):
            yield
    finally:
        sys.stdout.flush()
        os.dup2(saved, 1)
        os.close(saved)


def _run_quiet(name: str) -> dict:
    from ..benchmarks import run_benchmark

    with _stdout_to_stderr():
        return run_benchmark(name)


def run(args: argparse.Namespace) -> int:
    from ..benchmarks import available

    names = available()
    if args.list:
        print("\n".join(sorted(names)))
        return 0
    if args.all:
        out = args.out or os.path.join("bench", "results")
        os.makedirs(out, exist_ok=True)
        failed = 0
        for name in sorted(names):
            print(f"[bench] {name} ...", file=sys.stderr, flush=True)
            try:
                result = _run_quiet(name)
            except Exception as exc:  # keep going, report at the end
                failed += 1
                result = {"error": f"{type(exc).__name__}: {exc}"}
            with open(os.path.join(out, f"{name}.json"), "w") as f:
                json.dump(result, f, indent=2, sort_keys=True)
            print(json.dumps({name: result}))
        return 1 if failed else 0
    if not args.name:
        raise UsageError("give a benchmark NAME, --list or --all")
    if args.name not in names:
        raise UsageError(f"unknown benchmark {args.name!r}; available: {', '.join(sorted(names))}")
    print(json.dumps(_run_quiet(args.name)))
    return 0
