"""A reader that goes away (`python -m material_structures render --list | head -1`) ends the command quietly."""

from __future__ import annotations

import subprocess
import sys


def test_a_closed_pipe_is_not_a_bug():
    proc = subprocess.Popen([sys.executable, "-c", "import time, sys; time.sleep(1.5); "
                             "from material_structures.cli import main; sys.exit(main(['render', '--list']))"],
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE)
    proc.stdout.close()  # the reader is gone before the command writes
    _, err = proc.communicate(timeout=120)
    assert proc.returncode == 0, err.decode()
    assert b"internal error" not in err and b"Traceback" not in err, err.decode()
