"""``build``: validate the extension and write the installable zips with the builder shipped in bpy.

``make build`` writes one zip per platform and Python version, each with the wheels the add-on's features
import that a desktop Blender lacks (pyproject.toml's extra ``wheels``, at the versions uv.lock resolves for
that CPython: :func:`locked_wheels`): ``material_structures-VERSION-cp313-linux_x64.zip`` for Blender 5.1+
(CPython 3.13), ``...-cp311-...`` for Blender 4.5 LTS / 5.0 (CPython 3.11), for linux-x64, windows-x64 and
macos-arm64. The wheels are downloaded once (``pip download``, checked against uv.lock's hashes) into
``build/wheels``; the zips are built from a staged copy of the source whose manifest (written with tomlkit)
lists them (the checkout's manifest lists none, so that the checkout itself stays a loadable extension for
development).
"""

from __future__ import annotations

import argparse
import glob
import importlib.util
import os
import shutil
import subprocess
import sys
import tomllib

from ..core.errors import UserError
from .checks import UsageError

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))

# Blender versions per CPython: 4.5 LTS and 5.0 ship 3.11, 5.1 and later 3.13 (the manifest's max is exclusive)
BLENDER_RANGE: dict[str, tuple[str, str | None]] = {"3.11": ("4.5.0", "5.1.0"), "3.13": ("5.1.0", None)}
# pyproject.toml's extra that lists what a desktop Blender's Python lacks and a feature needs: scipy for the fabric
# fit, the scratch model's special functions and the teeth tracer's reference path; numba + llvmlite for the
# compiled teeth tracer that the teeth fit renders with. Their versions are uv.lock's, nowhere else.
WHEELS_EXTRA = "wheels"
# Blender platform -> pip's --platform tags (any of them; the Blender versions above run on all of them)
PLATFORMS: dict[str, tuple[str, ...]] = {
    "linux-x64": ("manylinux_2_28_x86_64", "manylinux_2_17_x86_64", "manylinux2014_x86_64"),
    "windows-x64": ("win_amd64",),
    "macos-arm64": ("macosx_12_0_arm64", "macosx_11_0_arm64"),
}


def wheel_cache() -> str:
    """Where downloaded wheels are kept between builds (outside the checkout)."""
    base = os.environ.get("XDG_CACHE_HOME") or os.path.join(os.path.expanduser("~"), ".cache")
    return os.path.join(base, "material_structures", "wheels")


def add_parser(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("build", help="validate and build the extension zips (dist/)")
    add_build_options(p)
    p.add_argument("--validate-only", action="store_true", help="only validate the manifest")
    p.add_argument("--no-wheels", action="store_true",
                   help="one zip without wheels for every platform (needs scipy and numba installed by hand)")
    p.set_defaults(func=run)


def add_build_options(p: argparse.ArgumentParser) -> None:
    """The options ``build`` and ``release`` share: where, for which platforms and Pythons, which version."""
    p.add_argument("--out", default="dist", help="output folder (default: dist)")
    p.add_argument("--platform", action="append", choices=sorted(PLATFORMS), default=None,
                   help="build for this platform (repeatable; default: all)")
    p.add_argument("--python", action="append", choices=sorted(BLENDER_RANGE), default=None,
                   help="build for Blender with this CPython (repeatable; default: all)")
    p.add_argument("--set-version", default=None, metavar="X.Y.Z",
                   help="write this version into the zips instead of blender_manifest.toml's (a release "
                        "candidate; the update test publishes a newer build this way)")


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


def locked_wheels(python: str, root: str = ROOT) -> list[tuple[str, str, list[str]]]:
    """``(name, version, sha256 hashes)`` of each package of pyproject's extra ``wheels``, as uv.lock resolves
    it for CPython ``python`` ("3.11", "3.13")."""
    from packaging.markers import Marker
    from packaging.requirements import Requirement
    from packaging.utils import canonicalize_name

    with open(os.path.join(root, "pyproject.toml"), "rb") as f:
        extra = tomllib.load(f)["project"]["optional-dependencies"][WHEELS_EXTRA]
    with open(os.path.join(root, "uv.lock"), "rb") as f:
        lock = tomllib.load(f)
    env = {"python_version": python, "python_full_version": f"{python}.0"}
    out = []
    for req in extra:
        name = canonicalize_name(Requirement(req).name)
        hits = [p for p in lock["package"] if p["name"] == name
                and (not p.get("resolution-markers")
                     or any(Marker(m).evaluate(env) for m in p["resolution-markers"]))]
        if len(hits) != 1:
            raise RuntimeError(f"uv.lock holds {len(hits)} versions of {name} for CPython {python}: run `uv lock`")
        hashes = [w["hash"].removeprefix("sha256:") for w in hits[0].get("wheels", [])]
        out.append((name, hits[0]["version"], hashes))
    return out


def wheel_pins(python: str, root: str = ROOT) -> list[str]:
    """``NAME==VERSION`` of the wheels bundled for CPython ``python`` (:func:`locked_wheels`)."""
    return [f"{name}=={version}" for name, version, _ in locked_wheels(python, root)]


def download_wheels(python: str, platform: str, cache: str) -> list[str]:
    """The wheels of :func:`locked_wheels` for the Blender ``platform`` (downloaded into ``cache`` once)."""
    want = locked_wheels(python)
    dest = os.path.join(cache, f"cp{python.replace('.', '')}-{platform}")
    os.makedirs(dest, exist_ok=True)

    def present() -> list[str]:
        names = os.listdir(dest)
        found = []
        for name, ver, _ in want:
            prefix = f"{name.replace('-', '_')}-{ver}-"
            hits = [n for n in names if n.endswith(".whl") and n.lower().startswith(prefix)]
            if not hits:
                return []
            found.append(os.path.join(dest, sorted(hits)[0]))
        return found

    if present():
        return present()
    reqs = os.path.join(dest, "requirements.txt")  # pip checks each download against uv.lock's hashes
    with open(reqs, "w", encoding="utf-8") as f:
        for name, ver, hashes in want:
            f.write(f"{name}=={ver} " + " ".join(f"--hash=sha256:{h}" for h in hashes) + "\n")
    tags = [a for tag in PLATFORMS[platform] for a in ("--platform", tag)]
    proc = subprocess.run([sys.executable, "-m", "pip", "download", "-q", "--disable-pip-version-check", "--no-deps",
                           "--only-binary=:all:", *tags, "--python-version", python, "--dest", dest,
                           "--require-hashes", "-r", reqs],
                          capture_output=True, text=True)
    if proc.returncode == 0 and present():
        return present()
    errors = " ".join(ln for ln in proc.stderr.splitlines() if ln.startswith("ERROR"))[:400]
    pins = ", ".join(f"{n}=={v}" for n, v, _ in want)
    raise UserError(f"no wheels of {pins} for {platform} / CPython {python}: {errors}")


def _stage(source_dir: str, stage: str, manifest: dict) -> None:
    """A copy of the extension's files (the manifest's root exclusions left out) in ``stage``."""
    # the root-anchored exclusions ("/tests/", "/showcase/previews/") as paths relative to the root
    anchored = {p.strip("/") for p in manifest.get("build", {}).get("paths_exclude_pattern", [])
                if p.startswith("/") and "*" not in p}
    shutil.rmtree(stage, ignore_errors=True)

    def ignore(folder: str, names: list[str]) -> set[str]:
        out = {n for n in names if n in ("__pycache__", ".git") or n.endswith((".pyc", ".oso", ".blend1"))}
        rel = os.path.relpath(folder, source_dir).replace(os.sep, "/")
        out |= {n for n in names if (n if rel == "." else f"{rel}/{n}") in anchored}
        if rel == ".":
            out |= {n for n in names if n.endswith(".egg-info") or n.startswith(".venv")}
        return out

    shutil.copytree(source_dir, stage, ignore=ignore, symlinks=False)


def _staged_manifest(text: str, python: str, wheels: list[str], platforms: list[str],
                     version: str | None = None) -> str:
    """The checkout's manifest ``text`` with the Blender range of ``python``, ``platforms`` and ``wheels`` (and
    ``version`` instead of its own when given)."""
    import tomlkit

    doc = tomlkit.parse(text)
    if version is not None:
        doc["version"] = version
    for key in ("blender_version_max", "platforms", "wheels"):
        if key in doc:
            raise UserError(f"blender_manifest.toml: {key} is written by the build")
    lo, hi = BLENDER_RANGE[python]
    doc["blender_version_min"] = lo
    if hi:
        doc["blender_version_max"] = hi
    doc["platforms"] = list(platforms)
    listed = tomlkit.array()
    listed.extend(f"./wheels/{os.path.basename(w)}" for w in wheels)
    doc["wheels"] = listed.multiline(True)
    return tomlkit.dumps(doc)


def build_platforms(out_dir: str = "dist", source_dir: str = ROOT, platforms: list[str] | None = None,
                    pythons: list[str] | None = None, version: str | None = None) -> list[str]:
    """One zip per Python version and platform, with that platform's wheels; returns their paths. Writes
    only into ``out_dir`` (wheels: :func:`wheel_cache`; staging: a temporary folder)."""
    import tempfile

    validate(source_dir)
    manifest = _manifest(source_dir)
    if version is not None:
        _check_version(version)
        manifest = {**manifest, "version": version}
    platforms = list(platforms or PLATFORMS)
    pythons = list(pythons or BLENDER_RANGE)
    out_dir = os.path.abspath(out_dir)
    with tempfile.TemporaryDirectory(prefix="ms-build-") as work_dir:
        return _build_platforms(out_dir, source_dir, manifest, platforms, pythons, version, work_dir)


def _check_version(version: str) -> None:
    parts = version.split(".")
    if len(parts) != 3 or not all(p.isdigit() for p in parts):
        raise UsageError(f"--set-version must be a version like 1.2.3, got {version!r}")


def _build_platforms(out_dir: str, source_dir: str, manifest: dict, platforms: list[str], pythons: list[str],
                     version: str | None, work_dir: str) -> list[str]:
    os.makedirs(out_dir, exist_ok=True)
    with open(os.path.join(source_dir, "blender_manifest.toml"), encoding="utf-8") as f:
        manifest_text = f.read()
    written = []
    for python in pythons:
        wheels = [w for p in platforms for w in download_wheels(python, p, wheel_cache())]
        cp = f"cp{python.replace('.', '')}"
        stage = os.path.join(work_dir, f"stage-{cp}")
        _stage(source_dir, stage, manifest)
        os.makedirs(os.path.join(stage, "wheels"), exist_ok=True)
        for w in wheels:
            shutil.copy2(w, os.path.join(stage, "wheels", os.path.basename(w)))
        with open(os.path.join(stage, "blender_manifest.toml"), "w", encoding="utf-8") as f:
            f.write(_staged_manifest(manifest_text, python, wheels, platforms, version))
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
    for path in build_platforms(args.out, platforms=args.platform, pythons=args.python, version=args.set_version):
        print(f"{path}  {os.path.getsize(path) / 2**20:.1f} MiB")
    return 0
