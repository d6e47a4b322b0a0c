"""Independent parts of a fit's computation, run in this process or as tasks on a cluster.

The fit's long steps are sums of renders that do not depend on each other: the Gauss-Newton matrix over
groups of lights (``gauss_newton.gauss_newton_matrix``), the intervals' information over shape directions and
chunks of lights (``sensitivity.capture_sensitivity``). Each such step is written as a function applied to a
list of items; a *task map* applies it,

    task_map(fn, shared, items) = [fn(*shared, *item) for item in items]

in the items' order, and the step adds the results up on the caller in that order. ``local_map`` computes the
list here; ``scaleout.teeth.DaskMap`` submits one Dask task per item (``shared``, the scene and the capture,
sent to the workers once per call). Every item carries its own seeds, so both give the same numbers.

``parallel`` is how many items the map computes at once (1 here): a step whose items cost more when split
finer (chunks of lights share their camera paths) splits finer only for a map that runs them side by side.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from typing import Any, Protocol


class TaskMap(Protocol):
    """``task_map(fn, shared, items)``: ``[fn(*shared, *item) for item in items]``, computed somewhere."""

    parallel: int

    def __call__(self, fn: Callable, shared: tuple, items: Sequence[tuple]) -> list: ...


class LocalMap:
    """The items one after another in this process."""

    parallel = 1

    def __call__(self, fn: Callable, shared: tuple, items: Sequence[tuple]) -> list[Any]:
        return [fn(*shared, *item) for item in items]


local_map = LocalMap()
