"""Teeth gradient rendering on a real 2-worker local Dask cluster: per-view tasks reduced on the
client equal the same decomposition computed locally, also when a worker is killed mid-iteration."""

from __future__ import annotations

import os
import signal
import threading
import time

import numpy as np
import pytest

pytest.importorskip("distributed")

from material_structures.core.teeth.capture import default_rig  # noqa: E402
from material_structures.core.teeth.optimise import l2_loss  # noqa: E402
from material_structures.core.teeth.param_vector import ParamLayout  # noqa: E402
from material_structures.core.teeth.path_tracer import RenderSettings  # noqa: E402
from material_structures.core.teeth.synthetic import make_scene, render_capture, scene_target  # noqa: E402
from material_structures.scaleout.cluster import dask_client  # noqa: E402
from material_structures.scaleout.teeth import DaskGradient, local_gradient, loss_normaliser  # noqa: E402


@pytest.fixture(scope="module")
def problem():
    scene = make_scene(n_teeth=1, resolution=12, with_gums=False, with_cavity=False)
    cams, lights = default_rig(target=scene_target(scene), width=20, height=14, n_lights=4, n_cameras=3)
    capture = render_capture(scene, cams, lights, spp=2, spp_background=0, seed=3)
    start = scene.copy()
    for t in start.teeth:
        t.enamel.sigma_t = np.asarray(t.enamel.sigma_t) * 1.3
    return start, capture


def _dead(pid: int, wait: float = 5.0) -> bool:
    import psutil

    deadline = time.monotonic() + wait
    while True:
        try:
            if psutil.Process(pid).status() == psutil.STATUS_ZOMBIE:
                return True
        except psutil.NoSuchProcess:
            return True
        if time.monotonic() > deadline:
            return False
        time.sleep(0.05)


@pytest.fixture(scope="module")
def client():
    with dask_client(n_workers=2) as c:
        yield c


def test_normaliser_matches_l2_loss(problem):
    _, capture = problem
    rng = np.random.default_rng(0)
    images = rng.normal(size=capture.images[:, :2].shape)
    loss, _ = l2_loss(images, np.zeros_like(images), capture.masks)
    w = capture.masks[:, None, :, :, None]
    assert loss == pytest.approx(float(np.sum((images * w) ** 2)) / loss_normaliser(capture, 2), rel=1e-12)


def test_dask_gradient_equals_local_and_survives_a_killed_worker(problem, client):
    scene, capture = problem
    layout = ParamLayout(scene)
    st = RenderSettings(spp=16, max_depth=4)
    ids = np.array([0, 2])
    ref_loss, ref_grad, _ = local_gradient(capture)(scene, capture, ids, st, 7, layout)
    assert ref_loss > 0 and np.any(ref_grad != 0)
    dask_grad = DaskGradient(client, capture)
    loss, grad, _ = dask_grad(scene, capture, ids, st, 7, layout)
    assert loss == ref_loss
    np.testing.assert_array_equal(grad, ref_grad)

    pids = client.run(os.getpid)
    killed = {}

    done = threading.Event()

    def kill_soon():
        # kill a worker as soon as it is computing one of the iteration's tasks
        deadline = time.monotonic() + 60
        while time.monotonic() < deadline and not done.is_set():
            busy = [w for w, keys in client.processing().items() if keys and w in pids]
            if busy:
                killed["during"] = not done.is_set()
                os.kill(pids[busy[0]], signal.SIGKILL)
                killed["pid"] = pids[busy[0]]
                return
            time.sleep(0.002)

    killer = threading.Thread(target=kill_soon)
    killer.start()
    loss2, grad2, _ = dask_grad(scene, capture, ids, st, 7, layout)
    done.set()
    killer.join()
    assert killed.get("during"), "the iteration finished before a worker could be killed"
    assert _dead(killed["pid"]), "the killed worker is still running"
    assert loss2 == ref_loss
    np.testing.assert_array_equal(grad2, ref_grad)


def test_fit_on_dask_is_deterministic_and_matches_local_decomposition(problem, client, tmp_path):
    from material_structures.core.teeth.optimise import FitSettings, fit

    scene, capture = problem
    # a Gauss-Newton matrix at iteration 1: its light groups are tasks too
    fs = FitSettings(iterations=3, spp=1, max_depth=4, lights_per_iteration=2, seed=1, gn_start=1, gn_every=1,
                     gn_passes=2)
    on_cluster = DaskGradient(client, capture, bands_per_camera=2)
    a, log_a = fit(scene, capture, fs, gradient=on_cluster, task_map=on_cluster.task_map)
    b, log_b = fit(scene, capture, fs, gradient=local_gradient(capture, 2))
    assert any("gauss_newton_seconds" in e for e in log_a)
    assert [e["loss"] for e in log_a] == [e["loss"] for e in log_b]
    assert a.to_dict() == b.to_dict()


def test_image_spp_reaches_the_dask_tasks(problem, client):
    """``FitSettings.image_spp`` (pass A's samples) on Dask equals the local decomposition exactly and
    changes the fit (the setting is not dropped on the way to the tasks)."""
    from material_structures.core.teeth.optimise import FitSettings, fit

    scene, capture = problem
    fs = FitSettings(iterations=2, spp=1, max_depth=4, lights_per_iteration=2, seed=1, image_spp=3)
    a, log_a = fit(scene, capture, fs, gradient=DaskGradient(client, capture))
    b, log_b = fit(scene, capture, fs, gradient=local_gradient(capture))
    assert [e["loss"] for e in log_a] == [e["loss"] for e in log_b]
    assert a.to_dict() == b.to_dict()
    _, log_1 = fit(scene, capture, FitSettings(iterations=2, spp=1, max_depth=4, lights_per_iteration=2, seed=1),
                   gradient=local_gradient(capture))
    assert log_a[0]["loss"] != log_1[0]["loss"]


def test_row_bands_cover_each_camera_once_and_equal_their_local_decomposition(problem, client):
    """Bands of rows (whole loss blocks) split every camera's masked pixels without overlap, and a gradient of 3
    bands per camera on the cluster equals the same decomposition in this process, to the bit."""
    from material_structures.scaleout.teeth import camera_bands, gradient_items

    scene, capture = problem
    for c in range(len(capture.cameras)):
        bands = camera_bands(capture.masks[c], 2, 3)
        assert 1 < len(bands) <= 3 and all(y0 % 2 == 0 for y0, _ in bands)
        covered = np.zeros(capture.masks.shape[1], int)
        for y0, y1 in bands:
            covered[y0:y1] += 1
        assert covered.max() == 1 and np.all(covered[np.any(capture.masks[c], axis=1)] == 1)
    layout = ParamLayout(scene)
    st = RenderSettings(spp=4, max_depth=4)
    ids = np.array([1, 3])
    items = gradient_items(capture, 2, 3)
    assert len(items) > len(capture.cameras)
    ref_loss, ref_grad, _ = local_gradient(capture, 3)(scene, capture, ids, st, 5, layout, loss_block=2)
    loss, grad, stats = DaskGradient(client, capture, bands_per_camera=3)(scene, capture, ids, st, 5, layout,
                                                                          loss_block=2)
    assert stats["tasks"] == len(items)
    assert loss == ref_loss and np.any(grad != 0)
    np.testing.assert_array_equal(grad, ref_grad)


def test_gauss_newton_matrix_and_intervals_on_the_cluster_equal_this_process(problem, client):
    """The Gauss-Newton matrix's light groups and the intervals' renders as tasks (DaskMap): the same matrix to
    the bit; the same information with the lights in other chunks (one per worker)."""
    from material_structures.core.teeth.gauss_newton import gauss_newton_matrix
    from material_structures.core.teeth.param_vector import scene_to_vector, to_optimiser
    from material_structures.core.teeth.sensitivity import capture_sensitivity, default_directions
    from material_structures.scaleout.teeth import DaskMap

    scene, capture = problem
    layout = ParamLayout(scene)
    cols = np.arange(layout.size)
    y = to_optimiser(scene_to_vector(scene, layout), layout)
    task_map = DaskMap(client, capture)
    kw = dict(passes=2, block=2, max_depth=3, seed=11, lights_per_render=2, estimator="pooled")
    here = gauss_newton_matrix(scene, capture, layout, cols, y, **kw)
    there = gauss_newton_matrix(scene, capture, layout, cols, y, task_map=task_map, **kw)
    assert np.abs(here).max() > 0
    np.testing.assert_array_equal(there, here)

    names, dirs = default_directions(scene, layout)
    assert any(".c[" in n for n in names)  # the dentin coefficients' tasks too
    assert task_map.parallel == 2 and len(capture.lights) > 2  # two chunks of lights there, one here
    a = capture_sensitivity(scene, capture, dirs, passes=2, block=2, max_depth=3, seed=4, capture_spp=2)
    b = capture_sensitivity(scene, capture, dirs, passes=2, block=2, max_depth=3, seed=4, capture_spp=2,
                            task_map=task_map)
    scale = np.abs(a["information"]).max()
    assert scale > 0
    np.testing.assert_allclose(b["information"], a["information"], rtol=1e-9, atol=1e-12 * scale)
    assert b["noise_variance"] == pytest.approx(a["noise_variance"], rel=1e-12)
    assert b["reduced_chi2"] == pytest.approx(a["reduced_chi2"], rel=1e-9)
