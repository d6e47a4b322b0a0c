"""The core fit (``python -m material_structures teeth fit ...``) as a background process.

Blender stays responsive: the fit runs in its own interpreter, its output (tqdm progress on stderr,
messages on stdout) is read by a thread into ``OUT/fit_log.txt`` and parsed for the iteration count and
loss; ``cancel()`` terminates the process and the workers it forked (the core's checkpoint lets
``--resume`` continue). When it finishes the CLI has written ``scene_fit.json``, ``loss.json`` and
``loss.png`` into OUT.

The one fit of this Blender session is ``current_job()``. Whether a fit runs, and its progress, are read
from it (``Scene.ms_teeth_fit.running`` / ``progress`` / ``status`` have getters, nothing of a job is stored
in the .blend): a file saved while a fit ran reopens with no fit running.
"""

from __future__ import annotations

import json
import os
import re
import subprocess
import sys
import threading

from ...core.teeth.fit_settings import FitSettings

FIT_DEFAULTS = FitSettings()

PROGRESS_ENV = "MATERIAL_STRUCTURES_PROGRESS"  # "json": the fit reports progress as JSON lines (cli/teeth.py)


def package_parent() -> str:
    """The folder that holds the ``material_structures`` package (this checkout or the extension)."""
    root = os.path.dirname(os.path.dirname(os.path.dirname(os.path.abspath(__file__))))
    return os.path.dirname(root)


def _fit_can_run_here() -> bool:
    """This interpreter can run the fit: numpy, and numba (the compiled tracer) or scipy (the numpy
    reference tracer's neighbour search); progress bars, plots and images need nothing else."""
    import importlib.util

    def has(m: str) -> bool:
        return importlib.util.find_spec(m) is not None

    return has("numpy") and (has("numba") or has("scipy"))


def python_executable() -> str:
    """The interpreter for the fit: ``MS_PYTHON`` if set; else this process's when it can run the fit
    (``_fit_can_run_here``); else the checkout's ``.venv``; else this process's."""
    if os.environ.get("MS_PYTHON"):
        return os.environ["MS_PYTHON"]
    if _fit_can_run_here():
        return sys.executable
    root = os.path.dirname(os.path.dirname(os.path.dirname(os.path.abspath(__file__))))
    for cand in (os.path.join(root, ".venv", "bin", "python"), os.path.join(root, ".venv", "Scripts", "python.exe")):
        if os.path.isfile(cand):
            return cand
    return sys.executable


def fit_command(capture_dir: str, out_dir: str, iterations: int = FIT_DEFAULTS.iterations, init: str = "literature",
                extra: list[str] | None = None, workers: int = 1) -> list[str]:
    """The CLI call (the fit's own settings; the panel sets only the iterations and the start). The fit renders
    in the one background process (with ``workers`` > 1 in that many processes it forks per render where numba
    is missing), so that cancelling stops all of it; pass ``extra=["--scheduler", ADDRESS]`` to use a Dask
    cluster instead."""
    extra = list(extra or [])
    if "--scheduler" not in extra and workers > 1:
        extra[:0] = ["--workers", str(int(workers))]
    return [python_executable(), "-m", "material_structures", "teeth", "fit", capture_dir, "--out", out_dir,
            "--iterations", str(int(iterations)), "--init", init, *extra]


def usable_cores() -> int:
    """Cores this process may run on (CPU affinity / container limits where the OS reports them)."""
    try:
        return max(1, len(os.sched_getaffinity(0)))
    except AttributeError:  # not on Linux
        return max(1, os.cpu_count() or 1)


_JOB: dict[str, FitJob | None] = {"job": None}  # the one background fit of this Blender session


def _progress_event(line: str) -> dict | None:
    """One progress line of the fit (a JSON object with a "progress" key), else None (a log line)."""
    if not line.startswith("{"):
        return None
    try:
        event = json.loads(line)
    except ValueError:
        return None
    return event if isinstance(event, dict) and "progress" in event else None


def current_job() -> FitJob | None:
    """The background fit started last in this Blender session (running or ended), or None."""
    return _JOB["job"]


def set_current_job(job: FitJob | None) -> None:
    _JOB["job"] = job


def job_running() -> bool:
    """Whether this session's fit process is alive (never blocks)."""
    job = _JOB["job"]
    return job is not None and job.is_alive()


class FitJob:
    """One background fit. ``poll()`` -> state; ``cancel()``; ``result_path`` once finished. ``outcome``: what
    became of the result (set by whoever applied it; ``settled`` then)."""

    def __init__(self, capture_dir: str, out_dir: str, iterations: int = FIT_DEFAULTS.iterations,
                 init: str = "literature", extra: list[str] | None = None, workers: int = 1):
        if not os.path.isfile(os.path.join(capture_dir, "capture.json")):
            raise FileNotFoundError(f"no capture.json in {capture_dir!r}")
        self.capture_dir, self.out_dir = capture_dir, out_dir
        self.iterations = int(iterations)
        self.cmd = fit_command(capture_dir, out_dir, iterations, init, extra, workers)
        self.proc: subprocess.Popen | None = None
        self.done_iterations = 0
        self.loss: float | None = None
        self.last_line = ""
        self.message = ""  # what the fit does between iterations (the literature search, a Gauss-Newton matrix)
        self.cancelled = False
        self._lock = threading.Lock()
        self._threads: list[threading.Thread] = []
        self.log_path = os.path.join(out_dir, "fit_log.txt")
        self.outcome = ""
        self.settled = False

    def start(self) -> FitJob:
        os.makedirs(self.out_dir, exist_ok=True)
        env = dict(os.environ)
        env["PYTHONPATH"] = os.pathsep.join([package_parent(), env.get("PYTHONPATH", "")]).rstrip(os.pathsep)
        env.setdefault("PYTHONUNBUFFERED", "1")
        env[PROGRESS_ENV] = "json"
        self._log = open(self.log_path, "w", encoding="utf-8")
        self._log.write("$ " + " ".join(self.cmd) + "\n")
        self._log.flush()
        # POSIX: its own process group, so that cancel() reaches the render workers it forks
        self.proc = subprocess.Popen(self.cmd, stdout=subprocess.PIPE, stderr=subprocess.PIPE, env=env,
                                     cwd=package_parent(), start_new_session=os.name == "posix")
        for stream in (self.proc.stdout, self.proc.stderr):
            t = threading.Thread(target=self._read, args=(stream,), daemon=True)
            t.start()
            self._threads.append(t)
        return self

    def _read(self, stream) -> None:
        buf = b""
        while True:
            chunk = stream.read1(4096) if hasattr(stream, "read1") else stream.read(4096)
            if not chunk:
                break
            buf += chunk
            parts = re.split(rb"[\r\n]", buf)
            buf = parts.pop()
            for raw in parts:
                self._line(raw.decode("utf-8", "replace"))
        if buf:
            self._line(buf.decode("utf-8", "replace"))

    def _line(self, line: str) -> None:
        line = line.strip()
        if not line:
            return
        with self._lock:
            self._log.write(line + "\n")
            self._log.flush()
            self.last_line = line
            event = _progress_event(line)
            if event is None:
                return
            if event.get("progress") == "fit":
                self.done_iterations = int(event.get("iteration", self.done_iterations))
                if event.get("loss") is not None:
                    self.loss = float(event["loss"])
            elif event.get("progress") in ("status", "init"):
                self.message = str(event.get("message", ""))

    @property
    def progress(self) -> float:
        return min(1.0, self.done_iterations / max(self.iterations, 1))

    def is_alive(self) -> bool:
        """The fit process has been started and has not exited (never blocks)."""
        return self.proc is not None and self.proc.poll() is None

    def state(self) -> str:
        """``poll()``'s state without waiting for the output readers (for drawing the UI)."""
        if self.proc is None or self.proc.poll() is None:
            return "RUNNING"
        if self.cancelled:
            return "CANCELLED"
        return "FINISHED" if self.proc.returncode == 0 and os.path.isfile(self.result_path) else "FAILED"

    def ended_text(self) -> str:
        """One line on an ended fit: its ``outcome`` once settled, else where its result / log is."""
        if self.settled and self.outcome:
            return self.outcome
        state = self.state()
        if state == "FINISHED":
            return f"finished, not applied: Apply Fit Result on {self.result_path}"
        return f"{state.lower()}: see {self.log_path}"

    def poll(self) -> str:
        """'RUNNING', 'FINISHED', 'CANCELLED' or 'FAILED'."""
        if self.proc is None:
            return "RUNNING"
        rc = self.proc.poll()
        if rc is None:
            return "RUNNING"
        for t in self._threads:
            t.join(timeout=5)
        if not self._log.closed:
            self._log.close()
        if self.cancelled:
            return "CANCELLED"
        return "FINISHED" if rc == 0 and os.path.isfile(self.result_path) else "FAILED"

    def wait(self, timeout: float | None = None) -> str:
        if self.proc is not None:
            self.proc.wait(timeout=timeout)
        return self.poll()

    def cancel(self) -> None:
        if self.proc is not None and self.proc.poll() is None:
            self.cancelled = True
            self._signal("SIGTERM")
            try:
                self.proc.wait(timeout=10)
            except subprocess.TimeoutExpired:
                self._signal("SIGKILL")
                try:
                    self.proc.wait(timeout=10)
                except subprocess.TimeoutExpired:  # poll() keeps reporting it; nothing more to send
                    pass
            if os.name == "posix":  # forked workers that outlived the fit process
                self._signal("SIGKILL")

    def _signal(self, name: str) -> None:
        """Send SIGTERM / SIGKILL to the fit's process group (POSIX) or terminate / kill it."""
        if os.name != "posix":
            (self.proc.terminate if name == "SIGTERM" else self.proc.kill)()
            return
        import signal

        try:
            os.killpg(self.proc.pid, getattr(signal, name))
        except ProcessLookupError:  # the group has ended
            pass

    @property
    def result_path(self) -> str:
        return os.path.join(self.out_dir, "scene_fit.json")

    @property
    def loss_plot(self) -> str:
        return os.path.join(self.out_dir, "loss.png")

    @property
    def check_image(self) -> str:
        """capture | fit | difference for the held-out lights (written when the fit ends)."""
        return os.path.join(self.out_dir, "check.png")

    def status_text(self) -> str:
        loss = "" if self.loss is None else f", loss {self.loss:.3e}"
        doing = f", {self.message}" if self.message else ""
        return f"Teeth fit: iteration {self.done_iterations}/{self.iterations}{loss}{doing} (Esc cancels)"
