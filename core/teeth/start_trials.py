"""Which start the fit goes on from: a short trial fit from each candidate, the best trial loss wins.

The literature search cannot tell the phase functions' mean cosine g (``literature_init``): a homogeneous
tooth of g 0.3, 0.6 or 0.9 matches the capture equally well, and the fit keeps the valley its start's g
puts it in. On the Mitsuba acceptance capture, 80 iterations from the search's best points of g 0.3 and
0.6 ended with sigma_t 34 % and 29 % off the truth, from g 0.9 (the search's choice) 144 %, and the fits
from g 0.9 stayed there, 42 % above the truth's loss (docs/teeth-fit.md, "The start's mean cosine decides
the valley").

Every trial is the first ``FitSettings.start_trials`` iterations of the fit itself, with the same seed, so
iteration i of every trial draws the same lights and the same path seeds; the trials' losses over their
last half are therefore paired, and their mean compares the starts (common random numbers; at 30
iterations the trial losses of g 0.3 and 0.6 on the acceptance capture were 2-4x lower than g 0.9's).
Each trial stops with a checkpoint; the fit resumes the winner's, so it is the fit from the winning start,
and its trial iterations count towards ``FitSettings.iterations``.
"""

from __future__ import annotations

import os
from collections.abc import Callable

import numpy as np

from .capture import Capture
from .fit_settings import FitSettings
from .optimise import fit
from .scene import TeethScene


def trial_score(log: list[dict]) -> float:
    """The mean loss of a trial's last half of iterations (at least one)."""
    losses = [e["loss"] for e in log]
    return float(np.mean(losses[len(losses) // 2:]))


def best_start(starts: list[TeethScene], capture: Capture, settings: FitSettings, work_dir: str,
               progress: Callable[[dict], None] | None = None) -> tuple[int | None, list[float]]:
    """(the winning start's index, every trial's score) of the fit's first ``settings.start_trials``
    iterations from each of ``starts`` (module docstring). Trial k leaves its checkpoint, loss.json and
    scene files in ``trial_dir(work_dir, k)``; ``fit(..., resume=True)`` on that folder goes on.
    One start, or ``start_trials`` 0: (None, []), nothing run."""
    if not starts:
        raise ValueError("no start to try")
    if len(starts) == 1 or settings.start_trials == 0:
        return None, []
    scores = []
    for k, start in enumerate(starts):
        _, log = fit(start, capture, settings, out_dir=trial_dir(work_dir, k), progress=progress,
                     until=settings.start_trials)
        scores.append(trial_score(log))
    return int(np.argmin(scores)), scores


def trial_dir(work_dir: str, k: int) -> str:
    """The folder of start ``k``'s trial."""
    return os.path.join(work_dir, f"start{k}")
