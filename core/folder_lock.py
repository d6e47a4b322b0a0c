"""One writer per output folder: a lock file naming the process that writes there (teeth and fabric fits)."""

from __future__ import annotations

import os

from .errors import UserError


class FolderLock:
    """``FOLDER/.fit.lock`` holding this process's id while a fit writes to FOLDER: a second fit into the
    same folder is refused with the first one's id; a lock whose process has died is taken over."""

    def __init__(self, folder: str):
        self.path = os.path.join(folder, ".fit.lock")
        self.held = False

    def __enter__(self) -> FolderLock:
        for _ in range(2):
            try:
                fd = os.open(self.path, os.O_CREAT | os.O_EXCL | os.O_WRONLY)
            except FileExistsError:
                try:
                    with open(self.path) as f:
                        pid = int(f.read().strip() or 0)
                except (OSError, ValueError):
                    pid = 0
                if pid and _alive(pid):
                    raise UserError(f"another fit (process {pid}) is writing to {os.path.dirname(self.path)!r}; "
                                    "wait for it, stop it, or choose another output folder") from None
                os.remove(self.path)  # stale: its process is gone
                continue
            with os.fdopen(fd, "w") as f:
                f.write(str(os.getpid()))
            self.held = True
            return self
        raise UserError(f"cannot lock {os.path.dirname(self.path)!r} for the fit")

    def __exit__(self, *exc) -> None:
        if self.held:
            try:
                os.remove(self.path)
            except OSError:
                pass
            self.held = False


def _alive(pid: int) -> bool:
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except PermissionError:
        return True
    return True
