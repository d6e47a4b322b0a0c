"""A BTF streamed through the fit a band of texel rows at a time, in a bounded space.

A BTF is stored image after image, ``(N, H, W, 3)``; a tile's fit needs its texels' values over every image,
texel-major. Mapping a tile straight from the images costs a page fault per image and row (4096 x 20 per
20 x 20 tile, each a random 4 KB read where the BTF is not in memory): on a 1024 x 1024 texel BTF with 4096
images (51 GB) the fit then ran 8 times slower than its arithmetic. Instead the fit reads one band of ``tile``
rows of every image (whole rows: one sequential read per image), checks its values, and writes it texel-major
``(rows, W, N, 3)`` float32 into one of two band files of the fit cache; the workers map their tile from it (20
contiguous runs per tile). While the workers fit one band, the next is read into the other file, so the space
taken is two bands (2 GB for 1024 texels x 4096 images x 20 rows), whatever the texel count.
"""

from __future__ import annotations

import os
from collections import defaultdict
from collections.abc import Callable, Iterable
from dataclasses import dataclass
from typing import Any, Protocol

import numpy as np

from ..errors import UserError
from .btf_io import ArrayInFile, check_values

Tile = tuple[int, int, int, int]  # y0, y1, x0, x1


@dataclass(frozen=True)
class BandFile:
    """Texel rows ``y0 ...`` of a BTF, texel-major ``(rows, W, N, 3)`` float32, in a file workers map."""

    values: ArrayInFile
    y0: int

    def tile_values(self, t: Tile) -> np.ndarray:
        """Tile ``t``'s values ``(texels, N, 3)`` float64; the band is mapped only meanwhile."""
        y0, y1, x0, x1 = t
        band = self.values.map()
        block = np.asarray(band[y0 - self.y0:y1 - self.y0, x0:x1], dtype=np.float64)  # (th, tw, N, 3)
        del band
        return block.reshape(-1, block.shape[2], 3)


def read_rows(images: ArrayInFile, y0: int, y1: int, source: str) -> np.ndarray:
    """Rows ``y0:y1`` of every image of ``images`` (N, H, W, 3) as float32 ``(N, y1 - y0, W, 3)``: one read of
    whole rows per image. Refuses (one line, naming the image) a file cut short and values a BTF cannot hold."""
    n, h, w, c = images.shape
    dtype = np.dtype(images.dtype)
    row = w * c * dtype.itemsize
    out = np.empty((n, y1 - y0, w, c), dtype=dtype)
    with open(images.path, "rb", buffering=0) as f:
        fd = f.fileno()
        for k in range(n):
            got = os.preadv(fd, [memoryview(out[k]).cast("B")], images.offset + (k * h + y0) * row)
            if got != out[k].nbytes:
                raise UserError(f"{source}: values is truncated near image {k}")
    vals = out.astype(np.float32, copy=False)
    check_values(source, 0, vals)
    return vals


def write_band(path: str, rows: np.ndarray, y0: int) -> BandFile:
    """Write ``rows`` (N, th, W, 3) texel-major into the band file ``path`` (replaced whole, so a worker still
    mapping the band it held keeps it)."""
    n, th, w, c = rows.shape
    tmp = f"{path}.tmp-{os.getpid()}.npy"
    band = np.lib.format.open_memmap(tmp, mode="w+", dtype=np.float32, shape=(th, w, n, c))
    for x in range(0, w, 64):  # in column blocks: each a cache-sized transposition
        band[:, x:x + 64] = rows[:, :, x:x + 64].transpose(1, 2, 0, 3)
    offset = band.offset
    band.flush()
    del band
    os.replace(tmp, path)
    return BandFile(ArrayInFile(path=os.path.abspath(path), offset=offset, dtype="<f4", shape=(th, w, n, c)), y0)


class TileRunner(Protocol):
    """Where the tiles are fitted: a process pool, a Dask cluster, this process."""

    def submit(self, t: Tile, band: BandFile) -> Any: ...

    def wait_some(self, running: set) -> Iterable: ...

    def result(self, handle: Any) -> tuple: ...


def fit_in_bands(images: ArrayInFile, source: str, band_dir: str, todo: list[Tile], runner: TileRunner,
                 done: Callable[[tuple], None]) -> None:
    """Fit the tiles ``todo`` (row-major; whole bands of rows) through two band files in ``band_dir``: band k is
    read while band k - 1 is fitted, and written once band k - 2's tiles are all done. ``done(result)`` is called
    for every finished tile, in the order they finish."""
    bands: dict[tuple[int, int], list[Tile]] = {}
    for t in todo:
        bands.setdefault((t[0], t[1]), []).append(t)
    left: dict[int, int] = defaultdict(int)
    band_of: dict[Any, int] = {}
    running: set = set()

    def settle(handles: Iterable) -> None:
        for h in list(handles):
            running.discard(h)
            k = band_of.pop(h)
            done(runner.result(h))
            left[k] -= 1

    try:
        for k, ((y0, y1), tiles) in enumerate(bands.items()):
            rows = read_rows(images, y0, y1, source)
            while left[k - 2] > 0:
                settle(runner.wait_some(running))
            band = write_band(os.path.join(band_dir, f"band{k % 2}.npy"), rows, y0)
            del rows
            for t in tiles:
                h = runner.submit(t, band)
                running.add(h)
                band_of[h] = k
                left[k] += 1
        while running:
            settle(runner.wait_some(running))
    finally:  # done, failed or interrupted: the bands go (a tile still running keeps its mapping of the file)
        for name in os.listdir(band_dir):
            if name.startswith("band") and name.endswith(".npy"):
                os.remove(os.path.join(band_dir, name))
