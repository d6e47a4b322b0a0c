"""JSON files written whole or not at all: under a temporary name (per process), renamed when complete."""

from __future__ import annotations

import json
import os


def save_json(path: str | os.PathLike, obj, indent: int | None = None) -> None:
    """``obj`` as JSON at ``path``, written to ``path.tmpPID`` and renamed."""
    path = os.fspath(path)
    tmp = f"{path}.tmp{os.getpid()}"
    with open(tmp, "w") as f:
        json.dump(obj, f, indent=indent)
    os.replace(tmp, path)
