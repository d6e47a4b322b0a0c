#!/usr/bin/env bash
# Bootstrap a project virtual environment. Usage: scripts/bootstrap.sh main|compat|bare|bare-compat|lock
#   main        -> .venv              CPython 3.13, bpy 5.2.3, this checkout with the extra `dev`
#   compat      -> .venv-compat       CPython 3.11, bpy 4.5.15, this checkout with the extra `compat`
#   bare        -> .venv-bare         CPython 3.13, only bpy 5.2.3 + numpy: a desktop Blender's Python (make test-bare)
#   bare-compat -> .venv-bare-compat  CPython 3.11, only bpy 4.5.15 + numpy 1.26.4
#   lock [ARGS] -> uv.lock            `uv lock ARGS`, after an edit of pyproject.toml's dependencies (make lock)
# Each venv is pyproject.toml's dependencies (+ an extra) at uv.lock's versions, installed by `uv sync --locked`;
# uv is the one on PATH, else one installed from PyPI into .venv-uv. Re-running is instant while uv.lock and
# pyproject.toml are unchanged.
set -euo pipefail
cd "$(dirname "$0")/.."
kind=${1:-main}
case "$kind" in
  main)   want=3.13; venv=.venv;        sync=(--extra dev) ;;
  compat) want=3.11; venv=.venv-compat; sync=(--extra compat) ;;
  bare)   want=3.13; venv=.venv-bare;   sync=(--no-install-project) ;;
  bare-compat) want=3.11; venv=.venv-bare-compat; sync=(--no-install-project) ;;
  lock)   want=3.13 ;;
  *) echo "usage: $0 main|compat|bare|bare-compat|lock" >&2; exit 2 ;;
esac

log() { printf '[setup] %s\n' "$*" >&2; }

is_version() {  # is_version BIN X.Y -> true when BIN runs and is Python X.Y
  [ -n "$1" ] && "$1" -c "import sys; sys.exit(0 if '%d.%d' % sys.version_info[:2] == '$2' else 1)" 2>/dev/null
}

find_python() {
  local cand root
  for cand in "python$want" "python3"; do
    cand=$(command -v "$cand" 2>/dev/null || true)
    if is_version "$cand" "$want"; then echo "$cand"; return 0; fi
  done
  root=$(pyenv root 2>/dev/null || echo "$HOME/.pyenv")
  for cand in "$root"/versions/"$want".*/bin/python"$want"; do
    if is_version "$cand" "$want"; then echo "$cand"; return 0; fi
  done
  cand=$(uv python find "$want" 2>/dev/null || true)
  if is_version "$cand" "$want"; then echo "$cand"; return 0; fi
  cat >&2 <<MSG
[setup] CPython $want was not found (looked at python$want on PATH, pyenv's versions folder, uv).
[setup] Install it, for example one of:
[setup]   Debian 13 / Ubuntu 24.04+:  apt-get install python$want python$want-venv
[setup]   pyenv:                      pyenv install $want
[setup]   uv:                         pip install uv && uv python install $want
MSG
  return 1
}

apt_install() {  # apt_install PKG... -> true when apt-get (as root or through sudo) installed them
  local sudo=""
  command -v apt-get >/dev/null 2>&1 || return 1
  if [ "$(id -u)" != 0 ]; then command -v sudo >/dev/null 2>&1 && sudo=sudo || return 1; fi
  log "installing: $*"
  $sudo apt-get update -qq && $sudo env DEBIAN_FRONTEND=noninteractive apt-get install -y -qq "$@" >/dev/null
}

ensure_system_libs() {  # bpy needs X/GL libraries even headless; Mitsuba's llvm_* variants load libLLVM 19
  local lib missing=""
  for lib in libX11.so.6 libXrender.so.1 libXfixes.so.3 libXi.so.6 libxkbcommon.so.0 libSM.so.6 libICE.so.6 \
      libGL.so.1 libXext.so.6 libxcb.so.1; do
    ldconfig -p 2>/dev/null | grep -q "$lib" || missing="$missing $lib"
  done
  local pkgs="libx11-6 libxrender1 libxfixes3 libxi6 libxkbcommon0 libsm6 libice6 libgl1 libxext6 libxcb1"
  if [ -n "$missing" ]; then
    log "missing X/GL libraries needed by bpy:$missing"
    apt_install $pkgs || { log "install these packages with your system's package manager: $pkgs"; exit 1; }
  fi
  # not fatal: without it Mitsuba's scalar variants still work (bench teeth-vs-mitsuba needs llvm_ad_rgb)
  if [ "$kind" = main ] && ! ldconfig -p 2>/dev/null | grep -q "libLLVM.so.19" && ! apt_install libllvm19; then
    log "libLLVM 19 not found (needed by Mitsuba's llvm_ad_rgb variant): install libllvm19"
  fi
}

ensure_uv() {  # sets $uv; pyproject's [tool.uv] required-version is the version asked of PyPI (uv checks it too)
  uv=$(command -v uv 2>/dev/null || echo .venv-uv/bin/uv)
  [ -x "$uv" ] && return 0
  local spec out
  spec=$("$py" -c 'import tomllib; print(tomllib.load(open("pyproject.toml", "rb"))["tool"]["uv"]["required-version"])')
  log "installing uv$spec from PyPI into .venv-uv"
  rm -rf .venv-uv
  "$py" -m venv .venv-uv
  if ! out=$(.venv-uv/bin/python -m pip install -q --disable-pip-version-check "uv$spec" 2>&1); then
    printf '%s\n' "$out" >&2; log "pip install uv failed"; exit 1
  fi
}

if [ "$kind" = lock ]; then
  py=$(find_python) || exit 1
  ensure_uv
  exec "$uv" lock "${@:2}"
fi

stamp="$venv/.material-structures-stamp"
digest=$(cat uv.lock pyproject.toml | sha256sum | cut -d' ' -f1)
if [ -f "$stamp" ] && [ "$(cat "$stamp")" = "$digest" ] && [ -x "$venv/bin/python" ]; then
  exit 0  # up to date
fi

py=$(find_python) || exit 1
log "using $py ($("$py" --version 2>&1)) for $venv"
ensure_system_libs
ensure_uv
log "installing uv.lock into $venv (${sync[*]}; first time: a minute or two, bpy is large)"
# --locked: stop, instead of re-resolving, when pyproject.toml's dependencies changed and uv.lock did not.
# --compile-bytecode: the .pyc files now (20 s), not on first import, which never happens where
# PYTHONDONTWRITEBYTECODE is set: there every process (test workers, fits, Dask workers, Blender) compiled
# numpy, scipy, numba and dask afresh, 2 s each, and a clean clone's make test took 531 s instead of 342 s
if ! UV_PROJECT_ENVIRONMENT="$PWD/$venv" "$uv" sync --locked --quiet --compile-bytecode --python "$py" \
    --no-python-downloads "${sync[@]}"; then
  log "uv sync failed (after an edit of pyproject.toml's dependencies: make lock, and commit uv.lock)"; exit 1
fi
case "$kind" in
  bare*) "$venv/bin/python" -c "import bpy" || { log "installation failed"; exit 1; } ;;  # nothing of ours
  *) "$venv/bin/python" -c "import numpy, material_structures.core" || { log "installation failed"; exit 1; } ;;
esac
echo "$digest" > "$stamp"
log "$venv ready"
