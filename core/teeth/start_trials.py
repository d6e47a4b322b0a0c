"""Which start the fit goes on from: a short trial fit from each candidate, the best trial loss wins.

An option (``FitSettings.start_trials`` > 0); the default fit starts at g 0.6 without trials: on the Mitsuba
captures of ``bench teeth-extrapolation`` the trials chose g 0.3 on two of three truths, the start that converges
fastest, and predicted new lights worse where the truth's g is high (``literature_init``).

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
A start whose trial loss over the first half (iterations 7-14 of 30) is at least ``DROP_RATIO`` times the
best start's stops there. On the acceptance capture (seed 0) g 0.3's and g 0.9's first halves scored 4.7x
and 5.2x g 0.6's, and their whole trials 2.1x and 3.3x: the choice was the same, and g 0.9's iterations
are the slowest (a median 6.6 s on 2 cores against 3.5-3.8 s: its paths are longer).
Each trial stops with a checkpoint; the fit resumes the winner's, so it is the fit from the winning start,
and its trial iterations count towards ``FitSettings.iterations``.
"""

from __future__ import annotations

import os
from collections.abc import Callable
from dataclasses import dataclass

import numpy as np

from .capture import Capture
from .fit_settings import FitSettings
from .optimise import fit
from .scene import TeethScene
from .task_map import TaskMap


def trial_score(log: list[dict]) -> float:
    """The mean loss of a trial's last half of iterations (at least one)."""
    losses = [e["loss"] for e in log]
    return float(np.mean(losses[len(losses) // 2:]))


DROP_RATIO = 2.0  # a start whose first-half trial loss is this many times the best's stops at the half


@dataclass
class StartTrials:
    """What the trials found: the winning start and, per start, the iterations its trial ran (the trial's
    length, or half of it for a start dropped there) and its score over the last half of those."""

    chosen: int
    scores: list[float]
    iterations: list[int]


def best_start(starts: list[TeethScene], capture: Capture, settings: FitSettings, work_dir: str,
               progress: Callable[[dict], None] | None = None,
               dropped: Callable[[int], None] | None = None, gradient: Callable | None = None,
               task_map: TaskMap | None = None) -> StartTrials | None:
    """The trials (module docstring) of the fit's first ``settings.start_trials`` iterations (at most
    ``settings.iterations``) from each of ``starts``: each start's first half, then the rest for those
    under ``DROP_RATIO`` times the best (positive) first-half score. Trial k leaves its checkpoint, loss.json and
    scene files in ``trial_dir(work_dir, k)``, from which ``fit(..., resume=True)`` goes on; a trial that
    finds a checkpoint there (an interrupted fit's trials) goes on from it, so that trials run again after an
    interruption end as the uninterrupted ones would.
    ``progress(entry)`` after every trial iteration; ``dropped(n)`` with the iterations a dropped start
    will not run. ``gradient`` and ``task_map``: where the trials render (``optimise.fit``'s). One start, or
    ``start_trials`` 0: None, nothing run."""
    if not starts:
        raise ValueError("no start to try")
    if len(starts) == 1 or settings.start_trials == 0:
        return None
    n = min(settings.start_trials, settings.iterations)
    half = n // 2 if n >= 2 else n

    def run(k: int, until: int) -> list[dict]:
        # a trial with a checkpoint (an interrupted fit's) goes on from it: the same iterations, to the bit
        folder = trial_dir(work_dir, k)
        resume = os.path.isfile(os.path.join(folder, "checkpoint.json"))
        return fit(starts[k], capture, settings, out_dir=folder, resume=resume, progress=progress, until=until,
                   gradient=gradient, task_map=task_map)[1]

    logs = [run(k, half) for k in range(len(starts))]
    # over the first half only: a resumed trial may have run past it before the interruption
    first = [trial_score(log[:half]) for log in logs]
    lead = int(np.argmin(first))
    # a ratio of scores means something only where they are positive (the paired loss estimate of a
    # tiny, noisy capture can be below 0)
    goes_on = [half < n and (k == lead or first[lead] <= 0 or first[k] < DROP_RATIO * first[lead])
               for k in range(len(starts))]
    # every drop is known before the second halves run: the progress total is right from here on
    for k in range(len(starts)):
        if half < n and not goes_on[k] and dropped is not None:
            dropped(n - half)
    for k in range(len(starts)):
        if goes_on[k]:
            logs[k] = run(k, n)
    runs = [len(log) for log in logs]
    scores = [trial_score(log) for log in logs]
    chosen = min((k for k in range(len(starts)) if runs[k] == n), key=lambda k: scores[k])
    return StartTrials(chosen, scores, runs)


def trial_dir(work_dir: str, k: int) -> str:
    """The folder of start ``k``'s trial."""
    return os.path.join(work_dir, f"start{k}")
