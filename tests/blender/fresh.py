"""Run a snippet in a fresh Blender process (``bpy`` imports once per process; reopening a saved file
in the test's own process would keep its Python state: sessions, caches, job objects).

The child redirects Blender's user resources to a temporary folder, enables this checkout as the
extension ``bl_ext.<repo>.material_structures`` from a new repository folder (``repo_dir``: pass a
different one to see the extension "reinstalled elsewhere"), optionally opens a .blend, runs the
snippet and prints the JSON-serialisable value the snippet assigns to ``RESULT``.
"""

from __future__ import annotations

import json
import os
import subprocess
import sys
import tempfile
import textwrap

ROOT = os.path.dirname(os.path.dirname(os.path.dirname(os.path.abspath(__file__))))
_MARK = "MS-FRESH-RESULT:"

_PRELUDE = """
import json, os, sys, tempfile
os.environ["BLENDER_USER_RESOURCES"] = tempfile.mkdtemp(prefix="ms-fresh-user-")
import bpy, addon_utils
repo_dir = {repo_dir!r}
os.makedirs(repo_dir, exist_ok=True)
link = os.path.join(repo_dir, "material_structures")
if not os.path.exists(link):
    os.symlink({root!r}, link)
bpy.context.preferences.extensions.repos.new(name="fresh", module="fresh", custom_directory=repo_dir, source="USER")
ADDON = "bl_ext.fresh.material_structures"
if {enable!r}:
    assert addon_utils.enable(ADDON, default_set=True, handle_error=lambda e: (_ for _ in ()).throw(e)) is not None
if {blend!r}:
    bpy.ops.wm.open_mainfile(filepath={blend!r})
RESULT = None
"""


def run_fresh(snippet: str, blend: str | None = None, repo_dir: str | None = None, enable: bool = True,
              timeout: float = 600, env: dict[str, str] | None = None) -> object:
    """Run ``snippet`` in a new interpreter (after opening ``blend``); return its ``RESULT``.

    ``env``: variables to set in the child (e.g. ``TMPDIR``: another machine's temporary folder)."""
    repo_dir = repo_dir or tempfile.mkdtemp(prefix="ms-fresh-repo-")
    code = _PRELUDE.format(repo_dir=repo_dir, root=ROOT, enable=enable, blend=blend or "")
    code += textwrap.dedent(snippet) + f"\nprint({_MARK!r} + json.dumps(RESULT))\n"
    proc = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=timeout,
                          env={**os.environ, **(env or {})})
    for line in proc.stdout.splitlines():
        if line.startswith(_MARK):
            return json.loads(line[len(_MARK):])
    raise AssertionError(f"fresh process failed (rc {proc.returncode}):\n{proc.stdout[-3000:]}\n{proc.stderr[-4000:]}")
