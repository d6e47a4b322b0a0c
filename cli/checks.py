"""Argument checks shared by the subcommands: numeric ranges at the parser, old spellings of renamed options,
outputs that would overwrite inputs. A bad command line (a parser check, :class:`UsageError`) is a one-line
``error: ...`` and exit status 2 (``cli.OneLineParser``); a check of the files (``refuse_*``) is a
``UserError``: one line and exit status 1."""

from __future__ import annotations

import argparse
import math
import os

from ..core.errors import UserError
from ..core.output_paths import input_written_over


class UsageError(UserError):
    """A command line that cannot work, found after parsing (options that exclude each other, a required one
    left out): one line and exit status 2, as the parser's own errors."""


OLD_SPELLING_NOTE = "note: {old} is an old spelling and goes in the next release: use {new}"


class _OldSpelling(argparse.Action):
    """An old spelling of a renamed option: it stores into the new option's ``dest`` (through ``convert``,
    where the unit changed) and prints a one-line note on stderr."""

    def __init__(self, option_strings, dest, new: str = "", convert=None, **kwargs):
        super().__init__(option_strings, dest, **kwargs)
        self.new, self.convert = new, convert

    def __call__(self, parser, namespace, values, option_string=None):
        import sys

        print(OLD_SPELLING_NOTE.format(old=option_string, new=self.new), file=sys.stderr)
        if self.convert is not None:
            values = [self.convert(v) for v in values] if isinstance(values, list) else self.convert(values)
        setattr(namespace, self.dest, values)


def old_spelling(container, old: str, new: str, convert=None, unit: str = "", type=None) -> None:
    """Accept ``old`` for the option ``new`` of ``container`` (a parser or a group of it) for one more
    release: the same type and range check (or ``type``), a note on stderr when it is used. ``convert`` maps an
    old value to the new option's (``unit``: the old one's unit, said in its help)."""
    action = container._option_string_actions[new]
    container.add_argument(old, dest=action.dest, type=type or action.type, nargs=action.nargs,
                           metavar=action.metavar, default=argparse.SUPPRESS, action=_OldSpelling,
                           new=f"{new} (degrees)" if convert is not None and new.endswith("-deg") else new,
                           convert=convert,
                           help=f"old spelling of {new}{f' in {unit}' if unit else ''}, accepted until the next "
                                "release (with a note)")


def resolution(text: str) -> tuple[int, int]:
    """An argparse ``type`` for an image size ``WxH`` in pixels, each side in [1, 16384]."""
    try:
        w, h = (int(v) for v in text.lower().split("x"))
    except ValueError:
        raise argparse.ArgumentTypeError(f"must look like 320x240 (width x height in pixels), got {text!r}") from None
    if w < 1 or h < 1:
        raise argparse.ArgumentTypeError(f"must be at least 1x1, got {text}")
    if w > MAX_SIDE or h > MAX_SIDE:
        raise argparse.ArgumentTypeError(f"{w}x{h} is larger than {MAX_SIDE} pixels a side")
    return w, h


resolution.__name__ = "WxH"
MAX_SIDE = 16384  # pixels a side of a rendered image (Cycles' own limit is far above what fits in memory here)


def at_least(low: float, kind: type = int):
    """An argparse ``type`` that parses ``kind`` and refuses values below ``low`` (and NaN / inf)."""

    def parse(text: str):
        try:
            value = kind(text)
        except ValueError:
            raise argparse.ArgumentTypeError(f"{text!r} is not a{'n integer' if kind is int else ' number'}") from None
        if isinstance(value, float) and not math.isfinite(value):
            raise argparse.ArgumentTypeError(f"{text!r} is not a finite number")
        if value < low:
            raise argparse.ArgumentTypeError(f"must be >= {low:{'d' if kind is int else 'g'}}, got {text}")
        return value

    parse.__name__ = f"{kind.__name__} >= {low:g}"
    return parse


def between(low: float, high: float, kind: type = float):
    """An argparse ``type`` that parses ``kind`` and refuses values outside [low, high] (and NaN / inf)."""

    def parse(text: str):
        value = at_least(low, kind)(text)
        if value > high:
            raise argparse.ArgumentTypeError(f"must be <= {high:{'d' if kind is int else 'g'}}, got {text}")
        return value

    parse.__name__ = f"{kind.__name__} in [{low:g}, {high:g}]"
    return parse


def seed(text: str) -> int:
    """An argparse ``type`` for a random seed: an integer in [0, 2^31 - 1]."""
    return between(0, 2**31 - 1, int)(text)


def finite_float(text: str) -> float:
    """An argparse ``type``: any finite number."""
    return at_least(-math.inf, float)(text)


def available_memory() -> int | None:
    """Bytes of memory available to a new allocation (Linux: MemAvailable), None where unknown."""
    try:
        with open("/proc/meminfo") as f:
            for line in f:
                if line.startswith("MemAvailable:"):
                    return int(line.split()[1]) * 1024
    except (OSError, ValueError, IndexError):
        pass
    try:
        return os.sysconf("SC_AVPHYS_PAGES") * os.sysconf("SC_PAGE_SIZE")
    except (ValueError, OSError, AttributeError):
        return None


def check_memory(nbytes: float, what: str) -> None:
    """Refuse work whose arrays need more than the memory available, before allocating them."""
    avail = available_memory()
    if avail is not None and nbytes > avail:
        raise UserError(f"{what} needs about {nbytes / 2**30:.1f} GiB of memory; {avail / 2**30:.1f} GiB is "
                        "available")


def positive_float(text: str) -> float:
    value = at_least(0.0, float)(text)
    if value <= 0.0:
        raise argparse.ArgumentTypeError(f"must be > 0, got {text}")
    return value


def refuse_output_over_inputs(out: str, inputs: list[str]) -> None:
    """Refuse an output path that is one of ``inputs``, lies inside an input folder, or holds an input."""
    inp = input_written_over(out, inputs)
    if inp is not None:
        raise UserError(f"--out {out!r} would write over the input {inp!r}; choose another output")


def refuse_unwritable_folder(path: str, flag: str = "--out") -> None:
    """Refuse, before the work, an output folder that cannot be made or written: an existing file at ``path`` or
    at a folder above it (the work would end in "Not a directory" after minutes), or a nearest existing folder this
    user may not write in (the work would end in "Permission denied", another output perhaps written already)."""
    p = os.path.abspath(path)
    while True:
        if os.path.exists(p):
            if not os.path.isdir(p):
                what = "is a file" if p == os.path.abspath(path) else f"lies under the file {p!r}"
                raise UserError(f"{flag} {path!r} {what}, not a folder; choose another output")
            if not os.access(p, os.W_OK | os.X_OK):
                raise UserError(f"{flag} {path!r}: the folder {p!r} is not writable (permission denied); choose "
                                "another output")
            return
        parent = os.path.dirname(p)
        if parent == p:
            return
        p = parent
