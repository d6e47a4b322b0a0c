"""``build``: validate the extension and write the installable zip with the builder shipped in bpy."""

from __future__ import annotations

import argparse
import glob
import importlib.util
import os
import subprocess
import sys

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))


def add_parser(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("build", help="validate and build the extension zip (dist/)")
    p.add_argument("--out", default="dist", help="output folder (default: dist)")
    p.add_argument("--validate-only", action="store_true", help="only validate the manifest")
    p.set_defaults(func=run)


def blender_ext_tool() -> str:
    """Path of ``blender_ext.py`` inside the installed bpy wheel (no Blender binary needed)."""
    spec = importlib.util.find_spec("bpy")
    if spec is None or not spec.submodule_search_locations:
        raise RuntimeError("bpy is not installed in this Python; run `make build` (it sets up .venv)")
    base = list(spec.submodule_search_locations)[0]
    hits = sorted(
        glob.glob(os.path.join(base, "*", "scripts", "addons_core", "bl_pkg", "cli", "blender_ext.py"))
    )
    if not hits:
        raise RuntimeError(f"blender_ext.py not found under {base}")
    return hits[-1]


def validate(source_dir: str = ROOT) -> None:
    tool = blender_ext_tool()
    proc = subprocess.run([sys.executable, tool, "validate", source_dir], capture_output=True, text=True)
    if proc.returncode != 0:
        raise RuntimeError(f"manifest validation failed:\n{proc.stdout}{proc.stderr}")


def build(out_dir: str = "dist", source_dir: str = ROOT) -> str:
    """Validate, then build ``<out_dir>/material_structures-<version>.zip``; return its path."""
    import tomllib

    validate(source_dir)
    with open(os.path.join(source_dir, "blender_manifest.toml"), "rb") as f:
        manifest = tomllib.load(f)
    out_dir = os.path.abspath(out_dir)
    os.makedirs(out_dir, exist_ok=True)  # the builder fails without it
    zip_path = os.path.join(out_dir, f"{manifest['id']}-{manifest['version']}.zip")
    if os.path.exists(zip_path):
        os.remove(zip_path)
    proc = subprocess.run(
        [sys.executable, blender_ext_tool(), "build", "--source-dir", source_dir, "--output-dir", out_dir],
        capture_output=True,
        text=True,
    )
    if proc.returncode != 0 or not os.path.isfile(zip_path):
        raise RuntimeError(f"extension build failed:\n{proc.stdout}{proc.stderr}")
    proc = subprocess.run(
        [sys.executable, blender_ext_tool(), "validate", zip_path], capture_output=True, text=True
    )
    if proc.returncode != 0:
        raise RuntimeError(f"built zip does not validate:\n{proc.stdout}{proc.stderr}")
    return zip_path


def run(args: argparse.Namespace) -> int:
    if args.validate_only:
        validate()
        print("manifest valid")
        return 0
    print(build(args.out))
    return 0
