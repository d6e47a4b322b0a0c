"""Inverse rendering: the fit loop (thesis Sec. 5.6-5.7): "homogeneous" then "textured" phases, Adam
(eq. 2.38-2.39) and Gauss-Newton steps on the dual domains xi = log sigma_t (eq. 5.24), kappa =
log10(1 - albedo) (eq. 5.22), best-loss tracking and Polyak-Ruppert averaging, checkpoints and resume.

Each iteration draws a random subset of the lights (stochastic gradient), never one of the held-out
lights (``held_out_light_ids``), and asks the gradient estimator (``fit_gradient.iteration_gradient``,
or ``scaleout.teeth.DaskGradient``) for the loss and the physical gradient, which is mapped to the dual
domains and stepped. The settings and why their defaults are what they are: ``fit_settings``.
"""

from __future__ import annotations

import fnmatch
import hashlib
import inspect
import os
import time
from collections.abc import Callable
from dataclasses import asdict

import numpy as np

from ..errors import MissingFileError, UserError
from ..folder_lock import FolderLock
from ..json_io import save_json
from .adam import Adam
from .capture import Capture
from .fit_checkpoint import FitState, check_identity, load_state
from .fit_gradient import iteration_gradient
from .fit_loss import block_sums, l2_loss, paired_loss
from .fit_report import plot_loss
from .fit_settings import DEFAULT_FREE, FitSettings
from .gauss_newton import DivergenceGuard, PreconditionedMomentum, damped_inverse, gauss_newton_matrix
from .param_vector import (
    ParamLayout,
    chain_to_optimiser,
    from_optimiser,
    optimiser_bounds,
    scene_to_vector,
    to_optimiser,
    vector_to_scene,
)
from .path_tracer import RenderSettings
from .scene import TeethScene
from .synthetic import scene_target
from .task_map import TaskMap

__all__ = ["Adam", "DEFAULT_FREE", "FitSettings", "FitState", "block_sums", "fit", "free_mask", "held_out_light_ids",
           "light_angles_deg", "iteration_gradient", "l2_loss", "paired_loss", "plot_loss", "tail_start",
           "texture_phase_scene"]

GN_ESTIMATOR = "pooled"  # (mean J_i)^T (mean J_i): the per-pass mean lost (docs/teeth-fit.md)
GN_GUARD_FACTOR = 4.0  # the divergence guard's damping factor


def light_angles_deg(capture: Capture, target: np.ndarray) -> np.ndarray:
    """Each light's angle in degrees off the capture's axis, seen from ``target`` (the teeth's centre): the
    axis is the mean of the unit directions from ``target`` to the cameras (the mouth axis of a capture rig)."""
    target = np.asarray(target, dtype=np.float64)

    def unit(v: np.ndarray) -> np.ndarray:
        return v / max(float(np.linalg.norm(v)), 1e-300)

    axis = unit(np.sum([unit(c.center - target) for c in capture.cameras], axis=0))
    dirs = np.array([unit(li.position - target) for li in capture.lights]).reshape(-1, 3)
    return np.degrees(np.arccos(np.clip(dirs @ axis, -1.0, 1.0)))


def held_out_light_ids(capture: Capture, target: np.ndarray, n_held_out: int) -> np.ndarray:
    """The lights a fit never uses, to check it afterwards: the ``n_held_out`` farthest off the capture's axis
    (``light_angles_deg``; ties by index), so that the check predicts lights outside the cone the fit was
    trained in. At most a quarter of the lights; none from captures of fewer than 4."""
    n = min(int(n_held_out), len(capture.lights) // 4)
    if n <= 0:
        return np.zeros(0, dtype=np.int64)
    angles = light_angles_deg(capture, target)
    order = np.lexsort((np.arange(len(angles)), -np.round(angles, 9)))
    return np.sort(order[:n]).astype(np.int64)


def fit_identity(scene: TeethScene, capture: Capture, layout: ParamLayout, free: np.ndarray, s: FitSettings) -> dict:
    """What a checkpoint was made for: the capture (sizes and a digest of its images and masks), the
    parameter layout and which of it is free, the held-out lights, the seed, the samples per pixel of both
    passes, the learning rate and the optimiser. A resume under anything
    else is refused (its state would mean something else)."""
    h = hashlib.sha1()
    h.update(np.ascontiguousarray(capture.images, dtype=np.float32).tobytes())
    h.update(np.ascontiguousarray(capture.masks).tobytes())
    for c in capture.cameras:
        h.update(np.concatenate([c.K.ravel(), c.R.ravel(), c.t]).tobytes())
    for li in capture.lights:
        h.update(np.concatenate([li.position, li.intensity]).tobytes())
    return {"capture": {"cameras": len(capture.cameras), "lights": len(capture.lights),
                        "size": [int(capture.images.shape[2]), int(capture.images.shape[3])], "digest": h.hexdigest()},
            "teeth": [t.name for t in scene.teeth],
            "layout": [[e.name, int(e.size)] for e in layout.entries],
            "free": np.flatnonzero(free).tolist(), "seed": s.seed,
            "held_out_lights": held_out_light_ids(capture, scene_target(scene), s.held_out_lights).tolist(),
            "spp": s.spp, "image_spp": s.image_spp, "lr": s.lr, "optimiser": s.optimiser}


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


def tail_start(n_iterations: int, average_tail: float) -> int:
    """First iteration of the last phase whose iterate enters the averaged result (``average_tail``)."""
    if average_tail <= 0:
        return n_iterations
    return n_iterations - max(1, int(round(n_iterations * average_tail)))


def _gn_seed(s: FitSettings, phase_index: int, iteration: int) -> int:
    """Seed of the Gauss-Newton Jacobian passes estimated at ``iteration`` (their renders use this + up
    to 1000 * passes + lights / 9; far above the pass A / B seeds)."""
    return 3_000_000_000 + 10_000_000 * s.seed + 1_000_000 * phase_index + 10_000 * iteration


def gauss_newton_columns(layout: ParamLayout, s: FitSettings) -> np.ndarray:
    """The variables ``optimiser="gauss-newton"`` steps (the rest of the free ones keep Adam): the free ones but
    the dentin coefficients, which keep Adam on their difference gradient (dentin_shape_gradient): their
    path-space Jacobian columns, which the matrix would need, are noise. None with ``optimiser="adam"``."""
    if s.optimiser != "gauss-newton":
        return np.zeros(0, dtype=np.int64)
    return np.flatnonzero(free_mask(layout, s.free) & (layout.kinds() != "c"))


def fit_gauss_newton_matrix(scene: TeethScene, capture: Capture, layout: ParamLayout, gn_idx: np.ndarray,
                            y: np.ndarray, s: FitSettings, seed: int, task_map: TaskMap | None = None) -> np.ndarray:
    """The Gauss-Newton matrix over the variables ``gn_idx`` that ``optimiser="gauss-newton"`` steps."""
    return gauss_newton_matrix(scene, capture, layout, gn_idx, y, passes=s.gn_passes, block=s.gn_block,
                               max_depth=s.max_depth, seed=seed, workers=s.workers, estimator=GN_ESTIMATOR,
                               task_map=task_map)


def _new_guard(s: FitSettings) -> DivergenceGuard | None:
    if s.optimiser != "gauss-newton" or s.gn_guard_window == 0:
        return None
    return DivergenceGuard(s.gn_guard_window, s.gn_guard_rise, GN_GUARD_FACTOR, s.gn_damping, s.gn_damping)


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


def fit(scene: TeethScene, capture: Capture, settings: FitSettings, out_dir: str | None = None,
        resume: bool = False, progress: Callable | None = None,
        callback: Callable | None = None, gradient: Callable | None = None,
        status: Callable[[str], None] | None = None, until: int | None = None,
        task_map: TaskMap | None = None) -> tuple[TeethScene, list]:
    """Fit ``scene``'s free parameters to ``capture``; returns (result, log): the best-loss scene, or with
    ``settings.average_tail`` the mean of the last iterates (Polyak-Ruppert averaging).

    ``until``: stop after that many iterations of the first phase, with a checkpoint in ``out_dir``, from
    which ``resume`` continues exactly as the uninterrupted fit would (a start trial, ``start_trials``).

    With ``out_dir``: writes ``checkpoint.json`` every ``checkpoint_every`` iterations, ``loss.json`` (the
    log, the settings and the held-out lights), ``scene_fit.json`` (the result so far: the best-loss scene
    until the averaged iterations begin, then their running mean) and ``scene_best.json`` (the best-loss
    scene); ``resume`` continues from the checkpoint. ``gradient`` replaces
    :func:`fit_gradient.iteration_gradient` (same signature), e.g. ``scaleout.teeth.DaskGradient``;
    ``task_map`` computes the Gauss-Newton matrices' light groups (``core.teeth.task_map``; default: this process).
    ``progress(entry)`` and ``callback(entry, scene)`` are called after every iteration; ``status(text)``
    says what the fit does between iterations that takes long (the Gauss-Newton matrix estimate; "" when
    it is done).
    """
    if capture.images is None or capture.masks is None:
        raise UserError("the capture needs images and masks to fit")
    if not capture.masks.any():
        raise UserError("the capture's masks select no pixel: nothing to fit")
    if out_dir is not None:
        os.makedirs(out_dir, exist_ok=True)
        with FolderLock(out_dir):
            return _fit(scene, capture, settings, out_dir, resume, progress, callback, gradient, status, until,
                        task_map)
    return _fit(scene, capture, settings, out_dir, resume, progress, callback, gradient, status, until, task_map)


def _fit(scene, capture, settings, out_dir, resume, progress, callback, gradient, status, until, task_map):
    s = settings
    if until is not None and until < 1:
        raise ValueError("until must be at least 1 iteration")
    phases = [("homogeneous", s.iterations)]
    if s.textured_iterations > 0:
        phases.append(("textured", s.textured_iterations))
    # settings that reach the gradient function as keywords once above their "off" value: a
    # replacement gradient function must accept them
    for setting, off in (("loss_block", 1), ("image_spp", 0)):
        if getattr(s, setting) > off and gradient is not None and setting not in inspect.signature(gradient).parameters:
            raise ValueError(f"settings.{setting} > {off} needs a gradient function that takes {setting}=; "
                             f"set {setting}={off} to use this one")
    held_out = held_out_light_ids(capture, scene_target(scene), s.held_out_lights)
    training = np.setdiff1d(np.arange(len(capture.lights)), held_out)
    layout0 = ParamLayout(scene)
    identity = fit_identity(scene, capture, layout0, free_mask(layout0, s.free), s)
    st = RenderSettings(spp=s.spp, max_depth=s.max_depth, workers=s.workers)
    state: FitState | None = None
    ckpt = None if out_dir is None else os.path.join(out_dir, "checkpoint.json")
    if out_dir is not None:
        os.makedirs(out_dir, exist_ok=True)
    if resume:
        if ckpt is None or not os.path.exists(ckpt):
            if ckpt is None:
                raise ValueError("resume=True needs the out_dir of the fit to resume")
            raise MissingFileError(f"no checkpoint to resume from in {out_dir!r}", ckpt)
        state = load_state(ckpt)
        check_identity(ckpt, state.identity, identity)
    log = [] if state is None else state.log
    best_loss = np.inf if state is None else state.best_loss
    best_scene = scene if state is None else TeethScene.from_dict(state.best_scene)
    cur = scene if state is None else TeethScene.from_dict(state.scene)
    avg_sum = None if state is None or state.avg_sum is None else np.array(state.avg_sum)
    avg_count = 0 if state is None else state.avg_count
    n_l = min(s.lights_per_iteration, len(training))
    names = [p for p, _ in phases]
    if state is not None and state.phase not in names:
        raise UserError(f"{ckpt!r} stopped in the {state.phase!r} phase, which these settings do not run "
                        f"(textured_iterations={s.textured_iterations}); resume with the settings the fit started with")
    start_phase = 0 if state is None else names.index(state.phase)
    for pi, (phase, n_it) in enumerate(phases):
        if pi < start_phase:
            continue
        start_it = 0
        if state is not None:
            start_it = state.iteration
            layout = ParamLayout(cur)
            y = np.array(state.y)
            opt = Adam(s.lr, m=None if state.adam_m is None else np.array(state.adam_m),
                       v=None if state.adam_v is None else np.array(state.adam_v), n=state.adam_n)
            gn_opt = PreconditionedMomentum(s.gn_lr, m=None if state.gn_m is None else np.array(state.gn_m),
                                            n=state.gn_n, max_step=s.gn_max_step)
            hmat = None if state.gn_hmat is None else np.array(state.gn_hmat)
            precond_it = state.precond_iteration
            guard = _resumed_guard(state.gn_guard, s)
            state = None
        else:
            if phase == "textured":
                cur = texture_phase_scene(best_scene, s.texture_size)
                best_scene = texture_phase_scene(best_scene, s.texture_size)
            layout = ParamLayout(cur)
            y = to_optimiser(scene_to_vector(cur, layout), layout)
            opt = Adam(s.lr)
            gn_opt = PreconditionedMomentum(s.gn_lr, max_step=s.gn_max_step)
            hmat, precond_it, guard = None, -1, _new_guard(s)
        free = free_mask(layout, s.free)
        # every step is projected onto the valid ranges: a variable left beyond its bound would hold the
        # parameter there (clamped) until steps against the gradient's new sign had walked it back
        y_lo, y_hi = optimiser_bounds(layout)
        y = np.clip(y, y_lo, y_hi)
        is_c = layout.kinds() == "c"
        gn_idx = gauss_newton_columns(layout, s)
        gn = np.zeros_like(free)
        gn[gn_idx] = True
        # with Gauss-Newton the dentin coefficients wait for it (gn_start) in the first phase: before, the
        # materials are far off, the coefficients' gradient follows their error, and the coefficients run into
        # the valley they share with the dentin's materials, where they stay (docs/teeth-fit.md, "The
        # coefficients wait for Gauss-Newton")
        c_from = s.gn_start if s.optimiser == "gauss-newton" and pi == 0 and len(gn_idx) else 0
        # the last phase's iterations from this one on enter the averaged result (average_tail)
        avg_from = tail_start(n_it, s.average_tail) if pi == len(phases) - 1 else n_it
        if not free.any():
            raise UserError(f"no parameter matches the free patterns {s.free!r}")
        stop = n_it if until is None or pi > 0 else min(n_it, until)
        for it in range(start_it, stop):
            t0 = time.perf_counter()
            rng = np.random.default_rng([s.seed, pi, it])
            light_ids = np.sort(rng.choice(training, n_l, replace=False))
            x = from_optimiser(y, layout)
            cur = vector_to_scene(cur, x, layout)
            seed = s.seed * 100003 + 10007 * pi + it
            kw = {"loss_block": s.loss_block} if s.loss_block > 1 else {}
            if s.image_spp > 0:
                kw["image_spp"] = s.image_spp
            free_now = free & ~is_c if it < c_from else free
            if not free_now[is_c].any() and (gradient is None or "shape" in inspect.signature(gradient).parameters):
                kw["shape"] = False  # no dentin coefficient is fitted: skip their two renders
            gn_on = len(gn_idx) > 0 and it >= s.gn_start
            if gn_on and (hmat is None or it - precond_it >= s.gn_every):
                t_gn = time.perf_counter()
                if status is not None:
                    status(f"estimating the Gauss-Newton matrix ({s.gn_passes} passes of all lights)")
                hmat = fit_gauss_newton_matrix(cur, capture, layout, gn_idx, y, s, _gn_seed(s, pi, it), task_map)
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
            g = chain_to_optimiser(g_phys, y, layout)
            g[~free_now] = 0.0
            decay = 1.0 + s.lr_decay * it  # lr_n = lr / (1 + lr_decay * n), gn_lr likewise
            by_gn = gn if gn_on else np.zeros_like(gn)
            back = guard.observe(loss, y) if gn_on and guard is not None else None
            if back is not None:
                # a divergence: no step from this iterate's gradient; back to the best window's mean
                # iterate with more damping and a fresh gradient average (Adam's moments stay)
                y_new = back
                gn_opt.reset()
            else:
                y_new = np.where(free_now & ~by_gn, opt.step(y, np.where(by_gn, 0.0, g), s.lr / decay), y)
                if gn_on:
                    damping = s.gn_damping if guard is None else guard.damping
                    y_new[gn_idx] = gn_opt.step(y[gn_idx], g[gn_idx], damped_inverse(hmat, damping),
                                                s.gn_lr / decay)
            y = np.clip(y_new, y_lo, y_hi)
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
            last = it == stop - 1
            if out_dir is not None and ((it + 1) % s.checkpoint_every == 0 or last):
                cur_scene = vector_to_scene(cur, from_optimiser(y, layout), layout)
                save_json(ckpt, asdict(FitState(phase, it + 1, cur_scene.to_dict(), y.tolist(),
                                                 opt.m.tolist(), opt.v.tolist(), opt.n, best_loss,
                                                 best_scene.to_dict(), log,
                                                 None if hmat is None else hmat.tolist(), precond_it,
                                                 None if gn_opt.m is None else gn_opt.m.tolist(), gn_opt.n,
                                                 None if guard is None else guard.to_dict(),
                                                 None if avg_sum is None else avg_sum.tolist(), avg_count,
                                                 identity, asdict(s))))
                save_json(os.path.join(out_dir, "loss.json"), {"log": log, "settings": asdict(s),
                                                               "held_out_lights": held_out.tolist()})
                save_json(os.path.join(out_dir, "scene_best.json"), best_scene.to_dict())
                result = best_scene if avg_sum is None else _averaged(cur, avg_sum, avg_count, layout)
                save_json(os.path.join(out_dir, "scene_fit.json"), result.to_dict())
        cur = vector_to_scene(cur, from_optimiser(y, layout), layout)
        if stop < n_it:
            break  # ``until``: the rest continues from the checkpoint
    if avg_sum is not None:
        return _averaged(cur, avg_sum, avg_count, layout), log
    return best_scene, log


def _averaged(scene: TeethScene, y_sum: np.ndarray, count: int, layout: ParamLayout) -> TeethScene:
    """``scene`` with the mean ``y_sum / count`` of the averaged optimiser-domain iterates."""
    return vector_to_scene(scene, from_optimiser(y_sum / count, layout), layout)
