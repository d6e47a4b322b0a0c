"""Scratch sets in a .blend: packed float images (source of truth) + an EXR cache for OSL.

OSL ``texture()`` needs a file path, and packed images have none. So a scratch set lives in the
.blend as four packed, float, Non-Color images laid out exactly like the EXR tables of
``core/scratch/scratch_io.py`` (row 0 = top; 1024-wide wrapped tables)::

    "MS Scratch <name> segments"   RGBA x0, y0, x1, y1 (um)
    "MS Scratch <name> params"     RGBA width, depth, profile, scratch id
    "MS Scratch <name> grid"       R, G offset, count (nx x ny)
    "MS Scratch <name> cells"      R    segment index

plus the scalars (patch size, sigma, cell size, query radius, M, K) in an ID property (``PROP``)
of the set's node group, and the four images themselves in a second one (``IMAGES_PROP``: ID
pointers, which follow renames and come along when the material is appended). The images belong to
that one group: a set is never found by its name, except in files from before ``IMAGES_PROP`` (the
images named after ``meta["name"]``). Before rendering (render_pre, load_post, and whenever a
material is built) the tables are extracted with ``core.scratch.scratch_io.save_scratch_set_exr``
(plus two derived cell-major tables, :func:`write_cell_major_tables`) into a content-addressed cache
folder ``<tempdir>/material_structures_scratch-<user>/<sha1>/``: identical content -> identical path, so
OpenImageIO's texture cache can never serve stale tables, and a reopened file re-extracts what it
needs (folders unused for two weeks are removed). The shader reads the folder from its ``TableDir`` input.
"""

from __future__ import annotations

import hashlib
import os

import numpy as np

from ...core.errors import UserError
from ...core.scratch.scratch_io import save_scratch_set_exr, scratch_set_tables, wrap_table
from ...core.scratch.scratch_set import ScratchSet, validate_scratch_set
from ..common import array_to_image, image_to_array, mark_written, prune_cache, user_cache_root

IMAGE_PREFIX = "MS Scratch"
TABLES = {"segments": 4, "params": 4, "grid": 2, "cells": 1}
PROP = "ms_scratch_set"  # ID property (dict) on a set's node group: the set's scalars and name
IMAGES_PROP = "ms_scratch_images"  # ID property on the group: {table: Image} (files from before: absent)


def set_meta(s: ScratchSet, name: str) -> dict:
    ny, nx = s.grid_shape
    return {
        "name": name,
        "patch_size_um": [float(v) for v in s.patch_size_um],
        "sigma_um": float(s.sigma_um),
        "cell_size_um": float(s.cell_size_um),
        "query_radius_um": float(s.query_radius_um),
        "n_segments": int(s.n_segments),
        "n_cells_entries": int(s.cell_segments.size),
        "grid_nx": int(nx),
        "grid_ny": int(ny),
    }


def release_table_images() -> int:
    """Files from before kept every table image with a fake user, also after its material and group were gone
    (12 MB for a 3 000-scratch set, in every save): their group keeps them now, and a purge or a save removes those
    of a deleted set. Returns how many it released."""
    import bpy

    n = 0
    for img in bpy.data.images:
        if (img.library is None and img.use_fake_user and img.packed_file is not None
                and img.name.startswith(IMAGE_PREFIX + " ")):
            img.use_fake_user = False
            n += 1
    return n


def image_name(name: str, table: str) -> str:
    return f"{IMAGE_PREFIX} {name} {table}"


def _rewrite_image(image, arr: np.ndarray) -> None:
    """Overwrite a same-sized float image's pixels with ``arr`` (H, W, C), row 0 = top, and repack it."""
    h, w, c = arr.shape
    rgba = np.zeros((h, w, 4), dtype=np.float32)
    rgba[..., 3] = 1.0
    rgba[..., :c] = arr
    image.pixels.foreach_set(rgba[::-1].ravel())
    image.update()
    image.pack()
    mark_written(image)  # Blender's undo restores the packed data; the undo handler reloads the pixels


def store_scratch_set(s: ScratchSet, name: str, images: dict | None = None) -> tuple[dict, dict]:
    """Pack ``s`` into ``images`` ({table: Image}, the set's own images: rewritten in place where the
    size allows, else replaced) or, for a new set, into new images named after ``name`` (Blender makes
    a taken name unique). Returns (metadata dict, {table: Image})."""
    import bpy

    validate_scratch_set(s)
    out = {}
    for table, arr in scratch_set_tables(s).items():
        img = (images or {}).get(table)
        h, w = arr.shape[:2]
        if img is not None and tuple(img.size) == (w, h) and img.is_float:
            _rewrite_image(img, arr)
        else:
            if img is not None:
                bpy.data.images.remove(img)  # this set's own old table, another size
            img = array_to_image(arr, image_name(name, table), pack=True, replace=False)
        img.use_fake_user = False  # kept by its group (IMAGES_PROP), and gone with it
        out[table] = img
    return set_meta(s, name), out


def group_images(group) -> dict:
    """{table: Image or None} of a set's node group: its own images (``IMAGES_PROP``) or, in files from
    before, the images named after the set."""
    import bpy

    own = group.get(IMAGES_PROP)
    if own is not None:  # never by name then: a name may belong to another set by now
        return {t: img if isinstance(img := own.get(t), bpy.types.Image) else None for t in TABLES}
    name = str(group[PROP]["name"])
    return {t: bpy.data.images.get(image_name(name, t)) for t in TABLES}


def load_group_set(group) -> ScratchSet:
    """The scratch set stored by a set's node group."""
    return load_stored_set(group[PROP], group_images(group))


def load_stored_set(meta, images: dict | None = None) -> ScratchSet:
    """Rebuild the scratch set from its packed images: ``images`` ({table: Image}) or, when None, the
    images named after ``meta["name"]`` (``meta``: dict or ID property)."""
    import bpy

    name = str(meta["name"])
    arrays = {}
    for table, ch in TABLES.items():
        img = images.get(table) if images is not None else bpy.data.images.get(image_name(name, table))
        if img is None:
            raise ValueError(f"scratch set {name!r}: image {image_name(name, table)!r} is missing from the file")
        arrays[table] = image_to_array(img, ch).astype(np.float64)
    m, k = int(meta["n_segments"]), int(meta["n_cells_entries"])
    seg = arrays["segments"].reshape(-1, 4)[:m]
    par = arrays["params"].reshape(-1, 4)[:m]
    grid = arrays["grid"]
    s = ScratchSet(
        segments=seg,
        width_um=par[:, 0].copy(),
        depth_um=par[:, 1].copy(),
        profile=np.rint(par[:, 2]).astype(np.int64),
        scratch_id=np.rint(par[:, 3]).astype(np.int64),
        patch_size_um=np.asarray(list(meta["patch_size_um"]), np.float64),
        sigma_um=float(meta["sigma_um"]),
        cell_size_um=float(meta["cell_size_um"]),
        query_radius_um=float(meta["query_radius_um"]),
        grid_offset=np.rint(grid[..., 0]).astype(np.int64),
        grid_count=np.rint(grid[..., 1]).astype(np.int64),
        cell_segments=np.rint(arrays["cells"].reshape(-1)[:k]).astype(np.int64),
    )
    validate_scratch_set(s)
    return s


def content_hash(s: ScratchSet) -> str:
    h = hashlib.sha1()
    for arr in scratch_set_tables(s).values():
        h.update(np.ascontiguousarray(arr).tobytes())
    h.update(repr(set_meta(s, "")).encode())
    # scratch_io tables + cell-major tables; 3: the shader walks tile copies; 4: cell-major tables uncompressed
    h.update(b"cache-layout-4")
    return h.hexdigest()[:16]


def cache_root() -> str:
    return user_cache_root("material_structures_scratch")


def extract_tables(s: ScratchSet) -> str:
    """Write the EXR tables of ``s`` to its content-addressed cache folder (once); returns the folder. A cache that
    cannot be written (a full or read-only temporary folder) is a ``UserError`` naming it, with nothing left
    half-written."""
    import shutil

    folder = os.path.join(cache_root(), content_hash(s))
    if not os.path.isfile(os.path.join(folder, "cell_params.exr")):
        tmp = folder + f".tmp-{os.getpid()}"
        try:
            save_scratch_set_exr(tmp, s)
            write_cell_major_tables(tmp, s)
        except OSError as exc:
            shutil.rmtree(tmp, ignore_errors=True)
            raise UserError(f"cannot write the scratch tables to {cache_root()}: {exc.strerror or exc}; free space "
                            "there or point TMPDIR at a writable folder") from exc
        try:
            os.replace(tmp, folder)
        except OSError:  # another process extracted it first
            shutil.rmtree(tmp, ignore_errors=True)
        prune_cache(cache_root(), keep=folder)
    else:
        os.utime(folder)  # in use: kept by prune_cache of every session
    return folder


def write_cell_major_tables(folder: str, s: ScratchSet) -> None:
    """Derived tables the shader walks: entry i of ``cell_segments`` with its segment's geometry
    (``cell_geometry.exr`` RGBA = x0, y0, x1, y1) and parameters (``cell_params.exr`` RGBA = width,
    depth, profile, segment index), same 1024-wide layout. One texture lookup per walked entry
    instead of two (the walk is lookup-bound). Written uncompressed (:func:`_write_uncompressed`)."""
    cs = np.asarray(s.cell_segments, np.int64)
    geo = np.asarray(s.segments, np.float64)[cs] if cs.size else np.zeros((0, 4))
    par = (np.stack([s.width_um[cs], s.depth_um[cs], s.profile[cs], cs], 1).astype(np.float64)
           if cs.size else np.zeros((0, 4)))
    _write_uncompressed(os.path.join(folder, "cell_geometry.exr"), wrap_table(geo, 0.0), ("R", "G", "B", "A"))
    _write_uncompressed(os.path.join(folder, "cell_params.exr"), wrap_table(par, -1.0), ("R", "G", "B", "A"))


def _write_uncompressed(path: str, arr: np.ndarray, channels: tuple[str, ...]) -> None:
    """A float32 EXR without compression. Cycles loads every table whole at the start of each render:
    the cell-major tables of 10 000 scratches are 2 x 32 MB, whose ZIP decoding was a good part of the
    scratched metal's fixed cost per render (``bench scratch-render``); uncompressed they load at the
    speed of a copy. Same values either way; ``core.exr_io.read_exr`` reads both."""
    from ...core import exr_io

    a = np.ascontiguousarray(arr, dtype=np.float32)
    if exr_io._backend() == "oiio":  # inside a desktop Blender
        import OpenImageIO as oiio

        spec = oiio.ImageSpec(a.shape[1], a.shape[0], a.shape[2], oiio.FLOAT)
        spec.channelnames = channels
        spec.attribute("compression", "none")
        out = oiio.ImageOutput.create(path)
        if out is None or not out.open(path, spec):
            raise exr_io.ExrError(f"cannot write EXR {path}: {oiio.geterror()}")
        ok = out.write_image(a)
        out.close()
        if not ok:
            raise exr_io.ExrError(f"cannot write EXR {path}: {oiio.geterror()}")
        return
    import OpenEXR

    data = {name: np.ascontiguousarray(a[:, :, i]) for i, name in enumerate(channels)}
    OpenEXR.File({"compression": OpenEXR.NO_COMPRESSION, "type": OpenEXR.scanlineimage}, data).write(path)
