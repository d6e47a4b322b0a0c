"""The fit's saved state: written every ``checkpoint_every`` iterations (to a temporary name, then
renamed, so an interrupted write never leaves half a file), read back by ``fit(..., resume=True)``; a
resumed fit continues to the same result as an uninterrupted one (its random numbers come from
(seed, phase, iteration), and the optimisers' moments, the Gauss-Newton matrix and the averaged
iterates are part of the state)."""

from __future__ import annotations

import json
import os
from dataclasses import dataclass, field, fields

from ..errors import UserError

# in a fit's output folder: the start trials (one folder per start, and the starts they run from) until one wins
TRIALS_DIR = "start_trials"


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
    # optimiser "gauss-newton": the Gauss-Newton matrix in use (over its variables), its momentum and guard
    gn_hmat: list | None = None
    precond_iteration: int = -1
    gn_m: list | None = None
    gn_n: int = 0
    gn_guard: dict | None = None
    # average_tail: the sum and count of the averaged iterates so far (optimiser domain)
    avg_sum: list | None = None
    avg_count: int = 0
    identity: dict | None = None  # what the fit was made for (optimise.fit_identity)
    settings: dict | None = None  # the FitSettings it runs with (asdict; fit_settings.settings_from_dict)


def load_state(path: str) -> FitState:
    """The checkpoint at ``path``; a checkpoint of an earlier version is refused (start the fit again)."""
    try:
        with open(path, encoding="utf-8") as f:
            d = json.load(f)
    except ValueError as e:  # not JSON (cut short), or not text
        raise UserError(f"{path!r} is not a fit checkpoint ({e})") from None
    names = {f.name for f in fields(FitState)}
    if not isinstance(d, dict) or set(d) - names or "precond" in d or d.get("identity") is None:
        raise UserError(f"{path!r} is a checkpoint of an earlier version of the fit; start the fit again")
    try:
        state = FitState(**d)
    except TypeError as e:
        raise UserError(f"{path!r} is not a complete fit checkpoint ({e})") from None
    kinds = {"phase": str, "iteration": int, "scene": dict, "y": list, "adam_n": int, "best_loss": (int, float),
             "best_scene": dict, "log": list, "identity": dict, "settings": (dict, type(None))}
    wrong = [k for k, kind in kinds.items() if not isinstance(getattr(state, k), kind)]
    if wrong or not all(isinstance(e, dict) for e in state.log):
        raise UserError(f"{path!r} is a damaged fit checkpoint (fields of the wrong kind: {wrong or ['log']}); "
                        "start the fit again")
    return state


def check_identity(path: str, saved: dict, now: dict) -> None:
    """Refuse to resume the checkpoint at ``path`` (made for ``saved``) under ``now``, naming what differs."""
    # keys a checkpoint of an earlier version lacks: not compared where it lacks them
    later = ("spp", "image_spp", "lr", "optimiser")
    differ = [k for k in sorted(set(saved) | set(now)) if saved.get(k) != now.get(k) and (k in saved or k not in later)]
    if differ:
        what = {"capture": "the capture", "teeth": "the teeth", "layout": "the parameter layout",
                "free": "the free parameters", "seed": "the seed", "held_out_lights": "the held-out lights",
                "spp": "the samples per pixel", "image_spp": "the image samples per pixel",
                "lr": "the learning rate", "optimiser": "the optimiser"}
        raise UserError(f"{path!r} was made for another fit ({', '.join(what.get(k, k) for k in differ)} "
                        "differ); resume with the fit's own capture and settings, or start a new fit")


def stopped_fit(out_dir: str) -> bool:
    """Whether ``out_dir`` holds a fit that stopped before its end (cancelled, killed, the machine went down),
    which ``teeth fit --resume`` continues: start trials under way, or a checkpoint newer than the report a
    finished fit writes last (``fit_report.json``). Reads no file, so a panel can ask on every redraw."""
    if os.path.isfile(os.path.join(out_dir, TRIALS_DIR, "starts.json")):
        return True
    try:
        saved = os.path.getmtime(os.path.join(out_dir, "checkpoint.json"))
    except OSError:
        return False
    try:
        return os.path.getmtime(os.path.join(out_dir, "fit_report.json")) < saved
    except OSError:
        return True
