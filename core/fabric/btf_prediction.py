"""Model prediction of a BTF from parameter maps, and the PSNR used to score fits."""

from __future__ import annotations

import numpy as np

from .parameter_maps import FabricMaps
from .synthetic_btf import render_btf


def predict_btf(maps: FabricMaps, wi: np.ndarray, wo: np.ndarray) -> np.ndarray:
    """``f_r(wi, wo) cos(theta_i)`` (N, H, W, 3) float32 of eq. 3.9 for every texel of ``maps``."""
    return render_btf(maps, wi, wo, noise=0.0)


def psnr(pred: np.ndarray, ref: np.ndarray, peak: float | None = None) -> float:
    """``10 log10(peak^2 / MSE)`` over all values; ``peak`` defaults to ``max(ref)``."""
    pred = np.asarray(pred, dtype=np.float64)
    ref = np.asarray(ref, dtype=np.float64)
    mse = float(np.mean((pred - ref) ** 2))
    peak = float(np.max(ref)) if peak is None else float(peak)
    return float("inf") if mse == 0 else 10.0 * np.log10(peak * peak / mse)


def texel_psnr(pred: np.ndarray, ref: np.ndarray) -> np.ndarray:
    """Angular-domain PSNR per texel (as in the thesis' Fig. 3.4): values (N, H, W, 3) -> (H, W)."""
    pred = np.asarray(pred, dtype=np.float64)
    ref = np.asarray(ref, dtype=np.float64)
    mse = np.mean((pred - ref) ** 2, axis=(0, 3))
    peak = np.max(ref, axis=(0, 3))
    with np.errstate(divide="ignore"):
        return 10.0 * np.log10(peak * peak / np.maximum(mse, 1e-300))
