"""Teeth fitting on Dask: per-view loss and gradient rendering as tasks, reduced on the client.

One Adam iteration of ``core.teeth.optimise.fit`` renders every camera twice (pass A: image and
L2 adjoint; pass B: the gradient of sum(adjoint * C)). The L2 loss is a sum over cameras with a
global normalisation the client knows from the masks, so each camera is an independent task: it
renders its own masked pixels, forms its adjoint with the global normaliser and returns its loss
share and gradient; the client adds them up. The capture (images, masks, cameras, lights) is
scattered to the workers once per fit. Each task's random numbers come from (seed, camera), so a
task re-run after a worker died returns exactly what the lost one would have: the result of a
disturbed run equals an undisturbed one.
"""

from __future__ import annotations

import numpy as np

from ..core.teeth.fit_gradient import pass_pair
from ..core.teeth.path_tracer import RenderSettings


def view_loss_gradient(scene, capture, camera: int, light_ids, st: RenderSettings, seed: int, layout, norm: float,
                       loss_block: int = 1, image_spp: int = 0, shape: bool = True):
    """Loss share and physical-parameter gradient of one camera (runs on a worker): the fit's estimator
    (``fit_gradient.pass_pair``) for this camera, scaled by its share of the global normaliser ``norm``,
    with seeds from (seed, camera)."""
    seed_a, seed_b = [int(s) for s in np.random.SeedSequence([seed, camera]).generate_state(2)]
    # this camera's share of the global mean: its own mean times (its values / all values)
    share = max(float(np.count_nonzero(capture.masks[camera])) * len(light_ids) * 3.0, 1.0) / norm
    return pass_pair(scene, capture, [camera], light_ids, st, seed_a, seed_b, layout, loss_block, image_spp, share,
                     shape)


def loss_normaliser(capture, n_lights: int) -> float:
    """Number of masked pixel-light-channel values: the L2 loss is their mean (``optimise.l2_loss``)."""
    return max(float(np.count_nonzero(capture.masks)) * n_lights * 3.0, 1.0)


class DaskGradient:
    """A drop-in for ``optimise.iteration_gradient`` that runs one task per camera on ``client``."""

    attempts = 3  # whole-iteration resubmissions when scattered inputs were lost with a worker

    def __init__(self, client, capture):
        self.client = client
        self.capture = capture
        self.capture_future = None

    # hash=False everywhere: with content-hashed keys a scatter of data equal to a just-released
    # future (same scene twice, a new DaskGradient on the same capture) races with the release and
    # can leave gather() waiting forever (dask/distributed#3703; seen as a CI hang under load)
    def _scatter_capture(self):
        [self.capture_future] = self.client.scatter([self.capture], broadcast=True, hash=False)

    def __call__(self, scene, capture, light_ids, st, seed, layout, loss_block: int = 1, image_spp: int = 0,
                 shape: bool = True):
        from distributed.client import FutureCancelledError

        light_ids = np.asarray(light_ids)
        norm = loss_normaliser(capture, len(light_ids))
        for attempt in range(self.attempts):
            if self.capture_future is None or attempt > 0:
                self._scatter_capture()
            [scene_future] = self.client.scatter([scene], broadcast=True, hash=False)
            futures = [
                self.client.submit(view_loss_gradient, scene_future, self.capture_future, c, light_ids, st, seed,
                                   layout, norm, loss_block, image_spp, shape, pure=False, retries=3)
                for c in range(len(capture.cameras))
            ]
            try:
                results = self.client.gather(futures)  # in camera order: the sum is the same every run
                break
            except FutureCancelledError:  # every replica of an input died: scatter again, rerun
                if attempt == self.attempts - 1:
                    raise
        loss = float(sum(r[0] for r in results))
        grad = np.sum([r[1] for r in results], axis=0)
        stats = {
            "path_vertices": int(sum(r[2]["path_vertices"] for r in results)),
            "render_seconds": float(sum(r[2]["render_seconds"] for r in results)),
            "gradient_seconds": float(sum(r[2]["gradient_seconds"] for r in results)),
            "shape_seconds": float(sum(r[2]["shape_seconds"] for r in results)),
            "loss_single_pass": float(sum(r[2]["loss_single_pass"] for r in results)),
        }
        return loss, grad, stats


def local_gradient(capture):
    """The same per-camera decomposition evaluated in this process (reference for the Dask path)."""

    def gradient(scene, capture_, light_ids, st, seed, layout, loss_block: int = 1, image_spp: int = 0,
                 shape: bool = True):
        light_ids = np.asarray(light_ids)
        norm = loss_normaliser(capture_, len(light_ids))
        results = [view_loss_gradient(scene, capture_, c, light_ids, st, seed, layout, norm, loss_block, image_spp,
                                      shape)
                   for c in range(len(capture_.cameras))]
        return (float(sum(r[0] for r in results)), np.sum([r[1] for r in results], axis=0),
                {"path_vertices": int(sum(r[2]["path_vertices"] for r in results))})

    return gradient
