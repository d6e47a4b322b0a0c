"""Inputs for ``make test-bare`` (run in the project venv): the data a user brings, made small.

    .venv/bin/python tests/bare/prepare.py DIR

writes DIR/capture (a 1-tooth teeth capture), DIR/btf (a 16 x 16 synthetic BTF) and DIR/states/state_0..7
(the fabric brush's data-driven states: fibres brushed toward k * 45 degrees).
"""

from __future__ import annotations

import os
import shutil
import sys

import numpy as np

from material_structures.cli import main
from material_structures.core.fabric.parameter_maps import make_maps, save_params
from material_structures.core.fabric.quaternion import quat_from_axis_angle


def prepare(out: str) -> None:
    shutil.rmtree(out, ignore_errors=True)
    os.makedirs(out)
    assert main(["teeth", "synth", "--out", os.path.join(out, "capture"), "--teeth", "1", "--width", "12",
                 "--height", "10", "--lights", "4", "--cameras", "1", "--samples", "1", "--samples-background", "0",
                 "--mesh-resolution", "10"]) == 0
    assert main(["fabric", "synth", "--out", os.path.join(out, "btf"), "--width", "16", "--height", "16",
                 "--lights", "8", "--views", "8"]) == 0
    for k in range(8):
        tilt = quat_from_axis_angle(np.array([-np.sin(np.radians(45 * k)), np.cos(np.radians(45 * k)), 0.0]),
                                    np.array(np.radians(40.0)))
        maps = make_maps(np.full((8, 8, 3), 0.05 + 0.02 * k), np.full((8, 8, 3), 0.4),
                         np.full((8, 8, 2), (0.3, 0.6)), np.tile(tilt, (8, 8, 1)))
        save_params(os.path.join(out, "states", f"state_{k}"), maps)


if __name__ == "__main__":
    prepare(sys.argv[1])
