"""The BTF streamed through the fabric fit a band at a time (core/fabric/btf_bands.py)."""

from __future__ import annotations

import os

import numpy as np
import pytest

from material_structures.core.errors import UserError
from material_structures.core.fabric import btf_bands
from material_structures.core.fabric.btf_bands import fit_in_bands, write_band
from material_structures.core.fabric.btf_io import npz_stored_array


def _stored(tmp_path, values):
    np.savez(tmp_path / "b.npz", values=values, wi=np.zeros((len(values), 3)), wo=np.zeros((len(values), 3)))
    return npz_stored_array(str(tmp_path / "b.npz"), "values")


@pytest.mark.parametrize("dtype", ["<f4", ">f8"])
def test_a_band_written_texel_major_holds_the_images_rows(tmp_path, dtype, monkeypatch):
    """Rows 3:7 of 5 images of 9 x 130 texels, read 2 images at a time (a group of 2 x 4 rows) and written a band
    row at a time: the band file is the images' rows texel-major, and every tile cut from it equals the same
    texels of the images."""
    values = np.random.default_rng(3).random((5, 9, 130, 3)).astype(dtype)
    images = _stored(tmp_path, values)
    monkeypatch.setattr(btf_bands, "GROUP_BYTES", 2 * 4 * 130 * 3 * np.dtype(dtype).itemsize)
    band = write_band(images, 3, 7, "b.npz", str(tmp_path / "band0.npy"))
    rows = values[:, 3:7].astype(np.float32).transpose(1, 2, 0, 3)
    np.testing.assert_array_equal(np.load(tmp_path / "band0.npy"), rows)
    for t in ((3, 7, 0, 20), (3, 7, 120, 130), (5, 7, 60, 70)):
        want = values[:, t[0]:t[1], t[2]:t[3]].astype(np.float32).astype(np.float64).transpose(1, 2, 0, 3)
        np.testing.assert_array_equal(band.tile_values(t), want.reshape(-1, 5, 3))


def test_a_band_with_a_bad_value_or_cut_short_is_refused_by_image(tmp_path, monkeypatch):
    values = np.ones((4, 6, 5, 3), dtype=np.float32)
    values[2, 4, 1, 0] = np.nan
    images = _stored(tmp_path, values)
    monkeypatch.setattr(btf_bands, "GROUP_BYTES", 1)  # an image at a time
    band = str(tmp_path / "band.npy")
    write_band(images, 0, 4, "b.npz", band)  # the NaN is in row 4
    with pytest.raises(UserError, match=r"b.npz: values\[2\] holds non-finite values"):
        write_band(images, 3, 6, "b.npz", band)
    cut = tmp_path / "cut.npz"
    cut.write_bytes((tmp_path / "b.npz").read_bytes())
    short = type(images)(path=str(cut), offset=images.offset, dtype=images.dtype, shape=(40, 6, 5, 3))
    monkeypatch.setattr(btf_bands, "GROUP_BYTES", 1 << 20)  # one group: every image is read before any check
    with pytest.raises(UserError, match=r"cut.npz: values is truncated near image \d+"):
        write_band(short, 0, 3, "cut.npz", band)  # images past the file's end


class _Recorder:
    """A runner that finishes tiles when asked, recording which band file each tile was given and when."""

    def __init__(self):
        self.events, self.pending = [], []

    def submit(self, t, band):
        self.events.append(("submit", t, band.values.path))
        values = band.tile_values(t)
        self.pending.append((t, values))
        return t

    def wait_some(self, running):
        t, values = self.pending.pop(0)  # one at a time: the slowest order the bands allow
        self.events.append(("done", t))
        self.last = values
        return [t]

    def result(self, handle):
        return handle, 0.0, 1


def test_band_k_is_written_only_after_band_k_minus_2_is_fitted(tmp_path):
    """Five bands of one tile row (tile 2 of an 10 x 4 sample): every tile gets its own texels, band k is written
    only when every tile of band k - 2 has finished (at most two band files at a time), and the band files are gone
    at the end."""
    values = np.random.default_rng(5).random((3, 10, 4, 3)).astype(np.float32)
    images = _stored(tmp_path, values)
    todo = [(y, y + 2, x, x + 2) for y in range(0, 10, 2) for x in (0, 2)]
    runner, got = _Recorder(), {}
    cache = tmp_path / "cache"
    cache.mkdir()

    def done(result):
        got[result[0]] = runner.last

    fit_in_bands(images, "b.npz", str(cache), todo, runner, done)
    assert sorted(got) == sorted(todo)
    for t, v in got.items():
        np.testing.assert_array_equal(v, values[:, t[0]:t[1], t[2]:t[3]].transpose(1, 2, 0, 3).reshape(-1, 3, 3))
    finished = set()
    for e in runner.events:
        if e[0] == "done":
            finished.add(e[1])
        else:
            band = e[1][0] // 2
            slot_users = [t for t in todo if t[0] // 2 == band - 2]
            assert set(slot_users) <= finished, (e, finished)
            assert os.path.basename(e[2]) == f"band{band}.npy"
            assert len([f for f in os.listdir(cache) if f.startswith("band")]) <= 2
    assert os.listdir(cache) == []


@pytest.mark.heavy  # a fit of a 100 x 100 BTF stopped after its first tiles (a few seconds)
def test_sigterm_stops_a_streamed_fit_and_it_resumes(tmp_path):
    """Ctrl-C (SIGTERM) on a fit reading its BTF a band at a time in a process pool: exit 130 with one line, no
    worker left, no band file left in the cache, and the next run fits only the tiles that were missing."""
    import json
    import subprocess
    import sys

    from material_structures.core.fabric.btf_io import save_btf
    from material_structures.core.fabric.synthetic_btf import light_view_pairs, render_btf, synthetic_maps

    from ._interrupt import interrupt_when

    wi, wo = light_view_pairs(16, 16)
    save_btf(str(tmp_path / "b.npz"), render_btf(synthetic_maps(60, 60, seed=1), wi, wo), wi, wo)
    out = tmp_path / "fit"
    argv = [sys.executable, "-m", "material_structures", "fabric", "fit", str(tmp_path / "b.npz"), "--out", str(out),
            "--tile", "6", "--workers", "2", "--no-dask", "--no-progress"]
    proc = subprocess.Popen(argv, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    tiles = out / ".fit_cache" / "tiles"
    interrupt_when(proc, lambda: tiles.is_dir() and len(list(tiles.glob("tile_*.npz"))) >= 3, 120)
    kept = len(list(tiles.glob("tile_*.npz")))
    assert 3 <= kept < 100
    assert not list((out / ".fit_cache").glob("band*"))
    r = subprocess.run(argv, capture_output=True, text=True, timeout=600)
    assert r.returncode == 0, r.stderr[-2000:]
    assert json.loads(r.stdout)["tiles_fitted_this_run"] == 100 - kept


def test_a_band_for_workers_on_other_machines_is_synced_to_storage(tmp_path, monkeypatch):
    """``durable`` (a cluster this fit did not start): the band file is fsync'ed before its tiles go out; a fit on
    this machine's workers (they read the page cache) does not wait for the disk."""
    images = _stored(tmp_path, np.ones((3, 4, 4, 3), dtype=np.float32))
    synced = []
    monkeypatch.setattr(btf_bands.os, "fsync", lambda fd: synced.append(fd))
    write_band(images, 0, 2, "b.npz", str(tmp_path / "local.npy"))
    assert synced == []
    write_band(images, 0, 2, "b.npz", str(tmp_path / "shared.npy"), durable=True)
    assert len(synced) == 1
