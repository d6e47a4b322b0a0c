"""The core fit (``python -m material_structures teeth fit ...``) as a background process
(``..background_job``: progress as JSON lines, cancel). When it finishes the CLI has written
``scene_fit.json``, ``loss.json``, ``loss.png`` and its held-out check into OUT.

The one fit of this Blender session is ``current_job()``. Whether a fit runs, and its progress, are read
from it (``Scene.ms_teeth_fit.running`` / ``progress`` / ``status`` have getters, nothing of a job is stored
in the .blend): a file saved while a fit ran reopens with no fit running.
"""

from __future__ import annotations

import os
import re

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
# the CLI's progress during its start trials: {"progress": "init", "message": "trying K starts: D of N iterations"}
_TRIALS = re.compile(r"trying \d+ starts: (\d+) of (\d+) iterations")


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

    trial_done = 0
    trial_total = 0  # iterations of the start trials (0: none reported yet)

    def on_event(self, event: dict) -> None:
        """Also counts the start trials' iterations, which run before the fit's own (their count is in the
        "init" events' message)."""
        super().on_event(event)
        m = _TRIALS.search(str(event.get("message", ""))) if event.get("progress") == "init" else None
        if m is not None:
            self.trial_done, self.trial_total = int(m.group(1)), max(int(m.group(2)), 1)

    @property
    def progress(self) -> float:
        """The start trials and the fit as one bar: (trial iterations + fit iterations done) / both totals."""
        if not self.trial_total:
            return super().progress
        if self.done_iterations:
            self.trial_done = self.trial_total  # the trials are over once the fit reports
        total = self.trial_total + max(self.iterations, 1)
        return min(1.0, (min(self.trial_done, self.trial_total) + self.done_iterations) / total)

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
