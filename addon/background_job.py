"""A CLI command (``python -m material_structures ...``) as a background process of Blender, with progress.

Blender stays responsive: the command runs in its own interpreter (``python_executable``: Blender's Python,
which sees the wheels the extension bundles), with ``MATERIAL_STRUCTURES_PROGRESS=json`` so that it reports
progress as JSON lines on stdout (``{"progress": "fit", "iteration": i, "iterations": n, "loss": ...}``,
``{"progress": "status", "message": ...}``); two threads read its stdout and stderr into ``OUT/<log>``.
``cancel()`` terminates the process and the workers it forked (POSIX: its own process group).

The teeth fit (``teeth/fit_job.py``) and the fabric BTF fit (``fabric/fit_job.py``) subclass ``BackgroundJob``.
Each feature has one job per Blender session (``current_job(kind)``); nothing of a job is stored in the .blend.
"""

from __future__ import annotations

import json
import os
import re
import subprocess
import sys
import threading

PROGRESS_ENV = "MATERIAL_STRUCTURES_PROGRESS"  # "json": the CLI reports progress as JSON lines


def package_parent() -> str:
    """The folder that holds the ``material_structures`` package (this checkout or the installed extension)."""
    root = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
    return os.path.dirname(root)


def _has(module: str) -> bool:
    import importlib.util

    try:
        return importlib.util.find_spec(module) is not None
    except (ImportError, ValueError):
        return False


def can_run_here(*modules: str) -> bool:
    """This interpreter (with the paths ``child_path`` passes on) can import every one of ``modules``."""
    return all(_has(m) for m in modules)


def python_executable(needs: tuple[str, ...] = ("numpy",)) -> str:
    """The interpreter for a background command: ``MS_PYTHON`` if set; else this process's (Blender's own
    Python, or the venv's of the ``bpy`` module) when it can import ``needs`` (an installed extension: its
    bundled wheels); else the checkout's ``.venv`` (a checkout linked into a Blender without the wheels);
    else this process's (the command then says what it misses)."""
    if os.environ.get("MS_PYTHON"):
        return os.environ["MS_PYTHON"]
    if can_run_here(*needs):
        return sys.executable
    root = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
    for cand in (os.path.join(root, ".venv", "bin", "python"), os.path.join(root, ".venv", "Scripts", "python.exe")):
        if os.path.isfile(cand):
            return cand
    return sys.executable


def blender_site_packages() -> list[str]:
    """The site-packages Blender ships beside its Python (OpenImageIO, OpenColorIO, ...): in a desktop Blender
    that is its Python's own, in the ``bpy`` module it is not on ``sys.path``."""
    if "bpy" not in sys.modules:
        return []
    import glob

    import bpy

    local = bpy.utils.resource_path("LOCAL")
    ver = f"python{sys.version_info[0]}.{sys.version_info[1]}"
    return sorted(p for p in glob.glob(os.path.join(local, "python", "lib*", ver, "site-packages"))
                  + glob.glob(os.path.join(local, "python", "lib", "site-packages")) if os.path.isdir(p))


def child_path() -> list[str]:
    """``PYTHONPATH`` of a background command: the package's parent, this process's ``sys.path`` in its order
    (the extension's wheels, which Blender adds there) and Blender's own site-packages."""
    out: list[str] = []
    for p in [package_parent(), *sys.path, *blender_site_packages()]:
        if p and os.path.isdir(p) and p not in out:
            out.append(p)
    return out


def progress_event(line: str) -> dict | None:
    """One progress line of a command (a JSON object with a "progress" key), else None (a log line)."""
    if not line.startswith("{"):
        return None
    try:
        event = json.loads(line)
    except ValueError:
        return None
    return event if isinstance(event, dict) and "progress" in event else None


_JOBS: dict[str, BackgroundJob | None] = {}  # kind -> the job of this Blender session


def current_job(kind: str) -> BackgroundJob | None:
    """The ``kind`` job started last in this Blender session (running or ended), or None."""
    return _JOBS.get(kind)


def set_current_job(kind: str, job: BackgroundJob | None) -> None:
    _JOBS[kind] = job


def job_running(kind: str) -> bool:
    """Whether this session's ``kind`` job is alive (never blocks)."""
    job = _JOBS.get(kind)
    return job is not None and job.is_alive()


_WATCHES: list = []  # timers that follow a job (bpy.app.timers functions)


def watch(tick, first_interval: float = 0.5) -> None:
    """Register ``tick`` as a timer that follows a job (removed again by :func:`stop_all`)."""
    import bpy

    _WATCHES[:] = [t for t in _WATCHES if bpy.app.timers.is_registered(t)]
    _WATCHES.append(tick)
    bpy.app.timers.register(tick, first_interval=first_interval)


def stop_all(wait: bool = True) -> None:
    """Stop every running job of this session and the timers that follow them: the extension is disabled (its
    Cancel buttons go with it) or Blender quits (a fit would otherwise run on, orphaned, for its next output
    line). ``wait``: wait for each to end (else the signal alone, at exit)."""
    import bpy

    for tick in _WATCHES:
        if bpy.app.timers.is_registered(tick):
            bpy.app.timers.unregister(tick)
    _WATCHES.clear()
    for job in _JOBS.values():
        if job is not None and job.is_alive():
            if wait:
                job.cancel()
            else:
                job.cancelled = True
                job._signal("SIGTERM")


def stop_at_exit() -> None:
    """For ``atexit`` (registered while the extension is): Blender quits, its jobs get the signal to stop."""
    try:
        stop_all(wait=False)
    except Exception:  # noqa: BLE001  (Blender is going away; nothing to report to)
        pass


def usable_cores() -> int:
    """Cores this process may run on (CPU affinity / container limits where the OS reports them)."""
    try:
        return max(1, len(os.sched_getaffinity(0)))
    except AttributeError:  # not on Linux
        return max(1, os.cpu_count() or 1)


class BackgroundJob:
    """One background command. ``start()``; ``poll()`` -> state; ``cancel()``; ``result_path`` once finished.
    ``outcome``: what became of the result (set by whoever applied it; ``settled`` then). Subclasses give
    ``label`` (for the status bar) and ``result_path``."""

    label = "Job"
    unit = "iteration"  # what ``iterations`` counts, for the status bar
    log_name = "log.txt"

    def __init__(self, cmd: list[str], out_dir: str, iterations: int = 1):
        self.cmd = list(cmd)
        self.out_dir = out_dir
        self.iterations = max(int(iterations), 1)
        self.iterations_known = iterations > 1  # else the command reports its count; until then no "0/1"
        self.proc: subprocess.Popen | None = None
        self.done_iterations = 0
        self.loss: float | None = None
        self.last_line = ""
        self.message = ""  # what the command does between iterations
        self.cancelled = False
        self._lock = threading.Lock()
        self._threads: list[threading.Thread] = []
        self.log_path = os.path.join(out_dir, self.log_name)
        self.outcome = ""
        self.settled = False

    def start(self) -> BackgroundJob:
        os.makedirs(self.out_dir, exist_ok=True)
        env = dict(os.environ)
        env["PYTHONPATH"] = os.pathsep.join([*child_path(), env.get("PYTHONPATH", "")]).rstrip(os.pathsep)
        env.setdefault("PYTHONUNBUFFERED", "1")
        env.setdefault("PYTHONNOUSERSITE", "1")  # the packages the extension was tested with, not the user's
        env[PROGRESS_ENV] = "json"
        self._log = open(self.log_path, "w", encoding="utf-8")
        self._log.write("$ " + " ".join(self.cmd) + "\n")
        self._log.flush()
        # POSIX: its own process group, so that cancel() reaches the workers it forks
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
            event = progress_event(line)
            if event is not None:
                self.on_event(event)

    def on_event(self, event: dict) -> None:
        """A progress event: ``fit`` (iteration, iterations, loss) or ``status`` / ``init`` (message)."""
        if event.get("progress") == "fit":
            self.done_iterations = int(event.get("iteration", self.done_iterations))
            if event.get("iterations"):
                self.iterations = max(int(event["iterations"]), 1)
                self.iterations_known = True
            if event.get("loss") is not None:
                self.loss = float(event["loss"])
            if "message" in event:
                self.message = str(event["message"])
        elif event.get("progress") in ("status", "init"):
            self.message = str(event.get("message", ""))

    @property
    def progress(self) -> float:
        return min(1.0, self.done_iterations / max(self.iterations, 1))

    @property
    def result_path(self) -> str:
        raise NotImplementedError

    def is_alive(self) -> bool:
        """The process has been started and has not exited (never blocks)."""
        return self.proc is not None and self.proc.poll() is None

    def state(self) -> str:
        """``poll()``'s state without waiting for the output readers (for drawing the UI)."""
        if self.proc is None or self.proc.poll() is None:
            return "RUNNING"
        if self.cancelled:
            return "CANCELLED"
        return "FINISHED" if self.proc.returncode == 0 and os.path.isfile(self.result_path) else "FAILED"

    def ended_text(self) -> str:
        """One line on an ended job: its ``outcome`` once settled, else where its result / log is."""
        if self.settled and self.outcome:
            return self.outcome
        state = self.state()
        if state == "FINISHED":
            return f"finished, not applied: {self.result_path}"
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
            if os.name == "posix":  # forked workers that outlived the process
                self._signal("SIGKILL")

    def _signal(self, name: str) -> None:
        """Send SIGTERM / SIGKILL to the process group (POSIX) or terminate / kill the process."""
        if os.name != "posix":
            (self.proc.terminate if name == "SIGTERM" else self.proc.kill)()
            return
        import signal

        try:
            os.killpg(self.proc.pid, getattr(signal, name))
        except ProcessLookupError:  # the group has ended
            pass

    def status_text(self) -> str:
        loss = "" if self.loss is None else f", loss {self.loss:.3e}"
        doing = f", {self.message}" if self.message else ""
        if not self.iterations_known and not self.done_iterations:
            return f"{self.label}: starting{doing} (Esc cancels)"
        return f"{self.label}: {self.unit} {self.done_iterations}/{self.iterations}{loss}{doing} (Esc cancels)"
