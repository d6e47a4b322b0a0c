"""Saves of several files (a scratch set's EXR tables, a BTF folder or .npz, a fabric fit's maps) interrupted half way
leave the old files, never a mix (core/staged_write.py).

Before, a scratch generate stopped by Ctrl+C on its third of five tables left a folder that loaded without a word
with the new segments over the old grid index (180 of 16 462 segments in their own cell), and a BTF folder loaded
with half its images from the previous BTF; a BTF .npz was half written under its real name."""

from __future__ import annotations

import os

import numpy as np
import pytest

from material_structures.core import staged_write
from material_structures.core.fabric import btf_io
from material_structures.core.fabric import parameter_maps as pm
from material_structures.core.scratch import hairline_brush, load_scratch_set, save_scratch_set, scratch_io


def _interrupt_on_call(monkeypatch, module, name: str, n: int):
    """``module.name`` raises KeyboardInterrupt (Ctrl+C) on its n-th call."""
    real, calls = getattr(module, name), [0]

    def stop(*args, **kwargs):
        calls[0] += 1
        if calls[0] == n:
            raise KeyboardInterrupt
        return real(*args, **kwargs)

    monkeypatch.setattr(module, name, stop)


def _files(folder) -> dict:
    return {f: os.path.getsize(os.path.join(folder, f)) for f in sorted(os.listdir(folder))}


def _set(angle: float):
    return hairline_brush(60, (4000.0, 4000.0), angle_rad=angle, seed=3)


def _same_set(a, b) -> bool:
    return a.n_segments == b.n_segments and np.allclose(a.segments, b.segments, atol=1e-3)


def test_a_scratch_set_saved_over_another_and_interrupted_is_the_old_set(tmp_path, monkeypatch):
    folder = str(tmp_path / "tables")
    old, new = _set(0.0), _set(1.2)
    save_scratch_set(folder, old)
    before = _files(folder)
    _interrupt_on_call(monkeypatch, scratch_io, "write_exr", 3)  # Ctrl+C on the third table
    with pytest.raises(KeyboardInterrupt):
        save_scratch_set(folder, new)
    assert _files(folder) == before  # no staging folder left either
    assert _same_set(load_scratch_set(folder), old)
    monkeypatch.undo()
    save_scratch_set(folder, new)
    assert _same_set(load_scratch_set(folder), new) and sorted(os.listdir(folder)) == sorted(before)


@pytest.mark.parametrize("call", [2, 5, 8])  # while the old tables move aside, as the new ones move in, the last
def test_an_error_while_the_files_move_leaves_the_old_set(tmp_path, monkeypatch, call):
    """A move that fails (on Windows: a table open in a viewer) or an interrupt between the moves: the old tables
    come back, the error is raised (before, the key file was gone and a loadable folder was refused)."""
    folder = str(tmp_path / "tables")
    old = _set(0.0)
    save_scratch_set(folder, old)
    before = _files(folder)
    _interrupt_on_call(monkeypatch, staged_write, "_move", call)
    with pytest.raises(KeyboardInterrupt):
        save_scratch_set(folder, _set(1.2))
    monkeypatch.undo()
    assert _files(folder) == before
    assert _same_set(load_scratch_set(folder), old)


def test_a_btf_saved_over_another_and_interrupted_is_the_old_btf(tmp_path, monkeypatch):
    rng = np.random.default_rng(0)
    wi = np.tile([[0.0, 0.0, 1.0]], (16, 1))
    wo = np.tile([[0.0, 0.6, 0.8]], (16, 1))
    old, new = rng.uniform(0, 1, (16, 4, 4, 3)), rng.uniform(2, 3, (16, 4, 4, 3))
    folder = str(tmp_path / "btf")
    btf_io.save_btf(folder, old, wi, wo)
    _interrupt_on_call(monkeypatch, btf_io, "write_exr", 9)  # after 8 of the 16 images
    with pytest.raises(KeyboardInterrupt):
        btf_io.save_btf(folder, new, wi, wo)
    monkeypatch.undo()
    np.testing.assert_allclose(btf_io.load_btf(folder).values, old, rtol=1e-6)
    assert not any(f.startswith(".staging") for f in os.listdir(folder))
    npz = str(tmp_path / "btf.npz")
    btf_io.save_btf(npz, old, wi, wo)
    _interrupt_on_call(monkeypatch, btf_io.np, "savez", 1)
    with pytest.raises(KeyboardInterrupt):
        btf_io.save_btf(npz, new, wi, wo)
    monkeypatch.undo()
    np.testing.assert_allclose(btf_io.load_btf(npz).values, old, rtol=1e-6)
    assert sorted(os.listdir(tmp_path)) == ["btf", "btf.npz"]


def test_fabric_maps_saved_over_others_and_interrupted_are_the_old_maps(tmp_path, monkeypatch):
    def maps(value: float) -> pm.FabricMaps:
        h, w = 3, 4
        basis = np.zeros((h, w, 4), np.float32)
        basis[..., 0] = 1.0
        return pm.FabricMaps(kd=np.full((h, w, 3), value, np.float32), ks=np.full((h, w, 3), 0.1, np.float32),
                             sigma=np.full((h, w, 2), 0.5, np.float32), basis=basis)

    folder = str(tmp_path / "fit")
    pm.save_params(folder, maps(0.2))
    (tmp_path / "fit" / "fit_log.txt").write_text("kept")  # the fit's other files are left alone
    _interrupt_on_call(monkeypatch, pm, "write_exr", 3)
    with pytest.raises(KeyboardInterrupt):
        pm.save_params(folder, maps(0.7))
    monkeypatch.undo()
    np.testing.assert_allclose(pm.load_params(folder).kd, 0.2)
    pm.save_params(folder, maps(0.7))
    np.testing.assert_allclose(pm.load_params(folder).kd, 0.7)
    assert (tmp_path / "fit" / "fit_log.txt").read_text() == "kept"
    assert sorted(os.listdir(folder)) == ["basis.exr", "fit_log.txt", "kd.exr", "ks.exr", "params.json", "sigma.exr"]
