"""Gauss-Newton preconditioning of the teeth fit: the tile Gauss-Newton matrix against a brute-force
recomputation (per-pass Jacobians, tiles summed by loops, the optimiser map by finite differences of
``from_optimiser``), the damped inverse and the momentum step against closed forms, and the fit with
``optimiser="gauss-newton"`` (runs, lowers the loss, resumes exactly, clear errors)."""

from __future__ import annotations

import numpy as np
import pytest

from material_structures.core.teeth.capture import Capture
from material_structures.core.teeth.gauss_newton import (
    DivergenceGuard,
    PreconditionedMomentum,
    damped_inverse,
    gauss_newton_matrix,
)
from material_structures.core.teeth.optimise import FitSettings, fit, free_mask, iteration_gradient
from material_structures.core.teeth.param_vector import ParamLayout, from_optimiser, scene_to_vector, to_optimiser
from material_structures.core.teeth.path_tracer import RenderSettings, render
from material_structures.core.teeth.scene import VolumeMaterial

from ._teeth_scenes import down_camera, light, slab_scene

# the settings these tests were written for (FitSettings' defaults before the fit's defaults became the
# best measured ones): Gauss-Newton from iteration 0, every 50, damping 0.03, guard at +25 %, per-pixel loss,
# the best-loss result, every light in the fit
PINNED = dict(gn_start=0, gn_every=50, gn_damping=0.03, gn_guard_rise=0.25, gn_passes=4, loss_block=1,
              average_tail=0.0, lr=0.03, lr_decay=0.0, image_spp=0, held_out_lights=0)


def _settings(**kw) -> FitSettings:
    return FitSettings(**{**PINNED, **kw})


def _problem():
    truth = slab_scene([1.0, 1.3, 1.7], [0.95, 0.9, 0.8], floor_albedo=[0.4, 0.3, 0.2])
    cams = [down_camera(12, 12, fov=6.0)]
    lights = [light((60.0 * np.cos(a), 60.0 * np.sin(a), 200.0)) for a in (0.0, 2.1, 4.2)]
    img = render(truth, cams, lights, RenderSettings(64, 6, 999)).images
    masks = np.ones((1, 12, 12), dtype=bool)
    masks[0, :2, :5] = False  # partly masked tiles
    cap = Capture(cams, lights, img.astype(np.float32), masks)
    theta = truth.copy()
    theta.teeth[0].enamel = VolumeMaterial([1.5, 0.9, 2.4], [0.85, 0.95, 0.6], 0.5, -0.3, 0.7)
    return truth, theta, cap


@pytest.mark.parametrize("estimator", ["per-pass", "pooled"])
def test_gauss_newton_matrix_matches_brute_force(estimator):
    _, theta, cap = _problem()
    layout = ParamLayout(theta)
    cols = np.flatnonzero(free_mask(layout, ("slab.enamel.sigma_t", "slab.enamel.albedo")))
    y = to_optimiser(scene_to_vector(theta, layout), layout)
    passes, block, seed = 2, 4, 11
    hmat = gauss_newton_matrix(theta, cap, layout, cols, y, passes=passes, block=block, max_depth=4,
                               seed=seed, lights_per_render=2, estimator=estimator)
    # optimiser map dx/dy by central differences of from_optimiser
    h = 1e-6
    dxdy = np.zeros((len(cols), len(cols)))
    for j, c in enumerate(cols):
        yp, ym = y.copy(), y.copy()
        yp[c] += h
        ym[c] -= h
        dxdy[:, j] = (from_optimiser(yp, layout) - from_optimiser(ym, layout))[cols] / (2 * h)
    m = cap.masks[0]
    pix = [np.flatnonzero(m.ravel())]
    tiles = {}  # (light group, tile) -> per pass: the tile's Jacobian sum / sqrt(pixels), (L * 3, k)
    groups = [np.array([0, 1]), np.array([2])]
    for p in range(passes):
        for gi, ids in enumerate(groups):
            r = render(theta, cap.cameras, cap.lights, RenderSettings(1, 4, seed + 1000 * p + gi), pixels=pix,
                       light_ids=ids, jacobian_cols=cols)
            jy = r.jacobian @ dxdy  # (rows, L, 3, k), rows in pixel order
            full = np.zeros((12, 12) + jy.shape[1:])
            full.reshape(144, *jy.shape[1:])[pix[0]] = jy
            for ty in range(0, 12, block):
                for tx in range(0, 12, block):
                    n = m[ty:ty + block, tx:tx + block].sum()
                    if n == 0:
                        continue
                    t = full[ty:ty + block, tx:tx + block].sum(axis=(0, 1)).reshape(-1, len(cols))
                    tiles.setdefault((gi, ty, tx), []).append(t / np.sqrt(n))
    ref = np.zeros((len(cols), len(cols)))
    for ts in tiles.values():
        if estimator == "pooled":  # (mean over passes of J)^T (mean over passes of J)
            ref += np.mean(ts, axis=0).T @ np.mean(ts, axis=0) * passes
        else:  # mean over passes of J^T J
            ref += sum(t.T @ t for t in ts)
    ref *= 2.0 / (m.sum() * 3 * 3 * passes)
    np.testing.assert_allclose(hmat, ref, rtol=1e-9, atol=1e-12 * np.abs(ref).max())
    assert np.linalg.eigvalsh(hmat).min() > 0


def test_damped_inverse_and_momentum_step_closed_forms():
    rng = np.random.default_rng(0)
    a = rng.normal(size=(5, 5))
    hmat = a @ a.T + np.diag([1e-4, 1.0, 10.0, 100.0, 1e3])
    np.testing.assert_allclose(damped_inverse(hmat, 0.1), np.linalg.inv(hmat + 0.1 * np.diag(np.diag(hmat))),
                               rtol=1e-8)
    # on a quadratic 0.5 (y - y*)^T H (y - y*), b1 = 0 and lr = 1 with P = H^-1 is Newton's method: one step
    y_star = rng.normal(size=5)
    y0 = rng.normal(size=5)
    opt = PreconditionedMomentum(1.0, b1=0.0)
    np.testing.assert_allclose(opt.step(y0, hmat @ (y0 - y_star), np.linalg.inv(hmat)), y_star, rtol=1e-6)
    # with momentum the first step is bias-corrected: the same step as without
    opt = PreconditionedMomentum(0.5, b1=0.9)
    np.testing.assert_allclose(opt.step(y0, hmat @ (y0 - y_star), np.linalg.inv(hmat)), 0.5 * (y0 + y_star),
                               rtol=1e-6)
    with pytest.raises(ValueError, match="damping"):
        damped_inverse(hmat, 0.0)
    bad = hmat.copy()
    bad[2, 2] = 0.0
    with pytest.raises(ValueError, match="diagonal"):
        damped_inverse(bad, 0.1)
    bad = hmat.copy()
    bad[1, 1] = np.nan
    with pytest.raises(ValueError, match="not finite"):
        damped_inverse(bad, 0.1)
    # a variable without effect (zero row and column, e.g. the gums' g2 while their beta sits at 1): no step for
    # it, and the others' block is the damped inverse of their own sub-matrix
    dead = hmat.copy()
    dead[3, :] = dead[:, 3] = 0.0
    inv = damped_inverse(dead, 0.1)
    keep = [0, 1, 2, 4]
    sub = dead[np.ix_(keep, keep)]
    np.testing.assert_allclose(inv[np.ix_(keep, keep)], np.linalg.inv(sub + 0.1 * np.diag(np.diag(sub))), rtol=1e-8)
    assert np.all(inv[3, :] == 0.0) and np.all(inv[:, 3] == 0.0)


def test_momentum_step_is_shortened_as_a_whole():
    """Over ``max_step`` the step keeps its direction (a descent direction): per-coordinate clipping would
    turn this one, whose first coordinate is far over the bound, into an ascent direction."""
    hmat = np.array([[1.0, 9.9], [9.9, 100.0]])  # correlated, unevenly scaled variables
    p = np.linalg.inv(hmat)
    g = hmat @ np.array([20.0, -1.0])
    d = p @ g  # [20, -1]
    y0 = np.zeros(2)
    y1 = PreconditionedMomentum(1.0, b1=0.0, max_step=0.05).step(y0, g, p)
    np.testing.assert_allclose(y1, -d * 0.05 / 20.0, rtol=1e-12)
    assert g @ (y1 - y0) < 0  # the loss's first-order change is negative
    clipped = -np.clip(d, -0.05, 0.05)
    assert g @ clipped > 0  # what per-coordinate clipping would have done
    # within the bound the step is the plain one
    np.testing.assert_allclose(PreconditionedMomentum(0.5, b1=0.0, max_step=20.0).step(y0, g, p), -0.5 * d,
                               rtol=1e-12)


def test_divergence_guard_windows_rollback_and_damping():
    g = DivergenceGuard(window=3, rise=0.25, factor=4.0, damping=0.12, min_damping=0.03)
    ys = [np.array([float(i), -2.0 * i]) for i in range(12)]
    # window 1 (loss mean 1.0): the first is the best; damping relaxes 0.12 -> 0.03
    assert [g.observe(v, y) for v, y in zip([1.1, 0.9, 1.0], ys[:3], strict=True)] == [None] * 3
    assert g.best_loss == pytest.approx(1.0) and g.damping == pytest.approx(0.03)
    np.testing.assert_allclose(g.best_y, [1.0, -2.0])
    # window 2 (mean 1.2): worse, within the 25 % rise: nothing; damping stays at its floor
    assert [g.observe(v, y) for v, y in zip([1.2, 1.2, 1.2], ys[3:6], strict=True)] == [None] * 3
    assert g.damping == pytest.approx(0.03) and g.best_loss == pytest.approx(1.0)
    # window 3 (mean 1.3 > 1.25): back to window 1's mean iterate, damping x 4
    out = [g.observe(v, y) for v, y in zip([1.3, 1.3, 1.3], ys[6:9], strict=True)]
    assert out[:2] == [None, None]
    np.testing.assert_allclose(out[2], [1.0, -2.0])
    assert g.damping == pytest.approx(0.12) and g.rollbacks == 1
    # window 4 better than the best: new best, damping divided again
    assert [g.observe(v, y) for v, y in zip([0.5, 0.5, 0.5], ys[9:12], strict=True)] == [None] * 3
    np.testing.assert_allclose(g.best_y, [10.0, -20.0])
    assert g.damping == pytest.approx(0.03)
    # the state survives a checkpoint mid-window
    g.observe(0.7, ys[0])
    h = DivergenceGuard.from_dict(g.to_dict())
    for guard in (g, h):  # the window (0.7, 0.7, 9.0) rises: both go back to window 4's mean iterate
        assert guard.observe(0.7, ys[1]) is None
        np.testing.assert_allclose(guard.observe(9.0, ys[2]), [10.0, -20.0])
        assert guard.damping == pytest.approx(0.12) and guard.rollbacks == 2


def test_fit_goes_back_when_the_loss_rises(tmp_path):
    """A loss that jumps (here: multiplied by 3 from iteration 6 on) sends the Gauss-Newton phase back
    to the best window's mean iterate with 4x the damping; an interrupted fit resumes exactly across it."""
    _, theta, cap = _problem()

    def rising(scene, capture, light_ids, st, seed, layout, image_spp=0):
        loss, g, stats = iteration_gradient(scene, capture, light_ids, st, seed, layout, image_spp=image_spp)
        return (loss * 3.0 if seed % 100003 >= 6 else loss), g, stats

    base = dict(iterations=9, spp=1, image_spp=2, lights_per_iteration=2, free=("slab.enamel.albedo",),
                optimiser="gauss-newton", gn_lr=0.5, gn_passes=1, gn_block=4, gn_guard_window=3, seed=0,
                max_depth=4, checkpoint_every=1)
    layout = ParamLayout(theta)
    seen: list = []
    said: list = []  # status texts and iterations, in call order
    _, log = fit(theta, cap, _settings(**base), gradient=rising, status=said.append,
                 progress=lambda e: said.append(e["iteration"]),
                 callback=lambda e, sc: seen.append(to_optimiser(scene_to_vector(sc, layout), layout)))
    # the Gauss-Newton matrix (gn_start 0, gn_every 50) is estimated once, before iteration 0, and said so
    assert said[:2] == ["estimating the Gauss-Newton matrix (1 passes of all lights)", ""]
    assert said[2:] == list(range(9))
    assert [bool(e.get("gauss_newton_rollback")) for e in log] == [False] * 8 + [True]
    assert [e["gauss_newton_damping"] for e in log] == pytest.approx([0.03] * 8 + [0.12])
    losses = [e["loss"] for e in log]
    best = int(np.argmin([np.mean(losses[0:3]), np.mean(losses[3:6])]))
    # one more iteration shows where the rollback went
    more, log2 = fit(theta, cap, _settings(**{**base, "iterations": 10}), gradient=rising, out_dir=str(tmp_path),
                     callback=lambda e, sc: seen.append(to_optimiser(scene_to_vector(sc, layout), layout)))
    np.testing.assert_allclose(seen[-1], np.mean(seen[3 * best:3 * best + 3], axis=0), rtol=1e-9)
    np.testing.assert_allclose([e["loss"] for e in log2[:9]], losses, rtol=1e-12)
    # interrupted after 7 iterations (mid-window), resumed: the same as straight through
    out = str(tmp_path / "cut")
    fit(theta, cap, _settings(**{**base, "iterations": 7}), gradient=rising, out_dir=out)
    resumed, log_r = fit(theta, cap, _settings(**{**base, "iterations": 10}), gradient=rising, out_dir=out,
                         resume=True)
    np.testing.assert_allclose([e["loss"] for e in log_r], [e["loss"] for e in log2], rtol=1e-9)
    assert log_r[8].get("gauss_newton_rollback")
    np.testing.assert_allclose(resumed.teeth[0].enamel.albedo, more.teeth[0].enamel.albedo, rtol=1e-9)


def test_checkpoint_of_the_earlier_gauss_newton_format_is_a_clear_error(tmp_path):
    _, theta, cap = _problem()
    base = dict(iterations=2, spp=1, lights_per_iteration=1, free=("slab.enamel.albedo",), optimiser="gauss-newton",
                gn_passes=1, gn_block=4, seed=0, max_depth=3)
    out = tmp_path / "fit"
    fit(theta, cap, _settings(**base), out_dir=str(out))
    ckpt = out / "checkpoint.json"
    d = __import__("json").loads(ckpt.read_text())
    d["precond"] = d.pop("gn_hmat")
    ckpt.write_text(__import__("json").dumps(d))
    with pytest.raises(ValueError, match="earlier version"):
        fit(theta, cap, _settings(**{**base, "iterations": 3}), out_dir=str(out), resume=True)


def _albedo_error(scene, truth) -> float:
    return float(np.abs(scene.teeth[0].enamel.albedo / truth.teeth[0].enamel.albedo - 1).max())


def test_gauss_newton_fit_lowers_the_error_and_resumes_exactly(tmp_path):
    truth, theta, cap = _problem()
    theta.teeth[0].enamel = VolumeMaterial(truth.teeth[0].enamel.sigma_t, theta.teeth[0].enamel.albedo, 0.5, -0.3,
                                           0.7)
    base = dict(iterations=8, spp=2, image_spp=4, lights_per_iteration=3, free=("slab.enamel.albedo",),
                optimiser="gauss-newton", gn_lr=0.5, gn_passes=2, gn_block=4, gn_every=4, checkpoint_every=1,
                seed=3, max_depth=6)
    fitted, log = fit(theta, cap, _settings(**base))
    assert "gauss_newton_seconds" in log[0] and "gauss_newton_seconds" in log[4]
    assert "gauss_newton_seconds" not in log[1]
    assert _albedo_error(theta, truth) == pytest.approx(0.25, abs=0.01)
    assert _albedo_error(fitted, truth) < 0.1  # 8 steps of at most gn_max_step = 0.05 in kappa
    # interrupted after 5 iterations (the preconditioner of iteration 4 in the checkpoint), resumed;
    # sigma_t free too, and the dentin-coefficient-free split (Adam for c) is exercised by the recovery
    base["free"] = ("slab.enamel.sigma_t", "slab.enamel.albedo")
    out = str(tmp_path / "fit")
    fit(theta, cap, _settings(**{**base, "iterations": 5}), out_dir=out)
    resumed, log_r = fit(theta, cap, _settings(**base), out_dir=out, resume=True)
    straight, log_s = fit(theta, cap, _settings(**base), out_dir=str(tmp_path / "straight"))
    np.testing.assert_allclose([e["loss"] for e in log_r], [e["loss"] for e in log_s], rtol=1e-9)
    np.testing.assert_allclose(resumed.teeth[0].enamel.sigma_t, straight.teeth[0].enamel.sigma_t, rtol=1e-9)


def test_gauss_newton_takes_over_from_adam_at_gn_start():
    """Before ``gn_start`` the fit is Adam's, iteration for iteration; from it on the matrix is estimated."""
    _, theta, cap = _problem()
    base = dict(iterations=3, spp=1, lights_per_iteration=2, free=("slab.enamel.albedo",), seed=5, max_depth=4)
    seen: dict = {"adam": [], "gn": []}
    _, log_a = fit(theta, cap, _settings(**base, optimiser="adam"),
                   callback=lambda e, sc: seen["adam"].append(sc.copy()))
    _, log_g = fit(theta, cap, _settings(**base, optimiser="gauss-newton", gn_start=2, gn_passes=1, gn_block=4),
                   callback=lambda e, sc: seen["gn"].append(sc.copy()))
    assert ["gauss_newton_seconds" in e for e in log_g] == [False, False, True]
    np.testing.assert_allclose([e["loss"] for e in log_g[:2]], [e["loss"] for e in log_a[:2]], rtol=1e-12)
    # the scene of iteration 2 is the result of two Adam steps in both fits
    np.testing.assert_allclose(seen["gn"][2].teeth[0].enamel.albedo, seen["adam"][2].teeth[0].enamel.albedo,
                               rtol=1e-12)


@pytest.mark.parametrize("kw, match", [({"optimiser": "newton"}, "optimiser"),
                                       ({"optimiser": "gauss-newton", "gn_damping": 0.0}, "gn_damping"),
                                       ({"optimiser": "gauss-newton", "gn_passes": 0}, "gn_passes"),
                                       ({"optimiser": "gauss-newton", "gn_start": -1}, "gn_start"),
                                       ({"optimiser": "gauss-newton", "gn_max_step": 0.0}, "gn_max_step"),
                                       ({"optimiser": "gauss-newton", "gn_lr": 0.0}, "gn_lr"),
                                       ({"optimiser": "gauss-newton", "gn_guard_rise": 0.0}, "gn_guard"),
                                       ({"optimiser": "gauss-newton", "gn_guard_window": -1}, "gn_guard")])
def test_bad_optimiser_settings_are_clear_errors(kw, match):
    with pytest.raises(ValueError, match=match):
        FitSettings(iterations=1, **kw)


def test_pooled_estimator_removes_most_of_the_per_pass_bias():
    """Each 1-spp pass's J^T J carries its Monte Carlo variance Sigma as extra curvature, whatever the pass
    count; (mean J)^T (mean J) carries Sigma / passes. Reference: the pooled matrix of 128 passes."""
    _, theta, cap = _problem()
    layout = ParamLayout(theta)
    cols = np.flatnonzero(free_mask(layout, ("slab.enamel.sigma_t", "slab.enamel.albedo")))
    y = to_optimiser(scene_to_vector(theta, layout), layout)
    kw = {"block": 4, "max_depth": 4}
    ref = gauss_newton_matrix(theta, cap, layout, cols, y, passes=128, seed=5000, estimator="pooled", **kw)
    w, v = np.linalg.eigh(ref)
    for seed in (0, 100, 200):
        per_pass = gauss_newton_matrix(theta, cap, layout, cols, y, passes=8, seed=seed, **kw)
        pooled = gauss_newton_matrix(theta, cap, layout, cols, y, passes=8, seed=seed, estimator="pooled", **kw)
        # curvature along the reference's eigenvectors, flattest first, relative to the reference's
        r_pp, r_po = (np.array([v[:, i] @ h @ v[:, i] / w[i] for i in range(len(w))]) for h in (per_pass, pooled))
        # measured: per pass 120-225x the curvature along the 3 flattest directions, pooled 10-31x
        assert np.all(r_pp[:3] > 50), r_pp
        assert np.all(r_po[:3] - 1 < (r_pp[:3] - 1) / 3), (r_po, r_pp)
        # the stiff directions stay within 30 % either way (measured 1.0-1.3)
        assert np.all(np.abs(r_pp[3:] - 1) < 0.3) and np.all(np.abs(r_po[3:] - 1) < 0.3), (r_pp, r_po)


def _coefficient_problem():
    """A one-tooth capture (``fd_test_scene``) and a start off in sigma_t, albedo and the coefficients."""
    from material_structures.core.teeth.gradient_check import fd_test_scene
    from material_structures.core.teeth.synthetic import perturbed_start

    truth, cams, lights = fd_test_scene()
    img = render(truth, cams, lights, RenderSettings(8, 4, 3)).images
    cap = Capture(cams, lights, img.astype(np.float32), np.ones((1, cams[0].height, cams[0].width), dtype=bool))
    return perturbed_start(truth, seed=2, reset_c=False), cap


def test_dentin_coefficients_wait_for_gauss_newton():
    """With Gauss-Newton the coefficients stay at the start until ``gn_start`` while the materials move, and
    move from then on; with Adam alone, and when they are all that is free, they move from the first step."""
    start, cap = _coefficient_problem()
    base = dict(iterations=4, spp=1, lights_per_iteration=len(cap.lights), free=("*.enamel.sigma_t", "*.c"), seed=1,
                max_depth=4, gn_passes=1, gn_block=4)

    def iterates(**kw) -> list:
        seen: list = []
        fit(start, cap, _settings(**{**base, **kw}), callback=lambda e, sc: seen.append(sc.copy()))
        return seen

    gn = iterates(optimiser="gauss-newton", gn_start=2)
    for k in (1, 2):  # iterations 0 and 1 left the coefficients alone, not the enamel
        np.testing.assert_array_equal(gn[k].teeth[0].c, start.teeth[0].c)
        assert np.abs(gn[k].teeth[0].enamel.sigma_t - gn[k - 1].teeth[0].enamel.sigma_t).min() > 1e-6
    assert np.abs(gn[3].teeth[0].c - gn[2].teeth[0].c).min() > 1e-4  # iteration 2 moved them
    for kw in ({"optimiser": "adam"}, {"optimiser": "gauss-newton", "gn_start": 2, "free": ("*.c",)}):
        it = iterates(**kw)
        assert np.abs(it[1].teeth[0].c - start.teeth[0].c).min() > 1e-4, kw


def test_resumed_fit_takes_the_guard_settings_of_the_resuming_settings(tmp_path):
    """The guard's windows and escalation survive a resume; its rise, factor and base damping are the
    resuming settings' (the checkpoint's were kept before); a guard turned off stays off."""
    import json

    _, theta, cap = _problem()
    base = dict(iterations=3, spp=1, image_spp=2, lights_per_iteration=2, free=("slab.enamel.albedo",),
                optimiser="gauss-newton", gn_passes=1, gn_block=4, seed=0, max_depth=4, checkpoint_every=1,
                gn_guard_rise=0.25, gn_damping=0.03)
    out = str(tmp_path / "fit")
    fit(theta, cap, _settings(**base), out_dir=out)
    path = f"{out}/checkpoint.json"
    with open(path) as f:
        ck = json.load(f)
    assert ck["gn_guard"]["rise"] == 0.25 and ck["gn_guard"]["n"] == 3
    ck["gn_guard"]["damping"] = 0.12  # as after one rollback (4x the base 0.03)
    with open(path, "w") as f:
        json.dump(ck, f)
    fit(theta, cap, _settings(**{**base, "iterations": 4, "gn_guard_rise": 1.0, "gn_damping": 0.01}), out_dir=out,
        resume=True)
    with open(path) as f:
        guard = json.load(f)["gn_guard"]
    assert guard["rise"] == 1.0 and guard["n"] == 4  # the window's first 3 iterations carried over
    assert guard["min_damping"] == pytest.approx(0.01) and guard["damping"] == pytest.approx(0.04)
    fit(theta, cap, _settings(**{**base, "iterations": 5, "gn_guard_window": 0}), out_dir=out, resume=True)
    with open(path) as f:
        assert json.load(f)["gn_guard"] is None
