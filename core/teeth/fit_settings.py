"""The settings of a teeth fit: one dataclass, whose defaults are the settings that recovered best.

``FitSettings()`` is what ``teeth fit CAPTURE --out FIT``, the Blender panel's Fit button and
``bench teeth`` run; the command line and the panel take their defaults from it (tests check that).
The measurements behind each default are in docs/teeth-fit.md. In short, per iteration: 6 random
lights of the capture, pass A (the image that forms the adjoint, eq. 5.7-5.8) at 32 samples per pixel
and pass B (the gradient) at 4, the L2 loss of 8 x 8 box-filtered images; Adam (eq. 2.38-2.39) on the
dual domains xi = log sigma_t, kappa = log10(1 - albedo) (eq. 5.22-5.24) for 80 iterations, then
Gauss-Newton steps for the materials (the dentin coefficients join the fit only then, and keep Adam, on
a gradient by central differences with common random numbers: ``dentin_shape_gradient``); 300
iterations; the result is the mean of the last 30 % of the iterates (Polyak-Ruppert averaging). A few
lights never enter the fit and check it afterwards (``held_out_lights``): those farthest off the capture's
axis, so the check is a prediction outside the cone of lights the fit was trained in.

Plain data without numpy, so the command line's ``--help`` can show it without loading the renderer.
"""

from __future__ import annotations

from dataclasses import dataclass, fields

from ..errors import UserError

DEFAULT_FREE = ("*.sigma_t", "*.albedo", "*.g1", "*.g2", "*.beta", "*.a_t", "*.c")


@dataclass
class FitSettings:
    # ---- schedule
    # 0: the fit starts from the literature search's start at g literature_init.START_G; n > 0: the fit's first n
    # iterations are run from the start of every g, and it goes on from the best trial, whose iterations count
    # (start_trials.best_start; the trials choose the start that converges fastest, not the one that predicts
    # new lights best: literature_init)
    start_trials: int = 0
    iterations: int = 300  # "homogeneous" phase (thesis Sec. 5.7)
    textured_iterations: int = 0  # "textured" phase: a_t becomes a texture_size^2 texture
    texture_size: int = 8
    seed: int = 0
    free: tuple = DEFAULT_FREE  # fnmatch patterns of the parameter names to optimise
    # ---- sampling
    spp: int = 4  # pass B (gradient) samples per pixel
    image_spp: int = 32  # pass A (image) samples per pixel; 0 = spp
    lights_per_iteration: int = 6
    loss_block: int = 8  # L2 loss of block x block box-filtered images (1: per pixel, as in the thesis)
    # None: all bounces (Russian roulette), as in a photograph; an int caps the path length (experiments
    # only: a capped renderer is 13-26 % too dark on teeth, docs/teeth-tracer.md)
    max_depth: int | None = None
    # processes per pass for the numpy reference tracer where numba is missing (the compiled tracer
    # runs one thread per core by itself)
    workers: int = 1
    # ---- optimiser
    lr: float = 0.04  # Adam
    lr_decay: float = 0.01  # lr_n = lr / (1 + lr_decay n), gn_lr likewise
    optimiser: str = "gauss-newton"  # or "adam" (the thesis)
    gn_start: int = 80  # Adam iterations before Gauss-Newton steps the materials and the dentin coefficients join
    gn_every: int = 40  # iterations between Gauss-Newton matrix estimates
    gn_lr: float = 0.5  # fraction of the Gauss-Newton step
    gn_passes: int = 8  # 1-spp Jacobian passes pooled into the matrix
    gn_block: int = 8  # pixel tiles the Jacobian passes are pooled over
    gn_damping: float = 0.01
    gn_max_step: float = 0.05  # trust region in the optimiser domain
    gn_guard_window: int = 10  # divergence guard windows (0: off), gauss_newton.DivergenceGuard
    gn_guard_rise: float = 1.0  # a window whose mean loss is this much above the best window's rolls back
    # ---- result
    average_tail: float = 0.3  # the result is the mean of this fraction of the last iterates (0: best loss)
    held_out_lights: int = 3  # lights left out of the fit and rendered at the result to check it
    # a camera left out of the fit, rendered at the result under every light to check new views by (-1: none;
    # the thesis holds out the left one of its 3)
    held_out_camera: int = -1
    checkpoint_every: int = 5

    def __post_init__(self) -> None:
        if self.iterations < 1 or self.textured_iterations < 0 or self.texture_size < 1 or self.start_trials < 0:
            raise UserError("iterations must be >= 1, textured_iterations and start_trials >= 0, texture_size >= 1")
        if self.spp < 1 or self.image_spp < 0 or self.lights_per_iteration < 1 or self.loss_block < 1:
            raise UserError("spp, lights_per_iteration and loss_block must be >= 1, image_spp >= 0 (0 = spp)")
        if self.max_depth is not None and self.max_depth < 1:
            raise UserError(f"max_depth must be None (all bounces) or >= 1, got {self.max_depth}")
        if self.workers < 1:
            raise UserError(f"workers must be >= 1, got {self.workers}")
        if not self.lr > 0 or self.lr_decay < 0:
            raise UserError(f"lr must be > 0 and lr_decay >= 0, got {self.lr}, {self.lr_decay}")
        if not 0.0 <= self.average_tail < 1.0:
            raise UserError(f"average_tail must be in [0, 1), got {self.average_tail}")
        if self.held_out_lights < 0 or self.checkpoint_every < 1:
            raise UserError("held_out_lights must be >= 0 and checkpoint_every >= 1")
        if self.held_out_camera < -1:
            raise UserError(f"held_out_camera must be a camera's index or -1 (none), got {self.held_out_camera}")
        if self.optimiser not in ("adam", "gauss-newton"):
            raise UserError(f'optimiser must be "adam" or "gauss-newton", got {self.optimiser!r}')
        if self.optimiser == "gauss-newton":
            if not self.gn_lr > 0:
                raise UserError(f"gn_lr must be > 0, got {self.gn_lr}")
            if self.gn_passes < 1 or self.gn_block < 1 or self.gn_every < 1 or self.gn_start < 0:
                raise UserError("gn_passes, gn_block and gn_every must be >= 1, gn_start >= 0")
            if not self.gn_damping > 0:
                raise UserError(f"gn_damping must be > 0, got {self.gn_damping}")
            if not self.gn_max_step > 0:
                raise UserError(f"gn_max_step must be > 0, got {self.gn_max_step}")
            if self.gn_guard_window < 0 or not self.gn_guard_rise > 0:
                raise UserError("gn_guard_window must be >= 0 and gn_guard_rise > 0, got "
                                f"{self.gn_guard_window}, {self.gn_guard_rise}")


def setting_names() -> tuple[str, ...]:
    return tuple(f.name for f in fields(FitSettings))


def settings_from_dict(values: dict) -> FitSettings:
    """FitSettings from a saved ``asdict`` (a checkpoint, loss.json): unknown keys (settings of an
    earlier version) are refused with their names."""
    if not isinstance(values, dict):
        raise UserError(f"fit settings must be a JSON object, got {type(values).__name__}")
    unknown = sorted(set(values) - set(setting_names()))
    if unknown:
        raise UserError(f"unknown fit settings {unknown} (saved by an earlier version?)")
    v = dict(values)
    try:
        if "free" in v:
            if isinstance(v["free"], str) or not all(isinstance(p, str) for p in v["free"]):
                raise TypeError(f"free must be a list of name patterns, got {v['free']!r}")
            v["free"] = tuple(v["free"])
        return FitSettings(**v)
    except TypeError as exc:  # a value of the wrong kind (text for a number, ...)
        raise UserError(f"fit settings of the wrong kind ({exc})") from None
