"""Regenerate the sample data shipped with the extension (``make samples``), with the project's own commands:

    .venv/bin/python scripts/make_samples.py [DIR]      (DIR: default samples/ of this checkout)

writes, replacing what was there (``DIR/library``, the generated asset library, is left alone):

- ``DIR/fabric_btf``: a 16 x 16 texel synthetic BTF, 8 lights x 8 views (``fabric synth``): the Fabric panel's
  Fit BTF input;
- ``DIR/teeth_capture``: a one-tooth synthetic capture, one camera, 4 lights, 24 x 16 pixels, with its
  ``scene.json`` (``teeth synth``): the Teeth panel's Fit to capture input;
- ``DIR/brush_states/state_0`` ... ``state_7``: the fabric brush's Data-Driven states, parameter folders of fibres
  brushed toward k * 45 degrees (``save_params``).

Every number is fixed here (seeds included), so a rerun writes the same files on the same platform.
"""

from __future__ import annotations

import os
import shutil
import sys

import numpy as np

from material_structures.cli import main
from material_structures.core.fabric.parameter_maps import make_maps, save_params
from material_structures.core.fabric.quaternion import quat_from_axis_angle

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
BTF = ["--width", "16", "--height", "16", "--lights", "8", "--views", "8", "--seed", "0"]
CAPTURE = ["--teeth", "1", "--width", "24", "--height", "16", "--lights", "4", "--cameras", "1", "--samples", "4",
           "--samples-background", "0", "--mesh-resolution", "10", "--seed", "12345"]
STATE_TEXELS = 8  # each state's maps: 8 x 8 texels of one value (the brush samples them at the stroke)
STATE_TILT_DEG = 40.0  # how far the brushed fibres lean toward the stroke


def brush_state(k: int):
    """State ``k``: fibres tilted ``STATE_TILT_DEG`` toward k * 45 degrees, a velvet red a little darker per k."""
    a = np.radians(45.0 * k)
    tilt = quat_from_axis_angle(np.array([-np.sin(a), np.cos(a), 0.0]), np.array(np.radians(STATE_TILT_DEG)))
    n = STATE_TEXELS
    return make_maps(np.full((n, n, 3), (0.30 - 0.02 * k, 0.03, 0.05)), np.full((n, n, 3), 0.4),
                     np.full((n, n, 2), (0.3, 0.6)), np.tile(tilt, (n, n, 1)))


def make_samples(out: str) -> dict[str, str]:
    """Write the three samples into ``out``; returns ``{name: folder}``."""
    paths = {name: os.path.join(out, name) for name in ("fabric_btf", "teeth_capture", "brush_states")}
    for path in paths.values():
        shutil.rmtree(path, ignore_errors=True)
    os.makedirs(out, exist_ok=True)
    assert main(["fabric", "synth", "--out", paths["fabric_btf"], *BTF]) == 0
    assert main(["teeth", "synth", "--out", paths["teeth_capture"], *CAPTURE]) == 0
    for k in range(8):
        save_params(os.path.join(paths["brush_states"], f"state_{k}"), brush_state(k))
    return paths


def folder_bytes(path: str) -> int:
    return sum(os.path.getsize(os.path.join(d, f)) for d, _, files in os.walk(path) for f in files)


if __name__ == "__main__":
    target = sys.argv[1] if len(sys.argv) > 1 else os.path.join(ROOT, "samples")
    for name, path in make_samples(target).items():
        print(f"{name}: {folder_bytes(path) / 1024:.0f} KiB in {path}")
