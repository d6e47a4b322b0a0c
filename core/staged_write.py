"""Several files written into a folder as one: a reader finds the old set or the new set, never a mix (an
interrupted save of a scratch set once loaded as new segments over the old grid).

The files are written into a staging folder inside the target. Then the folder's files of the same names are moved
aside into a backup folder (the key file, the one the loader reads first: ``meta.exr``, ``btf.json``,
``params.json``, first), the new files moved in (the key file last), and the backup removed. An error or an
interrupt (Ctrl+C) at any step moves the new files out and the old ones back: the folder is as it was, and the
error is raised. Only a crash of the machine in the middle can leave a folder without its key file, which the
loaders refuse in one line. Other files in the folder are left alone.
"""

from __future__ import annotations

import os
import shutil
import tempfile
from collections.abc import Iterator
from contextlib import contextmanager


@contextmanager
def staged_files(folder: str | os.PathLike, key_file: str) -> Iterator[str]:
    """Yields a staging folder; on a normal exit its files replace those of the same names in ``folder`` as one
    step (:func:`_swap`). On an exception or an interrupt, in the caller's writing or in the swap, ``folder`` is as
    it was. The staging folder is removed either way."""
    folder = os.fspath(folder)
    os.makedirs(folder, exist_ok=True)
    stage = tempfile.mkdtemp(prefix=".staging-", dir=folder)
    try:
        yield stage
        names = sorted(os.listdir(stage))
        if key_file not in names:
            raise RuntimeError(f"staged write into {folder} made no {key_file}")  # a bug in the caller
        _swap(folder, stage, [key_file] + [n for n in names if n != key_file])
    finally:
        shutil.rmtree(stage, ignore_errors=True)


def _swap(folder: str, stage: str, names: list[str]) -> None:
    """Move ``names`` (key file first) from ``stage`` into ``folder``, the old ones aside first; undone on any
    error or interrupt."""
    backup = tempfile.mkdtemp(prefix=".previous-", dir=folder)
    aside: list[str] = []
    moved_in: list[str] = []
    try:
        for name in names:  # the key file first: from here the folder is refused until the new key file is in
            if os.path.lexists(os.path.join(folder, name)):
                _move(os.path.join(folder, name), os.path.join(backup, name))
                aside.append(name)
        for name in names[1:] + names[:1]:  # the key file last
            _move(os.path.join(stage, name), os.path.join(folder, name))
            moved_in.append(name)
    except BaseException:
        for name in moved_in:
            os.replace(os.path.join(folder, name), os.path.join(stage, name))
        for name in reversed(aside):
            os.replace(os.path.join(backup, name), os.path.join(folder, name))
        raise
    finally:
        shutil.rmtree(backup, ignore_errors=True)


def _move(src: str, dst: str) -> None:
    """One file into place (atomic on one file system: the staging and backup folders are inside the target)."""
    os.replace(src, dst)
