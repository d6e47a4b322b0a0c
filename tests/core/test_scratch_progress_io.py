"""Scratch generation reports its progress; scratch-set files refuse what they cannot read or write
with one clear line (issue: an artist never loses work; scratched-metal items 10d, 10e, 10h)."""

from __future__ import annotations

import hashlib
import os

import numpy as np
import pytest

from material_structures.core.scratch import scratch_set as S
from material_structures.core.scratch.scratch_generators import circular_polish, hairline_brush, uniform_wear
from material_structures.core.scratch.scratch_io import load_scratch_set, save_scratch_set, save_scratch_set_exr

pytestmark = pytest.mark.heavy  # seconds each: outside `make test-fast`


def _digest(s) -> str:
    h = hashlib.sha1()
    for a in (s.segments, s.width_um, s.scratch_id, s.grid_offset, s.grid_count, s.cell_segments):
        h.update(np.ascontiguousarray(a).tobytes())
    return h.hexdigest()


def test_progress_callback_rises_to_one_for_10k_scratches():
    calls: list[float] = []
    s = uniform_wear(10_000, (20000.0, 20000.0), seed=4, progress=calls.append)
    assert s.n_scratches >= 9_900
    assert len(calls) >= 20, calls  # a bar that moves, not one jump
    assert all(0.0 <= f <= 1.0 for f in calls)
    assert all(b > a for a, b in zip(calls, calls[1:], strict=False)), "fractions must increase"
    assert calls[-1] == 1.0
    assert calls[len(calls) // 2] < 0.9  # spread over the run, not all reported at the end


@pytest.mark.parametrize("gen", [circular_polish, hairline_brush])
def test_other_generators_report_progress_too(gen):
    calls: list[float] = []
    gen(300, (5000.0, 5000.0), seed=1, progress=calls.append)
    assert len(calls) >= 5 and calls[-1] == 1.0
    assert all(b > a for a, b in zip(calls, calls[1:], strict=False))


def test_progress_changes_nothing_in_the_set():
    """The grid built in chunks (with progress) is exactly the one built in one pass."""
    a = uniform_wear(1500, (8000.0, 8000.0), seed=2)
    seg, ps = a.segments, a.patch_size_um
    one = S.build_grid_index(seg, ps, a.cell_size_um, a.query_radius_um)
    calls: list[float] = []
    chunked = S.build_grid_index(seg, ps, a.cell_size_um, a.query_radius_um, progress=calls.append,
                                 chunk_candidates=500)
    for x, y in zip(one, chunked, strict=True):
        np.testing.assert_array_equal(x, y)
    assert len(calls) > 10 and calls[-1] == 1.0
    b = uniform_wear(1500, (8000.0, 8000.0), seed=2, progress=lambda f: None)
    assert _digest(a) == _digest(b)


def test_too_many_grid_entries_are_refused_before_the_grid_is_built(monkeypatch):
    monkeypatch.setattr(S, "MAX_TABLE_INDEX", 20_000)
    calls: list[float] = []
    with pytest.raises(ValueError, match="too many"):
        uniform_wear(4000, (20000.0, 20000.0), seed=1, progress=calls.append)
    assert calls and calls[-1] < 0.9, "the refusal came only after all the work"


def test_load_refuses_files_that_are_not_npz(tmp_path):
    s = uniform_wear(30, (3000.0, 3000.0), seed=8)
    save_scratch_set_exr(tmp_path / "tables", s)
    (tmp_path / "notes.txt").write_text("hello")
    (tmp_path / "junk.npz").write_bytes(b"\x80\x04not a zip at all")
    for bad in (tmp_path / "tables" / "segments.exr", tmp_path / "notes.txt", tmp_path / "junk.npz"):
        with pytest.raises(ValueError) as info:
            load_scratch_set(bad)
        msg = str(info.value)
        assert "pickle" not in msg.lower(), msg
        assert "\n" not in msg and ".npz" in msg, msg
    with pytest.raises(ValueError, match="EXR-table folder"):
        load_scratch_set(tmp_path / "tables" / "segments.exr")
    assert load_scratch_set(tmp_path / "tables").n_segments == s.n_segments


def test_save_refuses_paths_with_another_extension(tmp_path):
    s = uniform_wear(30, (3000.0, 3000.0), seed=8)
    for name in ("set.exr", "set.EXR", "set.png", "set.npy"):
        with pytest.raises(ValueError, match="extension"):
            save_scratch_set(tmp_path / name, s)
        assert not os.path.exists(tmp_path / name), f"{name}: something was written"
    save_scratch_set(tmp_path / "set.npz", s)
    save_scratch_set(tmp_path / "tables", s)
    assert os.path.isfile(tmp_path / "set.npz") and os.path.isfile(tmp_path / "tables" / "meta.exr")
    assert load_scratch_set(tmp_path / "tables").n_segments == s.n_segments
