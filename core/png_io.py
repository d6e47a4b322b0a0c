"""8-bit RGB PNG writing with the standard library (zlib), for previews where no imaging package is
installed (a desktop Blender's Python has numpy, not Pillow or matplotlib). PNG: signature, IHDR (8-bit
truecolour), one IDAT of filter-0 scanlines, IEND; each chunk length, type, data, CRC-32."""

from __future__ import annotations

import os
import struct
import zlib

import numpy as np


def _chunk(kind: bytes, data: bytes) -> bytes:
    return struct.pack(">I", len(data)) + kind + data + struct.pack(">I", zlib.crc32(kind + data) & 0xFFFFFFFF)


def png_bytes(rgb: np.ndarray) -> bytes:
    """(H, W, 3) uint8 as PNG bytes."""
    a = np.ascontiguousarray(rgb, dtype=np.uint8)
    if a.ndim != 3 or a.shape[2] != 3 or a.shape[0] < 1 or a.shape[1] < 1:
        raise ValueError(f"png: need an (H, W, 3) image, got {a.shape}")
    h, w = a.shape[:2]
    raw = np.concatenate([np.zeros((h, 1), dtype=np.uint8), a.reshape(h, w * 3)], axis=1).tobytes()
    return (b"\x89PNG\r\n\x1a\n" + _chunk(b"IHDR", struct.pack(">IIBBBBB", w, h, 8, 2, 0, 0, 0))
            + _chunk(b"IDAT", zlib.compress(raw, 6)) + _chunk(b"IEND", b""))


def write_png(path: str | os.PathLike, rgb: np.ndarray) -> None:
    """Write ``rgb`` to ``path`` under a temporary name, renamed when complete."""
    path = os.fspath(path)
    tmp = f"{path}.tmp{os.getpid()}.png"
    with open(tmp, "wb") as f:
        f.write(png_bytes(rgb))
    os.replace(tmp, path)
