"""What a fit leaves to check it by: the loss plot and the held-out lights.

The held-out check renders the fitted scene for the lights the fit never used
(``optimise.held_out_light_ids``) with every camera, and compares the tooth pixels with the capture:

    rms_relative = sqrt(mean (F - C)^2) / sqrt(mean C^2)     over tooth pixels, lights, channels

per pixel and of 8 x 8 box-filtered images (``fit_loss.block_sums``; the per-pixel figure includes the
Monte Carlo noise of capture and check render), and the per-channel ratio of the tooth-pixel means.
``check.png`` shows, per held-out light and camera, capture | fit | 4 x |difference|, tone-mapped alike.
"""

from __future__ import annotations

import os

import numpy as np

from ..png_io import write_png
from .capture import Capture
from .fit_loss import block_counts, block_sums
from .path_tracer import RenderSettings, render
from .scene import TeethScene

CHECK_SPP = 64
CHECK_BLOCK = 8
DIFFERENCE_GAIN = 4.0


def plot_loss(log: list, path: str) -> None:
    """Loss per iteration (and best loss) as a PNG, like the thesis' Fig. 5.14-5.16 (matplotlib where it
    is installed, else a plain raster plot: log-scale loss in blue, best loss in orange)."""
    try:
        import matplotlib
    except ImportError:
        write_png(path, loss_raster(log))
        return

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(6, 3.5))
    it = np.arange(len(log))
    ax.semilogy(it, [e["loss"] for e in log], label="loss (L2)")
    ax.semilogy(it, [e["best_loss"] for e in log], label="best loss")
    ax.set_xlabel("iteration")
    ax.set_ylabel("loss")
    ax.legend()
    fig.tight_layout()
    fig.savefig(path, dpi=100)
    plt.close(fig)


def loss_raster(log: list, size: tuple[int, int] = (240, 400)) -> np.ndarray:
    """(H, W, 3) uint8 plot of the loss (blue) and best loss (orange) per iteration on a log scale."""
    h, w = size
    img = np.full((h, w, 3), 255, dtype=np.uint8)
    img[[8, h - 9], 8:w - 8] = 120
    img[8:h - 8, [8, w - 9]] = 120
    series = [np.array([e["loss"] for e in log], dtype=np.float64),
              np.array([e["best_loss"] for e in log], dtype=np.float64)]
    vals = np.concatenate(series)
    vals = vals[np.isfinite(vals) & (vals > 0)]
    if len(log) == 0 or len(vals) == 0:
        return img
    lo, hi = np.log10(vals.min()), np.log10(vals.max())
    hi = hi if hi > lo else lo + 1.0
    for ys, colour in zip(series, ((31, 119, 180), (255, 127, 14)), strict=True):
        ok = np.isfinite(ys) & (ys > 0)
        if not ok.any():
            continue
        x = np.interp(np.linspace(0, len(ys) - 1, 4 * (w - 20)), np.arange(len(ys))[ok], np.log10(ys[ok]))
        col = np.linspace(10, w - 11, len(x)).astype(int)
        row = (h - 11 - (x - lo) / (hi - lo) * (h - 22)).astype(int)
        img[row, col] = colour
    return img


def held_out_errors(fitted: np.ndarray, capture: np.ndarray, masks: np.ndarray) -> dict:
    """The check's figures for (n_cam, n_light, H, W, 3) images of the fit and the capture."""
    w = np.broadcast_to(masks[:, None, :, :, None], fitted.shape)
    f, c = fitted[w], capture[w]
    tile_f = block_sums(fitted * w, CHECK_BLOCK) / block_counts(masks, CHECK_BLOCK)
    tile_c = block_sums(capture * w, CHECK_BLOCK) / block_counts(masks, CHECK_BLOCK)
    tiles = np.broadcast_to(block_sums(masks[:, None, :, :, None].astype(np.float64), CHECK_BLOCK) > 0, tile_f.shape)
    mean_f = (fitted * w).sum(axis=(0, 1, 2, 3)) / max(w[..., 0].sum(), 1)
    mean_c = (capture * w).sum(axis=(0, 1, 2, 3)) / max(w[..., 0].sum(), 1)
    return {
        "rms_relative": float(np.sqrt(np.mean((f - c) ** 2) / max(np.mean(c**2), 1e-300))),
        "rms_relative_tiles": float(np.sqrt(np.mean((tile_f[tiles] - tile_c[tiles]) ** 2)
                                            / max(np.mean(tile_c[tiles] ** 2), 1e-300))),
        "mean_ratio_rgb": (mean_f / np.maximum(mean_c, 1e-300)).tolist(),
    }


def _tone(x: np.ndarray, white: float) -> np.ndarray:
    return np.clip(np.clip(x / white, 0.0, 1.0) ** (1 / 2.2) * 255.0 + 0.5, 0, 255).astype(np.uint8)


def check_image(fitted: np.ndarray, capture: np.ndarray, masks: np.ndarray) -> np.ndarray:
    """(rows, 3 panels) sRGB-ish uint8 image: per light and camera, capture | fit | gain x |difference| on
    the tooth pixels (the fit is rendered there only)."""
    rows = []
    for li in range(fitted.shape[1]):
        for ci in range(fitted.shape[0]):
            cap, fit_ = capture[ci, li], fitted[ci, li]
            tooth = masks[ci]
            white = float(np.percentile(cap[tooth], 99)) if tooth.any() else float(cap.max())
            white = max(white, 1e-12)
            gap = np.full((cap.shape[0], 2, 3), 255, dtype=np.uint8)
            diff = DIFFERENCE_GAIN * np.abs(fit_ - cap) * tooth[:, :, None]  # the fit renders tooth pixels only
            rows.append(np.concatenate([_tone(cap, white), gap, _tone(fit_, white), gap, _tone(diff, white)], axis=1))
            rows.append(np.full((2, rows[-1].shape[1], 3), 255, dtype=np.uint8))
    return np.concatenate(rows[:-1], axis=0) if rows else np.zeros((1, 1, 3), dtype=np.uint8)


def held_out_check(scene: TeethScene, capture: Capture, light_ids: np.ndarray, image_path: str | None = None,
                   spp: int = CHECK_SPP, seed: int = 7, max_depth: int | None = None, workers: int = 1) -> dict:
    """Render ``scene`` for the held-out ``light_ids`` with every camera (tooth pixels, ``spp``), compare
    with the capture (``held_out_errors``) and write the side-by-side image to ``image_path``."""
    light_ids = np.asarray(light_ids, dtype=np.int64)
    if len(light_ids) == 0:
        return {"lights": [], "note": "no held-out lights (fewer than 4 lights, or none asked for)"}
    pixels = [np.flatnonzero(m.ravel()) for m in capture.masks]
    res = render(scene, capture.cameras, capture.lights,
                 RenderSettings(spp=spp, max_depth=max_depth, seed=seed, workers=workers), pixels=pixels,
                 light_ids=light_ids)
    ref = capture.images[:, light_ids].astype(np.float64)
    out = {"lights": light_ids.tolist(), "spp": spp, **held_out_errors(res.images, ref, capture.masks)}
    if image_path is not None:
        write_png(image_path, check_image(res.images, ref, capture.masks))
        out["image"] = os.path.basename(image_path)
    return out
