"""BTF I/O, NDF extraction (eq. 3.11-3.16), batched LM (3.17-3.19), post-processing and the
end-to-end fitter, checked against closed forms, finite differences and synthetic ground truth."""

from __future__ import annotations

import json
import os

import numpy as np
import pytest

from material_structures.core.errors import UserError
from material_structures.core.exr_io import write_exr
from material_structures.core.fabric.btf_fitter import fit_btf
from material_structures.core.fabric.btf_io import load_btf, read_directions, save_btf
from material_structures.core.fabric.btf_prediction import predict_btf, psnr
from material_structures.core.fabric.initial_guess import initial_basis
from material_structures.core.fabric.levenberg_marquardt import Samples, levenberg_marquardt, specular_terms
from material_structures.core.fabric.ndf_extraction import (
    NdfOperator,
    ndf_operator,
    parabolic_coords,
    parabolic_direction,
    parabolic_solid_angle,
)
from material_structures.core.fabric.parameter_maps import load_params, make_maps
from material_structures.core.fabric.postprocess import (
    flip_tangent,
    label_flip_regions,
    postprocess_basis,
    sort_basis,
)
from material_structures.core.fabric.quaternion import (
    quat_from_axis_angle,
    quat_from_rotvec,
    quat_multiply,
    quat_to_matrix,
)
from material_structures.core.fabric.sggx_brdf import sggx_brdf, sggx_specular
from material_structures.core.fabric.sggx_matrix import sggx_matrix
from material_structures.core.fabric.sggx_ndf import sggx_ndf
from material_structures.core.fabric.synthetic_btf import light_view_pairs, render_btf, synthetic_maps


def small_axis(rot, sigma):
    """Axis with the smallest deviation (the tangent) of bases (T, 3, 3) with sigma (T, 2)."""
    return np.where((sigma[:, 0] <= sigma[:, 1])[:, None], rot[:, :, 0], rot[:, :, 1])


# ---------------------------------------------------------------- BTF input


def test_btf_folder_and_npz_roundtrip(tmp_path):
    wi, wo = light_view_pairs(3, 2)
    vals = np.random.default_rng(0).random((6, 4, 5, 3)).astype(np.float32)
    save_btf(tmp_path / "f", vals, wi, wo)
    save_btf(tmp_path / "b.npz", vals, wi, wo)
    for p in (tmp_path / "f", tmp_path / "f" / "btf.json", tmp_path / "b.npz"):
        btf = load_btf(p)
        assert np.array_equal(btf.values, vals)
        assert np.allclose(btf.wi, wi, atol=1e-12) and np.allclose(btf.wo, wo, atol=1e-12)
    desc = json.loads((tmp_path / "f" / "btf.json").read_text())
    assert set(desc) == {"width", "height", "samples"} and desc["width"] == 5 and desc["height"] == 4
    assert np.allclose(read_directions(tmp_path / "f" / "btf.json")[0], wi)
    assert np.allclose(read_directions(tmp_path / "b.npz")[1], wo)
    np.savez(tmp_path / "dirs.npz", wi=wi, wo=wo)  # directions alone: what `fabric eval --directions` says suffices
    got_wi, got_wo = read_directions(tmp_path / "dirs.npz")
    assert np.allclose(got_wi, wi) and np.allclose(got_wo, wo)
    np.savez(tmp_path / "half.npz", wi=wi)
    with pytest.raises(UserError, match="missing array 'wo'"):
        read_directions(tmp_path / "half.npz")
    with open(tmp_path / "one.npz", "wb") as f:  # np.save: one array, whatever the name
        np.save(f, wi)
    with pytest.raises(UserError, match="a single array, not an .npz archive"):
        read_directions(tmp_path / "one.npz")
    with pytest.raises(UserError, match="a single array, not an .npz archive"):  # as a BTF too (was a TypeError)
        load_btf(tmp_path / "one.npz")


def _folder(tmp_path, samples, w=3, h=2):
    d = tmp_path / "btf"
    d.mkdir(exist_ok=True)
    (d / "btf.json").write_text(json.dumps({"width": w, "height": h, "samples": samples}))
    return d


def test_btf_errors_are_clear(tmp_path):
    up = [0.0, 0.0, 1.0]
    write_exr(tmp_path / "ok.exr", np.ones((2, 3, 3)))
    write_exr(tmp_path / "big.exr", np.ones((4, 3, 3)))
    nan = np.ones((2, 3, 3))
    nan[0, 0, 0] = np.nan
    write_exr(tmp_path / "nan.exr", nan)
    os.makedirs(tmp_path / "btf", exist_ok=True)
    for name in ("ok.exr", "big.exr", "nan.exr"):
        os.replace(tmp_path / name, tmp_path / "btf" / name)
    with pytest.raises(FileNotFoundError, match="missing.exr"):
        load_btf(_folder(tmp_path, [{"wi": up, "wo": up, "image": "missing.exr"}]))
    with pytest.raises(ValueError, match="3x4"):
        load_btf(_folder(tmp_path, [{"wi": up, "wo": up, "image": "big.exr"}]))
    with pytest.raises(ValueError, match="non-finite"):
        load_btf(_folder(tmp_path, [{"wi": up, "wo": up, "image": "nan.exr"}]))
    with pytest.raises(ValueError, match="below the horizon"):
        load_btf(_folder(tmp_path, [{"wi": [0.6, 0.0, -0.8], "wo": up, "image": "ok.exr"}]))
    with pytest.raises(ValueError, match="not a unit vector"):
        load_btf(_folder(tmp_path, [{"wi": [0.0, 0.0, 2.0], "wo": up, "image": "ok.exr"}]))
    with pytest.raises(FileNotFoundError, match="btf.json"):
        load_btf(tmp_path / "nowhere")
    wi, wo = light_view_pairs(2, 1)
    np.savez(tmp_path / "bad.npz", values=np.ones((3, 2, 2, 3)), wi=wi, wo=wo)
    with pytest.raises(ValueError, match="3 images but wi/wo have 2"):
        load_btf(tmp_path / "bad.npz")
    v = np.ones((2, 2, 2, 3))
    v[1, 0, 1, 2] = np.nan
    np.savez(tmp_path / "nan.npz", values=v, wi=wi, wo=wo)
    with pytest.raises(ValueError, match=r"values\[1\].*non-finite"):
        load_btf(tmp_path / "nan.npz")


# ---------------------------------------------------------------- NDF extraction and initial guess


def test_parabolic_map_roundtrip_and_solid_angle():
    rng = np.random.default_rng(0)
    w = rng.normal(size=(1000, 3))
    w[:, 2] = np.abs(w[:, 2])
    w /= np.linalg.norm(w, axis=1, keepdims=True)
    assert np.allclose(parabolic_direction(parabolic_coords(w)), w, atol=1e-12)
    n = 800  # midpoint rule over the disk of the map: total solid angle of the hemisphere is 2 pi
    c = (np.arange(n) + 0.5) / n
    xy = np.stack(np.meshgrid(c, c), -1)
    inside = np.sum((2 * xy - 1) ** 2, -1) <= 1
    assert np.sum(parabolic_solid_angle(xy)[inside]) / n**2 == pytest.approx(2 * np.pi, rel=2e-3)


def test_eq_3_11_estimator_normalisation_against_quadrature():
    """For a constant BTF f = 1 the stratified MC estimate of eq. 3.11 is the fraction of incident
    directions whose mirror direction about h stays above the horizon: compare every map cell
    with a midpoint quadrature of that fraction."""
    wi, wo = light_view_pairs(24, 24, theta_max_deg=89.5)
    op = ndf_operator(wi, wo, resolution=12, strata=24, max_distance=10.0)
    est = op.apply(np.ones((len(wi), 1)))[:, 0]
    nt, nph = 200, 400
    t = (np.arange(nt) + 0.5) / nt * np.pi / 2
    p = (np.arange(nph) + 0.5) / nph * 2 * np.pi
    tt, pp = np.meshgrid(t, p, indexing="ij")
    w = np.stack([np.sin(tt) * np.cos(pp), np.sin(tt) * np.sin(pp), np.cos(tt)], -1).reshape(-1, 3)
    da = (np.sin(tt) * (np.pi / 2 / nt) * (2 * np.pi / nph)).ravel()
    inside = np.flatnonzero(op.valid)
    assert inside.size > 60
    for c in inside:
        h = op.directions[c]
        mirror_z = 2 * (w @ h) * h[2] - w[:, 2]
        ref = np.sum(da * (mirror_z > 0)) / (2 * np.pi)
        assert est[c] == pytest.approx(ref, abs=0.03)


def test_eq_3_16_recovers_projected_areas_from_exact_ndf():
    """With D_BTF = the SGGX NDF on the full hemisphere, eq. 3.13-3.16 return the true basis and
    sigma ratios (int_{Omega+} |w_k . h| D dh = sigma(w_k))."""
    res = 160
    c = (np.arange(res) + 0.5) / res
    xy = np.stack(np.meshgrid(c, c, indexing="xy"), -1).reshape(-1, 2)
    inside = np.sum((2 * xy - 1) ** 2, -1) <= 1
    h = parabolic_direction(np.where(inside[:, None], xy, 0.5))
    op = NdfOperator(A=np.zeros((h.shape[0], 1)), directions=h,
                     solid_angle=np.where(inside, parabolic_solid_angle(xy) / res**2, 0), valid=inside,
                     resolution=res)
    q_true = quat_multiply(quat_from_axis_angle(np.array([0.2, 1.0, 0.0]), np.array(np.radians(25))),
                           quat_from_axis_angle(np.array([0.0, 0.0, 1.0]), np.array(0.7)))
    sig = np.array([0.6, 0.3])  # w_0 (larger spread) is the x axis
    d = sggx_ndf(h, sggx_matrix(q_true, sig))[:, None]
    q, s = initial_basis(d, op, floor_quantile=None)
    r, rt = quat_to_matrix(q[0]), quat_to_matrix(q_true)
    for k in range(3):
        assert abs(r[:, k] @ rt[:, k]) > np.cos(np.radians(1.0))
    assert s[0] == pytest.approx(sig, rel=0.02)


def test_ndf_extraction_finds_tilted_peak():
    """eq. 3.11 by stratified MC on measured pairs: argmax direction within 10 degrees of the true
    z axis for fibres tilted up to 30 degrees."""
    wi, wo = light_view_pairs(32, 32)
    maps = synthetic_maps(6, 6, seed=3)
    vals = render_btf(maps, wi, wo).reshape(len(wi), -1, 3)
    op = ndf_operator(wi, wo)
    q, _ = initial_basis(op.apply(vals.mean(2) / wi[:, 2:3]), op)
    z_true = quat_to_matrix(maps.basis.reshape(-1, 4).astype(np.float64))[:, :, 2]
    err = np.degrees(np.arccos(np.clip(np.abs(np.sum(quat_to_matrix(q)[:, :, 2] * z_true, -1)), 0, 1)))
    assert np.max(err) < 10.0 and np.median(err) < 5.0  # parabolic cells are ~4 degrees wide


# ---------------------------------------------------------------- Levenberg-Marquardt


def _random_texels(pairs: int, t: int, seed: int, sigma_range: tuple[float, float]):
    """Samples of ``pairs`` x ``pairs`` light/view pairs and ``t`` texels of random deviations and bases."""
    wi, wo = light_view_pairs(pairs, pairs)
    rng = np.random.default_rng(seed)
    u = np.log(rng.uniform(*sigma_range, (t, 2)))
    q = quat_from_axis_angle(rng.normal(size=(t, 3)), rng.uniform(0, 3, t))
    return wi, wo, Samples.make(wi, wo), u, q, rng


def test_lm_analytic_derivatives_match_finite_differences():
    t = 20
    wi, wo, s, u, q, _ = _random_texels(8, t, 1, (0.1, 1.2))
    g, dl = specular_terms(s, u, q, derivatives=True)
    ref = sggx_specular(wi[None], wo[None], np.exp(u)[:, None], q[:, None]) * wi[:, 2]
    assert np.allclose(g, ref, rtol=1e-12)
    eps = 1e-6
    for j in range(5):
        if j < 2:
            du = np.zeros_like(u)
            du[:, j] = eps
            gp, _ = specular_terms(s, u + du, q)
            gm, _ = specular_terms(s, u - du, q)
        else:
            r = np.zeros((t, 3))
            r[:, j - 2] = eps
            gp, _ = specular_terms(s, u, quat_multiply(q, quat_from_rotvec(r)))
            gm, _ = specular_terms(s, u, quat_multiply(q, quat_from_rotvec(-r)))
        fd = (np.log(gp) - np.log(gm)) / (2 * eps)
        assert np.allclose(dl[..., j], fd, atol=2e-5 * max(1.0, np.abs(fd).max()))


def test_compiled_moments_equal_the_numpy_sums_in_float64():
    """The LM's sums over samples (``specular_moments``, numba) against the same sums built from the numpy
    model (``specular_terms`` in float64, itself checked against eq. 3.9 and finite differences above), for
    texels picked out of the targets by ``rows`` (out of order, one twice)."""
    from material_structures.core.fabric import levenberg_marquardt as LM

    wi, _, s, u, q, rng = _random_texels(16, 12, 5, (0.05, 2.0))
    y = rng.uniform(0.0, 1.0, (20, len(wi), 3))
    rows = np.array([3, 0, 19, 7, 7, 11, 2, 15, 8, 1, 4, 13])
    kd = s.kernel_data()
    kd["e64"] = s.weight / np.pi
    assert LM._compiled is not None and "compiled" in kd  # the compiled path is the one under test
    m, by = LM._normal_moments(kd, u, q, y, rows)
    mom = LM._trial_moments(kd, u, q, y, rows)
    g, dl = specular_terms(s, u, q, derivatives=True, dtype=np.float64)
    basis = np.concatenate([g[..., None] * dl, g[..., None], np.broadcast_to(kd["e64"], g.shape)[..., None]], -1)
    m_ref = np.einsum("tni,tnj->tij", basis, basis)
    by_ref = np.einsum("tni,tnc->tic", basis, y[rows])
    assert np.abs(m - m_ref).max() <= 1e-10 * np.abs(m_ref).max()
    assert np.abs(by - by_ref).max() <= 1e-10 * np.abs(by_ref).max()
    np.testing.assert_allclose(mom.gg, np.einsum("tn,tn->t", g, g), rtol=1e-10)
    np.testing.assert_allclose(mom.ge, g @ kd["e64"], rtol=1e-10)
    np.testing.assert_allclose(mom.gy, np.einsum("tn,tnc->tc", g, y[rows]), rtol=1e-10)
    ey, yy = LM.target_moments(y, kd["e64"])
    np.testing.assert_allclose(ey, np.einsum("n,tnc->tc", kd["e64"], y), rtol=1e-12)
    np.testing.assert_allclose(yy, np.einsum("tnc,tnc->tc", y, y), rtol=1e-12)
    # the numpy sums (float32 model) agree to its precision
    numpy_kd = {k: v for k, v in kd.items() if k != "compiled"}
    m32, by32 = LM._normal_moments(numpy_kd, u, q, y, rows)
    assert np.abs(m32 - m_ref).max() <= 1e-5 * np.abs(m_ref).max()
    assert np.abs(by32 - by_ref).max() <= 1e-5 * np.abs(by_ref).max()


def test_lm_recovers_parameters_from_perturbed_start():
    wi, wo = light_view_pairs(24, 24)
    s = Samples.make(wi, wo)
    maps = synthetic_maps(8, 8, seed=4)
    vals = render_btf(maps, wi, wo).reshape(len(wi), -1, 3).transpose(1, 0, 2)
    q_true = maps.basis.reshape(-1, 4).astype(np.float64)
    s_true = maps.sigma.reshape(-1, 2).astype(np.float64)
    rng = np.random.default_rng(2)
    q0 = quat_multiply(q_true, quat_from_rotvec(rng.normal(size=(64, 3)) * 0.08))
    res = levenberg_marquardt(s, vals, q0, s_true * np.exp(rng.normal(size=(64, 2)) * 0.2))
    assert np.all(res.cost < 1e-8)
    _, s_fit = sort_basis(res.quat, res.sigma)  # (sigma_x, sigma_y) may come out swapped: a symmetry
    assert np.allclose(s_fit, sort_basis(q_true, s_true)[1], rtol=1e-3)
    assert np.allclose(res.ks, maps.ks.reshape(-1, 3), atol=1e-3)
    assert np.allclose(res.kd, maps.kd.reshape(-1, 3), atol=1e-3)


def test_fit_tile_degenerate_texels():
    """Purely diffuse and black texels: k_d recovered exactly (closed form kd/pi * cos_i), no NaNs."""
    from material_structures.core.fabric.tile_fit import fit_tile

    wi, wo = light_view_pairs(16, 16)
    s = Samples.make(wi, wo)
    kd = np.array([[0.3, 0.2, 0.1], [0.0, 0.0, 0.0]])
    vals = (kd[:, None, :] / np.pi) * wi[None, :, 2:3]
    res = fit_tile(vals, s, ndf_operator(wi, wo))
    assert np.all(np.isfinite(res.quat)) and np.all(np.isfinite(res.sigma))
    assert np.allclose(res.kd, kd, atol=1e-6) and np.allclose(res.ks, 0.0, atol=1e-6)


# ---------------------------------------------------------------- post-processing


def test_postprocessing_preserves_brdf_and_aligns_tangents():
    rng = np.random.default_rng(5)
    maps = synthetic_maps(16, 16, seed=6)
    q = maps.basis.astype(np.float64)
    sig = maps.sigma.astype(np.float64)
    # scramble with BRDF symmetries: axis permutation (swap x/y with sigma swap), flips, -q
    swap = rng.random((16, 16)) < 0.5
    q_sw = quat_multiply(q, quat_from_axis_angle(np.array([0.0, 0, 1]), np.array(np.pi / 2)))
    q = np.where(swap[..., None], q_sw, q)
    sig = np.where(swap[..., None], sig[..., ::-1], sig)
    flip = rng.random((16, 16)) < 0.4
    q = np.where(flip[..., None], flip_tangent(q), q) * np.where(rng.random((16, 16, 1)) < 0.5, -1, 1)
    wi, wo = light_view_pairs(5, 5)
    wi, wo = wi[:, None, None], wo[:, None, None]
    before = sggx_brdf(wi, wo, maps.kd, maps.ks, sig, q)
    q2, s2, labels = postprocess_basis(q, sig)
    after = sggx_brdf(wi, wo, maps.kd, maps.ks, s2, q2)
    assert np.allclose(before, after, rtol=1e-9)
    assert np.all(s2[..., 0] <= s2[..., 1] + 1e-12) and np.all(s2 <= 1 + 1e-12)
    x = quat_to_matrix(q2)[..., :, 0]
    assert np.all(np.sum(x[1:] * x[:-1], -1) > 0) and np.all(np.sum(x[:, 1:] * x[:, :-1], -1) > 0)
    assert np.all(quat_to_matrix(q2)[..., 2, 2] > 0)
    assert labels.max() >= 1


def test_sort_basis_and_flip_labels():
    q = quat_from_axis_angle(np.array([0.0, 0.0, 1.0]), np.array(0.3))
    qs, ss = sort_basis(q[None], np.array([[2.0, 0.5]]))
    assert ss[0] == pytest.approx([0.25, 0.5])
    qq = np.tile(q, (4, 6, 1))
    qq[:, 3:] = flip_tangent(qq[:, 3:])  # an outline between columns 2 and 3
    labels, n = label_flip_regions(qq)
    assert n == 2 and len(np.unique(labels[:, :3])) == 1 and labels[0, 0] != labels[0, 5]


# ---------------------------------------------------------------- end to end


@pytest.fixture
def closures_from_the_table(monkeypatch):
    """``fit_btf`` takes every texel's Cycles closure mix from the closure table (FIT_KEY_BUDGET 0), as for a
    measured map, instead of fitting each distinct texel geometry (0.15-0.6 s each: 9 of a 4 x 4 fit's 10 s).
    For the tests of the BTF fit and its cache; ``test_a_fit_writes_the_closures_of_its_texel_geometries``
    runs the closure fit."""
    from material_structures.core.fabric import btf_fitter

    monkeypatch.setattr(btf_fitter, "FIT_KEY_BUDGET", 0)


@pytest.mark.heavy  # a whole fit (1-3 s): outside `make test-fast`
def test_a_fit_writes_the_closures_of_its_texel_geometries(tmp_path):
    """Up to FIT_KEY_BUDGET distinct texel geometries, the fit writes beside its maps the closure mix
    fitted to each (``fit_closure_maps``), not the table's."""
    from material_structures.core.fabric.closure_fit import fit_closure_maps, load_closure_maps
    from material_structures.core.fabric.closure_table import lookup_closure_texels

    maps = synthetic_maps(2, 1, seed=8)
    wi, wo = light_view_pairs(12, 12)
    save_btf(tmp_path / "btf", render_btf(maps, wi, wo), wi, wo)
    fit, _ = fit_btf(tmp_path / "btf", tmp_path / "fit", tile=2, workers=1, progress=False)
    got = load_closure_maps(tmp_path / "fit")
    want = fit_closure_maps(fit.sigma, fit.basis)
    for name in ("weights", "shape", "ggx_scale"):
        np.testing.assert_array_equal(getattr(got, name), getattr(want, name), err_msg=name)
    table = lookup_closure_texels(fit.sigma.reshape(-1, 2), fit.basis.reshape(-1, 4))[0]
    assert not np.array_equal(got.weights.reshape(table.shape), table)  # fitted, not looked up


def _fit_and_score(tmp_path, noise, n=24, size=10, workers=2):
    maps = synthetic_maps(size, size, seed=7)
    wi, wo = light_view_pairs(n, n)
    save_btf(tmp_path / "btf.npz", render_btf(maps, wi, wo, noise=noise, seed=3), wi, wo)
    fit, stats = fit_btf(tmp_path / "btf.npz", tmp_path / "fit", tile=5, workers=workers, progress=False)
    hwi, hwo = light_view_pairs(12, 12, rotation=0.9)
    ref = render_btf(maps, hwi, hwo)
    pred = predict_btf(load_params(tmp_path / "fit"), hwi, hwo)
    rot_t = quat_to_matrix(maps.basis.reshape(-1, 4).astype(np.float64))
    rot_f = quat_to_matrix(fit.basis.reshape(-1, 4).astype(np.float64))
    st, sf = maps.sigma.reshape(-1, 2), fit.sigma.reshape(-1, 2)
    ang = np.degrees(np.arccos(np.clip(np.abs(np.sum(small_axis(rot_t, st) * small_axis(rot_f, sf), -1)), 0, 1)))
    aniso = (st.max(1) / st.min(1)) > 1.5
    return psnr(pred, ref), ang[aniso], stats


@pytest.mark.heavy  # a whole fit (1-3 s): outside `make test-fast`
def test_fit_recovers_synthetic_model_noise_free(closures_from_the_table, tmp_path):
    p, ang, stats = _fit_and_score(tmp_path, 0.0)
    assert p >= 30.0
    assert ang.size > 10 and np.max(ang) <= 5.0
    assert stats["tiles"] == 4 and stats["tiles_fitted_this_run"] == 4


@pytest.mark.heavy  # a whole fit (1-3 s): outside `make test-fast`
def test_fit_with_five_percent_noise(closures_from_the_table, tmp_path):
    p, ang, _ = _fit_and_score(tmp_path, 0.05)
    assert p >= 20.0
    assert np.percentile(ang, 90) <= 5.0


@pytest.mark.heavy  # a whole fit (1-3 s): outside `make test-fast`
def test_fit_resumes_from_tile_checkpoints(closures_from_the_table, tmp_path):
    maps = synthetic_maps(4, 4, seed=8)  # 4 tiles of 2 x 2 texels: the checkpoints, not the fit, are under test
    wi, wo = light_view_pairs(12, 12)
    save_btf(tmp_path / "btf", render_btf(maps, wi, wo), wi, wo)
    first, _ = fit_btf(tmp_path / "btf", tmp_path / "fit", tile=2, workers=1, progress=False)
    tiles = sorted(os.listdir(tmp_path / "fit" / ".fit_cache" / "tiles"))
    assert len(tiles) == 4
    os.remove(tmp_path / "fit" / ".fit_cache" / "tiles" / tiles[1])
    again, stats = fit_btf(tmp_path / "btf", tmp_path / "fit", tile=2, workers=1, progress=False)
    assert stats["tiles_fitted_this_run"] == 1
    for name in ("kd", "ks", "sigma", "basis"):
        assert np.allclose(getattr(first, name), getattr(again, name), atol=1e-6)


@pytest.mark.parametrize("dtype", ["<f4", ">f8", "<f2"])
def test_an_uncompressed_npz_member_is_mapped_where_it_lies(tmp_path, dtype):
    """``npz_stored_array`` finds the bytes of ``values`` inside an ``np.savez`` file (what the fit maps instead of
    copying the BTF): the map equals ``np.load``'s array; a compressed member has no place to map."""
    from material_structures.core.fabric.btf_io import npz_stored_array

    a = np.random.default_rng(1).random((5, 3, 7, 3)).astype(dtype)
    np.savez(tmp_path / "s.npz", wi=np.ones((5, 3)), values=a, wo=np.ones((5, 3)))
    where = npz_stored_array(str(tmp_path / "s.npz"), "values")
    assert where.shape == a.shape and np.dtype(where.dtype) == a.dtype
    images = where.map()
    np.testing.assert_array_equal(images, a)
    del images
    np.savez_compressed(tmp_path / "c.npz", values=a)
    assert npz_stored_array(str(tmp_path / "c.npz"), "values") is None


@pytest.mark.heavy  # three small fits (about 1 s each): outside `make test-fast`
def test_the_fit_streams_an_npz_and_fits_every_layout_alike(closures_from_the_table, tmp_path):
    """An uncompressed .npz is fitted from where it lies (no copy in the fit cache); a compressed one and a folder
    of EXR images are copied image by image; all three fits are the same to the bit, with tiles that cut across
    the images' rows and columns (tile 3 of a 7 x 5 sample)."""
    maps = synthetic_maps(7, 5, seed=9)
    wi, wo = light_view_pairs(12, 12)
    values = render_btf(maps, wi, wo)
    save_btf(tmp_path / "b.npz", values, wi, wo)
    np.savez_compressed(tmp_path / "c.npz", values=values, wi=wi, wo=wo)
    save_btf(tmp_path / "folder", values, wi, wo)
    fits = {}
    for name in ("b.npz", "c.npz", "folder"):
        fits[name], _ = fit_btf(tmp_path / name, tmp_path / f"fit-{name}", tile=3, workers=2, progress=False)
    assert not (tmp_path / "fit-b.npz" / ".fit_cache" / "values.npy").exists()
    assert (tmp_path / "fit-c.npz" / ".fit_cache" / "values.npy").exists()
    for name in ("c.npz", "folder"):
        for m in ("kd", "ks", "sigma", "basis"):
            np.testing.assert_array_equal(getattr(fits[name], m), getattr(fits["b.npz"], m), err_msg=f"{name} {m}")


@pytest.mark.heavy  # a whole fit (1-3 s): outside `make test-fast`
def test_an_image_rewritten_in_place_invalidates_the_cache(closures_from_the_table, tmp_path):
    """The cache is keyed on every file's size and mtime, not the folder: after one image of the BTF is
    rewritten (same name, same size), the next fit recomputes every tile and its result follows the new
    data."""
    maps = synthetic_maps(4, 4, seed=8)  # 4 tiles of 2 x 2 texels: the cache, not the fit, is under test
    wi, wo = light_view_pairs(12, 12)
    values = render_btf(maps, wi, wo)
    save_btf(tmp_path / "btf", values, wi, wo)
    fit_btf(tmp_path / "btf", tmp_path / "fit", tile=2, workers=1, progress=False)
    _, again = fit_btf(tmp_path / "btf", tmp_path / "fit", tile=2, workers=1, progress=False)
    assert again["tiles_fitted_this_run"] == 0  # unchanged inputs: the cache is used
    images = sorted(f for f in os.listdir(tmp_path / "btf") if f.endswith(".exr"))
    path = tmp_path / "btf" / images[3]
    st = os.stat(path)
    write_exr(str(path), values[3] * 0.5)
    os.utime(path, ns=(st.st_atime_ns, st.st_mtime_ns + 1_000_000))  # same second on coarse clocks
    assert os.stat(path).st_size == st.st_size
    _, stats = fit_btf(tmp_path / "btf", tmp_path / "fit", tile=2, workers=1, progress=False)
    assert stats["tiles_fitted_this_run"] == 4


@pytest.mark.heavy  # a whole fit (1-3 s): outside `make test-fast`
def test_cli_fit_eval_score(closures_from_the_table, tmp_path, capsys):
    from material_structures.cli import main

    btf, hold = str(tmp_path / "btf"), str(tmp_path / "hold.npz")
    assert main(["fabric", "synth", "--out", btf, "--width", "6", "--height", "5", "--lights", "14",
                 "--views", "14", "--gt-out", str(tmp_path / "gt")]) == 0
    assert main(["fabric", "synth", "--out", hold, "--width", "6", "--height", "5", "--lights", "5",
                 "--views", "5", "--rotation-deg", "45.8"]) == 0
    # in this process (--no-dask): a local Dask cluster costs 5 s to start and stop; the sigterm tests
    # (test_bad_inputs_fabric_scratch) and tests/scaleout fit through Dask
    assert main(["fabric", "fit", btf, "--out", str(tmp_path / "fit"), "--no-dask", "--workers", "1",
                 "--no-progress"]) == 0
    for d in ("fit", "gt"):
        assert main(["fabric", "eval", str(tmp_path / d), "--directions", hold,
                     "--out", str(tmp_path / f"{d}.npz")]) == 0
    capsys.readouterr()
    assert main(["fabric", "score", str(tmp_path / "gt.npz"), hold]) == 0
    score = json.loads(capsys.readouterr().out)  # ground truth reproduces itself (to the bit: PSNR null)
    assert score["identical"] or score["psnr_db"] > 60
    assert main(["fabric", "score", str(tmp_path / "fit.npz"), hold]) == 0
    assert json.loads(capsys.readouterr().out)["psnr_db"] >= 30
    assert main(["fabric", "ndf", btf, "--texel", "2", "3", "--size", "32",
                 "--out", str(tmp_path / "ndf.exr")]) == 0
    from material_structures.core.exr_io import read_exr

    img = read_exr(tmp_path / "ndf.exr")[..., 0]
    gt = load_params(tmp_path / "gt")
    z = quat_to_matrix(gt.basis[3, 2].astype(np.float64))[:, 2]  # the NDF peaks at the z axis
    peak = np.unravel_index(np.argmax(img), img.shape)
    assert np.allclose(np.array([peak[1], peak[0]]) + 0.5, parabolic_coords(z) * 32, atol=2.5)
    desc = json.loads((tmp_path / "fit" / "params.json").read_text())
    assert set(desc["maps"]) == {"kd", "ks", "sigma", "basis"}
    assert main(["fabric", "fit", str(tmp_path / "nope"), "--out", str(tmp_path / "x")]) == 1  # runtime error


def test_synthetic_noise_levels():
    maps = synthetic_maps(6, 6, seed=2)
    wi, wo = light_view_pairs(16, 16)
    clean = render_btf(maps, wi, wo).astype(np.float64)
    rel = render_btf(maps, wi, wo, noise=0.05, seed=1).astype(np.float64)
    peak = render_btf(maps, wi, wo, noise=0.05, seed=1, noise_kind="peak").astype(np.float64)
    big = clean > 1e-3
    assert np.std((rel / clean)[big]) == pytest.approx(0.05, rel=0.05)
    scale = clean.max(axis=(0, 3))[None, :, :, None]
    inner = clean > 0.2 * scale  # away from the clipping at zero
    assert np.std(((peak - clean) / scale)[inner]) == pytest.approx(0.05, rel=0.05)


def test_synthetic_maps_ranges():
    maps = synthetic_maps(40, 40, seed=1, max_tilt_deg=30.0)
    z = quat_to_matrix(maps.basis.astype(np.float64))[..., 2, 2]
    tilt = np.degrees(np.arccos(np.clip(z, -1, 1)))
    assert tilt.max() <= 30.0 + 1e-3 and tilt.max() > 20.0
    assert np.all(maps.sigma > 0.1) and np.all(maps.sigma <= 1.0)
    m2 = make_maps(maps.kd, maps.ks, maps.sigma, maps.basis)
    assert np.allclose(m2.basis, maps.basis)


@pytest.mark.slow
@pytest.mark.parametrize("noise,kind,min_psnr", [(0.0, "relative", 30.0), (0.05, "relative", 20.0),
                                                 (0.05, "peak", 20.0)])
def test_fit_acceptance_64x64_pairs(tmp_path, noise, kind, min_psnr):
    """Issue acceptance at 64 x 64 light-view pairs on a 40 x 40 patch: held-out PSNR and basis axes
    within 5 degrees where sigma_x / sigma_y differ by more than 1.5x."""
    maps = synthetic_maps(40, 40, seed=12)
    wi, wo = light_view_pairs(64, 64)
    save_btf(tmp_path / "btf.npz", render_btf(maps, wi, wo, noise=noise, seed=5, noise_kind=kind), wi, wo)
    fit, _ = fit_btf(tmp_path / "btf.npz", tmp_path / "fit", tile=20, workers=2, progress=False)
    hwi, hwo = light_view_pairs(16, 16, rotation=0.9)
    p = psnr(predict_btf(fit, hwi, hwo), render_btf(maps, hwi, hwo))
    rot_t = quat_to_matrix(maps.basis.reshape(-1, 4).astype(np.float64))
    rot_f = quat_to_matrix(fit.basis.reshape(-1, 4).astype(np.float64))
    st, sf = maps.sigma.reshape(-1, 2), fit.sigma.reshape(-1, 2)
    ang = np.degrees(np.arccos(np.clip(np.abs(np.sum(small_axis(rot_t, st) * small_axis(rot_f, sf), -1)), 0, 1)))
    aniso = (st.max(1) / st.min(1)) > 1.5
    print(f"noise={noise} ({kind}): held-out PSNR {p:.2f} dB, axis error max {ang[aniso].max():.3f} deg "
          f"(median {np.median(ang[aniso]):.4f}) over {aniso.sum()} anisotropic texels")
    assert p >= min_psnr
    assert np.max(ang[aniso]) <= 5.0
