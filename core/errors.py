"""The error a user's mistake raises: bad input (a file, a field in it, a value, a flag), not a bug.

``UserError`` is what the command line prints as one line, ``error: ...`` (exit 2); any other exception
is a bug and gets its traceback (exit 1). It subclasses ``ValueError`` so that code catching bad values
(the add-on's operators report ``ValueError`` and ``OSError`` in the status bar) catches it too. Raise it
where input is checked, with a message that names the file and the field.
"""

from __future__ import annotations

import errno
import os


class UserError(ValueError):
    """Bad input: the message is the whole story (one line, naming the file, field or flag)."""


class BadFileError(UserError):
    """A file the user gave (or a folder holds) that cannot be read as what it should be."""


class MissingFileError(FileNotFoundError):
    """A file or folder the user named that is not there. A ``FileNotFoundError`` (code that catches that, or
    ``OSError``, still does) whose message says which and what it should have been; the command line prints
    it as one line, as a ``UserError``."""

    def __init__(self, message: str, path: str | os.PathLike) -> None:
        super().__init__(errno.ENOENT, message, os.fspath(path))

    def __str__(self) -> str:
        return str(self.strerror)
