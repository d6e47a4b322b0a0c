"""Several files written into a folder as one: a reader finds the old set, the new set, or a folder it refuses,
never a mix (an interrupted save of a scratch set once loaded as new segments over the old grid).

The files are written into a staging folder inside the target; then the key file (the one the loader reads
first: ``meta.exr``, ``btf.json``, ``params.json``) is removed, the other files are moved into place, and the
key file last. An interruption before the moves leaves the folder as it was; one during the moves leaves it
without its key file, which the loaders refuse in one line. Other files in the folder are left alone.
"""

from __future__ import annotations

import os
import shutil
import tempfile
from collections.abc import Iterator
from contextlib import contextmanager


@contextmanager
def staged_files(folder: str | os.PathLike, key_file: str) -> Iterator[str]:
    """Yields a staging folder; on a normal exit its files replace those of the same names in ``folder``
    (``key_file`` removed first and moved last). On an exception or an interrupt nothing in ``folder`` changes.
    The staging folder is removed either way."""
    folder = os.fspath(folder)
    os.makedirs(folder, exist_ok=True)
    stage = tempfile.mkdtemp(prefix=".staging-", dir=folder)
    try:
        yield stage
        names = sorted(os.listdir(stage))
        if key_file not in names:
            raise RuntimeError(f"staged write into {folder} made no {key_file}")  # a bug in the caller
        key = os.path.join(folder, key_file)
        if os.path.lexists(key):
            os.remove(key)
        for name in names:
            if name != key_file:
                _move(os.path.join(stage, name), os.path.join(folder, name))
        _move(os.path.join(stage, key_file), key)
    finally:
        shutil.rmtree(stage, ignore_errors=True)


def _move(src: str, dst: str) -> None:
    """One file into place (atomic on one file system: the staging folder is inside the target)."""
    os.replace(src, dst)
