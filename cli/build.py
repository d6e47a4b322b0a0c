"""``build``: validate the extension and write the installable zips with the builder shipped in bpy.

``make build`` writes one zip per platform and Python version, each with the wheels the add-on's features
import that a desktop Blender lacks (``WHEELS``): ``material_structures-VERSION-cp313-linux_x64.zip`` for
Blender 5.1+ (CPython 3.13), ``...-cp311-...`` for Blender 4.5 LTS / 5.0 (CPython 3.11), for linux-x64,
windows-x64 and macos-arm64. The wheels are downloaded once (``pip download``) into ``build/wheels``; the
zips are built from a staged copy of the source whose manifest lists them (the checkout's manifest lists
none, so that the checkout itself stays a loadable extension for development).
"""

from __future__ import annotations

import argparse
import glob
import importlib.util
import os
import shutil
import subprocess
import sys

from ..core.errors import UserError

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))

# What a desktop Blender's Python lacks and a feature needs (README "Installing"): scipy for the fabric
# fit (neighbour search, sparse graphs), the scratch model's special functions and the teeth tracer's
# reference path; numba + llvmlite for the compiled teeth tracer that the teeth fit renders with. Pinned as
# in requirements.txt (3.13) and requirements-compat.txt (3.11, beside Blender 4.5's numpy 1.26).
WHEELS: dict[str, tuple[str, ...]] = {
    "3.13": ("scipy==1.18.1", "numba==0.68.1", "llvmlite==0.50.0"),
    "3.11": ("scipy==1.13.1", "numba==0.68.1", "llvmlite==0.50.0"),
}
# Blender versions per CPython: 4.5 LTS and 5.0 ship 3.11, 5.1 and later 3.13 (the manifest's max is exclusive)
BLENDER_RANGE: dict[str, tuple[str, str | None]] = {"3.11": ("4.5.0", "5.1.0"), "3.13": ("5.1.0", None)}
# Blender platform -> pip's --platform tags (any of them; the Blender versions above run on all of them)
PLATFORMS: dict[str, tuple[str, ...]] = {
    "linux-x64": ("manylinux_2_28_x86_64", "manylinux_2_17_x86_64", "manylinux2014_x86_64"),
    "windows-x64": ("win_amd64",),
    "macos-arm64": ("macosx_12_0_arm64", "macosx_11_0_arm64"),
}


def add_parser(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("build", help="validate and build the extension zips (dist/)")
    p.add_argument("--out", default="dist", help="output folder (default: dist)")
    p.add_argument("--validate-only", action="store_true", help="only validate the manifest")
    p.add_argument("--platform", action="append", choices=sorted(PLATFORMS), default=None,
                   help="build for this platform (repeatable; default: all)")
    p.add_argument("--python", action="append", choices=sorted(WHEELS), default=None,
                   help="build for Blender with this CPython (repeatable; default: all)")
    p.add_argument("--no-wheels", action="store_true",
                   help="one zip without wheels for every platform (needs scipy and numba installed by hand)")
    p.set_defaults(func=run)


def blender_ext_tool() -> str:
    """Path of ``blender_ext.py`` inside the installed bpy wheel (no Blender binary needed)."""
    spec = importlib.util.find_spec("bpy")
    if spec is None or not spec.submodule_search_locations:
        raise UserError("bpy is not installed in this Python; run `make build` (it sets up .venv)")
    base = list(spec.submodule_search_locations)[0]
    hits = sorted(
        glob.glob(os.path.join(base, "*", "scripts", "addons_core", "bl_pkg", "cli", "blender_ext.py"))
    )
    if not hits:
        raise UserError(f"blender_ext.py not found under {base}")
    return hits[-1]


def _tool(*args: str) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, blender_ext_tool(), *args], capture_output=True, text=True)


def validate(source_dir: str = ROOT) -> None:
    proc = _tool("validate", source_dir)
    if proc.returncode != 0:
        raise RuntimeError(f"manifest validation failed:\n{proc.stdout}{proc.stderr}")


def _manifest(source_dir: str) -> dict:
    import tomllib

    with open(os.path.join(source_dir, "blender_manifest.toml"), "rb") as f:
        return tomllib.load(f)


def build(out_dir: str = "dist", source_dir: str = ROOT) -> str:
    """Validate, then build ``<out_dir>/material_structures-<version>.zip`` without wheels (every platform;
    the tests' quick build); return its path."""
    validate(source_dir)
    manifest = _manifest(source_dir)
    out_dir = os.path.abspath(out_dir)
    os.makedirs(out_dir, exist_ok=True)  # the builder fails without it
    zip_path = os.path.join(out_dir, f"{manifest['id']}-{manifest['version']}.zip")
    if os.path.exists(zip_path):
        os.remove(zip_path)
    proc = _tool("build", "--source-dir", source_dir, "--output-dir", out_dir)
    if proc.returncode != 0 or not os.path.isfile(zip_path):
        raise RuntimeError(f"extension build failed:\n{proc.stdout}{proc.stderr}")
    proc = _tool("validate", zip_path)
    if proc.returncode != 0:
        raise RuntimeError(f"built zip does not validate:\n{proc.stdout}{proc.stderr}")
    return zip_path


def download_wheels(python: str, platform: str, cache: str) -> list[str]:
    """The wheels of ``WHEELS[python]`` for the Blender ``platform`` (downloaded into ``cache`` once)."""
    want = WHEELS[python]
    dest = os.path.join(cache, f"cp{python.replace('.', '')}-{platform}")
    os.makedirs(dest, exist_ok=True)

    def present() -> list[str]:
        names = os.listdir(dest)
        found = []
        for req in want:
            name, ver = req.split("==")
            hits = [n for n in names if n.endswith(".whl") and n.lower().startswith(f"{name.lower()}-{ver}-")]
            if not hits:
                return []
            found.append(os.path.join(dest, sorted(hits)[0]))
        return found

    if present():
        return present()
    tags = [a for tag in PLATFORMS[platform] for a in ("--platform", tag)]
    proc = subprocess.run([sys.executable, "-m", "pip", "download", "-q", "--disable-pip-version-check", "--no-deps",
                           "--only-binary=:all:", *tags, "--python-version", python, "--dest", dest, *want],
                          capture_output=True, text=True)
    if proc.returncode == 0 and present():
        return present()
    errors = " ".join(ln for ln in proc.stderr.splitlines() if ln.startswith("ERROR"))[:400]
    raise UserError(f"no wheels of {', '.join(want)} for {platform} / CPython {python}: {errors}")


def _stage(source_dir: str, stage: str, manifest: dict) -> None:
    """A copy of the extension's files (the manifest's root exclusions left out) in ``stage``."""
    top = {p.strip("/") for p in manifest.get("build", {}).get("paths_exclude_pattern", [])
           if p.startswith("/") and p.count("/") <= 2}
    shutil.rmtree(stage, ignore_errors=True)

    def ignore(folder: str, names: list[str]) -> set[str]:
        out = {n for n in names if n in ("__pycache__", ".git") or n.endswith((".pyc", ".oso", ".blend1"))}
        if os.path.samefile(folder, source_dir):
            out |= {n for n in names if n in top or n.endswith(".egg-info") or n.startswith(".venv")}
        return out

    shutil.copytree(source_dir, stage, ignore=ignore, symlinks=False)


def _staged_manifest(text: str, python: str, wheels: list[str], platforms: list[str]) -> str:
    lo, hi = BLENDER_RANGE[python]
    lines = []
    for line in text.splitlines():
        if line.startswith("blender_version_min"):
            lines.append(f'blender_version_min = "{lo}"')
            if hi:
                lines.append(f'blender_version_max = "{hi}"')
            lines.append("platforms = [" + ", ".join(f'"{p}"' for p in platforms) + "]")
            lines.append("wheels = [")
            lines += [f'  "./wheels/{os.path.basename(w)}",' for w in wheels]
            lines.append("]")
        elif line.startswith(("blender_version_max", "platforms", "wheels")):
            raise UserError(f"blender_manifest.toml: {line.split('=')[0].strip()} is written by the build")
        else:
            lines.append(line)
    return "\n".join(lines) + "\n"


def build_platforms(out_dir: str = "dist", source_dir: str = ROOT, platforms: list[str] | None = None,
                    pythons: list[str] | None = None, work_dir: str | None = None) -> list[str]:
    """One zip per Python version and platform, with that platform's wheels; returns their paths."""
    validate(source_dir)
    manifest = _manifest(source_dir)
    platforms = list(platforms or PLATFORMS)
    pythons = list(pythons or WHEELS)
    work_dir = os.path.abspath(work_dir or os.path.join(source_dir, "build"))
    out_dir = os.path.abspath(out_dir)
    os.makedirs(out_dir, exist_ok=True)
    with open(os.path.join(source_dir, "blender_manifest.toml"), encoding="utf-8") as f:
        manifest_text = f.read()
    written = []
    for python in pythons:
        wheels = [w for p in platforms for w in download_wheels(python, p, os.path.join(work_dir, "wheels"))]
        cp = f"cp{python.replace('.', '')}"
        stage = os.path.join(work_dir, f"stage-{cp}")
        _stage(source_dir, stage, manifest)
        os.makedirs(os.path.join(stage, "wheels"), exist_ok=True)
        for w in wheels:
            shutil.copy2(w, os.path.join(stage, "wheels", os.path.basename(w)))
        with open(os.path.join(stage, "blender_manifest.toml"), "w", encoding="utf-8") as f:
            f.write(_staged_manifest(manifest_text, python, wheels, platforms))
        base = os.path.join(out_dir, f"{manifest['id']}-{manifest['version']}-{cp}.zip")
        expected = [base[:-4] + f"-{p.replace('-', '_')}.zip" for p in platforms]
        for path in expected:
            if os.path.exists(path):
                os.remove(path)
        proc = _tool("build", "--source-dir", stage, "--output-filepath", base, "--split-platforms")
        if proc.returncode != 0 or not all(os.path.isfile(p) for p in expected):
            raise RuntimeError(f"extension build failed ({cp}):\n{proc.stdout}{proc.stderr}")
        for path in expected:
            proc = _tool("validate", path)
            if proc.returncode != 0:
                raise RuntimeError(f"built zip {path} does not validate:\n{proc.stdout}{proc.stderr}")
        written += expected
    return written


def run(args: argparse.Namespace) -> int:
    if args.validate_only:
        validate()
        print("manifest valid")
        return 0
    if args.no_wheels:
        print(build(args.out))
        return 0
    for path in build_platforms(args.out, platforms=args.platform, pythons=args.python):
        print(f"{path}  {os.path.getsize(path) / 2**20:.1f} MiB")
    return 0
