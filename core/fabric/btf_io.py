"""Measured BTF input/output.

Two formats hold the same data: ``N`` light/view pairs and, for each, an ``H x W`` RGB image of
``f_r(wi, wo) * cos(theta_i)`` in linear RGB.

* a folder with ``btf.json`` = ``{"width": W, "height": H, "samples": [{"wi": [x, y, z],
  "wo": [x, y, z], "image": "0000.exr"}, ...]}`` and float EXR images (channels R, G, B), paths
  relative to the folder; directions are unit vectors in the patch's tangent frame (z = normal,
  x along image columns, y along rows);
* a single ``.npz`` with ``values[N, H, W, 3]``, ``wi[N, 3]``, ``wo[N, 3]``.
"""

from __future__ import annotations

import json
import os
import struct
import zipfile
import zlib
from dataclasses import dataclass

import numpy as np

from ..errors import MissingFileError, UserError
from ..exr_io import ExrError, read_exr, write_exr
from ..json_schema import check as check_schema
from ..staged_write import staged_files

UNIT_TOL = 1e-3


MAX_SIDE = 16384  # texels a side (fabric synth makes at most as many)
BLOCK_BYTES = 256 * 2**20  # iter_btf_blocks: images per block up to this many bytes (memory flat in the BTF's size)


@dataclass
class BtfHeader:
    """Directions and layout of a BTF without its pixel data."""

    width: int
    height: int
    wi: np.ndarray  # (N, 3) light directions
    wo: np.ndarray  # (N, 3) view directions
    source: str  # the folder, or the .npz path
    images: list[str] | None = None  # absolute EXR paths (folder format)

    @property
    def count(self) -> int:
        return int(self.wi.shape[0])


@dataclass
class Btf:
    """A loaded BTF: ``values[N, H, W, 3]`` = ``f_r cos(theta_i)``, directions ``wi, wo`` (N, 3)."""

    values: np.ndarray
    wi: np.ndarray
    wo: np.ndarray


def validate_directions(wi: np.ndarray, wo: np.ndarray, where: str = "BTF") -> tuple[np.ndarray, np.ndarray]:
    """Check shapes, finiteness, unit length (tolerance 1e-3) and ``z > 0``; return normalised float64."""
    out = []
    for name, w in (("wi", wi), ("wo", wo)):
        w = np.asarray(w, dtype=np.float64)
        if w.ndim != 2 or w.shape[1] != 3:
            raise UserError(f"{where}: {name} must have shape (N, 3), got {w.shape}")
        if not np.all(np.isfinite(w)):
            raise UserError(f"{where}: {name} holds non-finite values (NaN/Inf)")
        n = np.linalg.norm(w, axis=1)
        bad = np.flatnonzero(np.abs(n - 1.0) > UNIT_TOL)
        if bad.size:
            raise UserError(f"{where}: {name}[{bad[0]}] = {w[bad[0]].tolist()} is not a unit vector "
                            f"(|w| = {n[bad[0]]:.6g}); {bad.size} such sample(s)")
        below = np.flatnonzero(w[:, 2] <= 0.0)
        if below.size:
            raise UserError(f"{where}: {name}[{below[0]}] = {w[below[0]].tolist()} is below the horizon "
                            f"(z <= 0); {below.size} such sample(s)")
        out.append(w / n[:, None])
    if out[0].shape[0] != out[1].shape[0]:
        raise UserError(f"{where}: wi has {out[0].shape[0]} rows but wo has {out[1].shape[0]}")
    if out[0].shape[0] == 0:
        raise UserError(f"{where}: no samples")
    return out[0], out[1]


def _json_path(path: str) -> tuple[str, str]:
    if os.path.isdir(path):
        return path, os.path.join(path, "btf.json")
    if os.path.basename(path).endswith(".json"):
        return os.path.dirname(path) or ".", path
    raise MissingFileError(f"BTF not found: {path} (expected a folder with btf.json, a btf.json or a .npz)", path)


_NPZ_DAMAGE = (OSError, ValueError, EOFError, zipfile.BadZipFile, zlib.error)  # not an .npz, truncated, damaged


def _npz_directions(path: str, keys: tuple[str, ...]) -> tuple[np.ndarray, np.ndarray]:
    """The checked directions ``(wi, wo)`` of an existing ``.npz`` that must hold the arrays ``keys``; anything
    else about it (not an archive, a key missing, damage, non-numbers) is a one-line ``UserError``."""
    try:
        z = np.load(path)
        if not isinstance(z, np.lib.npyio.NpzFile):  # a single array (.npy) under an .npz name
            raise UserError(f"{path}: a single array, not an .npz archive with {', '.join(keys)}")
        with z:
            missing = [k for k in keys if k not in z.files]
            if missing:
                raise UserError(f"{path}: missing array {missing[0]!r}; has {sorted(z.files)}")
            wi, wo = z["wi"], z["wo"]
    except UserError:
        raise
    except _NPZ_DAMAGE as exc:
        raise UserError(f"{path}: not a readable .npz file ({type(exc).__name__}: {exc})") from None
    if wi.dtype.kind not in "iuf" or wo.dtype.kind not in "iuf":
        raise UserError(f"{path}: wi and wo must hold numbers, got {wi.dtype} and {wo.dtype}")
    return validate_directions(wi, wo, path)


def read_btf_header(path: str | os.PathLike) -> BtfHeader:
    """Read and validate the layout and directions of a BTF folder / ``btf.json`` / ``.npz``."""
    path = os.fspath(path)
    if path.endswith(".npz"):
        if not os.path.isfile(path):
            raise MissingFileError(f"BTF file not found: {path}", path)
        wi, wo = _npz_directions(path, ("values", "wi", "wo"))
        try:
            shape = _npz_shape(path, "values")
        except UserError:
            raise
        except _NPZ_DAMAGE as exc:
            raise UserError(f"{path}: not a readable .npz file ({type(exc).__name__}: {exc})") from None
        if len(shape) != 4 or shape[3] != 3:
            raise UserError(f"{path}: values must have shape (N, H, W, 3), got {shape}")
        if shape[0] != wi.shape[0]:
            raise UserError(f"{path}: values has {shape[0]} images but wi/wo have {wi.shape[0]} rows")
        return BtfHeader(width=shape[2], height=shape[1], wi=wi, wo=wo, source=path)
    folder, jpath = _json_path(path)
    if not os.path.isfile(jpath):
        raise MissingFileError(f"BTF description not found: {jpath}", jpath)
    try:
        with open(jpath, encoding="utf-8") as f:
            desc = json.load(f)
    except ValueError as exc:  # not JSON, or not text
        raise UserError(f"{jpath}: not valid JSON ({exc})") from None
    check_schema(desc, "btf", jpath)  # core/schemas/btf.schema.json: the fields, their kinds and ranges
    width, height = int(desc["width"]), int(desc["height"])
    wi, wo, images = [], [], []
    for k, s in enumerate(desc["samples"]):
        wi.append([float(v) for v in s["wi"]])
        wo.append([float(v) for v in s["wo"]])
        img = os.path.join(folder, s["image"])
        if not os.path.isfile(img):
            raise MissingFileError(f"{jpath}: samples[{k}] image not found: {img}", img)
        images.append(img)
    wi_a, wo_a = validate_directions(np.array(wi), np.array(wo), jpath)
    return BtfHeader(width=width, height=height, wi=wi_a, wo=wo_a, source=folder, images=images)


def _npz_member_header(zf, key: str):
    """Open ``key.npy`` inside an npz and return (file, shape, fortran_order, dtype) without loading."""
    f = zf.open(f"{key}.npy")
    version = np.lib.format.read_magic(f)
    if version == (1, 0):
        shape, fortran, dtype = np.lib.format.read_array_header_1_0(f)
    else:
        shape, fortran, dtype = np.lib.format.read_array_header_2_0(f)
    return f, tuple(shape), fortran, dtype


@dataclass(frozen=True)
class ArrayInFile:
    """An array stored uncompressed at byte ``offset`` of the file ``path``, in C order: mapped, not read."""

    path: str
    offset: int
    dtype: str
    shape: tuple[int, ...]

    def map(self) -> np.memmap:
        """A read-only memory map of the array (delete it when done: its pages then leave the process)."""
        return np.memmap(self.path, dtype=np.dtype(self.dtype), mode="r", offset=self.offset, shape=self.shape)


_ZIP_LOCAL_HEADER = struct.Struct("<4s5H3L2H")  # signature ... file name length, extra field length


def npz_stored_array(path: str, key: str) -> ArrayInFile | None:
    """Where ``key`` of an ``.npz`` lies in the file, if it is stored uncompressed (``np.savez``) in C order;
    ``None`` for a compressed member (``np.savez_compressed``) or a Fortran-order one, which must be read."""
    with zipfile.ZipFile(path) as zf:
        info = zf.getinfo(f"{key}.npy")
        if info.compress_type != zipfile.ZIP_STORED or info.flag_bits & 0x1:  # compressed or encrypted
            return None
        member, shape, fortran, dtype = _npz_member_header(zf, key)
        with member:
            header = member.tell()  # the .npy header's length: the data follow it
    with open(path, "rb") as f:
        f.seek(info.header_offset)
        local = _ZIP_LOCAL_HEADER.unpack(f.read(_ZIP_LOCAL_HEADER.size))
    if local[0] != b"PK\x03\x04" or fortran or dtype.hasobject:
        return None
    offset = info.header_offset + _ZIP_LOCAL_HEADER.size + local[-2] + local[-1] + header
    return ArrayInFile(path=os.path.abspath(path), offset=offset, dtype=dtype.str, shape=tuple(int(n) for n in shape))


def _npz_shape(path: str, key: str) -> tuple[int, ...]:
    with zipfile.ZipFile(path) as zf:
        f, shape, _, _ = _npz_member_header(zf, key)
        f.close()
    return shape


def check_values(source: str, k0: int, vals: np.ndarray) -> None:
    """Refuse non-finite or negative radiance in images ``k0...`` (``vals``: (m, H, W, 3)), naming the first
    image that holds one. A min and a max (NaN propagates through both) clear a good block in two passes."""
    lo, hi = vals.min(), vals.max()
    if np.isfinite(lo) and np.isfinite(hi) and lo >= 0:
        return
    finite = np.isfinite(vals).all(axis=(1, 2, 3))
    if not finite.all():
        bad = k0 + int(np.flatnonzero(~finite)[0])
        raise UserError(f"{source}: values[{bad}] holds non-finite values (NaN/Inf)")
    bad = k0 + int(np.flatnonzero((vals < 0).any(axis=(1, 2, 3)))[0])
    raise UserError(f"{source}: values[{bad}] holds negative radiance (a BTF's values are reflected radiance, >= 0)")


def iter_btf_blocks(path: str | os.PathLike, block: int = 256, progress: bool = False):
    """Yield ``(start, values[start:start + block])`` float32 blocks of a BTF (bounded memory: at most ``block``
    images and ``BLOCK_BYTES`` a block, at least one image; a block may be read-only).

    Raises ValueError/FileNotFoundError with the offending file for size mismatches, missing
    files, non-finite pixels and directions below the horizon.
    """
    hdr = read_btf_header(path)
    h, w = hdr.height, hdr.width
    block = max(1, min(block, BLOCK_BYTES // (h * w * 3 * 4)))
    bar = None
    if progress:
        from tqdm import tqdm

        bar = tqdm(total=hdr.count, desc="read BTF", unit="img")
    if hdr.images is None:
        with zipfile.ZipFile(hdr.source) as zf:
            f, shape, fortran, dtype = _npz_member_header(zf, "values")
            with f:
                if fortran:
                    raise UserError(f"{hdr.source}: values must be stored in C order")
                if not np.issubdtype(dtype, np.floating):
                    raise UserError(f"{hdr.source}: values must be floating point, got {dtype}")
                per = h * w * 3 * dtype.itemsize
                for k0 in range(0, hdr.count, block):
                    m = min(block, hdr.count - k0)
                    try:
                        buf = f.read(per * m)
                    except (OSError, EOFError, zipfile.BadZipFile, zlib.error) as exc:
                        raise UserError(f"{hdr.source}: values cannot be read near image {k0} "
                                        f"({type(exc).__name__}: {exc})") from None
                    if len(buf) != per * m:
                        raise UserError(f"{hdr.source}: values is truncated near image {k0}")
                    vals = np.frombuffer(buf, dtype=dtype).reshape(m, h, w, 3).astype(np.float32, copy=False)
                    check_values(hdr.source, k0, vals)
                    if bar:
                        bar.update(m)
                    yield k0, vals
    else:
        for k0 in range(0, hdr.count, block):
            m = min(block, hdr.count - k0)
            vals = np.empty((m, h, w, 3), dtype=np.float32)
            for j in range(m):
                k = k0 + j
                try:
                    img = read_exr(hdr.images[k], channels=("R", "G", "B"))
                except ExrError as exc:
                    raise UserError(f"BTF sample {k}: {exc}") from exc
                if img.shape[:2] != (h, w):
                    raise UserError(f"BTF sample {k}: {hdr.images[k]} is {img.shape[1]}x{img.shape[0]} "
                                    f"(W x H), btf.json says {w}x{h}")
                if (img < 0).any():
                    raise UserError(f"BTF sample {k}: {hdr.images[k]} holds negative radiance in "
                                    f"{int((img < 0).any(axis=-1).sum())} pixels (a BTF's values are reflected "
                                    "radiance, >= 0)")
                vals[j] = img
                if bar:
                    bar.update(1)
            yield k0, vals
    if bar:
        bar.close()


def load_btf(path: str | os.PathLike, out: np.ndarray | None = None, progress: bool = False) -> Btf:
    """Load a BTF (folder, ``btf.json`` or ``.npz``); values are float32 ``(N, H, W, 3)``.

    ``out`` may be a preallocated (e.g. memory-mapped) float32 array of that shape to fill.
    Raises ValueError/FileNotFoundError with the offending file for size mismatches, missing
    files, non-finite pixels and directions below the horizon.
    """
    hdr = read_btf_header(path)
    shape = (hdr.count, hdr.height, hdr.width, 3)
    if out is None:
        out = np.empty(shape, dtype=np.float32)
    elif out.shape != shape:
        raise ValueError(f"output array has shape {out.shape}, BTF needs {shape}")
    for k0, vals in iter_btf_blocks(path, progress=progress):
        out[k0:k0 + vals.shape[0]] = vals
    return Btf(values=out, wi=hdr.wi, wo=hdr.wo)


def save_btf(path: str | os.PathLike, values: np.ndarray, wi: np.ndarray, wo: np.ndarray) -> str:
    """Write a BTF: ``path`` ending in ``.npz`` -> single file, otherwise a folder with btf.json + EXRs."""
    path = os.fspath(path)
    values = np.asarray(values, dtype=np.float32)
    wi, wo = validate_directions(wi, wo, path)
    if values.ndim != 4 or values.shape[3] != 3 or values.shape[0] != wi.shape[0]:
        raise ValueError(f"values must be (N, H, W, 3) with N = {wi.shape[0]}, got {values.shape}")
    if path.endswith(".npz"):
        os.makedirs(os.path.dirname(path) or ".", exist_ok=True)
        tmp = f"{path}.tmp-{os.getpid()}.npz"
        try:
            np.savez(tmp, values=values, wi=wi, wo=wo)
            os.replace(tmp, path)  # never a half-written file under the real name
        finally:
            if os.path.exists(tmp):
                os.remove(tmp)
        return path
    width = len(str(max(values.shape[0] - 1, 0)))
    samples = []
    with staged_files(path, "btf.json") as stage:  # the images and their btf.json, or no btf.json: never a mix
        for k in range(values.shape[0]):
            name = f"{k:0{max(width, 4)}d}.exr"
            write_exr(os.path.join(stage, name), values[k])
            samples.append({"wi": wi[k].tolist(), "wo": wo[k].tolist(), "image": name})
        desc = {"width": int(values.shape[2]), "height": int(values.shape[1]), "samples": samples}
        with open(os.path.join(stage, "btf.json"), "w") as f:
            json.dump(desc, f)
    return path


def read_directions(path: str | os.PathLike) -> tuple[np.ndarray, np.ndarray]:
    """Directions ``(wi, wo)`` from a ``btf.json`` (images need not exist) or a ``.npz``."""
    path = os.fspath(path)
    if path.endswith(".npz"):  # wi and wo are enough: a BTF's values need not be there
        if not os.path.isfile(path):
            raise MissingFileError(f"directions file not found: {path}", path)
        return _npz_directions(path, ("wi", "wo"))
    _, jpath = _json_path(path)
    if not os.path.isfile(jpath):
        raise MissingFileError(f"directions file not found: {jpath}", jpath)
    try:
        with open(jpath, encoding="utf-8") as f:
            desc = json.load(f)
    except ValueError as exc:
        raise UserError(f"{jpath}: not valid JSON ({exc})") from None
    check_schema(desc, "btf", jpath)
    wi = np.array([s["wi"] for s in desc["samples"]], dtype=np.float64)
    wo = np.array([s["wo"] for s in desc["samples"]], dtype=np.float64)
    return validate_directions(wi, wo, jpath)
