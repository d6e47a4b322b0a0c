"""Scratch sets: generators, grid index completeness, npz/EXR round trips, malformed files."""

from __future__ import annotations

import os

import numpy as np
import pytest

from material_structures.core.exr_io import read_exr, write_exr
from material_structures.core.scratch import (
    circular_polish,
    from_curves,
    hairline_brush,
    load_scratch_set,
    make_scratch_set,
    save_scratch_set,
    uniform_wear,
)
from material_structures.core.scratch.scratch_io import TABLE_WIDTH
from material_structures.core.scratch.scratch_set import point_segment_distance


@pytest.mark.parametrize(
    "make",
    [
        lambda: uniform_wear(300, (8000.0, 6000.0), seed=1, boundary="clip"),
        lambda: uniform_wear(300, (8000.0, 6000.0), seed=1),
        lambda: circular_polish(200, (8000.0, 6000.0), seed=2),
        lambda: circular_polish(200, (8000.0, 6000.0), seed=2, centres=5, boundary="wrap"),
        lambda: hairline_brush(100, (8000.0, 6000.0), angle_rad=0.3, seed=3),
    ],
)
def test_generators_respect_patch_and_thesis_ranges(make):
    s = make()
    s.validate()
    seg = s.segments
    assert s.n_segments > 100
    mid = 0.5 * (seg[:, :2] + seg[:, 2:])
    assert np.all(mid >= 0) and np.all(mid < (8000.0, 6000.0))
    # clipped: inside the patch; wrapped: midpoints inside, ends at most half a segment (250 um) out
    slack = 125.0 + 1e-9 if np.any(seg < -1e-9) else 1e-9
    assert np.all(seg[:, [0, 2]] >= -slack) and np.all(seg[:, [0, 2]] <= 8000 + slack)
    assert np.all(seg[:, [1, 3]] >= -slack) and np.all(seg[:, [1, 3]] <= 6000 + slack)
    for a in (s.width_um, s.depth_um):
        assert a.min() >= 0.8 and a.max() <= 6.0
    # width and depth are constant along a scratch
    for sid in np.unique(s.scratch_id)[:20]:
        m = s.scratch_id == sid
        assert np.ptp(s.width_um[m]) == 0 and np.ptp(s.depth_um[m]) == 0


def test_hairline_brushing_is_parallel():
    s = hairline_brush(50, (5000.0, 5000.0), angle_rad=0.4, jitter_rad=0.005, waviness_um=0.0, seed=0)
    d = s.segments[:, 2:] - s.segments[:, :2]
    ang = np.mod(np.arctan2(d[:, 1], d[:, 0]), np.pi)
    assert np.all(np.abs(ang - 0.4) < 0.03)


def test_circular_polish_is_concentric():
    s = circular_polish(60, (10000.0, 10000.0), radius_um=(1000.0, 4000.0), seed=0)
    c = np.array([5000.0, 5000.0])
    r0 = np.linalg.norm(s.segments[:, :2] - c, axis=1)
    r1 = np.linalg.norm(s.segments[:, 2:] - c, axis=1)
    assert np.all(np.abs(r0 - r1) < 1e-6 * r0 + 1e-6)  # chords of circles around the centre
    assert r0.min() >= 1000 * np.cos(0.5) - 1 and r0.max() <= 4000 + 1


def test_from_curves_uv_and_validation():
    curves = [[(0.1, 0.1), (0.5, 0.2), (0.9, 0.8)], [(0.2, 0.9), (0.8, 0.9)]]
    s = from_curves(curves, (4000.0, 4000.0), width_um=2.0, depth_um=[1.0, 3.0], uv=True, segment_um=100)
    total = np.linalg.norm(s.segments[:, 2:] - s.segments[:, :2], axis=1).sum()
    ref = 4000 * (np.hypot(0.4, 0.1) + np.hypot(0.4, 0.6) + 0.6)
    assert abs(total - ref) < 1e-6 * ref
    assert np.all(s.width_um == 2.0) and set(np.unique(s.depth_um)) == {1.0, 3.0}
    with pytest.raises(ValueError, match="at least two points"):
        from_curves([[(0.1, 0.1)]], (4000.0, 4000.0), uv=True)
    with pytest.raises(ValueError, match="one value per curve"):
        from_curves(curves, (4000.0, 4000.0), width_um=[1.0, 2.0, 3.0], uv=True)


def test_grid_index_lists_every_segment_within_the_query_radius():
    s = uniform_wear(400, (6000.0, 6000.0), seed=5, max_footprint_um=150.0)
    rng = np.random.default_rng(0)
    pts = rng.uniform(0, 6000, (300, 2))
    ny, nx = s.grid_shape
    for p in pts:
        ix, iy = int(p[0] // s.cell_size_um), int(p[1] // s.cell_size_um)
        listed = set(s.cell_segments[s.grid_offset[iy, ix] : s.grid_offset[iy, ix] + s.grid_count[iy, ix]].tolist())
        near = np.flatnonzero(point_segment_distance(p, s.segments[:, :2], s.segments[:, 2:]) <= s.query_radius_um)
        assert set(near.tolist()) <= listed


def test_npz_and_exr_round_trip(tmp_path):
    s = uniform_wear(150, (5000.0, 4000.0), seed=7)
    save_scratch_set(tmp_path / "set.npz", s)
    a = load_scratch_set(tmp_path / "set.npz")
    save_scratch_set(tmp_path / "tables", s)
    b = load_scratch_set(tmp_path / "tables")
    for t in (a, b):
        assert np.allclose(t.segments, s.segments, atol=2e-3)  # float32 tables: ~1e-3 um
        assert np.array_equal(t.cell_segments, s.cell_segments)
        assert np.array_equal(t.grid_offset, s.grid_offset) and np.array_equal(t.grid_count, s.grid_count)
        assert np.allclose(t.width_um, s.width_um, rtol=1e-6) and np.array_equal(t.scratch_id, s.scratch_id)
        assert np.allclose(t.patch_size_um, s.patch_size_um) and t.sigma_um == s.sigma_um
    # layout: segment i at row i // 1024, column i % 1024 (closest-texel lookups)
    img = read_exr(tmp_path / "tables" / "segments.exr", ["R", "G", "B", "A"])
    i = s.n_segments - 1
    assert img.shape[1] == TABLE_WIDTH
    assert np.allclose(img[i // TABLE_WIDTH, i % TABLE_WIDTH], s.segments[i], atol=2e-3)
    grid = read_exr(tmp_path / "tables" / "grid.exr", ["R", "G"])
    assert grid.shape[:2] == s.grid_shape and np.array_equal(grid[..., 1], s.grid_count)


def test_malformed_files_give_clear_errors(tmp_path):
    s = uniform_wear(50, (3000.0, 3000.0), seed=8)
    with pytest.raises(FileNotFoundError, match="not found"):
        load_scratch_set(tmp_path / "missing.npz")
    (tmp_path / "junk.npz").write_bytes(b"not a zip")
    with pytest.raises(ValueError, match="not a readable"):
        load_scratch_set(tmp_path / "junk.npz")
    np.savez(tmp_path / "other.npz", a=np.zeros(3))
    with pytest.raises(ValueError, match="not a scratch-set file"):
        load_scratch_set(tmp_path / "other.npz")
    save_scratch_set(tmp_path / "ok.npz", s)
    d = dict(np.load(tmp_path / "ok.npz"))
    d["grid_count"] = d["grid_count"] + 10**6
    np.savez(tmp_path / "bad_grid.npz", **d)
    with pytest.raises(ValueError, match="outside the cell-segment list"):
        load_scratch_set(tmp_path / "bad_grid.npz")
    d = dict(np.load(tmp_path / "ok.npz"))
    d["width_um"] = -d["width_um"]
    np.savez(tmp_path / "bad_w.npz", **d)
    with pytest.raises(ValueError, match="widths must be"):
        load_scratch_set(tmp_path / "bad_w.npz")
    d = dict(np.load(tmp_path / "ok.npz"))
    d["profile"] = d["profile"] + 7
    np.savez(tmp_path / "bad_p.npz", **d)
    with pytest.raises(ValueError, match="unknown scratch profile"):
        load_scratch_set(tmp_path / "bad_p.npz")
    folder = tmp_path / "tables"
    save_scratch_set(folder, s)
    os.remove(folder / "grid.exr")
    with pytest.raises(FileNotFoundError, match="lacks grid.exr"):
        load_scratch_set(folder)
    save_scratch_set(folder, s)
    write_exr(folder / "cell_segments.exr", np.full((1, TABLE_WIDTH, 1), 0.5, np.float32), ("Y",))
    with pytest.raises(ValueError, match="cell_segments"):
        load_scratch_set(folder)
    save_scratch_set(folder, s)
    write_exr(folder / "segments.exr", np.zeros((1, 8, 3), np.float32), ("R", "G", "B"))
    with pytest.raises(ValueError, match="missing channel"):
        load_scratch_set(folder)
    with pytest.raises(ValueError, match="shape \\(M, 4\\)"):
        make_scratch_set(np.zeros((3, 3)), 1.0, 1.0, (100.0, 100.0))


@pytest.mark.parametrize("radius", [12.5, 37.0, 260.0])
def test_grid_index_is_the_exact_segment_square_test_of_every_pair(radius):
    """The index (cells decided by their centres where that settles it) lists exactly the segments whose exact
    distance to the cell's square is within the query radius, tested here for every (segment, cell) pair:
    short and long segments, axis-parallel ones, and segments ending on cell corners. (A cell exactly at the
    radius, a tie, can be left out: its candidate box stops there.)"""
    from material_structures.core.scratch.scratch_set import build_grid_index, segment_rect_distance

    rng = np.random.default_rng(4)
    p0 = rng.uniform(0, 3000, (300, 2))
    p1 = p0 + rng.normal(0, 400, (300, 2)) * rng.uniform(0.01, 1.0, (300, 1))
    p1[:20, 1] = p0[:20, 1]  # horizontal
    p1[20:40, 0] = p0[20:40, 0]  # vertical
    p0[40:60] = np.round(p0[40:60] / 100.0) * 100.0  # on cell corners
    seg = np.concatenate([p0, p1], 1)
    c = 100.0
    off, cnt, cells = build_grid_index(seg, (3000.0, 3000.0), c, radius, periodic=False, chunk_candidates=5000)
    iy, ix = np.divmod(np.arange(30 * 30), 30)
    for k in range(30 * 30):
        exact = np.flatnonzero(segment_rect_distance(seg, np.full(300, ix[k] * c), np.full(300, iy[k] * c), c)
                               <= radius)
        listed = cells[off.flat[k]: off.flat[k] + cnt.flat[k]]
        np.testing.assert_array_equal(listed, exact)
