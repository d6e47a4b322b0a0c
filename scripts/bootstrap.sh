#!/usr/bin/env bash
# Bootstrap a project virtual environment. Usage: scripts/bootstrap.sh main|compat|bare|bare-compat
#   main        -> .venv              CPython 3.13, bpy 5.2.3 (requirements.txt)
#   compat      -> .venv-compat       CPython 3.11, bpy 4.5.15 (requirements-compat.txt)
#   bare        -> .venv-bare         CPython 3.13, only bpy 5.2.3: a desktop Blender's Python (make test-bare)
#   bare-compat -> .venv-bare-compat  CPython 3.11, only bpy 4.5.15
# Re-running is fast: nothing is reinstalled while the requirements and pyproject are unchanged.
set -euo pipefail
cd "$(dirname "$0")/.."
kind=${1:-main}
case "$kind" in
  main)   want=3.13; venv=.venv;        reqs=requirements.txt ;;
  compat) want=3.11; venv=.venv-compat; reqs=requirements-compat.txt ;;
  bare)   want=3.13; venv=.venv-bare;   reqs=requirements-bare.txt ;;
  bare-compat) want=3.11; venv=.venv-bare-compat; reqs=requirements-bare-compat.txt ;;
  *) echo "usage: $0 main|compat|bare|bare-compat" >&2; exit 2 ;;
esac

log() { printf '[setup] %s\n' "$*" >&2; }

is_version() {  # is_version BIN X.Y -> true when BIN runs and is Python X.Y
  [ -n "$1" ] && "$1" -c "import sys; sys.exit(0 if '%d.%d' % sys.version_info[:2] == '$2' else 1)" 2>/dev/null
}

find_python() {
  local cand
  for cand in "python$want" "python3"; do
    cand=$(command -v "$cand" 2>/dev/null || true)
    if is_version "$cand" "$want"; then echo "$cand"; return 0; fi
  done
  local root
  root=$(pyenv root 2>/dev/null || echo "$HOME/.pyenv")
  for cand in "$root"/versions/"$want".*/bin/python"$want"; do
    if is_version "$cand" "$want"; then echo "$cand"; return 0; fi
  done
  if command -v uv >/dev/null 2>&1; then
    cand=$(uv python find "$want" 2>/dev/null || true)
    if is_version "$cand" "$want"; then echo "$cand"; return 0; fi
  fi
  return 1
}

ensure_gl_libs() {  # bpy needs X/GL libraries even headless
  local libs="libX11.so.6 libXrender.so.1 libXfixes.so.3 libXi.so.6 libxkbcommon.so.0 libSM.so.6 libICE.so.6 libGL.so.1 libXext.so.6 libxcb.so.1"
  local missing="" lib
  for lib in $libs; do
    ldconfig -p 2>/dev/null | grep -q "$lib" || missing="$missing $lib"
  done
  [ -z "$missing" ] && return 0
  local pkgs="libx11-6 libxrender1 libxfixes3 libxi6 libxkbcommon0 libsm6 libice6 libgl1 libxext6 libxcb1"
  log "missing X/GL libraries needed by bpy:$missing"
  if command -v apt-get >/dev/null 2>&1 && [ "$(id -u)" = 0 ]; then
    log "installing: $pkgs"
    apt-get update -qq && DEBIAN_FRONTEND=noninteractive apt-get install -y -qq $pkgs >/dev/null
  elif command -v apt-get >/dev/null 2>&1 && command -v sudo >/dev/null 2>&1; then
    sudo apt-get update -qq && sudo DEBIAN_FRONTEND=noninteractive apt-get install -y -qq $pkgs >/dev/null
  else
    log "install these packages with your system's package manager: $pkgs"; exit 1
  fi
}

ensure_llvm_lib() {  # Mitsuba's llvm_* variants (Dr.Jit's LLVM backend) load libLLVM; Debian ships it as libllvm19
  ldconfig -p 2>/dev/null | grep -q "libLLVM.so.19" && return 0
  local installed=""
  if command -v apt-get >/dev/null 2>&1 && [ "$(id -u)" = 0 ]; then
    log "installing libllvm19 (for Mitsuba's llvm_ad_rgb variant)"
    apt-get update -qq && DEBIAN_FRONTEND=noninteractive apt-get install -y -qq libllvm19 >/dev/null && installed=1
  elif command -v apt-get >/dev/null 2>&1 && command -v sudo >/dev/null 2>&1; then
    log "installing libllvm19 (for Mitsuba's llvm_ad_rgb variant)"
    sudo apt-get update -qq && sudo DEBIAN_FRONTEND=noninteractive apt-get install -y -qq libllvm19 >/dev/null \
      && installed=1
  fi
  # not fatal: without it Mitsuba's scalar variants still work (bench teeth-vs-mitsuba needs llvm_ad_rgb)
  [ -n "$installed" ] || log "libLLVM 19 not found (needed by Mitsuba's llvm_ad_rgb variant): install libllvm19"
}

stamp="$venv/.material-structures-stamp"
digest=$(cat "$reqs" pyproject.toml | sha256sum | cut -d' ' -f1)
if [ -f "$stamp" ] && [ "$(cat "$stamp")" = "$digest" ] && [ -x "$venv/bin/python" ]; then
  exit 0  # up to date
fi

py=$(find_python) || {
  cat >&2 <<MSG
[setup] CPython $want was not found (looked at python$want on PATH, pyenv's versions folder, uv).
[setup] Install it, for example one of:
[setup]   Debian 13 / Ubuntu 24.04+:  apt-get install python$want python$want-venv
[setup]   pyenv:                      pyenv install $want
[setup]   uv:                         pip install uv && uv python install $want
MSG
  exit 1
}
log "using $py ($("$py" --version 2>&1)) for $venv"
ensure_gl_libs
if [ "$kind" = main ]; then ensure_llvm_lib; fi

if [ ! -x "$venv/bin/python" ] || ! is_version "$venv/bin/python" "$want"; then
  rm -rf "$venv"
  "$py" -m venv "$venv"
fi
pip_install() {  # quiet unless it fails
  local out
  if ! out=$("$venv/bin/python" -m pip install -q --disable-pip-version-check "$@" 2>&1); then
    printf '%s\n' "$out" | grep -v '^WARNING: Location' >&2
    log "pip install $* failed"; exit 1
  fi
}
log "installing $reqs into $venv (first time: a few minutes, bpy is large)"
pip_install -r "$reqs"
case "$kind" in
  bare*) "$venv/bin/python" -c "import bpy" || { log "installation failed"; exit 1; } ;;  # nothing of ours
  *) pip_install --no-deps -e .
     "$venv/bin/python" -c "import numpy, material_structures.core" || { log "installation failed"; exit 1; } ;;
esac
echo "$digest" > "$stamp"
log "$venv ready"
