"""Shared pytest configuration: the render-regression switches (``--update-refs``, ``--cycles-kernel``) and
the numba warm-up.

Markers are registered in pyproject.toml and are strict (``--strict-markers``): a misspelt marker is an error.

The numba warm-up: the compiled teeth tracer's kernels are cached on disk (``cache=True``), but a cold cache
compiles them in every process that needs them first, which under ``pytest -n 2`` is both workers and the
fits' subprocesses at once. The controlling process (or a run without xdist) therefore starts
``tests/warm_numba.py`` in the background when the session starts; tests of the teeth tracer (``teeth`` in
their file's or their own name, the Dask suite, the ``numba`` marker) run after all others and wait for it.
So the kernels compile once per run, and a warm cache costs the warm-up a second or two.
"""

from __future__ import annotations

import os
import subprocess
import sys
import time

import pytest

# Test helpers (``regression``) import as top-level modules under --import-mode=importlib.
TESTS_DIR = os.path.dirname(os.path.abspath(__file__))
sys.path.insert(0, TESTS_DIR)

_WARM_ENV = "MS_TEST_NUMBA_WARM"  # path of the warm-up's done file, set by the controlling process
_WARM_TIMEOUT = 900.0


def pytest_addoption(parser: pytest.Parser) -> None:
    parser.addoption(
        "--update-refs",
        action="store_true",
        default=False,
        help="rewrite the reference EXRs under tests/references/ instead of comparing (make refs)",
    )
    parser.addoption(
        "--cycles-kernel",
        choices=("native", "sse42"),
        default="native",
        help="the Cycles CPU kernel of the render-regression suite: native (the best this CPU runs) or sse42 "
             "(forced through Cycles' debug flags)",
    )
    parser.addoption(
        "--no-numba-warmup",
        action="store_true",
        default=False,
        help="do not compile the teeth tracer's numba kernels in the background first",
    )


@pytest.fixture(scope="session")
def cycles_kernel(request) -> str:
    return request.config.getoption("--cycles-kernel")


def _needs_numba(item: pytest.Item) -> bool:
    """Tests of the teeth tracer: ``teeth`` in the file's or the test function's name (not a parameter's: the
    docs test of ``teeth-fit.md`` needs no tracer), the Dask suite, or the ``numba`` marker (the library's
    teeth fit demo)."""
    nodeid = item.nodeid.replace(os.sep, "/")
    name = getattr(item, "originalname", item.name)
    return ("teeth" in nodeid.split("::", 1)[0].rsplit("/", 1)[-1] or "teeth" in name
            or nodeid.startswith("tests/scaleout/") or item.get_closest_marker("numba") is not None)


_RUN_TMP_ENV = "MS_TEST_RUN_TMP"  # the run's temporary folder, set by the controlling process


def pytest_configure(config: pytest.Config) -> None:
    """One temporary folder per run (``TMPDIR``, inherited by the xdist workers, Blender and every subprocess),
    removed when the run passes and kept, named, when it fails: the runs' Blender user folders, extension
    repositories, compiled OSL shaders (Blender's script nodes leave their .oso files in the temporary folder) and
    Dask scratch space stay out of the machine's /tmp."""
    if hasattr(config, "workerinput") or os.environ.get(_RUN_TMP_ENV):
        return
    import tempfile

    run_tmp = tempfile.mkdtemp(prefix="ms-test-run-")
    os.environ[_RUN_TMP_ENV] = os.environ["TMPDIR"] = tempfile.tempdir = run_tmp
    config._ms_run_tmp = run_tmp  # type: ignore[attr-defined]


def pytest_unconfigure(config: pytest.Config) -> None:
    run_tmp = getattr(config, "_ms_run_tmp", None)
    if run_tmp is None:
        return
    import shutil

    if getattr(config, "_ms_exitstatus", 0) in (pytest.ExitCode.OK, pytest.ExitCode.NO_TESTS_COLLECTED):
        shutil.rmtree(run_tmp, ignore_errors=True)
    else:
        print(f"\nthe run's temporary files are kept in {run_tmp}", file=sys.stderr)


@pytest.hookimpl(tryfirst=True)  # before xdist's own sessionstart spawns the workers: they inherit the variable
def pytest_sessionstart(session: pytest.Session) -> None:
    config = session.config
    if hasattr(config, "workerinput") or os.environ.get(_WARM_ENV):
        return  # an xdist worker (or a nested pytest): the controlling process started the warm-up
    if config.getoption("--no-numba-warmup") or config.getoption("--collect-only"):
        return
    try:
        import numba  # noqa: F401
    except ImportError:  # the 4.5 environment: the numpy tracer, nothing to compile
        return
    import tempfile

    done = os.path.join(tempfile.mkdtemp(prefix="ms-numba-warm-"), "done")
    os.environ[_WARM_ENV] = done  # inherited by the xdist workers, started after this hook
    log = open(done + ".log", "w")  # noqa: SIM115  (the child writes it after this returns)
    config._ms_numba_warm = subprocess.Popen(  # type: ignore[attr-defined]
        [sys.executable, os.path.join(TESTS_DIR, "warm_numba.py"), done], stdout=log, stderr=subprocess.STDOUT,
    )


def pytest_collection_modifyitems(config: pytest.Config, items: list[pytest.Item]) -> None:
    """While the warm-up compiles, run everything else: the files holding a test of the teeth tracer go last,
    whole (a stable sort, the same in every xdist worker). Whole files, because ``--dist loadfile`` hands a file
    to a worker when its first test comes up: a file sorted apart would take its tracer test along early, and
    that worker would sit waiting for the warm-up while tests it could run are queued behind it."""
    if os.environ.get(_WARM_ENV):
        late = {item.nodeid.split("::", 1)[0] for item in items if _needs_numba(item)}
        items.sort(key=lambda item: item.nodeid.split("::", 1)[0] in late)


def pytest_sessionfinish(session: pytest.Session, exitstatus: int) -> None:
    session.config._ms_exitstatus = int(exitstatus)  # type: ignore[attr-defined]  (pytest_unconfigure reads it)
    proc = getattr(session.config, "_ms_numba_warm", None)
    if proc is not None and proc.poll() is None:
        proc.kill()
        proc.wait()


@pytest.fixture(autouse=True)
def _numba_warm(request) -> None:
    """Tests of the teeth tracer wait until the background warm-up has compiled its kernels."""
    done = os.environ.get(_WARM_ENV)
    if not done or not _needs_numba(request.node):
        return
    start = time.monotonic()
    while not os.path.exists(done) and not os.path.exists(done + ".failed"):
        if time.monotonic() - start > _WARM_TIMEOUT:
            break
        time.sleep(0.2)
