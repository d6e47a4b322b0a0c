"""Teeth fitting on Dask: the fit's renders as tasks, reduced on the client.

One iteration of ``core.teeth.optimise.fit`` renders every camera twice (pass A: image and L2 adjoint; pass B:
the gradient of sum(adjoint * C)). The L2 loss is a sum over the masked pixels with a global normalisation the
client knows from the masks, so any set of pixels is an independent task that returns its loss share and
gradient. A task here is a band of one camera's image rows (whole blocks of the loss's box filter): a smile
fitted from 2 cameras is 2 tasks per iteration by camera, and as many more as its bands (``bands_per_camera``:
enough for every worker of the cluster). The Gauss-Newton matrices (light groups) and the intervals (dentin
directions, chunks of lights) are tasks through :class:`DaskMap` (``core.teeth.task_map``).

The capture (images, masks, cameras, lights) is scattered to the workers once per fit. Each task's random
numbers come from (seed, camera, band), so a task re-run after a worker died returns exactly what the lost one
would have: the result of a disturbed run equals an undisturbed one, and ``local_gradient`` computes the same
decomposition in this process.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence

import numpy as np

from ..core.teeth.fit_gradient import pass_pair
from ..core.teeth.path_tracer import RenderSettings


def camera_bands(mask: np.ndarray, block: int, bands: int) -> list[tuple[int, int]]:
    """At most ``bands`` row bands [y0, y1) of a (H, W) mask, edges on multiples of ``block``, each holding about
    the same number of masked pixels; bands without a masked pixel are left out."""
    h = mask.shape[0]
    per_block = np.add.reduceat(mask.sum(axis=1), np.arange(0, h, block))  # masked pixels per block row
    total = int(per_block.sum())
    if total == 0:
        return []
    cum = np.cumsum(per_block)
    out, y0 = [], 0
    for b in range(1, bands + 1):
        # the first block row at which the band reaches its share of the pixels
        end = int(np.searchsorted(cum, total * b / bands - 1e-9)) + 1 if b < bands else len(per_block)
        y1 = min(end * block, h)
        if y1 > y0 and mask[y0:y1].any():
            out.append((y0, y1))
        y0 = max(y0, y1)
    return out


def view_loss_gradient(scene, capture, light_ids, st: RenderSettings, seed: int, layout, norm: float,
                       loss_block: int, image_spp: int, shape: bool, camera: int, band: int,
                       rows: tuple[int, int]):
    """Loss share and physical-parameter gradient of one camera's row band (runs on a worker): the fit's
    estimator (``fit_gradient.pass_pair``) for those pixels, scaled by their share of the global normaliser
    ``norm``, with seeds from (seed, camera, band) and the dentin coefficients' direction from the iteration's
    seed alone (one pair of shifted dentins per iteration: a worker refits them once, 0.85 s each for a smile)."""
    seed_a, seed_b = [int(s) for s in np.random.SeedSequence([seed, camera, band]).generate_state(2)]
    [seed_c] = [int(s) for s in np.random.SeedSequence([seed]).generate_state(1)]
    pixels = int(np.count_nonzero(capture.masks[camera, rows[0]:rows[1]]))
    share = max(float(pixels) * len(light_ids) * 3.0, 1.0) / norm
    return pass_pair(scene, capture, [camera], light_ids, st, seed_a, seed_b, layout, loss_block, image_spp, share,
                     shape, rows=rows, direction_seed=seed_c)


def loss_normaliser(capture, n_lights: int) -> float:
    """Number of masked pixel-light-channel values: the L2 loss is their mean (``optimise.l2_loss``)."""
    return max(float(np.count_nonzero(capture.masks)) * n_lights * 3.0, 1.0)


def gradient_items(capture, loss_block: int, bands_per_camera: int) -> list[tuple[int, int, tuple[int, int]]]:
    """(camera, band, rows) of every task of an iteration."""
    return [(c, b, rows) for c in range(len(capture.cameras))
            for b, rows in enumerate(camera_bands(capture.masks[c], max(loss_block, 1), bands_per_camera))]


def _reduce(results: list) -> tuple[float, np.ndarray, dict]:
    """The tasks' loss shares and gradients added up in task order (the same sum every run)."""
    stats = {"path_vertices": int(sum(r[2]["path_vertices"] for r in results))}
    for key in ("render_seconds", "gradient_seconds", "shape_seconds", "loss_single_pass"):
        stats[key] = float(sum(r[2][key] for r in results))
    stats["tasks"] = len(results)
    return float(sum(r[0] for r in results)), np.sum([r[1] for r in results], axis=0), stats


def _run_item(fn: Callable, shared: tuple, capture, capture_at: int | None, item: tuple):
    """``fn(*shared, *item)`` on a worker, the capture put back at ``capture_at`` (it travels on its own)."""
    args = list(shared)
    if capture_at is not None:
        args[capture_at] = capture
    return fn(*args, *item)


class DaskMap:
    """A ``core.teeth.task_map`` on ``client``: one task per item, results gathered in the items' order. The fit's
    ``capture`` is scattered to every worker once and reused; any other shared value travels once per call."""

    attempts = 3  # whole-call resubmissions when scattered inputs were lost with a worker

    def __init__(self, client, capture=None):
        self.client = client
        self.capture = capture
        self.capture_future = None

    @property
    def parallel(self) -> int:
        """The cluster's threads (tasks it runs at once)."""
        return max(1, sum(self.client.nthreads().values()))

    # hash=False everywhere: with content-hashed keys a scatter of data equal to a just-released
    # future (same scene twice, a new DaskMap on the same capture) races with the release and
    # can leave gather() waiting forever (dask/distributed#3703; seen as a CI hang under load)
    def __call__(self, fn: Callable, shared: tuple, items: Sequence[tuple]) -> list:
        from distributed.client import FutureCancelledError

        if not items:
            return []
        at = next((i for i, v in enumerate(shared) if self.capture is not None and v is self.capture), None)
        rest = tuple(None if i == at else v for i, v in enumerate(shared))
        for attempt in range(self.attempts):
            capture_future = None
            if at is not None:
                if self.capture_future is None or attempt > 0:
                    [self.capture_future] = self.client.scatter([self.capture], broadcast=True, hash=False)
                capture_future = self.capture_future
            [shared_future] = self.client.scatter([rest], broadcast=True, hash=False)
            futures = [self.client.submit(_run_item, fn, shared_future, capture_future, at, item, pure=False,
                                          retries=3) for item in items]
            try:
                return self.client.gather(futures)
            except FutureCancelledError:  # every replica of an input died: scatter again, rerun
                if attempt == self.attempts - 1:
                    raise
        raise AssertionError("unreachable")


class DaskGradient:
    """A drop-in for ``optimise.iteration_gradient`` that runs one task per camera row band on ``client``.

    ``bands_per_camera``: bands of each camera's image per iteration (default: enough for every thread of the
    cluster when the gradient is made). ``task_map`` is the :class:`DaskMap` that runs them, for the fit's other
    steps too (``fit(..., task_map=...)``)."""

    def __init__(self, client, capture, bands_per_camera: int | None = None):
        self.task_map = DaskMap(client, capture)
        self.capture = capture
        self.bands_per_camera = bands_per_camera or max(1, -(-self.task_map.parallel // len(capture.cameras)))

    def __call__(self, scene, capture, light_ids, st, seed, layout, loss_block: int = 1, image_spp: int = 0,
                 shape: bool = True):
        light_ids = np.asarray(light_ids)
        shared = (scene, self.capture, light_ids, st, seed, layout, loss_normaliser(capture, len(light_ids)),
                  loss_block, image_spp, shape)
        return _reduce(self.task_map(view_loss_gradient, shared,
                                     gradient_items(capture, loss_block, self.bands_per_camera)))


def local_gradient(capture, bands_per_camera: int = 1):
    """The same decomposition (``bands_per_camera`` bands of each camera) evaluated in this process (reference for
    the Dask path)."""

    def gradient(scene, capture_, light_ids, st, seed, layout, loss_block: int = 1, image_spp: int = 0,
                 shape: bool = True):
        light_ids = np.asarray(light_ids)
        shared = (scene, capture_, light_ids, st, seed, layout, loss_normaliser(capture_, len(light_ids)),
                  loss_block, image_spp, shape)
        return _reduce([view_loss_gradient(*shared, *item)
                        for item in gradient_items(capture_, loss_block, bands_per_camera)])

    return gradient
