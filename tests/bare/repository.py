"""The extension as an artist gets it: from a repository URL, in a Python holding only the bpy wheel.

Usage (run with the bare venv's Python): ``repository.py RELEASE_DIR NEWER_RELEASE_DIR WORKDIR``.
RELEASE_DIR and NEWER_RELEASE_DIR are what ``make release`` writes (zips + Blender's ``index.json``), the
second of a higher version. The test serves a folder over HTTP on 127.0.0.1 and, in fresh Blender processes:

1. adds the repository URL (Preferences > Get Extensions > Repositories), syncs, installs the extension with
   Blender's own repository operators and enables it;
2. appends a library material from the installed extension, renders it (not black) and saves the .blend;
3. runs the CLI the extension registers for ``blender -c material_structures`` (``render test-card`` and
   ``teeth synth --help``; the bpy module has no command line, so the registered function is called);
4. publishes the newer release into the same served folder; Blender's update check sees it and upgrades;
   the .blend saved before the upgrade renders the same.

Exit code 0 when every step holds; the failing step's message otherwise.
"""

from __future__ import annotations

import functools
import http.server
import json
import os
import shutil
import subprocess
import sys
import tempfile
import threading

MARK = "MS-REPO-RESULT:"
REPO_MODULE = "ms_repo"
EXT_ID = "material_structures"

_PRELUDE = r"""
import json, os, sys
os.environ["BLENDER_USER_RESOURCES"] = {user!r}
import bpy
site = os.path.join(bpy.utils.resource_path("LOCAL"), "python", "lib",
                    "python%d.%d" % sys.version_info[:2], "site-packages")
if site not in sys.path:
    sys.path.append(site)  # a desktop Blender has its bundled modules (OpenImageIO, ...) on the path
if os.path.isfile(os.path.join({user!r}, "config", "userpref.blend")):
    bpy.ops.wm.read_userpref()  # a desktop Blender starts with the saved preferences (the bpy module does not)
prefs = bpy.context.preferences
prefs.system.use_online_access = True
repos = prefs.extensions.repos
repo = next((r for r in repos if r.module == {module!r}), None)
if repo is None:
    repo = repos.new(name="Material Structures", module={module!r}, remote_url={url!r}, source="USER")
index = [r.module for r in repos].index({module!r})
assert bpy.ops.extensions.repo_sync(repo_directory=repo.directory, repo_index=index) == {{"FINISHED"}}
RESULT = {{}}
"""

_INSTALL = r"""
assert bpy.ops.extensions.package_install(repo_directory=repo.directory, repo_index=index, pkg_id={ext!r},
                                          enable_on_install=True) == {{"FINISHED"}}
import importlib, tomllib
ext = importlib.import_module("bl_ext.{module}.{ext}")
with open(os.path.join(repo.directory, {ext!r}, "blender_manifest.toml"), "rb") as f:
    RESULT["version"] = tomllib.load(f)["version"]
library = os.path.join(os.path.dirname(ext.__file__), "samples", "library", "material_structures_library.blend")
bpy.ops.wm.read_homefile(use_factory_startup=True)
scene = bpy.context.scene
with bpy.data.libraries.load(library, link=False) as (src, dst):
    dst.materials = [m for m in src.materials if m.startswith("Velvet")]
cube = bpy.data.objects["Cube"]
cube.data.materials.clear()
cube.data.materials.append(dst.materials[0])
scene.render.engine = "CYCLES"
scene.cycles.samples, scene.cycles.use_denoising, scene.cycles.seed = 8, False, 0
scene.render.resolution_x = scene.render.resolution_y = 48
from bl_ext.{module}.{ext}.render.output import render_to_array
img = render_to_array(scene)
RESULT["mean"] = float(img[..., :3].mean())
bpy.ops.wm.save_as_mainfile(filepath={blend!r})
cli = importlib.import_module("bl_ext.{module}.{ext}.cli.blender_command")
RESULT["cli_test_card"] = cli.run(["render", "test-card", "--out", {card!r}, "--samples", "2",
                                   "--resolution", "32x32"])
RESULT["card_written"] = os.path.isfile({card!r})
RESULT["cli_synth_help"] = cli.run(["teeth", "synth", "--help"])
RESULT["cli_bad_option"] = cli.run(["render", "--no-such-option"])
bpy.ops.wm.save_userpref()
"""

_UPGRADE = r"""
assert bpy.ops.extensions.package_upgrade_all() == {{"FINISHED"}}
import tomllib
with open(os.path.join(repo.directory, {ext!r}, "blender_manifest.toml"), "rb") as f:
    RESULT["version"] = tomllib.load(f)["version"]
RESULT["enabled"] = any(a.module == "bl_ext.{module}.{ext}" for a in prefs.addons)
import importlib
RESULT["loaded_version"] = importlib.import_module("bl_ext.{module}.{ext}").__version__
bpy.ops.wm.open_mainfile(filepath={blend!r})
from bl_ext.{module}.{ext}.render.output import render_to_array
img = render_to_array(bpy.context.scene)
RESULT["mean"] = float(img[..., :3].mean())
"""


def _run(code: str) -> dict:
    proc = subprocess.run([sys.executable, "-c", code + f"\nprint({MARK!r} + json.dumps(RESULT))\n"],
                          capture_output=True, text=True, timeout=1800)
    for line in proc.stdout.splitlines():
        if line.startswith(MARK):
            result = json.loads(line[len(MARK):])
            result["log"] = proc.stderr[-4000:]
            return result
    raise SystemExit(f"Blender step failed (rc {proc.returncode}):\n{proc.stdout[-3000:]}\n{proc.stderr[-3000:]}")


def _publish(release: str, served: str) -> None:
    """Make ``served`` hold exactly ``release`` (zips, index.json): a new release replaces the old one."""
    for name in os.listdir(served):
        os.remove(os.path.join(served, name))
    for name in os.listdir(release):
        if name.endswith((".zip", ".json", ".html")):
            shutil.copy2(os.path.join(release, name), served)
    if not os.path.isfile(os.path.join(served, "index.json")):
        raise SystemExit(f"{release} has no index.json: not a repository (make release writes one)")


def main(argv: list[str]) -> int:
    release, newer, work = argv
    os.makedirs(work, exist_ok=True)
    # Blender's temporary files (the .oso files its OSL script nodes compile and never delete) stay in the work
    # folder, emptied on every run, not in the machine's /tmp
    tmp = os.path.join(work, "tmp")
    shutil.rmtree(tmp, ignore_errors=True)
    os.makedirs(tmp)
    os.environ["TMPDIR"] = tempfile.tempdir = tmp
    served = tempfile.mkdtemp(prefix="served-", dir=work)
    user = tempfile.mkdtemp(prefix="user-", dir=work)
    blend = os.path.join(work, "before_upgrade.blend")
    card = os.path.join(work, "test-card.png")
    _publish(release, served)
    handler = functools.partial(http.server.SimpleHTTPRequestHandler, directory=served)
    server = http.server.ThreadingHTTPServer(("127.0.0.1", 0), handler)
    threading.Thread(target=server.serve_forever, daemon=True).start()
    url = f"http://127.0.0.1:{server.server_address[1]}/index.json"
    fmt = {"user": user, "module": REPO_MODULE, "url": url, "ext": EXT_ID, "blend": blend, "card": card}
    try:
        first = _run(_PRELUDE.format(**fmt) + _INSTALL.format(**fmt))
        print(f"installed {first['version']} from {url}; library velvet mean {first['mean']:.4f}; "
              f"CLI: test-card {first['cli_test_card']}, synth --help {first['cli_synth_help']}, "
              f"bad option {first['cli_bad_option']}")
        assert first["mean"] > 1e-3, "the library material renders black"
        assert first["cli_test_card"] == 0 and first["card_written"], "blender -c ... render test-card failed"
        assert first["cli_synth_help"] == 0, "blender -c ... teeth synth --help failed"
        assert first["cli_bad_option"] == 2, "a bad option must exit 2 as in python -m material_structures"
        _publish(newer, served)
        second = _run(_PRELUDE.format(**fmt) + _UPGRADE.format(**fmt))
        print(f"upgraded to {second['version']}; the saved file renders {second['mean']:.4f} "
              f"(before {first['mean']:.4f})")
        assert second["version"] != first["version"], "the update check did not upgrade"
        assert second["enabled"], "the upgraded extension is not enabled"
        assert second["loaded_version"] == second["version"], "Blender runs another version than it installed"
        assert abs(second["mean"] - first["mean"]) <= 1e-6 + 1e-3 * first["mean"], "the saved file renders differently"
    except AssertionError as exc:
        print(f"FAILED: {exc}", file=sys.stderr)
        for step in ("first", "second"):
            if step in locals():
                print(f"--- {step} step's stderr ---\n{locals()[step]['log']}", file=sys.stderr)
        return 1
    finally:
        server.shutdown()
    print("repository: install, render, CLI and upgrade all hold")
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
