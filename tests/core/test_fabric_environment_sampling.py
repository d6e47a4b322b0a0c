"""The environment sampler of the fabric's exact world light (core.fabric.environment_sampling).

Checked against what it did not compute: the alias table against the probabilities it was given, the
sampled texel counts against them (chi-square), the directions against the forward equirect map,
and the Monte Carlo estimate of eq. 3.9 under an HDRI against core.fabric.closure_accuracy's
midpoint quadrature (its own texel layout, resampled by ``to_blender_equirect``).
"""

from __future__ import annotations

import numpy as np
import pytest
from scipy import stats

from material_structures.core.fabric import closure_accuracy as A
from material_structures.core.fabric.environment_sampling import (
    EnvironmentMapError,
    build_environment_table,
    downsample,
    pdf,
    sample_directions,
    shader_files,
    texel_of,
    texel_solid_angles,
)
from material_structures.core.fabric.preset_maps import tilted_quat


def _random_env(h=8, w=16, seed=0):
    rng = np.random.default_rng(seed)
    env = rng.gamma(0.5, 1.0, size=(h, w, 3)).astype(np.float32)
    env[2, 3] = 0.0  # a black texel must never be drawn
    env[5, 7] = [40.0, 30.0, 20.0]  # a hot spot
    return env


def test_alias_table_realises_the_texel_probabilities():
    env = _random_env()
    t = build_environment_table(env)
    omega = texel_solid_angles(*env.shape[:2])[:, None]
    want = env.astype(np.float64).mean(axis=2) * omega
    want /= want.sum()
    np.testing.assert_allclose(t.probabilities(), want, rtol=1e-6, atol=1e-12)
    np.testing.assert_allclose(t.density * omega, want, rtol=1e-6, atol=1e-12)
    assert texel_solid_angles(64, 128).sum() * 128 == pytest.approx(4 * np.pi, rel=1e-12)


def test_sampled_texels_follow_the_probabilities_chi_square():
    env = _random_env()
    t = build_environment_table(env)
    n = 400_000
    d, rad, p = sample_directions(t, np.random.default_rng(1).random((n, 4)))
    row, col = texel_of(t, d)
    counts = np.bincount(row * 16 + col, minlength=128)
    expect = t.probabilities().ravel() * n
    assert counts[2 * 16 + 3] == 0
    used = expect > 0
    chi2 = np.sum((counts[used] - expect[used]) ** 2 / expect[used])
    assert stats.chi2.sf(chi2, used.sum() - 1) > 1e-3, chi2
    # radiance and pdf belong to the texel the direction lies in
    np.testing.assert_array_equal(rad, t.radiance[row, col])
    np.testing.assert_allclose(p, pdf(t, d), rtol=0)


def test_estimator_of_the_environment_integral_is_unbiased():
    env = _random_env(seed=3)
    t = build_environment_table(env)
    d, rad, p = sample_directions(t, np.random.default_rng(2).random((200_000, 4)))
    est = rad / p[:, None]
    exact = (env.astype(np.float64) * texel_solid_angles(8, 16)[:, None, None]).sum(axis=(0, 1))
    se = est.std(axis=0) / np.sqrt(len(est))
    assert np.all(np.abs(est.mean(axis=0) - exact) < 4 * se + 1e-9), (est.mean(axis=0), exact, se)
    assert np.all(np.abs(np.linalg.norm(d, axis=1) - 1) < 1e-12)


@pytest.mark.parametrize("env_name", ["sky", "interior"])
def test_world_light_estimate_matches_the_quadrature_of_eq_3_9(env_name):
    """The shader's estimator (without occlusion) against closure_accuracy's quadrature of eq. 3.9
    times the environment, for a tilted surface-like and a fibre-like pile, three views."""
    env = A.sky_hdri(32, 64) if env_name == "sky" else A.interior_hdri(32, 64)
    t = build_environment_table(A.to_blender_equirect(env)[::1])  # pixel buffer layout, row 0 = bottom
    kd, ks = np.array([0.05, 0.03, 0.02]), np.array([0.7, 0.4, 0.3])
    views = np.array([[0.0, 0.0, 1.0], [0.5, -0.2, 0.84], [-0.7, 0.3, 0.65]])
    views /= np.linalg.norm(views, axis=1, keepdims=True)
    n = 200_000
    for sigma, tilt in (((0.3, 0.8), 30.0), ((2.5, 2.5), 20.0)):
        fn = A.reference_eval(kd, ks, np.asarray(sigma), tilted_quat(tilt, 40.0))
        ref = A.env_radiance(fn, views, A.env_lights(env))
        d, rad, p = sample_directions(t, np.random.default_rng(5).random((n, 4)))
        for v, wo in enumerate(views):
            x = fn(d, np.broadcast_to(wo, d.shape)) * rad / p[:, None]
            mean, se = x.mean(axis=0), x.std(axis=0) / np.sqrt(n)
            assert np.all(np.abs(mean - ref[v]) < 4 * se + 1e-3 * ref[v]), (sigma, v, mean, ref[v], se)
            assert np.all(se < 0.02 * ref[v]), se / ref[v]  # importance sampling keeps the noise low


def test_bad_environments_are_refused_in_one_line():
    env = _random_env()
    bad = env.copy()
    bad[0, 0, 1] = np.nan
    with pytest.raises(EnvironmentMapError, match="NaN"):
        build_environment_table(bad)
    bad = env.copy()
    bad[1, 1, 0] = -1.0
    with pytest.raises(EnvironmentMapError, match="negative"):
        build_environment_table(bad)
    with pytest.raises(EnvironmentMapError, match="shape"):
        build_environment_table(np.ones((4, 4)))
    assert build_environment_table(np.zeros((4, 8, 3))) is None


def test_downsampling_keeps_the_mean_and_the_files_round_trip(tmp_path):
    env = np.random.default_rng(4).random((40, 90, 3)).astype(np.float32)
    small = downsample(env, max_width=30)
    assert small.shape == (13, 30, 3)
    assert small.mean() == pytest.approx(env.mean(), rel=2e-2)
    t = build_environment_table(env, max_width=30)
    from material_structures.core.exr_io import read_exr, write_exr

    for name, arr in shader_files(t).items():
        write_exr(tmp_path / name, arr)
        back = read_exr(tmp_path / name)
        np.testing.assert_array_equal(back[..., : arr.shape[2]], arr.astype(np.float32))
    alias = read_exr(tmp_path / "alias.exr")[::-1]
    np.testing.assert_array_equal(alias[..., 1].astype(np.int64), t.alias)
