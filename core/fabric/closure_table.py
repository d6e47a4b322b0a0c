"""Precomputed closure fits over the SGGX geometry, interpolated per texel (the brush's refit).

``closure_fit.fit_keys`` costs 0.1-0.2 s per distinct fibre geometry: too slow for a brush stroke,
whose segments create hundreds of geometries. The fit depends only on the canonical key of a texel
(``closure_fit.canonical_keys``: sigma_x, sigma_y, tilt of the fibre axis, twist of a0 about it), so it
is tabulated once on a grid of that key and looked up by multilinear interpolation of the fitted
parameters (16 corners): smooth in the key and about 3 us per texel.

Grid (``NODES``): log sigma at 12 nodes over [log 0.05, log 4] (steps of 49 %, clamped outside), tilt
0-90 degrees every 10, twist 0-90 degrees every 22.5. Two symmetries of eq. 3.9 and of the closure mix
reduce the key before the lookup: swapping sigma_x and sigma_y is the same ellipsoid with a0 turned by
90 degrees about a2 (twist + 90), and the mirror image in the tilt plane is twist -> 180 - twist.
Only nodes with sigma_x <= sigma_y are fitted (the rest follow); a tilt of 0, or sigma_x = sigma_y,
makes the twist irrelevant.

Interpolated parameters are those of the mix in ``closure_fit`` (view-basis coefficients, sheen
roughness, both velvets' sigma and tilt, GGX tilt and alpha scale); between nodes the mix is not the fit of
that key but a blend of its neighbours' fits: its accuracy against the exact fit is measured in
docs/accuracy.md. The table is built by ``python -m material_structures.core.fabric.closure_table``
(a few minutes) and ships as ``closure_table.npz`` beside this module.
"""

from __future__ import annotations

import functools
import os

import numpy as np

from .closure_fit import _canonical_params, canonical_keys, fit_keys

LOG_SIGMA = np.linspace(np.log(0.05), np.log(4.0), 12)
TILT = np.arange(0.0, 90.0 + 1e-9, 10.0)
TWIST = np.arange(0.0, 90.0 + 1e-9, 22.5)
NODES = (LOG_SIGMA, LOG_SIGMA, TILT, TWIST)
N_PARAMS = 27  # 20 view-basis coefficients, 6 shape parameters, 1 GGX alpha scale
TABLE_PATH = os.path.join(os.path.dirname(os.path.abspath(__file__)), "closure_table.npz")


def _reduce(keys: np.ndarray) -> np.ndarray:
    """Continuous canonical keys (log sx, log sy, tilt deg, twist deg) -> the fundamental domain
    (log sx <= log sy, twist in [0, 90])."""
    k = np.array(keys, dtype=np.float64)
    swap = k[:, 0] > k[:, 1]
    k[swap, 0], k[swap, 1] = keys[swap, 1], keys[swap, 0]
    tw = np.where(swap, k[:, 3] + 90.0, k[:, 3]) % 180.0
    k[:, 3] = np.where(tw > 90.0, 180.0 - tw, tw)
    return k


def table_keys() -> np.ndarray:
    """The keys that are fitted: (K, 4) on the grid, sigma_x <= sigma_y, one twist where it does not
    matter."""
    out = []
    for i, a in enumerate(LOG_SIGMA):
        for b in LOG_SIGMA[i:]:
            for t in TILT:
                twists = TWIST if (t > 0 and b > a) else TWIST[:1]
                out += [(a, b, t, w) for w in twists]
    return np.array(out)


def build_table(progress=None, workers: int = 1, chunk: int = 16) -> dict:
    """Fit every table key (``fit_keys``); returns the arrays stored in the .npz."""
    keys = table_keys()
    params = np.zeros((len(keys), N_PARAMS))
    chunks = [keys[c:c + chunk] for c in range(0, len(keys), chunk)]
    if workers > 1:
        from concurrent.futures import ProcessPoolExecutor

        with ProcessPoolExecutor(workers) as pool:
            results = pool.map(_fit_chunk, chunks)
            for n, (c, res) in enumerate(zip(range(0, len(keys), chunk), results, strict=True)):
                params[c:c + len(res)] = res
                if progress is not None:
                    progress(n + 1, len(chunks))
    else:
        for n, c in enumerate(range(0, len(keys), chunk)):
            params[c:c + chunk] = _fit_chunk(keys[c:c + chunk])
            if progress is not None:
                progress(n + 1, len(chunks))
    return {"keys": keys.astype(np.float32), "params": params.astype(np.float32)}


def _fit_chunk(keys: np.ndarray) -> np.ndarray:
    sigma, quat = _canonical_params(keys)
    w, s, c, _ = fit_keys(sigma, quat, chunk=len(keys))
    return np.concatenate([w.reshape(len(keys), 20), s, c], axis=1)


def _dense(keys: np.ndarray, params: np.ndarray) -> np.ndarray:
    """The full grid (12, 12, 10, 5, N_PARAMS) from the fitted keys and the symmetries."""
    idx = [np.clip(np.rint(np.interp(keys[:, d], NODES[d], np.arange(len(NODES[d])))).astype(int), 0,
                   len(NODES[d]) - 1) for d in range(4)]
    grid = np.full(tuple(len(n) for n in NODES) + (N_PARAMS,), np.nan)
    for i, j, t, w, p in zip(*idx, params, strict=True):
        if t == 0 or i == j:
            grid[i, j, t, :] = p  # twist irrelevant
        else:
            grid[i, j, t, w] = p
    nw = len(TWIST) - 1
    for i in range(len(LOG_SIGMA)):
        for j in range(i):  # sigma_x > sigma_y: swapped, twist + 90 -> mirrored 90 - twist
            grid[i, j] = grid[j, i][:, ::-1] if nw else grid[j, i]
    if np.isnan(grid).any():
        raise ValueError("the closure table misses grid nodes: rebuild it")
    return grid


@functools.lru_cache(maxsize=1)
def load_table(path: str = TABLE_PATH) -> np.ndarray:
    """The dense interpolation grid (cached per process)."""
    with np.load(path) as data:
        return _dense(data["keys"].astype(np.float64), data["params"].astype(np.float64))


def interpolate(keys: np.ndarray, grid: np.ndarray | None = None) -> np.ndarray:
    """Multilinear interpolation of the fitted parameters at continuous canonical keys (N, 4) -> (N, 27)."""
    grid = load_table() if grid is None else grid
    k = _reduce(np.asarray(keys, dtype=np.float64))
    lo, frac = [], []
    for d, nodes in enumerate(NODES):
        x = np.interp(k[:, d], nodes, np.arange(len(nodes)))  # clamps outside the grid
        i0 = np.minimum(np.floor(x).astype(int), len(nodes) - 2)
        lo.append(i0)
        frac.append(x - i0)
    out = np.zeros((len(k), grid.shape[-1]))
    for corner in range(16):
        bits = [(corner >> d) & 1 for d in range(4)]
        w = np.ones(len(k))
        for d in range(4):
            w *= frac[d] if bits[d] else 1.0 - frac[d]
        out += w[:, None] * grid[lo[0] + bits[0], lo[1] + bits[1], lo[2] + bits[2], lo[3] + bits[3]]
    return out


def lookup_closure_texels(sigma, basis, grid: np.ndarray | None = None):
    """Closure parameters of N texels by table lookup; returns what ``closure_fit.fit_closure_texels``
    returns: (weights (N, 5, 4), shape (N, 6), ggx_scale (N, 1)) float32."""
    sigma = np.asarray(sigma, float).reshape(-1, 2)
    basis = np.asarray(basis, float).reshape(-1, 4)
    keys = canonical_keys(sigma, basis, quantum=(1e-9, 1e-9, 1e-9))
    p = interpolate(keys, grid)
    n = len(p)
    return (p[:, :20].reshape(n, 5, 4).astype(np.float32), p[:, 20:26].astype(np.float32),
            p[:, 26:27].astype(np.float32))


def main() -> None:
    import sys
    import time

    start = time.perf_counter()
    workers = int(sys.argv[1]) if len(sys.argv) > 1 else 1

    def progress(done, total):
        print(f"\r{done}/{total} chunks, {time.perf_counter() - start:.0f} s", end="", flush=True)

    data = build_table(progress, workers=workers)
    tmp = TABLE_PATH + ".tmp.npz"
    np.savez_compressed(tmp, **data)
    os.replace(tmp, TABLE_PATH)
    print(f"\n{len(data['keys'])} keys -> {TABLE_PATH}")


if __name__ == "__main__":
    main()
