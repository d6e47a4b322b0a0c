"""The fit's capture model (core/teeth/capture_outliers.py): isolated bright spikes are clamped to the bound of
their neighbourhood, bright edges and the noise are left alone; the 3 x 3 median against scipy's."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.ndimage import median_filter

from material_structures.core.teeth.capture import Capture, default_rig
from material_structures.core.teeth.capture_outliers import (
    OUTLIER_RELATIVE,
    OUTLIER_SIGMAS,
    clamp_bright_outliers,
    median3x3,
)


def test_median3x3_matches_scipy():
    x = np.random.default_rng(3).normal(size=(2, 3, 9, 11, 3))
    np.testing.assert_array_equal(median3x3(x), median_filter(x, size=(1, 1, 3, 3, 1), mode="nearest"))


def _capture_with_spikes(sigma: float = 0.01):
    cams, lights = default_rig(width=40, height=30, n_lights=3)
    rng = np.random.default_rng(0)
    yy, xx = np.mgrid[0:30, 0:40]
    shading = 0.2 + 0.004 * xx + 0.003 * yy
    shading = np.where(xx >= 20, shading + 0.5, shading)  # a bright edge: real content, kept
    images = (shading[None, None, :, :, None] + rng.normal(0.0, sigma, (len(cams), 3, 30, 40, 3))).astype(np.float32)
    masks = np.zeros((len(cams), 30, 40), dtype=bool)
    masks[:, 3:27, 3:37] = True
    spikes = [(0, 0, 10, 10, 0), (0, 2, 12, 30, 1), (1, 1, 20, 5, 2), (2, 0, 25, 21, 0), (2, 2, 4, 19, 1)]
    for c, li, y, x, ch in spikes:
        images[c, li, y, x, ch] += 200.0 * sigma + 2.0 * shading[y, x]  # a frozen bright path
    return Capture(cams, lights, images, masks), spikes


def test_isolated_spikes_are_clamped_and_nothing_else_moves():
    """Five planted spikes (200 noise deviations and twice the shading above it): exactly those move, each to the
    median of its neighbourhood plus 50 deviations and 100 %; the edge and the noise stay bit for bit; a second
    pass moves nothing; the report counts them and the light they carried."""
    cap, spikes = _capture_with_spikes()
    out, rep = clamp_bright_outliers(cap)
    moved = np.argwhere(out.images != cap.images)
    assert sorted(map(tuple, moved)) == sorted(spikes)
    assert rep["values"] == len(spikes) and rep["share"] == pytest.approx(len(spikes) / cap.images.size)
    sd = rep["noise_sd"]
    assert sd == pytest.approx(0.01, rel=0.15)  # the noise from the capture's own pixels
    med = median3x3(cap.images.astype(np.float64))
    for c, li, y, x, ch in spikes:
        bound = med[c, li, y, x, ch] * (1 + OUTLIER_RELATIVE) + OUTLIER_SIGMAS * sd
        assert out.images[c, li, y, x, ch] == pytest.approx(bound, rel=1e-6)
    taken = float(np.sum(cap.images, dtype=np.float64) - np.sum(out.images, dtype=np.float64))
    assert rep["light_share"] == pytest.approx(taken / float(np.sum(cap.images, dtype=np.float64)), rel=1e-4)
    again, rep2 = clamp_bright_outliers(out)
    assert rep2["values"] == 0 and np.array_equal(again.images, out.images)
    assert out.masks is cap.masks and out.cameras is cap.cameras


def test_a_capture_without_images_or_noise_is_read_as_it_is():
    cap, _ = _capture_with_spikes()
    bare = Capture(cap.cameras, cap.lights, None, cap.masks)
    assert clamp_bright_outliers(bare) == (bare, {"skipped": "the capture has no images"})
    unmasked = Capture(cap.cameras, cap.lights, cap.images, np.zeros_like(cap.masks))
    same, rep = clamp_bright_outliers(unmasked)
    assert same is unmasked and "noise" in rep["skipped"]
