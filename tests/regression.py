"""Render-regression helper: compare a rendered image with its reference EXR.

References live in ``tests/references/NAME.exr``. ``make refs`` (pytest ``--update-refs``) rewrites
them deliberately. On a mismatch the new render and an absolute-difference image are written to
``tests/output/NAME.new.exr`` and ``tests/output/NAME.diff.exr`` and the failure names them.

A lit Cycles render with a fixed seed is bit-identical from run to run on one machine, but not across CPU
instruction sets: on a CPU with AVX-512 (where Embree and OSL's JIT can take other code paths; which of them it is
was not isolated), a handful of pixels of the 4-sample renders differ by up to 0.016, against the lit scenes' 0.002
(six of eighteen library renders, 1-28 of 6912 values each, measured 2026-11-27 against AVX2 references). Such a
CPU class has its own references, ``tests/references/CLASS/NAME.exr``, only for the renders that differ: ``make
refs`` run on a machine of that class writes one where its render does not match the default reference within the
test's tolerance (and removes one that is no longer needed); everything else compares against
``tests/references/NAME.exr``.
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


def cpu_class(cpuinfo: str = "/proc/cpuinfo") -> str:
    """"avx512" on a CPU with AVX-512 (Linux's CPU flags), else "" (the default references)."""
    try:
        with open(cpuinfo, encoding="utf-8", errors="replace") as fh:
            for line in fh:
                if line.startswith("flags"):
                    return "avx512" if "avx512f" in line.split() else ""
    except OSError:
        pass
    return ""


def reference_path(name: str, reference_dir: str = REFERENCE_DIR, cls: str | None = None) -> str:
    """The reference of ``name`` for CPU class ``cls`` (the host's by default): the class's own where it
    exists, else the default one."""
    cls = cpu_class() if cls is None else cls
    own = os.path.join(reference_dir, cls, f"{name}.exr")
    return own if cls and os.path.isfile(own) else os.path.join(reference_dir, f"{name}.exr")


def compare_to_reference(
    name: str,
    image: np.ndarray,
    update: bool,
    atol: float = 0.0,
    rtol: float = 0.0,
    reference_dir: str = REFERENCE_DIR,
    output_dir: str = OUTPUT_DIR,
    cls: str | None = None,
) -> None:
    """Assert ``|image - ref| <= atol + rtol * |ref|`` everywhere (exact when both are 0), ``ref`` the
    reference of the CPU class ``cls`` (the host's by default; see the module docstring).

    With ``update`` the reference of that class is (re)written and the comparison is skipped; a new reference
    (none for any class yet) is written as the default one, whatever the class.
    """
    image = np.asarray(image, dtype=np.float32)
    cls = cpu_class() if cls is None else cls
    if update:
        default = os.path.join(reference_dir, f"{name}.exr")
        if cls and os.path.isfile(default):  # a class keeps its own only where the default does not match
            own = os.path.join(reference_dir, cls, f"{name}.exr")
            if _matches(image, default, atol, rtol):
                if os.path.isfile(own):
                    os.remove(own)
                return
            os.makedirs(os.path.dirname(own), exist_ok=True)
            write_exr(own, image, _channel_names(image))
            return
        os.makedirs(reference_dir, exist_ok=True)
        write_exr(default, image, _channel_names(image))
        return
    ref_path = reference_path(name, reference_dir, cls)
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


def _matches(image: np.ndarray, ref_path: str, atol: float, rtol: float) -> bool:
    try:
        ref = read_exr(ref_path, channels=_channel_names(image), allow_nan=True)
    except (OSError, ValueError):  # other channels (ExrError is a ValueError): not a match
        return False
    return ref.shape == image.shape and bool(np.all(np.abs(image - ref) <= atol + rtol * np.abs(ref)))


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
