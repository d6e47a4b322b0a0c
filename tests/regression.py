"""Render-regression helper: compare a rendered image with its reference EXR.

References live in ``tests/references/NAME.exr``. ``make refs`` (pytest ``--update-refs``) rewrites
them deliberately. On a mismatch the new render and an absolute-difference image are written to
``tests/output/NAME.new.exr`` and ``tests/output/NAME.diff.exr`` and the failure names them.
"""

from __future__ import annotations

import os

import numpy as np

from material_structures.core.exr_io import read_exr, write_exr

TESTS_DIR = os.path.dirname(os.path.abspath(__file__))
REFERENCE_DIR = os.path.join(TESTS_DIR, "references")
OUTPUT_DIR = os.path.join(TESTS_DIR, "output")


class RegressionMismatch(AssertionError):
    pass


def compare_to_reference(
    name: str,
    image: np.ndarray,
    update: bool,
    atol: float = 0.0,
    rtol: float = 0.0,
    reference_dir: str = REFERENCE_DIR,
    output_dir: str = OUTPUT_DIR,
) -> None:
    """Assert ``|image - ref| <= atol + rtol * |ref|`` everywhere (exact when both are 0).

    With ``update`` the reference is (re)written and the comparison is skipped.
    """
    image = np.asarray(image, dtype=np.float32)
    ref_path = os.path.join(reference_dir, f"{name}.exr")
    if update:
        os.makedirs(reference_dir, exist_ok=True)
        write_exr(ref_path, image, _channel_names(image))
        return
    if not os.path.isfile(ref_path):
        _write_outputs(name, image, None, output_dir)
        raise RegressionMismatch(f"{name}: no reference {ref_path}; create it deliberately with `make refs`")
    ref = read_exr(ref_path, channels=_channel_names(image), allow_nan=True)
    if ref.shape != image.shape:
        new_path, _ = _write_outputs(name, image, None, output_dir)
        raise RegressionMismatch(
            f"{name}: shape {image.shape} != reference {ref.shape}; new render: {new_path}"
        )
    diff = np.abs(image - ref)
    bad = ~(diff <= atol + rtol * np.abs(ref))
    if np.any(bad):
        new_path, diff_path = _write_outputs(name, image, diff, output_dir)
        raise RegressionMismatch(
            f"{name}: {int(bad.sum())} of {bad.size} values differ from {ref_path} "
            f"(max abs diff {float(np.nanmax(diff)):.6g}, atol {atol}, rtol {rtol}); "
            f"new render: {new_path}, difference: {diff_path}"
        )


def _channel_names(image: np.ndarray) -> list[str]:
    n = image.shape[-1] if image.ndim == 3 else 1
    return ["R", "G", "B", "A"][:n] if n <= 4 else [f"C{i}" for i in range(n)]


def _write_outputs(name, image, diff, output_dir):
    os.makedirs(output_dir, exist_ok=True)
    new_path = os.path.join(output_dir, f"{name}.new.exr")
    write_exr(new_path, image, _channel_names(image))
    diff_path = None
    if diff is not None:
        diff_path = os.path.join(output_dir, f"{name}.diff.exr")
        write_exr(diff_path, diff, _channel_names(diff))
    return new_path, diff_path
