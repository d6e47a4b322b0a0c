"""The teeth fit runs where only numpy and numba are installed, as in a desktop Blender that bundles the
numba wheel: no scipy, tqdm, matplotlib, Pillow, trimesh or Dask (their imports are blocked in the fit's
process). It still writes its result, report, check image and loss plot."""

from __future__ import annotations

import json
import os
import subprocess
import sys

import pytest

from material_structures.cli import main

pytestmark = pytest.mark.heavy  # seconds each: outside `make test-fast`

BLOCKED = ("scipy", "tqdm", "matplotlib", "PIL", "trimesh", "dask", "distributed", "embreex")
RUN = """
import sys
class Blocker:
    def find_spec(self, name, path=None, target=None):
        if name.split(".")[0] in {blocked!r}:
            raise ImportError(f"blocked: {{name}}")
        return None
sys.meta_path.insert(0, Blocker())
from material_structures.cli import main
sys.exit(main({argv!r}))
"""


NEEDS_NUMBA = pytest.mark.skipif(__import__("importlib").util.find_spec("numba") is None, reason="needs numba")


@NEEDS_NUMBA
def test_a_fit_from_the_scene_runs_with_numpy_and_numba_only(tmp_path):
    """``test_fit_runs_with_numpy_and_numba_only`` (nightly) from the capture's scene (``--init scene``):
    without the literature search and the start trials (8 of its 16 s), the fit, its report, check image
    and loss plot."""
    _check_fit_runs_bare(tmp_path, ["--init", "scene"])


@pytest.mark.slow
@NEEDS_NUMBA
def test_fit_runs_with_numpy_and_numba_only(tmp_path):
    """Short counterpart in `make test`: test_a_fit_from_the_scene_runs_with_numpy_and_numba_only.
    The default fit: the literature search, the start trials, then the fit."""
    _check_fit_runs_bare(tmp_path, [])


def _check_fit_runs_bare(tmp_path, init: list[str]) -> None:
    cap = tmp_path / "cap"
    assert main(["teeth", "synth", "--out", str(cap), "--teeth", "1", "--width", "12", "--height", "10",
                 "--lights", "4", "--cameras", "1", "--samples", "1", "--samples-background", "0",
                 "--mesh-resolution", "10"]) == 0
    out = tmp_path / "fit"
    argv = ["teeth", "fit", str(cap), "--out", str(out), "--iterations", "2", *init]
    env = {**os.environ, "MATERIAL_STRUCTURES_PROGRESS": "json"}
    r = subprocess.run([sys.executable, "-c", RUN.format(blocked=BLOCKED, argv=argv)], capture_output=True,
                       text=True, env=env, timeout=600)
    assert r.returncode == 0, r.stderr[-3000:]
    for name in ("scene_fit.json", "fit_report.json", "check.png", "loss.png", "loss.json"):
        assert (out / name).is_file(), name
    assert (out / "check.png").read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    assert json.loads((out / "fit_report.json").read_text())["held_out"]["lights"] == [2]
