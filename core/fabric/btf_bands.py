"""A BTF streamed through the fit a band of texel rows at a time, in a bounded space.

A BTF is stored image after image, ``(N, H, W, 3)``; a tile's fit needs its texels' values over every image,
texel-major. Mapping a tile straight from the images costs a page fault per image and row (4096 x 20 per
20 x 20 tile, each a random 4 KB read where the BTF is not in memory): on a 1024 x 1024 texel BTF with 4096
images (51 GB) the fit then ran 8 times slower than its arithmetic. Instead the fit reads one band of ``tile``
rows of every image (whole rows: one sequential read per image), checks its values, and writes it texel-major
``(rows, W, N, 3)`` float32 into a band file of the fit cache; the workers map their tile from it (20 contiguous
runs per tile). While the workers fit one band, the next is written, so the cache holds two bands (2 GB for 1024
texels x 4096 images x 20 rows) and the process that reads them a 64 MB group of images' rows, whatever the texel
count.
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


GROUP_BYTES = 64 * 2**20  # a band is read this many bytes of images' rows at a time


def write_band(images: ArrayInFile, y0: int, y1: int, source: str, path: str, durable: bool = False) -> BandFile:
    """Rows ``y0:y1`` of every image of ``images`` (N, H, W, 3) into the band file ``path``, texel-major
    ``(rows, W, N, 3)`` float32. The images are read in groups of at most ``GROUP_BYTES`` of whole rows (one read
    per image) and written a band row at a time through a map of that row alone, so this process holds a group,
    not the band. ``durable``: the file is synced to its storage before it is handed on (workers on other machines
    read it from shared storage; this machine's workers read the page cache). Refuses (one line, naming the image)
    a file cut short and values a BTF cannot hold."""
    n, h, w, c = images.shape
    dtype = np.dtype(images.dtype)
    th = y1 - y0
    row = w * c * dtype.itemsize
    group = max(1, GROUP_BYTES // (th * row))
    band = np.lib.format.open_memmap(path, mode="w+", dtype=np.float32, shape=(th, w, n, c))
    offset = band.offset
    del band
    buf = np.empty((min(group, n), th, w, c), dtype=dtype)
    with open(images.path, "rb", buffering=0) as f:
        fd = f.fileno()
        for k0 in range(0, n, group):
            m = min(group, n - k0)
            for j in range(m):
                got = os.preadv(fd, [memoryview(buf[j]).cast("B")], images.offset + ((k0 + j) * h + y0) * row)
                if got != buf[j].nbytes:
                    raise UserError(f"{source}: values is truncated near image {k0 + j}")
            vals = buf[:m].astype(np.float32, copy=False)
            check_values(source, k0, vals)
            for r in range(th):
                texels = np.memmap(path, dtype=np.float32, mode="r+", offset=offset + r * w * n * c * 4,
                                   shape=(w, n, c))
                texels[:, k0:k0 + m] = vals[:, r].transpose(1, 0, 2)
                del texels
    if durable:
        with open(path, "rb+") as f:
            os.fsync(f.fileno())
    return BandFile(ArrayInFile(path=os.path.abspath(path), offset=offset, dtype="<f4", shape=(th, w, n, c)), y0)


class TileRunner(Protocol):
    """Where the tiles are fitted: a process pool, a Dask cluster, this process."""

    def submit(self, t: Tile, band: BandFile) -> Any: ...

    def wait_some(self, running: set) -> Iterable: ...

    def result(self, handle: Any) -> tuple: ...


def fit_in_bands(images: ArrayInFile, source: str, band_dir: str, todo: list[Tile], runner: TileRunner,
                 done: Callable[[tuple], None], durable: bool = False) -> None:
    """Fit the tiles ``todo`` (row-major; whole bands of rows) through band files in ``band_dir``, at most two at a
    time: band k is read and written while band k - 1 is fitted, once band k - 2's tiles are all done and its file
    is deleted. ``done(result)`` is called for every finished tile, in the order they finish; ``durable``: see
    :func:`write_band`."""
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
            while left[k - 2] > 0:
                settle(runner.wait_some(running))
            if os.path.exists(old := os.path.join(band_dir, f"band{k - 2}.npy")):
                os.remove(old)  # a worker that still maps it keeps its pages until it lets go
            band = write_band(images, y0, y1, source, os.path.join(band_dir, f"band{k}.npy"), durable)
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
