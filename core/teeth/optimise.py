"""Inverse rendering: L2 loss, Adam (eq. 2.38-2.39), best-loss tracking, "homogeneous" then
"textured" phases, checkpoints and resume (thesis Sec. 5.6-5.7).

Each iteration renders the image C with one seed (pass A), forms d rho / d C = 2 (C - C_ref) / M over
the masked pixels (L2 loss, eq. 5.7-5.8), and traces the gradient pass with an independent seed
(pass B), as in the thesis ("two independently seeded rendering passes"). A random subset of the
lights is used per iteration (stochastic gradient). The physical gradient is mapped to the dual
domains xi = log sigma_t (eq. 5.24), kappa = log10(1 - albedo) (eq. 5.22) and Adam steps them. The
parameters with the lowest loss seen are kept ("we keep track of the lowest loss value").
"""

from __future__ import annotations

import fnmatch
import inspect
import json
import os
import time
from collections.abc import Callable
from dataclasses import asdict, dataclass, field, replace

import numpy as np

from .capture import Capture
from .compiled_scene import CompiledScene
from .gauss_newton import ESTIMATORS, DivergenceGuard, PreconditionedMomentum, damped_inverse, gauss_newton_matrix
from .param_vector import (
    ParamLayout,
    chain_to_optimiser,
    from_optimiser,
    scene_to_vector,
    to_optimiser,
    vector_to_scene,
    volume_pairs,
)
from .path_tracer import RenderSettings, render
from .scene import TeethScene

DEFAULT_FREE = ("*.sigma_t", "*.albedo", "*.g1", "*.g2", "*.beta", "*.a_t", "*.c")


@dataclass
class FitSettings:
    iterations: int = 100  # "homogeneous" phase
    textured_iterations: int = 0  # "textured" phase (a_t becomes a texture_size^2 texture)
    texture_size: int = 8
    lr: float = 0.03
    b1: float = 0.9
    b2: float = 0.999
    # eq. 2.39's epsilon sits inside the square root, so it must stay far below the squared gradients:
    # the loss is a mean over pixels, and near the optimum the gradients are 1e-6 to 3e-5; 1e-8 (the
    # usual default) made sqrt(eps) = 1e-4 the divisor and Adam plain gradient descent there
    eps: float = 1e-24
    spp: int = 1
    # None: all bounces (Russian roulette), as in a photograph; an int caps the path length (experiments:
    # a capped renderer is 13-26 % too dark on teeth, docs/teeth-tracer.md)
    max_depth: int | None = None
    lights_per_iteration: int = 18
    seed: int = 0
    free: tuple = DEFAULT_FREE  # fnmatch patterns of parameter names to optimise
    checkpoint_every: int = 5
    lr_decay: float = 0.0  # lr_n = lr / (1 + lr_decay * n)
    # image control variate (see ``anchor_image``): 0 = off, else the spp of the anchor image of all lights
    anchor_spp: int = 0
    anchor_every: int = 20  # iterations between anchor refreshes
    # L2 loss of box-filtered images (block x block pixel tiles; 1 = per pixel as in the thesis). The
    # noise-free loss still has its minimum where the model matches the capture, and the gradient's
    # dominant noise near the optimum, the product of pass A's and pass B's independent per-pixel noise,
    # averages over each tile (see README, "Fit noise")
    loss_block: int = 1
    # samples per pixel of pass A (the image that forms the adjoint 2 (C_A - C_ref)); 0 = ``spp``. Near
    # the optimum the gradient's variance is mostly pass A's per-pixel noise times the pixel's
    # derivative, so pass A gets more samples than pass B (forward only, no derivative bookkeeping)
    image_spp: int = 0
    # processes that trace each pass with the numpy reference tracer, where numba is missing (the compiled
    # tracer runs one thread per core by itself) (``RenderSettings.workers``; on 2 cores a pass takes 1.4-2x less
    # time: the chunks of paths are dealt round-robin, so few chunks balance unevenly)
    workers: int = 1
    # optimiser domain of sigma_t / albedo: "thesis" (log sigma_t, log10(1 - albedo), eq. 5.22-5.24)
    # or "absorption" (log sigma_s, log sigma_a; see param_vector.to_optimiser)
    domain: str = "thesis"
    # "adam" (the thesis) or "gauss-newton": steps gn_lr * P m (m averages the gradients with b1, P the
    # damped inverse Gauss-Newton matrix of all lights, see gauss_newton.py), P estimated from gn_passes
    # 1-spp Jacobian passes pooled in gn_block tiles at the phase's start and every gn_every iterations.
    # Adam creeps along the loss valley in which enamel and dentin absorption trade off; this follows it.
    # lr_decay applies to gn_lr as to lr. The acceptance fit's values: fit_presets.FIT_PRESETS["acceptance"]
    # (README, "Why Adam stalls")
    optimiser: str = "adam"
    gn_lr: float = 0.3  # fraction of the Gauss-Newton step
    # Adam iterations before Gauss-Newton takes over (per phase): far from the optimum the linearised
    # model's steps along its flat directions are long and wrong, Adam's bounded steps are not
    gn_start: int = 0
    gn_passes: int = 4
    gn_block: int = 8
    gn_damping: float = 0.03
    # how the passes make the matrix: "per-pass" (mean of J_i^T J_i) or "pooled" ((mean J_i)^T (mean J_i));
    # see gauss_newton.gauss_newton_matrix
    gn_estimator: str = "per-pass"
    gn_every: int = 50
    gn_max_step: float = 0.05  # trust region: the step shrinks until no optimiser variable moves further
    # divergence guard (gauss_newton.DivergenceGuard): windows of gn_guard_window iterations; a window whose
    # mean loss is more than gn_guard_rise above the best window's goes back to that window's mean iterate
    # and multiplies the damping by gn_guard_factor (a better window divides it, down to gn_damping);
    # gn_guard_window = 0 turns the guard off
    gn_guard_window: int = 10
    gn_guard_rise: float = 0.25
    gn_guard_factor: float = 4.0
    # the dentin coefficients keep Adam (lr, b1, b2): their Jacobian columns are mostly Monte Carlo
    # noise at a few passes, so their Gauss-Newton rows and cross terms would be noise too
    gn_adam_c: bool = True
    # factor on their Adam lr while Gauss-Newton steps the materials: with the materials following
    # their conditional optimum, the coefficients sit in a flat valley (dentin shape against dentin
    # absorption) along which steps of the normalised size lr random-walk (README, "Why Adam stalls")
    gn_c_lr: float = 1.0
    # Polyak-Ruppert averaging: the result is the mean (in the optimiser domain) of the iterates of the
    # last ``average_tail`` fraction of the last phase's iterations. Near the optimum the iterates wander
    # by their gradient noise, and their mean is closer to the optimum than any one of them or than the
    # best-loss iterate (whose loss estimate is itself noisy). 0 = the best-loss scene (the thesis)
    average_tail: float = 0.0

    def __post_init__(self) -> None:
        if not 0.0 <= self.average_tail < 1.0:
            raise ValueError(f"average_tail must be in [0, 1), got {self.average_tail}")
        if self.image_spp < 0:
            raise ValueError(f"image_spp must be >= 0 (0 = spp), got {self.image_spp}")
        if self.workers < 1:
            raise ValueError(f"workers must be >= 1, got {self.workers}")
        if self.optimiser not in ("adam", "gauss-newton"):
            raise ValueError(f'optimiser must be "adam" or "gauss-newton", got {self.optimiser!r}')
        if self.optimiser == "gauss-newton":
            if not self.gn_lr > 0:
                raise ValueError(f"gn_lr must be > 0, got {self.gn_lr}")
            if self.gn_passes < 1 or self.gn_block < 1 or self.gn_every < 1 or self.gn_start < 0:
                raise ValueError("gn_passes, gn_block and gn_every must be >= 1, gn_start >= 0")
            if not self.gn_damping > 0:
                raise ValueError(f"gn_damping must be > 0, got {self.gn_damping}")
            if not self.gn_max_step > 0:
                raise ValueError(f"gn_max_step must be > 0, got {self.gn_max_step}")
            if not self.gn_c_lr > 0:
                raise ValueError(f"gn_c_lr must be > 0, got {self.gn_c_lr}")
            if self.gn_estimator not in ESTIMATORS:
                raise ValueError(f"gn_estimator must be one of {ESTIMATORS}, got {self.gn_estimator!r}")
            if self.gn_guard_window < 0 or not self.gn_guard_rise > 0 or not self.gn_guard_factor > 1:
                raise ValueError("gn_guard_window must be >= 0, gn_guard_rise > 0 and gn_guard_factor > 1, got "
                                 f"{self.gn_guard_window}, {self.gn_guard_rise}, {self.gn_guard_factor}")


@dataclass
class Adam:
    """Adam with bias correction (Kingma and Ba 2014; thesis eq. 2.38-2.39)."""

    lr: float
    b1: float = 0.9
    b2: float = 0.999
    eps: float = 1e-24  # inside the square root (eq. 2.39); see FitSettings.eps
    m: np.ndarray | None = None
    v: np.ndarray | None = None
    n: int = 0

    def step(self, y: np.ndarray, g: np.ndarray, lr: float | np.ndarray | None = None) -> np.ndarray:
        if self.m is None:
            self.m = np.zeros_like(y)
            self.v = np.zeros_like(y)
        self.n += 1
        self.m = self.b1 * self.m + (1 - self.b1) * g
        self.v = self.b2 * self.v + (1 - self.b2) * g * g
        mh = self.m / (1 - self.b1**self.n)
        vh = self.v / (1 - self.b2**self.n)
        return y - (self.lr if lr is None else lr) * mh / np.sqrt(vh + self.eps)


def block_sums(x: np.ndarray, block: int) -> np.ndarray:
    """Sums of (n_cam, n_light, H, W, 3) over block x block pixel tiles, (n_cam, n_light, H/b, W/b, 3)
    (edges padded with zeros)."""
    if block == 1:
        return x
    n, nl, h, w, c = x.shape
    hb, wb = -(-h // block), -(-w // block)
    pad = np.zeros((n, nl, hb * block, wb * block, c))
    pad[:, :, :h, :w] = x
    return pad.reshape(n, nl, hb, block, wb, block, c).sum(axis=(3, 5))


def _block_counts(masks: np.ndarray, block: int) -> np.ndarray:
    """Masked pixels per tile, (n_cam, 1, H/b, W/b, 1), at least 1."""
    return np.maximum(block_sums(masks[:, None, :, :, None].astype(np.float64), block), 1.0)


def l2_loss(images: np.ndarray, reference: np.ndarray, masks: np.ndarray, block: int = 1) -> tuple[float, np.ndarray]:
    """rho = mean over masked pixels, lights and channels of (C - C_ref)^2 and d rho / d C.

    ``block`` > 1: the L2 loss of the box-filtered images instead, sum over block x block tiles of
    (sum of the tile's masked differences)^2 / (masked pixels in the tile), with the same normaliser (so
    block = 1 is the per-pixel loss). Not in the thesis; see ``FitSettings.loss_block``."""
    w = np.broadcast_to(masks[:, None, :, :, None], images.shape).astype(np.float64)
    m = max(w.sum(), 1.0)
    diff = (images - reference) * w
    if block == 1:
        return float(np.sum(diff * diff) / m), 2.0 * diff / m
    h, wd = images.shape[2:4]
    sums = block_sums(diff, block)
    tile = sums / _block_counts(masks, block)  # per-tile mean difference
    up = np.repeat(np.repeat(tile, block, axis=2), block, axis=3)[:, :, :h, :wd]
    return float(np.sum(tile * sums) / m), 2.0 * up * w / m


def paired_loss(img_a: np.ndarray, img_b: np.ndarray, reference: np.ndarray, masks: np.ndarray,
                block: int = 1) -> float:
    """The L2 loss (of ``block``-filtered images) estimated from two independent renders: the product
    (C_A - C_ref)(C_B - C_ref) has no Monte Carlo variance bias, unlike (C_A - C_ref)^2."""
    w = masks[:, None, :, :, None]
    m = max(float(np.sum(np.broadcast_to(w, img_b.shape))), 1.0)
    ra, rb = block_sums((img_a - reference) * w, block), block_sums((img_b - reference) * w, block)
    return float(np.sum(ra * rb / _block_counts(masks, block)) / m)


def free_mask(layout: ParamLayout, patterns) -> np.ndarray:
    mask = np.zeros(layout.size, dtype=bool)
    for e in layout.entries:
        if any(fnmatch.fnmatch(e.name, p) for p in patterns):
            mask[e.start:e.start + e.size] = True
    return mask


def texture_phase_scene(scene: TeethScene, size: int) -> TeethScene:
    """Upsample every a_t to a size x size texture (constant), starting the "textured" phase."""
    out = scene.copy()
    for t in out.teeth:
        t.a_t = np.broadcast_to(t.a_t.reshape(-1, 3).mean(axis=0), (size, size, 3)).copy()
    if out.gums is not None:
        out.gums.a_t = np.broadcast_to(out.gums.a_t.reshape(-1, 3).mean(axis=0), (size, size, 3)).copy()
    return out


@dataclass
class FitState:
    phase: str
    iteration: int
    scene: dict
    y: list
    adam_m: list | None
    adam_v: list | None
    adam_n: int
    best_loss: float
    best_scene: dict
    log: list = field(default_factory=list)
    anchor_scene: dict | None = None  # the image control variate's scene (re-rendered on resume)
    anchor_iteration: int = -1
    # optimiser "gauss-newton": the Gauss-Newton matrix in use (over its variables), its momentum and guard
    gn_hmat: list | None = None
    precond_iteration: int = -1
    gn_m: list | None = None
    gn_n: int = 0
    gn_guard: dict | None = None
    # average_tail: the sum and count of the averaged iterates so far (optimiser domain)
    avg_sum: list | None = None
    avg_count: int = 0


def tail_start(n_iterations: int, average_tail: float) -> int:
    """First iteration of the last phase whose iterate enters the averaged result (``average_tail``)."""
    if average_tail <= 0:
        return n_iterations
    return n_iterations - max(1, int(round(n_iterations * average_tail)))


def _save_json(path: str, obj) -> None:
    tmp = f"{path}.tmp"
    with open(tmp, "w") as f:
        json.dump(obj, f)
    os.replace(tmp, path)


@dataclass
class Anchor:
    """An image control variate: ``images`` (all lights, ``spp`` samples) rendered at ``scene``.

    With an anchor, pass A estimates the image at theta as
    C(anchor; high spp) + [C(theta; w) - C(anchor; w)], the bracket evaluated with common random
    numbers (paths sampled at the anchor, evaluated at theta and at the anchor). Both terms are
    unbiased, so the gradient stays unbiased given the anchor image; the bracket's variance shrinks
    with |theta - anchor|, which removes most of the 1-spp noise that pass A puts into the adjoint
    2 (C_A - C_ref) (the dominant gradient-noise term near the optimum). The anchor image's own
    noise acts as a fixed bias for the iterations that share it and averages out across refreshes.
    The bracket is exact for the material parameters; for the dentin coefficients it uses theta's
    geometry on both sides, so between refreshes the image estimate lags in c by c - c_anchor.
    """
    scene: TeethScene
    images: np.ndarray  # (n_cam, n_lights, H, W, 3)
    spp: int
    iteration: int


def anchor_image(scene: TeethScene, capture: Capture, spp: int, max_depth: int | None, seed: int, layout: ParamLayout,
                 iteration: int = 0, workers: int = 1) -> Anchor:
    """Render the masked pixels of every light at ``spp`` for an :class:`Anchor`."""
    pixels = [np.flatnonzero(m.ravel()) for m in capture.masks]
    rs = RenderSettings(spp=spp, max_depth=max_depth, seed=seed, workers=workers)
    res = render(scene, capture.cameras, capture.lights, rs, pixels=pixels,
                 compiled=CompiledScene(scene, layout=layout))
    return Anchor(scene.copy(), res.images, spp, iteration)


def _anchor_seed(s: FitSettings, phase_index: int, iteration: int) -> int:
    """Seed of the anchor image refreshed at ``iteration``: odd and far from the passes' 2 seed, 2 seed + 1."""
    return 2 * (s.seed * 100003 + 10007 * phase_index + iteration + 7_000_003) + 1


def _gn_seed(s: FitSettings, phase_index: int, iteration: int) -> int:
    """Seed of the Gauss-Newton Jacobian passes estimated at ``iteration`` (their renders use this + up
    to 1000 * passes + lights / 9; far above the pass A / B and anchor seeds)."""
    return 3_000_000_000 + 10_000_000 * s.seed + 1_000_000 * phase_index + 10_000 * iteration


def fit_gauss_newton_matrix(scene: TeethScene, capture: Capture, layout: ParamLayout, gn_idx: np.ndarray,
                            y: np.ndarray, s: FitSettings, seed: int) -> np.ndarray:
    """The Gauss-Newton matrix over the variables ``gn_idx`` that ``optimiser="gauss-newton"`` steps."""
    return gauss_newton_matrix(scene, capture, layout, gn_idx, y, s.domain, passes=s.gn_passes, block=s.gn_block,
                               max_depth=s.max_depth, seed=seed, workers=s.workers, estimator=s.gn_estimator)


def _new_guard(s: FitSettings) -> DivergenceGuard | None:
    if s.optimiser != "gauss-newton" or s.gn_guard_window == 0:
        return None
    return DivergenceGuard(s.gn_guard_window, s.gn_guard_rise, s.gn_guard_factor, s.gn_damping, s.gn_damping)


def _resumed_guard(saved: dict | None, s: FitSettings) -> DivergenceGuard | None:
    """The checkpoint's divergence guard (its windows, best window and escalation) under the resuming
    settings: their window, rise and factor, and their gn_damping times the checkpoint's escalation
    (damping / min_damping); a new guard when the checkpoint had none, None when the settings turn it off."""
    fresh = _new_guard(s)
    if saved is None or fresh is None:
        return fresh
    guard = DivergenceGuard.from_dict(saved)
    escalation = guard.damping / guard.min_damping
    guard.window, guard.rise, guard.factor = fresh.window, fresh.rise, fresh.factor
    guard.min_damping, guard.damping = fresh.min_damping, fresh.min_damping * escalation
    return guard


def _load_state(path: str) -> FitState:
    with open(path) as f:
        d = json.load(f)
    if "precond" in d:
        raise ValueError(f"{path!r} is a Gauss-Newton checkpoint of an earlier version (it stores the inverse, "
                         "not the matrix); start the fit again")
    return FitState(**d)


def pass_a_image(scene: TeethScene, cameras: list, lights: list, sa: RenderSettings, pixels: list, light_ids,
                 compiled: CompiledScene, layout: ParamLayout, anchor_scene: TeethScene | None = None,
                 anchor_images: np.ndarray | None = None) -> tuple[np.ndarray, int]:
    """Pass A's image estimate (and its path vertices): plain, or with the anchor control variate
    ``anchor_images + [C(theta; w) - C(anchor; w)]`` (``anchor_images`` for these cameras and lights)."""
    if anchor_scene is None:
        ra = render(scene, cameras, lights, sa, pixels=pixels, light_ids=light_ids, compiled=compiled)
        return ra.images, ra.stats["path_vertices"]
    # the bracket's pair shares theta's dentin geometry: re-weighting a path to other dentin shapes
    # is only first-order exact (crossings are re-solved on the sampled triangles), so the anchor's
    # materials are paired with theta's coefficients c, and the image's response to c moves since
    # the anchor waits for the next anchor refresh
    base = anchor_scene.copy()
    for tb, t in zip(base.teeth, scene.teeth, strict=True):
        tb.c = np.array(t.c, dtype=np.float64)
    at_theta = render(scene, cameras, lights, sa, pixels=pixels, light_ids=light_ids,
                      compiled=CompiledScene(scene, base, layout=layout))
    at_anchor = render(base, cameras, lights, sa, pixels=pixels, light_ids=light_ids,
                       compiled=CompiledScene(base, layout=layout))
    return (anchor_images + at_theta.images - at_anchor.images,
            at_theta.stats["path_vertices"] + at_anchor.stats["path_vertices"])


def iteration_gradient(scene: TeethScene, capture: Capture, light_ids: np.ndarray, st: RenderSettings,
                       seed: int, layout: ParamLayout, anchor: Anchor | None = None,
                       loss_block: int = 1, image_spp: int = 0) -> tuple[float, np.ndarray, dict]:
    """One stochastic loss + gradient evaluation (pass A image, pass B gradient).

    Returns the loss estimate mean((C_A - C_ref)(C_B - C_ref)) over the masked pixels, the physical
    gradient and timing statistics. ``anchor``: image control variate for pass A (see :class:`Anchor`);
    ``loss_block``: tile size of the box-filtered L2 loss (see :func:`l2_loss`); ``image_spp``: pass A's
    samples per pixel (0 = ``st.spp``)."""
    if image_spp < 0:
        raise ValueError(f"image_spp must be >= 0 (0 = st.spp), got {image_spp}")
    pixels = [np.flatnonzero(m.ravel()) for m in capture.masks]
    cs = CompiledScene(scene, layout=layout)
    ref = capture.images[:, light_ids].astype(np.float64)
    sa = replace(st, spp=image_spp or st.spp, seed=2 * seed, jitter=True)
    t0 = time.perf_counter()
    img_a, vert_a = pass_a_image(scene, capture.cameras, capture.lights, sa, pixels, light_ids, cs, layout,
                                 None if anchor is None else anchor.scene,
                                 None if anchor is None else anchor.images[:, light_ids])
    render_seconds = time.perf_counter() - t0
    loss_a, adj = l2_loss(img_a, ref, capture.masks, loss_block)
    sb = replace(st, seed=2 * seed + 1, jitter=True)
    rb = render(scene, capture.cameras, capture.lights, sb, pixels=pixels, light_ids=light_ids, adjoint=adj,
                compiled=cs)
    # Monte Carlo noise adds Var(C) to (C_A - C_ref)^2; the product of the two independent passes
    # (C_A - C_ref)(C_B - C_ref) estimates the noise-free loss (E C - C_ref)^2 without that bias.
    loss = paired_loss(img_a, rb.images, ref, capture.masks, loss_block)
    stats = {"path_vertices": vert_a + rb.stats["path_vertices"],
             "render_seconds": render_seconds, "gradient_seconds": rb.stats["seconds"],
             "loss_single_pass": loss_a}
    return loss, rb.grad, stats


def fit(scene: TeethScene, capture: Capture, settings: FitSettings, out_dir: str | None = None,
        resume: bool = False, progress: Callable | None = None,
        callback: Callable | None = None, gradient: Callable | None = None,
        status: Callable[[str], None] | None = None) -> tuple[TeethScene, list]:
    """Fit ``scene``'s free parameters to ``capture``; returns (result, log): the best-loss scene, or with
    ``settings.average_tail`` the mean of the last iterates (Polyak-Ruppert averaging).

    With ``out_dir``: writes ``checkpoint.json`` every ``checkpoint_every`` iterations, ``loss.json``,
    ``scene_fit.json`` (the result so far: the best-loss scene until the averaged iterations begin, then
    their running mean) and ``scene_best.json`` (the best-loss scene); ``resume`` continues from the
    checkpoint. ``gradient`` replaces :func:`iteration_gradient` (same signature), e.g.
    ``scaleout.teeth.DaskGradient``. ``progress(entry)``
    and ``callback(entry, scene)`` are called after every iteration; ``status(text)`` says what the fit does
    between iterations that takes long (the Gauss-Newton matrix estimate; "" when it is done). With
    ``settings.anchor_spp`` the gradient function also gets ``anchor=`` (an :class:`Anchor`, re-rendered
    every ``anchor_every`` iterations and after a resume).
    """
    if capture.images is None or capture.masks is None:
        raise ValueError("the capture needs images and masks to fit")
    s = settings
    phases = [("homogeneous", s.iterations)]
    if s.textured_iterations > 0:
        phases.append(("textured", s.textured_iterations))
    if s.loss_block < 1:
        raise ValueError(f"settings.loss_block must be >= 1, got {s.loss_block}")
    # settings that reach the gradient function as keywords once above their "off" value: a
    # replacement gradient function must accept them
    for setting, off, keyword in (("anchor_spp", 0, "anchor"), ("loss_block", 1, "loss_block"),
                                  ("image_spp", 0, "image_spp")):
        if getattr(s, setting) > off and gradient is not None and keyword not in inspect.signature(gradient).parameters:
            raise ValueError(f"settings.{setting} > {off} needs a gradient function that takes {keyword}=; "
                             f"set {setting}={off} to use this one")
    st = RenderSettings(spp=s.spp, max_depth=s.max_depth, workers=s.workers)
    state: FitState | None = None
    ckpt = None if out_dir is None else os.path.join(out_dir, "checkpoint.json")
    if out_dir is not None:
        os.makedirs(out_dir, exist_ok=True)
    if resume:
        if ckpt is None or not os.path.exists(ckpt):
            raise FileNotFoundError(f"no checkpoint to resume from in {out_dir!r}")
        state = _load_state(ckpt)
    log = [] if state is None else state.log
    best_loss = np.inf if state is None else state.best_loss
    best_scene = scene if state is None else TeethScene.from_dict(state.best_scene)
    cur = scene if state is None else TeethScene.from_dict(state.scene)
    avg_sum = None if state is None or state.avg_sum is None else np.array(state.avg_sum)
    avg_count = 0 if state is None else state.avg_count
    n_l = min(s.lights_per_iteration, len(capture.lights))
    names = [p for p, _ in phases]
    start_phase = 0 if state is None else names.index(state.phase)
    for pi, (phase, n_it) in enumerate(phases):
        if pi < start_phase:
            continue
        start_it = 0
        anchor: Anchor | None = None
        if state is not None:
            start_it = state.iteration
            layout = ParamLayout(cur)
            if s.anchor_spp > 0 and state.anchor_scene is not None:
                # same scene, spp and seed as before the interruption: the same anchor image
                anchor = anchor_image(TeethScene.from_dict(state.anchor_scene), capture, s.anchor_spp, s.max_depth,
                                      _anchor_seed(s, pi, state.anchor_iteration), layout, state.anchor_iteration,
                                      s.workers)
            y = np.array(state.y)
            opt = Adam(s.lr, s.b1, s.b2, s.eps, None if state.adam_m is None else np.array(state.adam_m),
                       None if state.adam_v is None else np.array(state.adam_v), state.adam_n)
            gn_opt = PreconditionedMomentum(s.gn_lr, s.b1, None if state.gn_m is None else np.array(state.gn_m),
                                            state.gn_n, s.gn_max_step)
            hmat = None if state.gn_hmat is None else np.array(state.gn_hmat)
            precond_it = state.precond_iteration
            guard = _resumed_guard(state.gn_guard, s)
            state = None
        else:
            if phase == "textured":
                cur = texture_phase_scene(best_scene, s.texture_size)
                best_scene = texture_phase_scene(best_scene, s.texture_size)
            layout = ParamLayout(cur)
            y = to_optimiser(scene_to_vector(cur, layout), layout, s.domain)
            opt = Adam(s.lr, s.b1, s.b2, s.eps)
            gn_opt = PreconditionedMomentum(s.gn_lr, s.b1, max_step=s.gn_max_step)
            hmat, precond_it, guard = None, -1, _new_guard(s)
        free = free_mask(layout, s.free)
        # optimiser "gauss-newton": the variables it steps (the rest of the free ones keep Adam)
        gn = np.zeros_like(free)
        is_c = layout.kinds() == "c"
        if s.optimiser == "gauss-newton":
            gn = free & (~is_c if s.gn_adam_c else True)
        gn_idx = np.flatnonzero(gn)
        # the last phase's iterations from this one on enter the averaged result (average_tail)
        avg_from = tail_start(n_it, s.average_tail) if pi == len(phases) - 1 else n_it
        if not free.any():
            raise ValueError(f"no parameter matches the free patterns {s.free!r}")
        if s.domain == "absorption":
            si, ai = volume_pairs(layout)
            if np.any(free[si] != free[ai]):
                raise ValueError('domain "absorption" mixes sigma_t and albedo: free both or neither of a volume')
        for it in range(start_it, n_it):
            t0 = time.perf_counter()
            rng = np.random.default_rng([s.seed, pi, it])
            light_ids = np.sort(rng.choice(len(capture.lights), n_l, replace=False))
            x = from_optimiser(y, layout, s.domain)
            cur = vector_to_scene(cur, x, layout)
            seed = s.seed * 100003 + 10007 * pi + it
            kw = {"loss_block": s.loss_block} if s.loss_block > 1 else {}
            if s.image_spp > 0:
                kw["image_spp"] = s.image_spp
            if s.anchor_spp > 0:
                if anchor is None or it - anchor.iteration >= max(s.anchor_every, 1):
                    anchor = anchor_image(cur, capture, s.anchor_spp, s.max_depth, _anchor_seed(s, pi, it), layout, it,
                                          s.workers)
                kw["anchor"] = anchor
            gn_on = len(gn_idx) > 0 and it >= s.gn_start
            if gn_on and (hmat is None or it - precond_it >= s.gn_every):
                t_gn = time.perf_counter()
                if status is not None:
                    status(f"estimating the Gauss-Newton matrix ({s.gn_passes} passes of all lights)")
                hmat = fit_gauss_newton_matrix(cur, capture, layout, gn_idx, y, s, _gn_seed(s, pi, it))
                precond_it = it
                gn_seconds = time.perf_counter() - t_gn
                if status is not None:
                    status("")
            else:
                gn_seconds = 0.0
            loss, g_phys, stats = (gradient or iteration_gradient)(cur, capture, light_ids, st, seed, layout, **kw)
            if loss < best_loss:
                best_loss = loss
                best_scene = cur.copy()
            if it >= avg_from:
                avg_sum = y.copy() if avg_sum is None else avg_sum + y
                avg_count += 1
            g = chain_to_optimiser(g_phys, y, layout, s.domain)
            g[~free] = 0.0
            decay = 1.0 + s.lr_decay * it  # lr_n = lr / (1 + lr_decay * n), gn_lr likewise
            by_gn = gn if gn_on else np.zeros_like(gn)
            back = guard.observe(loss, y) if gn_on and guard is not None else None
            if back is not None:
                # a divergence: no step from this iterate's gradient; back to the best window's mean
                # iterate with more damping and a fresh gradient average (Adam's moments stay)
                y_new = back
                gn_opt.reset()
            else:
                lr = s.lr / decay * np.where(is_c & gn_on, s.gn_c_lr, 1.0)
                y_new = np.where(free & ~by_gn, opt.step(y, np.where(by_gn, 0.0, g), lr), y)
                if gn_on:
                    damping = s.gn_damping if guard is None else guard.damping
                    y_new[gn_idx] = gn_opt.step(y[gn_idx], g[gn_idx], damped_inverse(hmat, damping),
                                                s.gn_lr / decay)
            y = y_new
            entry = {"phase": phase, "iteration": it, "loss": loss, "best_loss": best_loss,
                     "seconds": time.perf_counter() - t0, "lights": light_ids.tolist(), **stats}
            if gn_seconds:
                entry["gauss_newton_seconds"] = gn_seconds
            if gn_on and guard is not None:
                entry["gauss_newton_damping"] = guard.damping
                if back is not None:
                    entry["gauss_newton_rollback"] = True
            log.append(entry)
            if progress is not None:
                progress(entry)
            if callback is not None:
                callback(entry, cur)
            last = it == n_it - 1
            if out_dir is not None and ((it + 1) % s.checkpoint_every == 0 or last):
                cur_scene = vector_to_scene(cur, from_optimiser(y, layout, s.domain), layout)
                _save_json(ckpt, asdict(FitState(phase, it + 1, cur_scene.to_dict(), y.tolist(),
                                                 opt.m.tolist(), opt.v.tolist(), opt.n, best_loss,
                                                 best_scene.to_dict(), log,
                                                 None if anchor is None else anchor.scene.to_dict(),
                                                 -1 if anchor is None else anchor.iteration,
                                                 None if hmat is None else hmat.tolist(), precond_it,
                                                 None if gn_opt.m is None else gn_opt.m.tolist(), gn_opt.n,
                                                 None if guard is None else guard.to_dict(),
                                                 None if avg_sum is None else avg_sum.tolist(), avg_count)))
                _save_json(os.path.join(out_dir, "loss.json"), {"log": log, "settings": asdict(s)})
                _save_json(os.path.join(out_dir, "scene_best.json"), best_scene.to_dict())
                result = best_scene if avg_sum is None else _averaged(cur, avg_sum, avg_count, layout, s.domain)
                _save_json(os.path.join(out_dir, "scene_fit.json"), result.to_dict())
        cur = vector_to_scene(cur, from_optimiser(y, layout, s.domain), layout)
    if avg_sum is not None:
        return _averaged(cur, avg_sum, avg_count, layout, s.domain), log
    return best_scene, log


def _averaged(scene: TeethScene, y_sum: np.ndarray, count: int, layout: ParamLayout, domain: str) -> TeethScene:
    """``scene`` with the mean ``y_sum / count`` of the averaged optimiser-domain iterates."""
    return vector_to_scene(scene, from_optimiser(y_sum / count, layout, domain), layout)


def plot_loss(log: list, path: str) -> None:
    """Loss per iteration (and best loss) as a PNG, like the thesis' Fig. 5.14-5.16."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(6, 3.5))
    it = np.arange(len(log))
    ax.semilogy(it, [e["loss"] for e in log], label="loss (L2)")
    ax.semilogy(it, [e["best_loss"] for e in log], label="best loss")
    ax.set_xlabel("iteration")
    ax.set_ylabel("loss")
    ax.legend()
    fig.tight_layout()
    fig.savefig(path, dpi=100)
    plt.close(fig)
