"""A capture's isolated bright outliers, clamped before a fit reads it (the fit's capture model).

A least-squares fit (eq. 5.7-5.8) weighs each value of the capture by its squared residual. A value far above its
neighbours, a path-traced capture's rare bright path or a photograph's hot pixel, is frozen into the reference:
the fit chases it at every iteration, unlike its own renders' fresh noise. On the Mitsuba captures of ``bench
teeth-extrapolation`` such values reach 2000 noise deviations; on translucent-forward the 0.004 % of values this
module clamps carry nine tenths of the fit's loss at the truth.

The rule: with s the capture's noise (``fit_intervals.capture_noise_variance``, from its own pixels) and m the
median of a value's 3 x 3 neighbourhood in its image and channel (edges repeated), a value above
m + ``OUTLIER_SIGMAS`` s + ``OUTLIER_RELATIVE`` m is set to that bound. The bound sits far above any shading an image
of a tooth holds at a pixel's scale (the relative term keeps bright edges), so only isolated spikes move.

Measured on the three captures of ``bench teeth-extrapolation`` (docs/teeth-fit.md, "Isolated bright values are
clamped"): with every other default as it was then (g1 free), the fit predicted the novel camera and lights with
median tooth-mean errors of 1.2 / 0.3 / 0.5 % against 2.6 / 0.4 / 1.2 % without the clamp, and 8 x 8 tiles within
0.3 points of the truth's own noise.
"""

from __future__ import annotations

import numpy as np

from ..errors import UserError
from .capture import Capture

OUTLIER_SIGMAS = 50.0
OUTLIER_RELATIVE = 1.0


def median3x3(images: np.ndarray) -> np.ndarray:
    """The median of each value's 3 x 3 neighbourhood in its image and channel, edges repeated:
    (..., H, W, C) -> same shape."""
    h, w = images.shape[-3:-1]
    pad = [(0, 0)] * (images.ndim - 3) + [(1, 1), (1, 1), (0, 0)]
    p = np.pad(images, pad, mode="edge")
    shifted = np.stack([p[..., dy:dy + h, dx:dx + w, :] for dy in range(3) for dx in range(3)])
    return np.median(shifted, axis=0)


def clamp_bright_outliers(capture: Capture) -> tuple[Capture, dict]:
    """The capture with its isolated bright outliers clamped (module docstring), and what was clamped:
    ``{"values": n, "share": n / all values, "light_share": clamped light / all light, "noise_sd": s}``. A capture
    without images is returned as it is; one whose noise cannot be estimated too, with ``{"skipped": why}``."""
    if capture.images is None:
        return capture, {"skipped": "the capture has no images"}
    from .fit_intervals import capture_noise_variance

    try:
        sd = float(np.sqrt(capture_noise_variance(capture)))
    except UserError as e:
        return capture, {"skipped": str(e)}
    images = capture.images
    out = np.array(images, copy=True)
    clamped = 0
    removed = 0.0
    for c in range(images.shape[0]):  # one image at a time: its nine shifted copies, whatever the capture's size
        for li in range(images.shape[1]):
            im = images[c, li].astype(np.float64)
            med = median3x3(im)
            bound = (med + OUTLIER_SIGMAS * sd + OUTLIER_RELATIVE * med).astype(images.dtype)  # the images' type
            over = images[c, li] > bound
            clamped += int(over.sum())
            removed += float((im - bound)[over].sum())
            out[c, li] = np.where(over, bound, images[c, li])
    total = float(np.sum(images, dtype=np.float64))
    report = {"values": clamped, "share": clamped / images.size, "light_share": removed / total if total > 0 else 0.0,
              "noise_sd": sd}
    return Capture(capture.cameras, capture.lights, out, capture.masks), report
