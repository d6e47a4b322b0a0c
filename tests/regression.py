"""Render-regression helper: a render compared statistically with its reference.

A fixed-seed Cycles render is bit-identical from run to run on one machine, but not across CPUs: on an AVX-512
EPYC, 280-710 values of five of the 4-sample library renders differed from the AVX2 machine's by more than
1e-4 relative (1-28 of 6912 values by more than 0.002, up to 0.016; 2026-11-27), as paths take another turn
after a rounding difference, and Cycles' SSE4.2 kernel differs again. A near-exact comparison fails on any
machine but the one its reference was made on. So a reference is a distribution, not an image:

``tests/references/NAME.exr`` holds, for every value of the image (pixel and channel), the mean of ``K``
renders with seeds ``0..K-1`` (channels ``R, G, B, A``), the unbiased variance of one render about that mean
(``var.R`` ...), the seed-0 render itself (``seed0.R`` ...) and ``K`` (channel ``n``). ``make refs`` (pytest
``--update-refs``) writes them, with ``K = SEEDS`` (16; ``MS_REF_SEEDS=8 make refs`` for fewer).

A test renders once, with seed 0, and :func:`compare` applies four tests, each with a quarter of the
comparison's false-alarm probability ``ALPHA``. Three are z-tests of ``d = image - mean`` against the
reference's noise (the approach of Mitsuba 3's render tests, with tiles and the image mean added):

* on every value: ``d`` against ``sqrt(var (1 + 1/K))``, Sidak-corrected over all values, with Student's t at
  ``K - 1`` degrees of freedom. This keeps exact renders (emission) exact.
* on every ``TILE x TILE``-pixel tile and channel: the tile's mean of ``d`` against its standard error
  (pixels are independent: the pixel filter keeps every sample in its pixel), Sidak-corrected over all tiles
  and channels, with Student's t at the tile's Welch-Satterthwaite degrees of freedom (a variance from ``K``
  renders is itself uncertain). This finds a local change (one object's material, a shadow) that is within
  the noise of each of its values.
* on each channel's mean over the whole image: a global shift larger than the image mean's noise (at 4
  samples and 48 x 36 pixels a lit library render's image mean has a standard error of 0.4-0.8 %).

The fourth is a sign test of the same-seed difference ``image - seed0``: a value that another CPU renders
differently (beyond ``SIGN_REL``) is another sample of the same pixel, as likely above as below; a regression
that darkens or brightens moves most values one way. Two-sided binomial test of the count above among the values
that differ. This is what finds a 1 % darker render, which the noise of the image mean hides (z about 1.2-2.4
there). Differences below ``SIGN_REL`` (0.2 %) are not counted: another kernel's arithmetic shifts a few hundred
values of a volume render by 1e-4 to 1e-3, and mostly one way (Cycles' SSE4.2 kernel against the references'
AVX2: the teeth smile 83 values up and 124 down beyond 1e-4 relative, sign test p 7e-5, but 7 up
and 18 down beyond 1e-3 and 5 up, 3 down beyond 1e-2; Dentin Shade A3 29 up, 5 down beyond 1e-4, 2 up
beyond 1e-3), while a change of 0.2 % or more moves every lit value past it.

A value that is the same in every reference render (emission, background) has a variance floor of
``(FLOOR_REL * |mean| + FLOOR_ABS)^2``, so an exact render stays exact up to float summation order. On a
mismatch the render and its z-score per tile are written to ``tests/output/NAME.new.exr`` and
``tests/output/NAME.z.exr`` and the failure names both.
"""

from __future__ import annotations

import os
from collections.abc import Callable

import numpy as np

from material_structures.core.exr_io import read_exr, write_exr

TESTS_DIR = os.path.dirname(os.path.abspath(__file__))
REFERENCE_DIR = os.path.join(TESTS_DIR, "references")
OUTPUT_DIR = os.path.join(TESTS_DIR, "output")

SEEDS = int(os.environ.get("MS_REF_SEEDS", "16"))  # renders per reference (seeds 0..SEEDS-1); a test renders seed 0
TILE = 4  # pixels per tile side
ALPHA = 1e-3  # false-alarm probability of one comparison (a quarter each: values, tiles, image means, signs)
FLOOR_REL, FLOOR_ABS = 1e-4, 1e-6  # the standard deviation a value has at least (deterministic values)
SIGN_REL = 2e-3  # the sign test counts values that differ from the seed-0 render by more than this, relative
TEST_SEED = 0


class RegressionMismatch(AssertionError):
    pass


def _channel_names(n: int) -> list[str]:
    return ["R", "G", "B", "A"][:n] if n <= 4 else [f"C{i}" for i in range(n)]


def reference_path(name: str, reference_dir: str = REFERENCE_DIR) -> str:
    return os.path.join(reference_dir, f"{name}.exr")


def write_reference(name: str, renders: list[np.ndarray], reference_dir: str = REFERENCE_DIR) -> str:
    """Write the reference of ``name`` from ``K >= 2`` renders, seeds ``0..K-1`` in that order: per-value mean,
    variance, the seed-0 render, K."""
    stack = np.stack([np.asarray(r, dtype=np.float64) for r in renders])
    if stack.ndim == 3:
        stack = stack[..., None]
    k = stack.shape[0]
    if k < 2:
        raise ValueError("a reference needs at least 2 renders")
    mean = stack.mean(axis=0)
    var = stack.var(axis=0, ddof=1)
    names = _channel_names(mean.shape[-1])
    data = np.concatenate([mean, var, stack[0], np.full(mean.shape[:2] + (1,), float(k))], axis=-1)
    os.makedirs(reference_dir, exist_ok=True)
    path = reference_path(name, reference_dir)
    write_exr(path, data.astype(np.float32), _reference_channels(names))
    return path


def _reference_channels(names: list[str]) -> list[str]:
    return names + [f"var.{c}" for c in names] + [f"seed0.{c}" for c in names] + ["n"]


def read_reference(name: str, channels: int, reference_dir: str = REFERENCE_DIR):
    """(mean, variance, K, seed-0 render) of ``name``'s reference: each value's mean, one render's variance."""
    data = read_exr(reference_path(name, reference_dir), _reference_channels(_channel_names(channels)),
                    allow_nan=True).astype(np.float64)
    c = channels
    return data[..., :c], data[..., c:2 * c], int(round(float(data[0, 0, -1]))), data[..., 2 * c:3 * c]


def _tile_sums(a: np.ndarray, tile: int) -> np.ndarray:
    """Sums over ``tile x tile`` blocks of an (H, W, C) array (edge tiles partial)."""
    h, w = a.shape[:2]
    th, tw = -(-h // tile), -(-w // tile)
    padded = np.zeros((th * tile, tw * tile) + a.shape[2:])
    padded[:h, :w] = a
    return padded.reshape(th, tile, tw, tile, *a.shape[2:]).sum(axis=(1, 3))


def _two_sided_threshold(p: float, dof: np.ndarray | float) -> np.ndarray:
    """|z| above which a two-sided test of probability ``p`` rejects: Student's t at ``dof`` (normal at inf)."""
    from scipy import stats

    dof = np.asarray(dof, dtype=np.float64)
    return np.where(np.isfinite(dof), stats.t.isf(p / 2.0, np.maximum(np.where(np.isfinite(dof), dof, 1.0), 1.0)),
                    stats.norm.isf(p / 2.0))


def statistics(image: np.ndarray, mean: np.ndarray, var: np.ndarray, k: int, seed0: np.ndarray | None = None,
               tile: int = TILE, alpha: float = ALPHA) -> dict:
    """The tests of ``image`` (seed 0) against a reference (module docstring): z-scores and thresholds per value
    (``z_values``, ``t_values``), per tile (``z_tiles`` (tiles_y, tiles_x, C), ``t_tiles``) and of the image
    mean per channel (``z_global``, ``t_global``); the sign test's counts ``n_up``, ``n_down`` and ``p_sign``
    (1 without ``seed0``); ``ok``."""
    image = np.asarray(image, dtype=np.float64)
    d = image - mean
    est = var * (1.0 + 1.0 / k)  # variance of d: the render's plus the reference mean's
    v = est + ((FLOOR_REL * np.abs(mean) + FLOOR_ABS) * np.sqrt(1.0 + 1.0 / k)) ** 2
    est2 = est**2 / (k - 1)  # Welch-Satterthwaite: the estimated part has k - 1 degrees of freedom, the floor is exact

    def dof(v_sum, est2_sum):
        return np.where(est2_sum > 0, v_sum**2 / np.maximum(est2_sum, 1e-300), np.inf)

    def threshold(n_tests, dofs):  # Sidak over n_tests, a quarter of alpha per test kind
        return _two_sided_threshold(1.0 - (1.0 - alpha / 4.0) ** (1.0 / n_tests), dofs)

    z_values = d / np.sqrt(v)
    t_values = threshold(z_values.size, dof(v, est2))
    d_t, v_t = _tile_sums(d, tile), _tile_sums(v, tile)
    z_tiles = d_t / np.sqrt(v_t)
    t_tiles = threshold(z_tiles.size, dof(v_t, _tile_sums(est2, tile)))
    v_g = v.sum(axis=(0, 1))
    z_global = d.sum(axis=(0, 1)) / np.sqrt(v_g)
    t_global = threshold(z_global.size, dof(v_g, est2.sum(axis=(0, 1))))
    n_up = n_down = 0
    p_sign = 1.0
    if seed0 is not None:
        same = image - seed0
        moved = np.abs(same) > SIGN_REL * np.abs(seed0) + FLOOR_ABS
        n_up, n_down = int(np.count_nonzero(moved & (same > 0))), int(np.count_nonzero(moved & (same < 0)))
        if n_up + n_down:
            from scipy import stats

            p_sign = float(stats.binomtest(n_up, n_up + n_down, 0.5).pvalue)
    ok = bool(np.all(np.abs(z_values) <= t_values) and np.all(np.abs(z_tiles) <= t_tiles)
              and np.all(np.abs(z_global) <= t_global) and p_sign >= alpha / 4.0)
    return {"z_values": z_values, "t_values": t_values, "z_tiles": z_tiles, "t_tiles": t_tiles,
            "z_global": z_global, "t_global": t_global, "n_up": n_up, "n_down": n_down, "p_sign": p_sign,
            "ok": ok}


def compare(name: str, image: np.ndarray, reference_dir: str = REFERENCE_DIR, output_dir: str = OUTPUT_DIR,
            tile: int = TILE, alpha: float = ALPHA) -> dict:
    """Raise :class:`RegressionMismatch` unless ``image`` (a seed-0 render) passes every test against the
    reference of ``name``; return :func:`statistics`."""
    image = np.asarray(image, dtype=np.float32)
    if image.ndim == 2:
        image = image[..., None]
    ref_path = reference_path(name, reference_dir)
    if not os.path.isfile(ref_path):
        _write_outputs(name, image, None, output_dir)
        raise RegressionMismatch(f"{name}: no reference {ref_path}; create it deliberately with `make refs`")
    try:
        mean, var, k, seed0 = read_reference(name, image.shape[-1], reference_dir)
    except ValueError as exc:  # ExrError: an old single-image reference or other channels
        raise RegressionMismatch(f"{name}: {ref_path} is not a statistical reference ({exc}); `make refs`") from exc
    if mean.shape != image.shape:
        new_path, _ = _write_outputs(name, image, None, output_dir)
        raise RegressionMismatch(f"{name}: shape {image.shape} != reference {mean.shape}; new render: {new_path}")
    st = statistics(image, mean, var, k, seed0, tile, alpha)
    if not st["ok"]:
        bad_v = np.abs(st["z_values"]) > st["t_values"]
        bad_t = np.abs(st["z_tiles"]) > st["t_tiles"]
        bad_g = np.abs(st["z_global"]) > st["t_global"]
        new_path, z_path = _write_outputs(name, image, st["z_tiles"], output_dir)
        worst = np.unravel_index(np.argmax(np.abs(st["z_tiles"]) / st["t_tiles"]), bad_t.shape)
        raise RegressionMismatch(
            f"{name}: {int(bad_v.sum())} of {bad_v.size} values and {int(bad_t.sum())} of {bad_t.size} tile values "
            f"({tile} x {tile} px) outside the reference's noise (worst tile z {float(st['z_tiles'][worst]):+.2f} "
            f"against {float(st['t_tiles'][worst]):.2f} at tile {tuple(int(i) for i in worst[:2])}, channel "
            f"{int(worst[2])}); image mean z per channel "
            f"{np.array2string(st['z_global'], precision=2)} against "
            f"{np.array2string(np.asarray(st['t_global']), precision=2)} ({int(bad_g.sum())} outside); "
            f"against the seed-0 reference render {st['n_up']} values up, {st['n_down']} down "
            f"(sign test p {st['p_sign']:.2g}, limit {alpha / 4:.2g}); "
            f"reference {ref_path} (K={k}); new render: {new_path}, z per tile: {z_path}"
        )
    return st


def check_render(name: str, render: Callable[[list[int]], list[np.ndarray]], update: bool, seeds: int = SEEDS,
                 reference_dir: str = REFERENCE_DIR, output_dir: str = OUTPUT_DIR) -> np.ndarray:
    """The regression test of one render: ``render(seeds)`` returns one image per seed (one scene, rendered
    with each). Seed 0 is rendered and compared; with ``update`` the reference is rewritten from seeds
    ``0..seeds-1`` instead. Returns the seed-0 render."""
    images = [np.asarray(im, dtype=np.float32) for im in render(list(range(seeds)) if update else [TEST_SEED])]
    if update:
        write_reference(name, images, reference_dir)
    else:
        compare(name, images[0], reference_dir, output_dir)
    return images[0]


def _write_outputs(name, image, z_tiles, output_dir):
    os.makedirs(output_dir, exist_ok=True)
    new_path = os.path.join(output_dir, f"{name}.new.exr")
    write_exr(new_path, image, _channel_names(image.shape[-1]))
    z_path = None
    if z_tiles is not None:
        z_path = os.path.join(output_dir, f"{name}.z.exr")
        write_exr(z_path, z_tiles.astype(np.float32), _channel_names(z_tiles.shape[-1]))
    return new_path, z_path
