"""Gauss-Newton preconditioning of the teeth fit (an option next to the thesis' Adam, Sec. 5.6).

The L2 loss rho(y) = mean over masked pixels, lights and channels of (C(y) - C_ref)^2 has, near a
good fit, the Gauss-Newton curvature

    H = 2 / M * sum over pixels, lights, channels of J^T J,     J = dC / dy (optimiser variables).

Its eigenvalues span several decades for teeth: enamel and dentin absorption trade off against each
other in every channel, so the loss is a long, narrow valley. Adam scales every coordinate by its own
gradient size, which does not follow a valley that runs diagonally through the coordinates, and the
fit creeps along it. A step ``P g`` with ``P = (H + lambda diag H)^-1`` (Levenberg-Marquardt damping)
does follow it.

H is estimated from ``passes`` independent 1-spp forward-mode Jacobian passes (``path_tracer.render``
with ``jacobian_cols``), pooled over ``block`` x ``block`` pixel tiles (the box-filtered images' H, a
lower bound of the per-pixel one with far less Monte Carlo noise per entry). Two estimators, both
positive semi-definite (products of two independent passes would be unbiased but indefinite):

* "per-pass", the mean of the passes' own J_i^T J_i: each carries its Monte Carlo variance Sigma as
  extra curvature, however many passes there are;
* "pooled", (mean_i J_i)^T (mean_i J_i): the bias is Sigma / passes.

The bias matters along the valley's flattest directions, whose true curvature is tiny. Measured at
the truth of the acceptance capture (6 passes of all 54 lights; reference: the unbiased mean of the
products of different passes), along the 8 flattest directions of the material parameters the
per-pass estimate of 4 passes was 6-16x the curvature, the pooled one 2.4-4.7x; with the damping
of 0.03 the steps there were 3-10 % of the Newton step per-pass, 4-39 % pooled, 9-50 % with
damping 0.01. ``tests/core/test_teeth_gauss_newton.py`` checks the bias against a 128-pass
reference on a slab.

In the fit (``FitSettings``' defaults: Adam for 80 iterations, then this
every 40 iterations) the per-pass matrix took the materials from 20 % to about 8 % (sigma_t) in 120
iterations, and the pooled one of 8 passes with damping 0.01 to about 4 % from the same state
(docs/teeth-fit.md). An earlier version clipped each coordinate's step on its own and had no guard, and
a sigma_t diverged after 30 iterations; the step is now shortened as a whole, and
:class:`DivergenceGuard` rolls back and raises the damping when windows of the loss rise.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..errors import UserError
from .capture import Capture
from .compiled_scene import CompiledScene
from .param_vector import ParamLayout, chain_to_optimiser
from .path_tracer import RenderSettings, render, traced_tiles
from .scene import TeethScene
from .task_map import TaskMap, local_map

ESTIMATORS = ("per-pass", "pooled")


def optimiser_jacobian_map(y: np.ndarray, layout: ParamLayout, cols: np.ndarray) -> np.ndarray:
    """(k, k) dx[cols] / dy[cols] at ``y``: the physical Jacobian columns ``cols`` times this map are the
    optimiser-variable columns (the map only mixes a volume's sigma_t and albedo, so ``cols`` must hold
    both or neither of a pair)."""
    eye = np.eye(layout.size)
    return np.array([chain_to_optimiser(eye[i], y, layout)[cols] for i in cols])


def gauss_newton_matrix(scene: TeethScene, capture: Capture, layout: ParamLayout, cols: np.ndarray, y: np.ndarray,
                        *, passes: int = 4, block: int = 8, max_depth: int | None = None,
                        seed: int = 0, workers: int = 1, lights_per_render: int = 9,
                        estimator: str = "per-pass", task_map: TaskMap | None = None) -> np.ndarray:
    """(k, k) Gauss-Newton matrix of the per-pixel L2 loss over all of ``capture``'s lights in the
    optimiser variables ``y[cols]``, estimated from ``passes`` 1-spp Jacobian passes (module docstring).

    ``estimator``: "per-pass" averages the passes' own J_i^T J_i (Monte Carlo bias Sigma, the variance
    of one pass's tile Jacobian); "pooled" is (mean_i J_i)^T (mean_i J_i), also positive semi-definite,
    with bias Sigma / passes (module docstring). Each group of ``lights_per_render`` lights is one item of
    ``task_map`` (default: this process); the matrix is their sum, the same whichever map computes it."""
    if estimator not in ESTIMATORS:
        raise ValueError(f"estimator must be one of {ESTIMATORS}, got {estimator!r}")
    if passes < 1:
        raise ValueError(f"passes must be >= 1, got {passes}")
    if block < 1:
        raise ValueError(f"block must be >= 1, got {block}")
    if capture.masks is None:
        raise UserError("the capture needs masks")
    cols = np.asarray(cols, dtype=np.int64)
    k = len(cols)
    chain = optimiser_jacobian_map(y, layout, cols)
    n_l = len(capture.lights)
    m = len(np.flatnonzero(capture.masks)) * n_l * 3
    groups = [(np.arange(i, min(i + lights_per_render, n_l)), gi)
              for gi, i in enumerate(range(0, n_l, lights_per_render))]
    shared = (scene, capture, layout, cols, chain, passes, block, max_depth, seed, workers, estimator)
    out = np.zeros((k, k))
    for part in (task_map or local_map)(light_group_curvature, shared, groups):
        out += part
    return out * (2.0 / (m * passes * (passes if estimator == "pooled" else 1)))


def light_group_curvature(scene: TeethScene, capture: Capture, layout: ParamLayout, cols: np.ndarray,
                          chain: np.ndarray, passes: int, block: int, max_depth: int | None, seed: int, workers: int,
                          estimator: str, ids: np.ndarray, group: int) -> np.ndarray:
    """One light group's share of :func:`gauss_newton_matrix` before its normaliser: the sum over passes of
    J_p^T J_p ("per-pass") or (sum_p J_p)^T (sum_p J_p) ("pooled"), J_p the pass's (tiles x lights x 3, k)
    tile Jacobian in the optimiser variables; pass p renders with seed ``seed + 1000 p + group``."""
    h, w = capture.masks.shape[1:]
    pixels = [np.flatnonzero(m.ravel()) for m in capture.masks]
    tile_of, n_tiles = traced_tiles(pixels, h, w, block)
    inv_sqrt_n = 1.0 / np.sqrt(np.bincount(tile_of, minlength=n_tiles).astype(np.float64))
    cs = CompiledScene(scene, layout=layout)
    k = len(cols)
    out = np.zeros((k, k))
    pooled = 0.0
    for p in range(passes):
        st = RenderSettings(spp=1, max_depth=max_depth, seed=seed + 1000 * p + group, workers=workers)
        r = render(scene, capture.cameras, capture.lights, st, pixels=pixels, light_ids=ids, compiled=cs,
                   jacobian_cols=cols)
        jt = np.zeros((n_tiles,) + r.jacobian.shape[1:])  # (tiles, L, 3, k) tile sums
        np.add.at(jt, tile_of, r.jacobian)
        jt = (jt * inv_sqrt_n[:, None, None, None]).reshape(-1, k) @ chain
        if estimator == "pooled":
            pooled = pooled + jt
        else:
            out += jt.T @ jt
    if estimator == "pooled":
        out = pooled.T @ pooled
    return out


def damped_inverse(hmat: np.ndarray, damping: float) -> np.ndarray:
    """(H + damping diag H)^-1 (Levenberg-Marquardt); H must be symmetric positive semi-definite.

    A variable whose row and column of H are zero does not change the masked pixels at this point (a lobe's
    g while the lobe's weight beta sits at its bound, say): it gets a zero row and column, so the matrix
    does not move it, and the inverse is taken over the others."""
    if damping <= 0:
        raise ValueError(f"damping must be > 0, got {damping}")
    if not np.all(np.isfinite(hmat)):
        raise ValueError("the Gauss-Newton matrix is not finite")
    d = np.diag(hmat).copy()
    dead = d == 0.0
    if np.any(d < 0) or np.any(hmat[dead] != 0.0):
        raise ValueError("the Gauss-Newton matrix needs a nonnegative diagonal, and zero rows where it is 0")
    live = ~dead
    s = 1.0 / np.sqrt(d[live])
    a = hmat[np.ix_(live, live)] * np.outer(s, s) + damping * np.eye(len(s))  # unit diagonal: better conditioned
    out = np.zeros_like(hmat)
    out[np.ix_(live, live)] = np.linalg.inv(a) * np.outer(s, s)
    return out


@dataclass
class PreconditionedMomentum:
    """y <- y - r lr P m_hat with m = b1 m + (1 - b1) g (an average of the stochastic gradients,
    bias-corrected like Adam's first moment); ``P`` the damped inverse Gauss-Newton matrix; r <= 1 the
    largest factor that keeps every coordinate's move within ``max_step``. The bound is a trust region:
    along directions the estimated curvature calls flat, the gradient's noise would otherwise take steps
    far outside the region where the curvature was estimated. It shortens the whole step, so the step
    stays a descent direction (clipping each coordinate on its own would not)."""

    lr: float
    b1: float = 0.9
    m: np.ndarray | None = None
    n: int = 0
    max_step: float = np.inf  # trust region: no coordinate moves further than this per step

    def step(self, y: np.ndarray, g: np.ndarray, precond: np.ndarray, lr: float | None = None) -> np.ndarray:
        if self.m is None:
            self.m = np.zeros_like(y)
        self.n += 1
        self.m = self.b1 * self.m + (1 - self.b1) * g
        mh = self.m / (1 - self.b1**self.n)
        d = (self.lr if lr is None else lr) * (precond @ mh)
        big = np.abs(d).max(initial=0.0)
        return y - (d * (self.max_step / big) if big > self.max_step else d)

    def reset(self) -> None:
        """Forget the gradient average (after a rollback its gradients belong to another place)."""
        self.m, self.n = None, 0


@dataclass
class DivergenceGuard:
    """Levenberg-Marquardt control of the stochastic Gauss-Newton phase.

    The per-iteration loss (a random subset of lights, Monte Carlo images) is too noisy to accept or
    reject single steps, so the guard compares windows: the mean loss of ``window`` iterations and
    the mean of their iterates. A window better than the best so far becomes the best and lowers the
    damping by ``factor`` (down to ``min_damping``); a window whose mean loss exceeds the best one's by
    more than ``rise`` (relative) is a divergence: the fit goes back to the best window's mean iterate
    and the damping rises by ``factor``, which shortens the steps along the flat directions of the
    matrix, where the gradient noise is amplified most."""

    window: int
    rise: float
    factor: float
    damping: float
    min_damping: float
    loss_sum: float = 0.0
    y_sum: np.ndarray | None = None
    n: int = 0
    best_loss: float = np.inf
    best_y: np.ndarray | None = None
    rollbacks: int = 0

    def observe(self, loss: float, y: np.ndarray) -> np.ndarray | None:
        """Record the loss measured at iterate ``y``; at a window's end, return the iterate to go back
        to (after a divergence) or None."""
        self.loss_sum += float(loss)
        self.y_sum = np.array(y, dtype=np.float64) if self.y_sum is None else self.y_sum + y
        self.n += 1
        if self.n < self.window:
            return None
        mean_loss, mean_y = self.loss_sum / self.n, self.y_sum / self.n
        self.loss_sum, self.y_sum, self.n = 0.0, None, 0
        if mean_loss < self.best_loss:
            self.best_loss, self.best_y = mean_loss, mean_y
            self.damping = max(self.min_damping, self.damping / self.factor)
            return None
        if mean_loss > self.best_loss * (1.0 + self.rise):
            self.damping *= self.factor
            self.rollbacks += 1
            return self.best_y.copy()
        return None

    def to_dict(self) -> dict:
        return {k: (v.tolist() if isinstance(v, np.ndarray) else v) for k, v in self.__dict__.items()}

    @classmethod
    def from_dict(cls, d: dict) -> DivergenceGuard:
        arrays = {k: None if d[k] is None else np.array(d[k]) for k in ("y_sum", "best_y")}
        return cls(**{**d, **arrays})
