"""Command-line interface: ``python -m material_structures SUBCOMMAND ...``.

Each subcommand lives in ``cli/<name>.py`` and exposes ``add_parser(subparsers)``, which registers
its parser and sets ``func(args) -> int``. Heavy imports (bpy, scipy) happen inside ``func`` so
``--help`` stays fast. The same entry point runs under ``blender -b --python scripts/ms.py -- ARGS`` and as the
``material-structures`` console command. Exit status: 2 for a usage error (the parser's, or a
:class:`checks.UsageError`), 1 for a runtime error (``UserError``, a bad file, a full disk) or a bug
(``EXIT_STATUS``).
"""

from __future__ import annotations

import argparse
import errno
import importlib
import os
import signal
import sys
import traceback

from .. import __version__
from ..core.errors import MissingFileError, UserError
from .checks import UsageError

SUBCOMMANDS = ("render", "build", "release", "bench", "demo", "library", "fabric", "scratch", "teeth")


PROG = "python -m material_structures"
USAGE_ERROR, RUNTIME_ERROR = 2, 1  # exit statuses (EXIT_STATUS below says them to the user)
EXIT_STATUS = ("Exit status: 0 done; 2 a usage error (an option missing, misspelt or out of range: one line "
               "'error: ...', nothing done); 1 a runtime error: a file that is missing or not what it should be, "
               "a full disk, too little memory (one line 'error: ...'; --debug shows its traceback), or a bug (its "
               "traceback); 130 interrupted (Ctrl-C, SIGTERM), after its cleanup.")


class DefaultsHelpFormatter(argparse.HelpFormatter):
    """Shows every option's default at the end of its help, unless the help says it already ("default") or
    there is none to show (an unset option, a flag)."""

    def _get_help_string(self, action: argparse.Action) -> str:
        text = action.help or ""
        default = action.default
        if (default is None or default is False or default is argparse.SUPPRESS or "default" in text
                or not action.option_strings or isinstance(action, argparse._VersionAction)):
            return text
        shown = " ".join(map(str, default)) if isinstance(default, list | tuple) else str(default)
        return f"{text} (default: {shown.replace('%', '%%')})"


class OneLineParser(argparse.ArgumentParser):
    """A bad command line is one line on stderr, ``error: PROG: PROBLEM`` (exit 2), without the usage
    (``--help`` has it). Subcommand parsers are of this class too; their help shows every option's default."""

    def __init__(self, *args, **kwargs):
        kwargs.setdefault("formatter_class", DefaultsHelpFormatter)
        super().__init__(*args, **kwargs)

    def error(self, message: str):
        self.exit(USAGE_ERROR, f"error: {self.prog}: {message}\n")


def build_parser(prog: str = PROG) -> argparse.ArgumentParser:
    parser = OneLineParser(
        prog=prog,
        description="Material Structures: pile fabric, scratched metal and teeth for Blender/Cycles. Every "
                    "subcommand speaks one vocabulary: --out for what it writes, --samples for samples per pixel, "
                    "angles in degrees (options ending in -deg), --workers for processes on this machine.",
        epilog=EXIT_STATUS,
    )
    parser.add_argument("--version", action="version", version=f"material-structures {__version__}",
                        help="print the version and exit")
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


def _end_progress_lines() -> None:
    """Close the progress bars (tqdm's) a failed command left open: its message then starts a line of its own
    instead of ending the bar's."""
    std = sys.modules.get("tqdm.std")
    if std is not None:
        for bar in list(getattr(std.tqdm, "_instances", ())):
            bar.close()


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
    name = os.path.basename(sys.argv[0]) if sys.argv else ""
    parser = build_parser("material-structures" if name == "material-structures" else PROG)
    try:
        args = parser.parse_args(argv)
    except SystemExit as exc:  # --help, --version (0) or a bad command line (2, said on stderr)
        return int(exc.code or 0)
    previous = _interrupt_on_sigterm()
    try:
        try:
            return int(args.func(args) or 0)
        except BaseException:
            _end_progress_lines()
            raise
    except KeyboardInterrupt:
        print("interrupted", file=sys.stderr)
        return 130
    except BrokenPipeError:  # the reader went away (`... | head`): not an error, and nothing more to say
        os.dup2(os.open(os.devnull, os.O_WRONLY), sys.stdout.fileno())  # no second error when stdout flushes
        return 0
    except MemoryError as exc:  # a size the machine cannot hold: the allocation failed, nothing was written
        if getattr(args, "debug", False):
            raise
        print(f"error: not enough memory for this size ({exc}); choose a smaller one", file=sys.stderr)
        return RUNTIME_ERROR
    except UsageError as exc:  # a command line that cannot work, found after parsing: as the parser's errors
        print(f"error: {_one_line(str(exc))}", file=sys.stderr)
        return USAGE_ERROR
    except (UserError, MissingFileError) as exc:  # bad input: the message says what and where (--debug: where)
        if getattr(args, "debug", False):
            raise
        print(f"error: {_one_line(str(exc))}", file=sys.stderr)
        return RUNTIME_ERROR
    except OSError as exc:
        # a path the user gave that is missing, a directory, a file, read-only, or a disk that is full: one
        # line. Any other OSError (and one without a file name) is a bug: its traceback, below
        if getattr(args, "debug", False):
            raise
        if not _user_os_error(exc):
            return _bug(exc)
        print(f"error: {exc.filename}: {exc.strerror or exc}", file=sys.stderr)
        return RUNTIME_ERROR
    except Exception as exc:  # a bug, not the user's mistake: its traceback, exit 1
        return _bug(exc)
    finally:
        if previous is not None:
            signal.signal(signal.SIGTERM, previous)
