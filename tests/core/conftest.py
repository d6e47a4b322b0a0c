"""Core fixtures.

``tracer``: a test that takes it runs once per teeth path tracer, the compiled one (numba,
``core/teeth/path_tracer_compiled.py``) and the numpy reference (``core/teeth/path_tracer.py``), as
Mitsuba 3 runs a test on every variant. ``tracer.reference`` is what ``render``, ``fit`` and the
gradient estimators take as ``reference=``.
"""

from __future__ import annotations

from dataclasses import dataclass

import pytest


@dataclass(frozen=True)
class Tracer:
    """One of the teeth path tracers."""

    name: str
    reference: bool  # the numpy reference tracer (True) or the compiled one (False)


TRACERS = (Tracer("compiled", False), Tracer("reference", True))


@pytest.fixture(params=TRACERS, ids=[t.name for t in TRACERS])
def tracer(request) -> Tracer:
    return request.param
