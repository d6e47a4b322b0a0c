"""The render-regression helper itself (tests/regression.py): a statistical reference passes renders that are
only other noise, fails changed ones, and writes its evidence."""

from __future__ import annotations

import numpy as np
import pytest
from regression import RegressionMismatch, check_render, compare, read_reference, statistics, write_reference

from material_structures.core.exr_io import read_exr, write_exr

H, W = 36, 48


def _noisy(seed: int, mean: np.ndarray, rel_sd: float = 0.2) -> np.ndarray:
    """A stand-in for a 4-sample render: each value mean * (1 + rel_sd * N(0, 1)), alpha exact."""
    rng = np.random.default_rng(seed)
    img = mean * (1.0 + rel_sd * rng.standard_normal(mean.shape))
    img[..., 3] = 1.0
    return img.astype(np.float32)


def _other_cpu(seed0: np.ndarray, mean: np.ndarray, cpu: int, fraction: float = 0.1, rel_sd: float = 0.2):
    """The seed-0 render on another CPU: ``fraction`` of its values took another path (a fresh sample)."""
    fresh = _noisy(10_000 + cpu, mean, rel_sd)
    moved = np.random.default_rng(20_000 + cpu).random(seed0.shape) < fraction
    return np.where(moved, fresh, seed0)


def _scene_mean() -> np.ndarray:
    y, x = np.mgrid[0:H, 0:W]
    mean = np.empty((H, W, 4))
    mean[..., 0] = 0.2 + 0.5 * x / W
    mean[..., 1] = 0.3 + 0.4 * y / H
    mean[..., 2] = 0.25
    mean[..., 3] = 1.0
    return mean


def test_reference_holds_mean_variance_seed0_and_count(tmp_path):
    mean = _scene_mean()
    renders = [_noisy(s, mean) for s in range(16)]
    write_reference("r", renders, str(tmp_path))
    m, v, k, seed0 = read_reference("r", 4, str(tmp_path))
    stack = np.stack(renders).astype(np.float64)
    assert k == 16
    np.testing.assert_allclose(m, stack.mean(axis=0), rtol=1e-6, atol=1e-7)
    np.testing.assert_allclose(v, stack.var(axis=0, ddof=1), rtol=1e-5, atol=1e-9)
    np.testing.assert_array_equal(seed0, renders[0])
    assert np.all(v[..., 3] == 0.0)


def test_other_cpus_and_other_seeds_pass_false_alarms_are_rare(tmp_path):
    """200 seed-0 renders of other CPUs (10 % of values another sample) and 200 renders with seeds the reference
    has not seen: at ALPHA = 1e-3 (0.2 false alarms expected of each if the values were Gaussian) at most 2 may
    fail; the reference CPU's own seed-0 render passes."""
    mean = _scene_mean()
    renders = [_noisy(s, mean) for s in range(16)]
    write_reference("r", renders, str(tmp_path))
    m, v, k, seed0 = read_reference("r", 4, str(tmp_path))
    assert statistics(renders[0], m, v, k, seed0)["ok"]
    fails_cpu = sum(not statistics(_other_cpu(renders[0], mean, c), m, v, k, seed0)["ok"] for c in range(200))
    fails_seed = sum(not statistics(_noisy(1000 + s, mean), m, v, k, seed0)["ok"] for s in range(200))
    assert fails_cpu <= 2, fails_cpu
    assert fails_seed <= 2, fails_seed


def test_darker_render_fails_by_its_signs(tmp_path):
    """1 % darker everywhere in 20 % noise per value: no z-test sees it (the image mean's z is about -2), the
    sign test against the seed-0 render does, on the reference's CPU and on another."""
    refs, outs = str(tmp_path / "refs"), str(tmp_path / "out")
    mean = _scene_mean()
    renders = [_noisy(s, mean) for s in range(16)]
    write_reference("x", renders, refs)
    ref = read_reference("x", 4, refs)
    for img in (renders[0], _other_cpu(renders[0], mean, 7)):
        compare("x", img, refs, outs)
        darker = img * np.array([0.99, 0.99, 0.99, 1.0], dtype=np.float32)
        st = statistics(darker, *ref)
        assert np.all(np.abs(st["z_values"]) <= st["t_values"])
        assert np.all(np.abs(st["z_tiles"]) <= st["t_tiles"])
        assert np.all(np.abs(st["z_global"]) <= st["t_global"])
        assert -4.0 < st["z_global"][0] < 0.0
        assert st["n_down"] > 0.9 * 3 * H * W and st["p_sign"] < 1e-100
        with pytest.raises(RegressionMismatch, match=r"x: 0 of 6912 values and 0 of 432 tile values .* \(0 "
                                                     r"outside\); against the seed-0 reference render \d+ values "
                                                     r"up, \d+ down \(sign test p 0,"):
            compare("x", darker, refs, outs)


def test_another_kernels_one_sided_rounding_passes_a_small_shift_fails(tmp_path):
    """Another kernel's arithmetic: 200 values 1e-4 to 1e-3 lower, 20 values another path (the SSE4.2 kernel on a
    volume render): the render passes, though the shifts go one way; the same render 0.5 % darker fails by its
    signs, and one with 300 values 0.3 % lower (a local darkening below every z-test) too."""
    refs = str(tmp_path / "refs")
    mean = _scene_mean()
    renders = [_noisy(s, mean) for s in range(16)]
    write_reference("x", renders, refs)
    ref = read_reference("x", 4, refs)
    rng = np.random.default_rng(5)
    kernel = _other_cpu(renders[0], mean, 11, fraction=20 / (H * W * 4))
    rgb = kernel[..., :3].reshape(-1)
    shifted = rng.choice(rgb.size, 200, replace=False)
    rgb[shifted] *= 1.0 - rng.uniform(1e-4, 1e-3, 200)
    kernel[..., :3] = rgb.reshape(H, W, 3)
    st = statistics(kernel, *ref)
    assert st["ok"] and st["n_up"] + st["n_down"] <= 40, (st["n_up"], st["n_down"])
    assert not statistics(kernel * np.array([0.995, 0.995, 0.995, 1.0]), *ref)["ok"]
    local = kernel.copy()
    rgb = local[..., :3].reshape(-1)
    rgb[rng.choice(rgb.size, 300, replace=False)] *= 0.997
    local[..., :3] = rgb.reshape(H, W, 3)
    st = statistics(local, *ref)
    assert np.all(np.abs(st["z_tiles"]) <= st["t_tiles"]) and not st["ok"] and st["p_sign"] < 1e-60


def test_local_change_on_another_cpu_fails_by_its_tile(tmp_path):
    """One 4 x 4 tile 10 % brighter in red (2 standard deviations per value, 5 % noise) on another CPU's render:
    its tile fails, the sign test alone would not; the failure names its evidence."""
    refs, outs = str(tmp_path / "refs"), str(tmp_path / "out")
    mean = _scene_mean()
    renders = [_noisy(s, mean, 0.05) for s in range(16)]
    write_reference("x", renders, refs)
    local = _other_cpu(renders[0], mean, 3, rel_sd=0.05)
    compare("x", local, refs, outs)
    local[8:12, 20:24, 0] *= 1.1
    st = statistics(local, *read_reference("x", 4, refs))
    assert st["p_sign"] > 1e-3
    with pytest.raises(RegressionMismatch, match=r"x: 0 of 6912 values and 1 of 432 tile values .* at tile "
                                                 r"\(2, 5\), channel 0") as info:
        compare("x", local, refs, outs)
    assert "x.new.exr" in str(info.value) and "x.z.exr" in str(info.value)
    z = read_exr(f"{outs}/x.z.exr", ["R", "G", "B", "A"])
    assert z.shape == (9, 12, 4)
    assert z[2, 5, 0] > 5.0
    np.testing.assert_array_equal(read_exr(f"{outs}/x.new.exr", ["R", "G", "B", "A"]), local)


def test_exact_reference_stays_exact(tmp_path):
    """Values equal in every reference render (emission) pass float-summation differences (1e-6 relative)
    and fail a 0.1 % change of one value."""
    refs, outs = str(tmp_path / "refs"), str(tmp_path / "out")
    img = np.random.default_rng(1).uniform(0.1, 1.0, size=(6, 5, 4)).astype(np.float32)
    write_reference("e", [img, img, img], refs)
    compare("e", img, refs, outs)
    compare("e", img * np.float32(1 + 1e-6), refs, outs)
    changed = img.copy()
    changed[2, 3, 1] *= 1.001
    with pytest.raises(RegressionMismatch, match=r"e: 1 of 120 values and 0 of 16 tile values"):
        compare("e", changed, refs, outs)


def test_missing_old_or_misshapen_reference_fails_with_instructions(tmp_path):
    with pytest.raises(RegressionMismatch, match="make refs"):
        compare("nothing", np.zeros((2, 2, 3)), str(tmp_path), str(tmp_path))
    write_exr(str(tmp_path / "old.exr"), np.zeros((2, 2, 4), dtype=np.float32))  # a single-image reference
    with pytest.raises(RegressionMismatch, match="not a statistical reference.*make refs"):
        compare("old", np.zeros((2, 2, 4)), str(tmp_path), str(tmp_path))
    write_reference("small", [np.zeros((2, 2, 4)), np.ones((2, 2, 4))], str(tmp_path))
    with pytest.raises(RegressionMismatch, match=r"shape \(3, 2, 4\) != reference \(2, 2, 4\)"):
        compare("small", np.zeros((3, 2, 4)), str(tmp_path), str(tmp_path))


def test_check_render_compares_seed_0_and_updates_from_seeds_1_to_k(tmp_path):
    refs, outs = str(tmp_path / "refs"), str(tmp_path / "out")
    mean = _scene_mean()
    seen = []

    def render(seeds):
        seen.append(seeds)
        return [_noisy(s, mean) for s in seeds]

    check_render("c", render, update=True, seeds=8, reference_dir=refs, output_dir=outs)
    assert seen == [list(range(8))]
    assert read_reference("c", 4, refs)[2] == 8
    seen.clear()
    out = check_render("c", render, update=False, reference_dir=refs, output_dir=outs)
    assert seen == [[0]]
    np.testing.assert_array_equal(out, _noisy(0, mean))
