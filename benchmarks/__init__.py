"""Benchmark registry.

Every module ``benchmarks/<module>.py`` defines ``BENCHMARKS: dict[str, Callable[[], dict]]``
mapping a benchmark name (e.g. ``"fabric-fit"``) to a function returning a JSON-serialisable dict
with the keys its issue names. Ratios are measured side by side in the same run.
"""

from __future__ import annotations

import importlib
import pkgutil
from collections.abc import Callable


def _registry() -> dict[str, Callable[[], dict]]:
    found: dict[str, Callable[[], dict]] = {}
    for info in pkgutil.iter_modules(__path__):
        if info.name.startswith("_"):
            continue
        module = importlib.import_module(f".{info.name}", __name__)
        for name, fn in getattr(module, "BENCHMARKS", {}).items():
            if name in found:
                raise RuntimeError(f"benchmark {name!r} defined twice")
            found[name] = fn
    return found


def available() -> list[str]:
    return sorted(_registry())


def run_benchmark(name: str) -> dict:
    return _registry()[name]()
