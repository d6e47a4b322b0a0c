"""Scratch-set files: ``.npz`` (one file) and float EXR tables (a folder) for the OSL shader.

NPZ (``save_scratch_set_npz`` / ``load_scratch_set``), format ``material_structures.scratch_set``
version 1, arrays:

    format (str), version (int), segments (M, 4) float64 x0 y0 x1 y1 [um], width_um (M,),
    depth_um (M,), profile (M,) int (0 = rectangular), scratch_id (M,) int, patch_size_um (2,),
    sigma_um, cell_size_um, query_radius_um (scalars), grid_offset (ny, nx) int,
    grid_count (ny, nx) int, cell_segments (K,) int

EXR tables (``save_scratch_set_exr`` / ``load_scratch_set``), a folder of 32-bit float EXRs laid out
for closest-texel ``texture()`` lookups. Row 0 is the first scanline (top; OIIO t = 0). Integers are
stored exactly as floats (limit 2^24 entries). Long 1D tables are wrapped into rows of
TABLE_WIDTH = 1024 texels: entry i lives at column i % 1024, row i // 1024, i.e. at texture
coordinates s = (i % 1024 + 0.5) / 1024, t = (i // 1024 + 0.5) / rows.

    segments.exr       RGBA  = x0, y0, x1, y1 (um)                    1024 x ceil(M / 1024)
    segment_params.exr RGBA  = width_um, depth_um, profile, scratch_id 1024 x ceil(M / 1024)
    grid.exr           R, G  = offset, count into cell_segments       nx x ny; cell (ix, iy) at
                                                                       column ix, row iy
    cell_segments.exr  Y     = segment index                          1024 x ceil(K / 1024)
    meta.exr           Y     = 16 floats in one row: version, Px, Py, nx, ny, cell_size_um,
                               query_radius_um, sigma_um, M, K, TABLE_WIDTH, 0...

Unused texels at the end of a wrapped table are -1 (segments: zero). Shader walk for a point
(x, y) um: ix = floor(x / cell), iy = floor(y / cell); (offset, count) = grid[ix, iy];
for j in 0..count-1: m = cell_segments[offset + j]; fetch segments[m] and segment_params[m].
"""

from __future__ import annotations

import os
import zipfile
import zlib

import numpy as np

from ..errors import MissingFileError, UserError
from ..exr_io import ExrError, read_exr, write_exr
from ..staged_write import staged_files
from .scratch_set import ScratchSet, validate_scratch_set

FORMAT = "material_structures.scratch_set"
VERSION = 1
TABLE_WIDTH = 1024
EXR_FILES = ("segments.exr", "segment_params.exr", "grid.exr", "cell_segments.exr", "meta.exr")
_NPZ_KEYS = (
    "segments", "width_um", "depth_um", "profile", "scratch_id", "patch_size_um", "sigma_um",
    "cell_size_um", "query_radius_um", "grid_offset", "grid_count", "cell_segments",
)


def save_scratch_set_npz(path: str | os.PathLike, s: ScratchSet) -> None:
    """Write the set as one ``.npz`` (layout in the module docstring)."""
    validate_scratch_set(s)
    path = os.fspath(path)
    tmp = f"{path}.tmp-{os.getpid()}"
    try:
        with open(tmp, "wb") as f:  # a file object: numpy appends no second ".npz" (e.g. to "set.NPZ")
            np.savez_compressed(
                f, format=FORMAT, version=VERSION, **{k: np.asarray(getattr(s, k)) for k in _NPZ_KEYS}
            )
        os.replace(tmp, path)  # never a half-written file under the real name
    finally:
        if os.path.exists(tmp):
            os.remove(tmp)


def _array(path: str, z, name: str) -> np.ndarray:
    """Array ``name`` of the .npz ``z``; one that cannot be read (Python objects, a damaged member) is refused."""
    try:
        return z[name]
    except (ValueError, OSError, EOFError, zipfile.BadZipFile, zlib.error) as exc:
        raise UserError(f"{path}: field {name!r} cannot be read ({type(exc).__name__}: {exc})") from None


def _field(path: str, name: str, z, dtype, scalar: bool = False):
    """Array ``name`` of the .npz ``z`` as ``dtype`` (a Python number with ``scalar``); an array of another
    kind (text, booleans, complex numbers, several values for one) is refused naming the file and the field."""
    a = _array(path, z, name)
    kinds = "iuf" if dtype is np.float64 else "iu"
    if a.dtype.kind == "f" and dtype is np.int64 and np.all(np.isfinite(a)) and np.all(a == np.round(a)):
        kinds += "f"  # whole numbers stored as floats
    if a.dtype.kind not in kinds:
        want = "numbers" if dtype is np.float64 else "integers"
        raise UserError(f"{path}: field {name!r} holds {a.dtype} values, expected {want}")
    if scalar:
        if a.size != 1:
            raise UserError(f"{path}: field {name!r} holds {a.size} values, expected one")
        return float(a.reshape(())) if dtype is np.float64 else int(a.reshape(()))
    return a.astype(dtype)


def _load_npz(path: str) -> ScratchSet:
    with open(path, "rb") as f:
        magic = f.read(4)
    if magic != b"PK\x03\x04":  # every .npz is a zip archive; np.load would try other formats
        raise UserError(f"{path}: not a readable .npz file (not a zip archive)")
    try:
        z = np.load(path, allow_pickle=False)
    except Exception as exc:
        first = (str(exc).splitlines() or [type(exc).__name__])[0]
        raise UserError(f"{path}: not a readable .npz file ({first})") from exc
    with z:
        tag = _array(path, z, "format") if "format" in z.files else None
        if tag is None or tag.dtype.kind not in "US" or str(tag) != FORMAT:
            raise UserError(f"{path}: not a scratch-set file (missing format tag {FORMAT!r})")
        version = _field(path, "version", z, np.int64, scalar=True) if "version" in z.files else None
        if version != VERSION:
            raise UserError(f"{path}: unsupported scratch-set version {version} (need {VERSION})")
        missing = [k for k in _NPZ_KEYS if k not in z.files]
        if missing:
            raise UserError(f"{path}: scratch-set file lacks array(s) {missing}")
        f, i = np.float64, np.int64
        s = ScratchSet(
            segments=_field(path, "segments", z, f),
            width_um=_field(path, "width_um", z, f),
            depth_um=_field(path, "depth_um", z, f),
            profile=_field(path, "profile", z, i),
            scratch_id=_field(path, "scratch_id", z, i),
            patch_size_um=_field(path, "patch_size_um", z, f),
            sigma_um=_field(path, "sigma_um", z, f, scalar=True),
            cell_size_um=_field(path, "cell_size_um", z, f, scalar=True),
            query_radius_um=_field(path, "query_radius_um", z, f, scalar=True),
            grid_offset=_field(path, "grid_offset", z, i),
            grid_count=_field(path, "grid_count", z, i),
            cell_segments=_field(path, "cell_segments", z, i),
        )
    try:
        validate_scratch_set(s)
    except ValueError as exc:
        raise UserError(f"{path}: {exc}") from exc
    return s


def wrap_table(table: np.ndarray, fill: float) -> np.ndarray:
    """(n, C) -> float32 (rows, TABLE_WIDTH, C) with entry i at (i // W, i % W); unused texels ``fill``."""
    n, c = table.shape
    rows = max(1, -(-n // TABLE_WIDTH))
    out = np.full((rows * TABLE_WIDTH, c), fill, dtype=np.float32)
    out[:n] = table
    return out.reshape(rows, TABLE_WIDTH, c)


def scratch_set_tables(s: ScratchSet) -> dict[str, np.ndarray]:
    """The four EXR tables of ``s`` as float32 (H, W, C) arrays, row 0 = top: "segments", "params", "grid",
    "cells" (the files ``segments.exr``, ``segment_params.exr``, ``grid.exr``, ``cell_segments.exr``)."""
    params = np.stack([s.width_um, s.depth_um, s.profile, s.scratch_id], 1)
    return {
        "segments": wrap_table(np.asarray(s.segments, np.float64), 0.0),
        "params": wrap_table(params.astype(np.float64), -1.0),
        "grid": np.stack([s.grid_offset, s.grid_count], -1).astype(np.float32),
        "cells": wrap_table(np.asarray(s.cell_segments, np.float64)[:, None], -1.0),
    }


def _unwrap(img: np.ndarray, n: int, name: str) -> np.ndarray:
    if img.shape[1] != TABLE_WIDTH or img.shape[0] * TABLE_WIDTH < n:
        raise UserError(f"{name}: expected a {TABLE_WIDTH}-wide table holding {n} entries, got {img.shape[:2]}")
    return img.reshape(-1, img.shape[2])[:n].astype(np.float64)


def save_scratch_set_exr(folder: str | os.PathLike, s: ScratchSet) -> list[str]:
    """Write the EXR tables into ``folder`` (created); returns the written paths."""
    validate_scratch_set(s)
    folder = os.fspath(folder)
    os.makedirs(folder, exist_ok=True)
    m, k = s.n_segments, int(s.cell_segments.size)
    ny, nx = s.grid_shape
    meta = np.zeros((1, 16, 1), np.float32)
    meta[0, :11, 0] = [
        VERSION, s.patch_size_um[0], s.patch_size_um[1], nx, ny, s.cell_size_um, s.query_radius_um,
        s.sigma_um, m, k, TABLE_WIDTH,
    ]
    tables = scratch_set_tables(s)
    with staged_files(folder, "meta.exr") as stage:  # all five or a folder without meta.exr: never a mix
        staged = [os.path.join(stage, f) for f in EXR_FILES]
        write_exr(staged[0], tables["segments"], ("R", "G", "B", "A"))
        write_exr(staged[1], tables["params"], ("R", "G", "B", "A"))
        write_exr(staged[2], tables["grid"], ("R", "G"))
        write_exr(staged[3], tables["cells"], ("Y",))
        write_exr(staged[4], meta, ("Y",))
    return [os.path.join(folder, f) for f in EXR_FILES]


def _load_exr_folder(folder: str) -> ScratchSet:
    for f in EXR_FILES:
        if not os.path.isfile(os.path.join(folder, f)):
            raise MissingFileError(f"{folder}: scratch-set EXR folder lacks {f} (needs {', '.join(EXR_FILES)})",
                                   os.path.join(folder, f))
    try:
        meta = read_exr(os.path.join(folder, "meta.exr"), ["Y"])[0, :, 0].astype(np.float64)
        if meta.size < 11 or int(meta[0]) != VERSION:
            raise UserError(f"{folder}/meta.exr: unsupported version {meta[0] if meta.size else '?'}")
        if int(meta[10]) != TABLE_WIDTH:
            raise UserError(f"{folder}/meta.exr: table width {int(meta[10])}, expected {TABLE_WIDTH}")
        m, k = int(meta[8]), int(meta[9])
        nx, ny = int(meta[3]), int(meta[4])
        seg = _unwrap(read_exr(os.path.join(folder, "segments.exr"), ["R", "G", "B", "A"]), m, "segments.exr")
        par = _unwrap(
            read_exr(os.path.join(folder, "segment_params.exr"), ["R", "G", "B", "A"]), m, "segment_params.exr"
        )
        grid = read_exr(os.path.join(folder, "grid.exr"), ["R", "G"]).astype(np.float64)
        if grid.shape[:2] != (ny, nx):
            raise UserError(f"{folder}/grid.exr: shape {grid.shape[:2]} but meta says (ny, nx) = {(ny, nx)}")
        cs = _unwrap(read_exr(os.path.join(folder, "cell_segments.exr"), ["Y"]), k, "cell_segments.exr")[:, 0]
    except ExrError as exc:
        raise UserError(str(exc)) from exc
    for name, a in (("segment_params", par[:, 2:]), ("grid", grid), ("cell_segments", cs)):
        if np.any(a != np.round(a)):
            raise UserError(f"{folder}: {name} holds non-integer indices")
    s = ScratchSet(
        segments=seg,
        width_um=par[:, 0],
        depth_um=par[:, 1],
        profile=par[:, 2].astype(np.int64),
        scratch_id=par[:, 3].astype(np.int64),
        patch_size_um=meta[1:3].copy(),
        sigma_um=float(meta[7]),
        cell_size_um=float(meta[5]),
        query_radius_um=float(meta[6]),
        grid_offset=grid[..., 0].astype(np.int64),
        grid_count=grid[..., 1].astype(np.int64),
        cell_segments=cs.astype(np.int64),
    )
    try:
        validate_scratch_set(s)
    except ValueError as exc:
        raise UserError(f"{folder}: {exc}") from exc
    return s


def load_scratch_set(path: str | os.PathLike) -> ScratchSet:
    """Load a ``.npz`` file or an EXR-table folder; raises FileNotFoundError/ValueError with the reason
    (one line; any file that is not ``.npz`` is refused, a table inside a folder included: pass the folder)."""
    path = os.fspath(path)
    if os.path.isdir(path):
        return _load_exr_folder(path)
    if not os.path.exists(path):
        raise MissingFileError(f"scratch set not found: {path}", path)
    if not path.lower().endswith(".npz"):
        inside = os.path.basename(path) in EXR_FILES
        hint = " (a table of an EXR-table folder: import the folder)" if inside else ""
        raise UserError(f"{path}: not a scratch set: expected a .npz file or an EXR-table folder{hint}")
    return _load_npz(path)


def save_scratch_set(path: str | os.PathLike, s: ScratchSet) -> None:
    """``.npz`` path -> one file; a path without an extension (or an existing folder) -> EXR-table folder.

    Any other extension (``.exr``, ``.png``, ...) is refused with a ValueError before anything is
    written: it would silently become a folder."""
    path = os.fspath(path)
    kind = save_kind(path)
    if kind == "npz":
        save_scratch_set_npz(path, s)
    elif kind == "folder":
        save_scratch_set_exr(path, s)
    else:
        raise UserError(f"{path}: cannot write a scratch set to a '{kind}' file: use a .npz file, or a folder "
                        "path without an extension for EXR tables")


def save_kind(path: str | os.PathLike) -> str:
    """What :func:`save_scratch_set` makes of ``path``: ``"npz"``, ``"folder"`` or the refused extension."""
    path = os.fspath(path)
    if os.path.isdir(path) or path.endswith(("/", os.sep)):
        return "folder"
    ext = os.path.splitext(path)[1]
    if ext.lower() == ".npz":
        return "npz"
    return "folder" if ext == "" else ext
