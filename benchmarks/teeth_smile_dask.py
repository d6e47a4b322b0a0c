"""``bench teeth-smile-dask``: how the whole-smile fit spreads over a Dask cluster.

The fit of ``bench teeth-smile`` (16 teeth, 345 parameters, 2 training cameras x 51 lights) takes about 2 hours on
this machine's 2 cores. On a cluster (``teeth fit --scheduler``) its renders are tasks (``scaleout/teeth.py``):
every iteration's bands of camera rows (start trials included), every Gauss-Newton matrix's groups of 9 lights, the
intervals' dentin-shape directions and chunks of lights. The literature search and the held-out checks stay on the
client.

This benchmark runs each kind of step on a local cluster of ``TEETH_SMILE_DASK_WORKERS`` single-threaded workers
(default: one per core), standing in for machines, at the kept fit's result, split as a cluster of
``TEETH_SMILE_DASK_SPLIT`` workers would split it (default 16: 8 bands per camera, 16 chunks of lights); it records
every task's compute time (Dask's task stream) and each call's wall time, and times the client's own steps here.
It then projects the fit's wall time on N workers: per step, the client's time around its tasks plus the makespan
of its tasks on N workers (longest first), times the number of such steps a default fit makes (300 iterations, a
Gauss-Newton matrix every 40 iterations from 80, the intervals once). Tasks split for 16 workers are conservative
for fewer (a coarser split renders less twice).

Environment: TEETH_SMILE_KEEP (the folder of ``bench teeth-smile``: its capture, and its fit's result if there is
one; otherwise the capture's own scene is the state timed), TEETH_SMILE_DASK_WORKERS, TEETH_SMILE_DASK_SPLIT,
TEETH_SMILE_DASK_ITERATIONS (gradient calls timed, default 4). About 20 minutes on 2 cores.
"""

from __future__ import annotations

import os
import sys
import tempfile
import time

import numpy as np

PROJECT_WORKERS = (1, 2, 4, 8, 16, 32)


def _log(msg: str) -> None:
    print(f"[teeth-smile-dask] {msg}", file=sys.stderr, flush=True)


def makespan(durations: list[float], workers: int) -> float:
    """Longest-processing-time-first list scheduling of ``durations`` on ``workers``: the finish time."""
    load = [0.0] * workers
    for d in sorted(durations, reverse=True):
        i = int(np.argmin(load))
        load[i] += d
    return max(load) if durations else 0.0


class _Split:
    """A task map that splits as a cluster of ``parallel`` workers would, run by another map."""

    def __init__(self, task_map, parallel: int):
        self.task_map, self.parallel = task_map, parallel

    def __call__(self, fn, shared, items):
        return self.task_map(fn, shared, items)


def _timed(client, call) -> dict:
    """Run ``call()``; its wall time and every task's compute time (s)."""
    from distributed import get_task_stream

    t0 = time.perf_counter()
    with get_task_stream(client) as stream:
        call()
    wall = time.perf_counter() - t0
    tasks = []
    for rec in stream.data:
        tasks.append(sum(s["stop"] - s["start"] for s in rec["startstops"] if s["action"] == "compute"))
    return {"wall": wall, "tasks": tasks}


def _step(records: list[dict], workers_here: int) -> dict:
    """A step's figures from its timed calls: the median call's tasks, and the client's time around them (the
    call's wall time less its tasks' makespan on the workers it ran on)."""
    walls = [r["wall"] for r in records]
    k = int(np.argsort(walls)[len(walls) // 2])
    tasks = records[k]["tasks"]
    return {"wall_here": walls[k], "tasks": sorted(tasks, reverse=True),
            "client": max(0.0, walls[k] - makespan(tasks, workers_here))}


def teeth_smile_dask() -> dict:
    from ..core.errors import UserError
    from ..core.teeth.capture import Capture, split_camera
    from ..core.teeth.capture_outliers import clamp_bright_outliers
    from ..core.teeth.fit_intervals import parameter_intervals
    from ..core.teeth.fit_report import held_out_check
    from ..core.teeth.fit_settings import FitSettings
    from ..core.teeth.literature_init import literature_starts
    from ..core.teeth.optimise import fit_gauss_newton_matrix, gauss_newton_columns, held_out_light_ids
    from ..core.teeth.param_vector import ParamLayout, scene_to_vector, to_optimiser
    from ..core.teeth.path_tracer import RenderSettings
    from ..core.teeth.scene import load_scene
    from ..core.teeth.synthetic import scene_target
    from ..scaleout.cluster import dask_client
    from ..scaleout.teeth import DaskGradient
    from .teeth_smile import HELD_OUT_CAMERA

    keep = os.environ.get("TEETH_SMILE_KEEP")
    if not keep or not os.path.isfile(os.path.join(keep, "capture", "capture.json")):
        raise UserError("bench teeth-smile-dask: set TEETH_SMILE_KEEP to the folder of a bench teeth-smile run "
                        "(it reads FOLDER/capture and, if there, FOLDER/fit/scene_fit.json)")
    workers = int(os.environ.get("TEETH_SMILE_DASK_WORKERS", os.cpu_count() or 1))
    split = int(os.environ.get("TEETH_SMILE_DASK_SPLIT", 16))
    n_calls = int(os.environ.get("TEETH_SMILE_DASK_ITERATIONS", 4))
    fs = FitSettings()
    fit_path = os.path.join(keep, "fit", "scene_fit.json")
    state = fit_path if os.path.isfile(fit_path) else os.path.join(keep, "capture", "scene.json")
    scene = load_scene(state)
    full, _ = clamp_bright_outliers(Capture.load(os.path.join(keep, "capture")))
    cap, cam_cap = split_camera(full, HELD_OUT_CAMERA)
    target = scene_target(scene)
    held_out = held_out_light_ids(cap, target, fs.held_out_lights)
    trained = np.setdiff1d(np.arange(len(cap.lights)), held_out)
    layout = ParamLayout(scene)
    x = scene_to_vector(scene, layout)
    gn_idx = gauss_newton_columns(layout, fs)
    st = RenderSettings(spp=fs.spp, max_depth=fs.max_depth)
    rng = np.random.default_rng(0)
    out: dict = {"state": os.path.relpath(state, keep), "workers_here": workers, "split_for": split,
                 "parameters": int(layout.size)}

    _log(f"client steps in this process ({state})")
    t0 = time.perf_counter()
    literature_starts(scene, cap)
    out["literature_search_s"] = time.perf_counter() - t0
    with tempfile.TemporaryDirectory() as work:
        t0 = time.perf_counter()
        held_out_check(scene, cap, held_out, os.path.join(work, "check.png"))
        held_out_check(scene, cam_cap, np.arange(len(cam_cap.lights)), os.path.join(work, "camera.png"))
    out["checks_s"] = time.perf_counter() - t0

    with dask_client(n_workers=workers) as client:
        gradient = DaskGradient(client, cap, bands_per_camera=max(1, split // len(cap.cameras)))
        task_map = _Split(gradient.task_map, split)
        _log(f"{n_calls} iteration gradients on {workers} workers")
        calls = []
        for _ in range(n_calls + 1):
            ids = np.sort(rng.choice(trained, fs.lights_per_iteration, replace=False))
            calls.append(_timed(client, lambda ids=ids: gradient(scene, cap, ids, st, int(rng.integers(1 << 30)),
                                                                 layout, fs.loss_block, fs.image_spp)))
        iteration = _step(calls[1:], workers)  # the first warms the workers (numba, the scattered capture)
        _log("a Gauss-Newton matrix")
        y = to_optimiser(x, layout)
        gn = _step([_timed(client, lambda: fit_gauss_newton_matrix(scene, cap, layout, gn_idx, y, fs, 1, task_map))],
                   workers)
        _log("the intervals")
        iv = _step([_timed(client, lambda: parameter_intervals(scene, cap, light_ids=trained, task_map=task_map))],
                   workers)

    # with start trials (an option), the losing starts' trials would add up to 2 x start_trials iterations
    n_iterations = fs.iterations + 2 * fs.start_trials
    n_gn = len(range(fs.gn_start, fs.iterations, fs.gn_every))
    steps = {"iteration": (iteration, n_iterations), "gauss_newton": (gn, n_gn), "intervals": (iv, 1)}
    serial = out["literature_search_s"] + out["checks_s"]
    projected = {}
    for n in PROJECT_WORKERS:
        projected[str(n)] = (serial + sum(count * (s["client"] + makespan(s["tasks"], n))
                                          for s, count in steps.values())) / 60.0
    out.update({
        "steps": {k: {"count": c, "tasks": len(s["tasks"]), "task_seconds": s["tasks"], "client_s": s["client"],
                      "wall_here_s": s["wall_here"]} for k, (s, c) in steps.items()},
        "projected_fit_minutes": projected,
        "workers_below_30_min": next((n for n in PROJECT_WORKERS if projected[str(n)] <= 30.0), None),
    })
    return out


BENCHMARKS = {"teeth-smile-dask": teeth_smile_dask}
