"""``bench fabric-fit-large`` (benchmarks/fabric.py): the banded BTF it streams is what it says it is, and a short
run gives every figure."""

from __future__ import annotations

import numpy as np
import pytest

from material_structures.benchmarks import fabric as bench
from material_structures.core.fabric.btf_io import load_btf
from material_structures.core.fabric.synthetic_btf import light_view_pairs, render_btf, synthetic_maps


def test_the_banded_btf_repeats_the_rendered_band_down_its_rows(tmp_path):
    """A 10 x 10 BTF from a 4-row band: rows 0-3, 4-7 and 8-9 are the band's rows 0-3, 0-3, 0-1, as rendered;
    np.load reads it back (a valid, uncompressed .npz)."""
    band = synthetic_maps(4, 10, seed=2)
    wi, wo = light_view_pairs(5, 4)
    path = str(tmp_path / "b.npz")
    bench._write_banded_npz(path, band, wi, wo, 10)
    got = load_btf(path)
    want = render_btf(band, wi, wo)
    assert got.values.shape == (20, 10, 10, 3)
    for y0 in (0, 4, 8):
        np.testing.assert_array_equal(got.values[:, y0:y0 + 4], want[:, : min(4, 10 - y0)])
    np.testing.assert_allclose(got.wi, wi, atol=1e-15)


@pytest.mark.slow
def test_a_short_run_gives_every_figure(monkeypatch):
    """Nightly: 32 x 32 and 64 x 64 texels from a 16-row band: both fits predict the held-out pairs (noise-free
    truth), and the figures are there."""
    monkeypatch.setenv("FABRIC_LARGE_SIZES", "32,64")
    monkeypatch.setenv("FABRIC_LARGE_BAND", "16")
    out = bench.bench_fit_large()
    assert set(out["sizes"]) == {"32", "64"} and out["texel_ratio_largest_vs_smallest"] == 4.0
    for run in out["sizes"].values():
        assert run["psnr_db_holdout_first_band"] >= 60.0 and run["seconds"] > 0 and run["peak_pss_gb"] > 0
