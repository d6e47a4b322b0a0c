"""Which start the fit goes on from: a short trial fit from each candidate, the best trial loss wins.

The literature search cannot tell the phase functions' mean cosine g (``literature_init``): a homogeneous
tooth of g 0.3, 0.6 or 0.9 matches the capture equally well, and the fit keeps the valley its start's g
puts it in. On the Mitsuba acceptance capture, 80 iterations from the search's best points of g 0.3 and
0.6 ended with sigma_t 34 % and 29 % off the truth, from g 0.9 (the search's choice) 144 %, and the fits
from g 0.9 stayed there, 42 % above the truth's loss (docs/teeth-fit.md, "The start's mean cosine decides
the valley").

Every trial runs ``FitSettings.start_trials`` iterations of the fit with the same seed, so iteration i of
every trial draws the same lights and the same path seeds; the trials' losses over their last half are
therefore paired, and their mean compares the starts (common random numbers; at 30 iterations the trial
losses of g 0.3 and 0.6 on the acceptance capture were 2-4x lower than g 0.9's). The fit goes on from
the winning trial's result.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import replace

import numpy as np

from .capture import Capture
from .fit_settings import FitSettings
from .optimise import fit
from .scene import TeethScene


def trial_score(log: list[dict]) -> float:
    """The mean loss of a trial's last half of iterations (at least one)."""
    losses = [e["loss"] for e in log]
    return float(np.mean(losses[len(losses) // 2:]))


def best_start(starts: list[TeethScene], capture: Capture, settings: FitSettings,
               progress: Callable[[dict], None] | None = None) -> tuple[TeethScene, list[float]]:
    """(the winning trial's result, every trial's score) of ``settings.start_trials``-iteration fits from
    ``starts`` (module docstring). One start, or ``start_trials`` 0: that start, unfitted, and no scores."""
    if not starts:
        raise ValueError("no start to try")
    if len(starts) == 1 or settings.start_trials == 0:
        return starts[0], []
    trial = replace(settings, iterations=settings.start_trials, textured_iterations=0)
    results, scores = [], []
    for start in starts:
        result, log = fit(start, capture, trial, progress=progress)
        results.append(result)
        scores.append(trial_score(log))
    return results[int(np.argmin(scores))], scores
