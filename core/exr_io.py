"""Float OpenEXR read/write for parameter maps, BTF images and renders.

Arrays are ``(H, W, C)`` float32, row 0 = top row of the file (the file's first scanline).

Backends: the ``OpenEXR`` package (project venv) or, where it is absent (inside a desktop
Blender), the ``OpenImageIO`` module that Blender bundles. Both give identical arrays.
"""

from __future__ import annotations

import contextlib
import errno
import io
import os
import re
import sys
import tempfile
import threading
from collections.abc import Iterator, Sequence

import numpy as np

from .errors import BadFileError, MissingFileError

DEFAULT_CHANNELS = {1: ("Y",), 2: ("R", "G"), 3: ("R", "G", "B"), 4: ("R", "G", "B", "A")}


class ExrError(BadFileError):
    """An EXR file is missing, unreadable or does not hold what the caller needs."""


BACKEND: str | None = None  # "openexr" or "oiio"; None = first available


def _backend() -> str:
    if BACKEND:
        return BACKEND
    try:
        import OpenEXR  # noqa: F401
    except ImportError:
        try:
            import OpenImageIO  # noqa: F401
        except ImportError:
            raise ExrError("reading EXR files needs the 'OpenEXR' package or Blender's OpenImageIO") from None
        return "oiio"
    return "openexr"


def _import_openexr():
    import OpenEXR

    return OpenEXR


def write_exr(path: str | os.PathLike, array: np.ndarray, channels: Sequence[str] | None = None) -> None:
    """Write ``array`` (H, W) or (H, W, C) as a 32-bit float EXR with one channel per last axis entry.

    The file is written to a temporary name and renamed, so an interrupted write never leaves a
    truncated file under ``path``.
    """
    a = np.asarray(array, dtype=np.float32)
    if a.ndim == 2:
        a = a[:, :, None]
    if a.ndim != 3 or a.shape[0] < 1 or a.shape[1] < 1:
        raise ExrError(f"write_exr expects an (H, W) or (H, W, C) array, got shape {np.shape(array)}")
    n = a.shape[2]
    if channels is None:
        if n not in DEFAULT_CHANNELS:
            raise ExrError(f"give channel names for a {n}-channel image")
        channels = DEFAULT_CHANNELS[n]
    channels = tuple(channels)
    if len(channels) != n or len(set(channels)) != n:
        raise ExrError(f"{n} channels need {n} distinct names, got {channels}")
    path = os.fspath(path)
    folder = os.path.dirname(os.path.abspath(path))
    if not os.path.isdir(folder):  # the libraries say so in a RuntimeError without the path
        raise MissingFileError(f"{path}: cannot write there, the folder {folder} does not exist", folder)
    if not os.access(folder, os.W_OK | os.X_OK):
        raise PermissionError(errno.EACCES, "cannot write into this folder", folder)
    tmp = f"{path}.tmp-{os.getpid()}.exr"
    try:
        if _backend() == "oiio":
            _write_oiio(tmp, a, channels)
        else:
            OpenEXR = _import_openexr()
            header = {"compression": OpenEXR.ZIP_COMPRESSION, "type": OpenEXR.scanlineimage}
            data = {name: np.ascontiguousarray(a[:, :, i]) for i, name in enumerate(channels)}
            OpenEXR.File(header, data).write(tmp)
        os.replace(tmp, path)
    finally:
        if os.path.exists(tmp):
            os.remove(tmp)


def _write_oiio(path: str, a: np.ndarray, channels: tuple[str, ...]) -> None:
    import OpenImageIO as oiio

    spec = oiio.ImageSpec(a.shape[1], a.shape[0], a.shape[2], oiio.FLOAT)
    spec.channelnames = channels
    spec.attribute("compression", "zip")
    out = oiio.ImageOutput.create(path)
    if out is None or not out.open(path, spec):
        raise ExrError(f"cannot write EXR {path}: {oiio.geterror()}")
    ok = out.write_image(np.ascontiguousarray(a))
    out.close()
    if not ok:
        raise ExrError(f"cannot write EXR {path}: {oiio.geterror()}")


def exr_channel_names(path: str | os.PathLike) -> list[str]:
    """Names of the channels stored in an EXR file (single part)."""
    return list(_read_channels(path))


def _read_channels(path: str | os.PathLike) -> dict[str, np.ndarray]:
    """All channels of a single-part EXR as ``name -> (H, W)`` arrays."""
    path = os.fspath(path)
    if not os.path.isfile(path):
        raise ExrError(f"EXR file not found: {path}")
    said = _HeldLines()
    try:
        if _backend() == "oiio":
            import OpenImageIO as oiio

            inp = oiio.ImageInput.open(path)
            if inp is None:
                raise RuntimeError(oiio.geterror())
            try:
                names = list(inp.spec().channelnames)
                pixels = inp.read_image(oiio.FLOAT)
            finally:
                inp.close()
            if pixels is None:
                raise RuntimeError(oiio.geterror())
            pixels = np.asarray(pixels).reshape(pixels.shape[0], pixels.shape[1], -1)
            return {n: pixels[:, :, i] for i, n in enumerate(names)}
        with _library_lines_held(said):
            f = _import_openexr().File(path, separate_channels=True)
            return {name: ch.pixels for name, ch in f.channels().items()}
    except Exception as exc:  # the libraries raise RuntimeError/ValueError variants
        # the C library's own line names the damage ("PATH: (EXR_ERR_...) ... corrupt leader ..."), where the
        # binding's exception says only that the file has no parts
        named = [ln[len(path) + 2:] for ln in said.text.splitlines() if ln.startswith(f"{path}: ")]
        reason = re.sub(r"^\(EXR_ERR_\w+\)\s*", "", named[0]) if named else str(exc)
        raise ExrError(f"not a readable OpenEXR file: {path} ({reason})") from exc


class _HeldLines:
    """What the C library printed while a file was read."""

    def __init__(self) -> None:
        self.text = ""


_HOLD_LOCK = threading.Lock()


@contextlib.contextmanager
def _library_lines_held(said: _HeldLines) -> Iterator[None]:
    """The OpenEXR library prints its own lines when a file is damaged: its error on the process's stderr, then
    the binding's warning through ``sys.stdout``. Hold what is printed while a file is read: on failure the caller
    names the damage in its one-line error and whatever else was printed meanwhile (another thread's lines) goes to
    stderr; on success all of it does. Where the streams cannot be redirected, the file is read without."""
    python_lines = io.StringIO()  # the binding's warning goes through Python's sys.stdout
    with _HOLD_LOCK:
        for stream in (sys.stdout, sys.stderr):
            with contextlib.suppress(Exception):
                stream.flush()
        _flush_c_streams()  # what C code printed before the read stays where it was going
        held, saved = None, []
        try:
            held = tempfile.TemporaryFile()
            saved = [os.dup(1)]
            saved.append(os.dup(2))
        except OSError:
            for fd in saved:
                os.close(fd)
            if held is not None:
                held.close()
            held = None
        if held is None:
            yield
            return
        failed = True
        try:
            os.dup2(held.fileno(), 1)
            os.dup2(held.fileno(), 2)
            with contextlib.redirect_stdout(python_lines), contextlib.redirect_stderr(python_lines):
                yield
            failed = False
        finally:
            _flush_c_streams()
            os.dup2(saved[0], 1)
            os.dup2(saved[1], 2)
            for fd in saved:
                os.close(fd)
            held.seek(0)
            said.text = held.read().decode("utf-8", "replace") + python_lines.getvalue()
            held.close()
            others = said.text if not failed else "".join(
                ln for ln in said.text.splitlines(keepends=True) if not _library_line(ln))
            if others:
                sys.stderr.write(others)


def _library_line(line: str) -> bool:
    """A line the OpenEXR library or its binding prints about a damaged file."""
    return line.startswith("Warning: Exception raised reading") or bool(
        re.match(r"^\S.*: \(EXR_ERR_\w+\)", line))


def _flush_c_streams() -> None:
    """fflush(NULL): C stdio buffers written while the descriptors were redirected stay in the held file."""
    import ctypes

    try:
        ctypes.CDLL(None).fflush(None)
    except (OSError, AttributeError, TypeError):  # no C runtime by that name (Windows): nothing buffered to lose
        pass


def read_exr(
    path: str | os.PathLike,
    channels: Sequence[str] | None = None,
    allow_nan: bool = False,
) -> np.ndarray:
    """Read an EXR as a float32 ``(H, W, C)`` array.

    ``channels`` picks and orders channels by name (default: R, G, B[, A] when present, else all in
    file order). Raises :class:`ExrError` for a missing/corrupt file, a missing channel or, unless
    ``allow_nan``, non-finite values.
    """
    stored = _read_channels(path)
    if channels is None:
        rgba = [c for c in ("R", "G", "B", "A") if c in stored]
        channels = rgba if rgba else list(stored)
    missing = [c for c in channels if c not in stored]
    if missing:
        raise ExrError(f"{os.fspath(path)}: missing channel(s) {missing}; file has {sorted(stored)}")
    out = np.stack([np.asarray(stored[c], dtype=np.float32) for c in channels], axis=-1)
    if not allow_nan and not np.all(np.isfinite(out)):
        bad = int(np.count_nonzero(~np.isfinite(out)))
        raise ExrError(f"{os.fspath(path)}: {bad} non-finite value(s) (NaN/Inf)")
    return out
