"""The fit's loss: L2 over the masked (tooth) pixels of every camera and light (eq. 5.7-5.8), optionally of
box-filtered images, and its estimate from two independent renders.

    rho = 1 / M sum_{masked pixels, lights, channels} (C - C_ref)^2,   d rho / d C = 2 (C - C_ref) / M

With ``block`` > 1 the images are first summed over block x block pixel tiles and each tile's squared
sum is divided by the tile's masked pixel count (same normaliser M, so block = 1 is the per-pixel
loss). The noise-free loss keeps its minimum where the model matches the capture, and the gradient's
dominant noise near the optimum, the product of pass A's and pass B's per-pixel noise, averages over
each tile (docs/teeth-fit.md).
"""

from __future__ import annotations

import numpy as np


def block_sums(x: np.ndarray, block: int) -> np.ndarray:
    """Sums of (n_cam, n_light, H, W, 3) over block x block pixel tiles, (n_cam, n_light, H/b, W/b, 3)
    (edges padded with zeros)."""
    if block == 1:
        return x
    n, nl, h, w, c = x.shape
    hb, wb = -(-h // block), -(-w // block)
    pad = np.zeros((n, nl, hb * block, wb * block, c))
    pad[:, :, :h, :w] = x
    return pad.reshape(n, nl, hb, block, wb, block, c).sum(axis=(3, 5))


def block_counts(masks: np.ndarray, block: int) -> np.ndarray:
    """Masked pixels per tile, (n_cam, 1, H/b, W/b, 1), at least 1."""
    return np.maximum(block_sums(masks[:, None, :, :, None].astype(np.float64), block), 1.0)


def l2_loss(images: np.ndarray, reference: np.ndarray, masks: np.ndarray, block: int = 1) -> tuple[float, np.ndarray]:
    """rho and d rho / d C of (n_cam, n_light, H, W, 3) images against ``reference`` over ``masks``."""
    w = np.broadcast_to(masks[:, None, :, :, None], images.shape).astype(np.float64)
    m = max(w.sum(), 1.0)
    diff = (images - reference) * w
    if block == 1:
        return float(np.sum(diff * diff) / m), 2.0 * diff / m
    h, wd = images.shape[2:4]
    sums = block_sums(diff, block)
    tile = sums / block_counts(masks, block)  # per-tile mean difference
    up = np.repeat(np.repeat(tile, block, axis=2), block, axis=3)[:, :, :h, :wd]
    return float(np.sum(tile * sums) / m), 2.0 * up * w / m


def paired_loss(img_a: np.ndarray, img_b: np.ndarray, reference: np.ndarray, masks: np.ndarray,
                block: int = 1) -> float:
    """The L2 loss (of ``block``-filtered images) estimated from two independent renders: the product
    (C_A - C_ref)(C_B - C_ref) has no Monte Carlo variance bias, unlike (C_A - C_ref)^2."""
    w = masks[:, None, :, :, None]
    m = max(float(np.sum(np.broadcast_to(w, img_b.shape))), 1.0)
    ra, rb = block_sums((img_a - reference) * w, block), block_sums((img_b - reference) * w, block)
    return float(np.sum(ra * rb / block_counts(masks, block)) / m)
