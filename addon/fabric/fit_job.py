"""The BTF fit (``python -m material_structures fabric fit BTF --out OUT``) as a background process of Blender
(``..background_job``: progress as JSON lines, one per fitted tile, and cancel). When it finishes OUT holds the
parameter maps, ``params.json`` and the fitted closure maps, ready for ``import_fit_material``."""

from __future__ import annotations

import os

from .. import background_job
from ..background_job import BackgroundJob

KIND = "fabric"
NEEDS = ("numpy", "scipy")  # the fitter's neighbour search and sparse graphs


def default_out_dir(btf_dir: str) -> str:
    """Where a fit of ``btf_dir`` goes unless told: beside it, ``<BTF folder>_fit`` (never inside the BTF)."""
    return os.path.normpath(btf_dir) + "_fit"


def fit_command(btf_dir: str, out_dir: str, workers: int = 1) -> list[str]:
    """The CLI call: the fitter's own defaults, in local processes (``--no-dask``; cancel stops them all)."""
    return [background_job.python_executable(NEEDS), "-m", "material_structures", "fabric", "fit", btf_dir,
            "--out", out_dir, "--no-dask", "--workers", str(max(1, int(workers)))]


def current_job() -> FabricFitJob | None:
    return background_job.current_job(KIND)


def set_current_job(job: FabricFitJob | None) -> None:
    background_job.set_current_job(KIND, job)


def job_running() -> bool:
    return background_job.job_running(KIND)


class FabricFitJob(BackgroundJob):
    """One background BTF fit; ``iterations`` counts its tiles (known once the fit reports them)."""

    label = "Fabric fit"
    unit = "tile"
    log_name = "fit_log.txt"

    def __init__(self, btf_dir: str, out_dir: str, workers: int = 1):
        if not (os.path.isfile(os.path.join(btf_dir, "btf.json")) or btf_dir.endswith((".json", ".npz"))):
            raise FileNotFoundError(f"no btf.json in {btf_dir!r}")
        super().__init__(fit_command(btf_dir, out_dir, workers), out_dir, iterations=1)
        self.btf_dir = btf_dir

    @property
    def result_path(self) -> str:
        return os.path.join(self.out_dir, "params.json")
