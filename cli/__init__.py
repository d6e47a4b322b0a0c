"""Command-line interface: ``python -m material_structures SUBCOMMAND ...``.

Each subcommand lives in ``cli/<name>.py`` and exposes ``add_parser(subparsers)``, which registers
its parser and sets ``func(args) -> int``. Heavy imports (bpy, scipy) happen inside ``func`` so
``--help`` stays fast. The same entry point runs under ``blender -b --python scripts/ms.py -- ARGS``.
"""

from __future__ import annotations

import argparse
import errno
import importlib
import signal
import sys
import traceback

from ..core.errors import MissingFileError, UserError

SUBCOMMANDS = ("render", "build", "release", "bench", "demo", "library", "fabric", "scratch", "teeth")


class OneLineParser(argparse.ArgumentParser):
    """A bad command line is one line on stderr, ``error: PROG: PROBLEM`` (exit 2), without the usage
    (``--help`` has it). Subcommand parsers are of this class too."""

    def error(self, message: str):
        self.exit(2, f"error: {self.prog}: {message}\n")


def build_parser() -> argparse.ArgumentParser:
    parser = OneLineParser(
        prog="python -m material_structures",
        description="Material Structures: pile fabric, scratched metal and teeth for Blender/Cycles.",
    )
    parser.add_argument("--debug", action="store_true", help="show the full traceback of an error")
    sub = parser.add_subparsers(dest="command", metavar="COMMAND", required=True)
    for name in SUBCOMMANDS:
        try:
            module = importlib.import_module(f".{name}", __name__)
        except ModuleNotFoundError as exc:
            if exc.name == f"{__name__}.{name}":
                continue  # feature not installed in this build
            raise
        module.add_parser(sub)
    return parser


def _raise_interrupt(signum, frame) -> None:
    raise KeyboardInterrupt


def _interrupt_on_sigterm():
    """SIGTERM (a job scheduler, ``kill``) stops a command as Ctrl-C does: its cleanup runs (worker pools
    shut down, temporary files removed, checkpoints kept). Returns the previous handler (None off the
    main thread, where handlers cannot be set)."""
    try:
        return signal.signal(signal.SIGTERM, _raise_interrupt)
    except ValueError:
        return None


# OSErrors about a path the user gave (or a disk they write to), said in one line; any other is a bug
_USER_OS_ERRORS = (FileNotFoundError, FileExistsError, IsADirectoryError, NotADirectoryError, PermissionError)
_USER_ERRNOS = (errno.ENOSPC, errno.EROFS, errno.EDQUOT, errno.ENAMETOOLONG, errno.ELOOP)


def _user_os_error(exc: OSError) -> bool:
    return exc.filename is not None and (isinstance(exc, _USER_OS_ERRORS) or exc.errno in _USER_ERRNOS)


def _one_line(text: str) -> str:
    return " ".join(text.split()) or "bad input"


def _bug(exc: BaseException) -> int:
    """An unexpected exception: a bug. Its traceback on stderr and exit status 1."""
    traceback.print_exception(exc)
    print(f"material_structures: internal error ({type(exc).__name__}); this is a bug, please report it with "
          "the traceback above", file=sys.stderr)
    return 1


def main(argv: list[str] | None = None) -> int:
    if argv is None:
        argv = sys.argv[1:]
        if "--" in sys.argv:  # blender -b --python script.py -- ARGS
            argv = sys.argv[sys.argv.index("--") + 1 :]
    parser = build_parser()
    try:
        args = parser.parse_args(argv)
    except SystemExit as exc:  # --help (0) or a bad command line (2, said on stderr)
        return int(exc.code or 0)
    previous = _interrupt_on_sigterm()
    try:
        return int(args.func(args) or 0)
    except KeyboardInterrupt:
        print("interrupted", file=sys.stderr)
        return 130
    except BrokenPipeError:  # the reader went away (`... | head`): not an error, and nothing more to say
        import os

        os.dup2(os.open(os.devnull, os.O_WRONLY), sys.stdout.fileno())  # no second error when stdout flushes
        return 0
    except MemoryError as exc:  # a size the machine cannot hold: the allocation failed, nothing was written
        if getattr(args, "debug", False):
            raise
        print(f"error: not enough memory for this size ({exc}); choose a smaller one", file=sys.stderr)
        return 2
    except (UserError, MissingFileError) as exc:  # bad input: the message says what and where (--debug: where)
        if getattr(args, "debug", False):
            raise
        print(f"error: {_one_line(str(exc))}", file=sys.stderr)
        return 2
    except OSError as exc:
        # a path the user gave that is missing, a directory, a file, read-only, or a disk that is full: one
        # line. Any other OSError (and one without a file name) is a bug: its traceback, below
        if getattr(args, "debug", False):
            raise
        if not _user_os_error(exc):
            return _bug(exc)
        print(f"error: {exc.filename}: {exc.strerror or exc}", file=sys.stderr)
        return 2
    except Exception as exc:  # a bug, not the user's mistake: its traceback, exit 1
        return _bug(exc)
    finally:
        if previous is not None:
            signal.signal(signal.SIGTERM, previous)
