"""The core fit (``python -m material_structures teeth fit ...``) as a background process
(``..background_job``: progress as JSON lines, cancel). When it finishes the CLI has written
``scene_fit.json``, ``loss.json``, ``loss.png`` and its held-out check into OUT.

The one fit of this Blender session is ``current_job()``. Whether a fit runs, and its progress, are read
from it (``Scene.ms_teeth_fit.running`` / ``progress`` / ``status`` have getters, nothing of a job is stored
in the .blend): a file saved while a fit ran reopens with no fit running.
"""

from __future__ import annotations

import os

from ...core.teeth.fit_settings import FitSettings
from .. import background_job
from ..background_job import PROGRESS_ENV, BackgroundJob, package_parent, progress_event, usable_cores

__all__ = ["FIT_DEFAULTS", "PROGRESS_ENV", "FitJob", "current_job", "fit_command", "job_running", "package_parent",
           "progress_event", "python_executable", "set_current_job", "usable_cores"]

FIT_DEFAULTS = FitSettings()
KIND = "teeth"
# the fit needs numpy, and numba (the compiled tracer) or scipy (the numpy reference tracer's neighbour search);
# progress bars, plots and images need nothing else
NEEDS_COMPILED, NEEDS_REFERENCE = ("numpy", "numba"), ("numpy", "scipy")


def python_executable() -> str:
    """The interpreter for the fit (``background_job.python_executable``): this process's when it has what the
    compiled or the reference tracer needs."""
    if background_job.can_run_here(*NEEDS_REFERENCE):
        return background_job.python_executable(NEEDS_REFERENCE)
    return background_job.python_executable(NEEDS_COMPILED)


def fit_command(capture_dir: str, out_dir: str, iterations: int = FIT_DEFAULTS.iterations, init: str = "literature",
                extra: list[str] | None = None, workers: int = 1) -> list[str]:
    """The CLI call (the fit's own settings; the panel sets only the iterations and the start). The fit renders
    in the one background process (with ``workers`` > 1 in that many processes it forks per render where numba
    is missing), so that cancelling stops all of it; pass ``extra=["--scheduler", ADDRESS]`` to use a Dask
    cluster instead."""
    extra = list(extra or [])
    if "--scheduler" not in extra and workers > 1:
        extra[:0] = ["--workers", str(int(workers))]
    return [python_executable(), "-m", "material_structures", "teeth", "fit", capture_dir, "--out", out_dir,
            "--iterations", str(int(iterations)), "--init", init, *extra]


def current_job() -> FitJob | None:
    """The background fit started last in this Blender session (running or ended), or None."""
    return background_job.current_job(KIND)


def set_current_job(job: FitJob | None) -> None:
    background_job.set_current_job(KIND, job)


def job_running() -> bool:
    """Whether this session's fit process is alive (never blocks)."""
    return background_job.job_running(KIND)


class FitJob(BackgroundJob):
    """One background teeth fit. ``poll()`` -> state; ``cancel()``; ``result_path`` once finished."""

    label = "Teeth fit"
    log_name = "fit_log.txt"

    def __init__(self, capture_dir: str, out_dir: str, iterations: int = FIT_DEFAULTS.iterations,
                 init: str = "literature", extra: list[str] | None = None, workers: int = 1):
        if not os.path.isfile(os.path.join(capture_dir, "capture.json")):
            raise FileNotFoundError(f"no capture.json in {capture_dir!r}")
        super().__init__(fit_command(capture_dir, out_dir, iterations, init, extra, workers), out_dir, iterations)
        self.capture_dir = capture_dir

    def ended_text(self) -> str:
        if not (self.settled and self.outcome) and self.state() == "FINISHED":
            return f"finished, not applied: Apply Fit Result on {self.result_path}"
        return super().ended_text()

    @property
    def result_path(self) -> str:
        return os.path.join(self.out_dir, "scene_fit.json")

    @property
    def loss_plot(self) -> str:
        return os.path.join(self.out_dir, "loss.png")

    @property
    def check_image(self) -> str:
        """capture | fit | difference for the held-out lights (written when the fit ends)."""
        return os.path.join(self.out_dir, "check.png")
