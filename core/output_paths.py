"""Where an output may go: never over an input. Shared by the command line (``cli/checks.py``) and the add-on's
operators, which say it in their own words."""

from __future__ import annotations

import os


def input_written_over(out: str | os.PathLike, inputs) -> str | None:
    """The first of ``inputs`` that writing ``out`` would write over (``out`` is it, lies inside it, or holds it),
    or None. Symbolic links are followed."""
    o = os.path.realpath(out)
    for inp in inputs:
        i = os.path.realpath(inp)
        if o == i or o.startswith(i + os.sep) or i.startswith(o + os.sep):
            return os.fspath(inp)
    return None
