#!/usr/bin/env bash
# Set up Blender as a Python module in its own virtual environment, for the Cycles row of
# `neural-bake bench bake`. Blender never runs in the project's venv: bpy needs Python 3.13 and the
# system library libvulkan.so.1, and the bench starts it as a separate process.
# Safe to run again: it only installs what is missing.
#   usage: scripts/setup-blender.sh [VENV_DIR]      (default .cache/blender-venv)
#   BLENDER_PYTHON=/path/to/python3.13 to choose the interpreter (else python3.13 on PATH, else pyenv's 3.13)
set -euo pipefail
VENV=${1:-.cache/blender-venv}
BPY_VERSION=${BPY_VERSION:-5.2.4}
cd "$(dirname "$0")/.."

say() { printf 'setup-blender: %s\n' "$*"; }
die() { say "error: $*" >&2; exit 1; }

# 1. bpy's Cycles links against libvulkan.so.1 (Debian/Ubuntu: libvulkan1, with the Mesa drivers).
if ! ldconfig -p 2>/dev/null | grep -q 'libvulkan.so.1'; then
  if command -v apt-get >/dev/null 2>&1; then
    SUDO=""; [ "$(id -u)" -ne 0 ] && SUDO="sudo"
    say "installing libvulkan1 mesa-vulkan-drivers (needed by bpy)"
    APT=($SUDO apt-get -o DPkg::Lock::Timeout=600)  # waits for another apt run instead of failing
    "${APT[@]}" update -qq && DEBIAN_FRONTEND=noninteractive "${APT[@]}" install -y -qq libvulkan1 mesa-vulkan-drivers >/dev/null
  else
    say "warning: libvulkan.so.1 not found and no apt-get; install the Vulkan loader with your package manager"
  fi
fi

# 2. A Python 3.13: $BLENDER_PYTHON, else python3.13 on PATH, else pyenv's newest 3.13.
is313() { [ -n "$1" ] && "$1" -c 'import sys; sys.exit(sys.version_info[:2] != (3, 13))' >/dev/null 2>&1; }
if [ ! -x "$VENV/bin/python" ]; then
  PY=""
  if [ -n "${BLENDER_PYTHON:-}" ]; then
    is313 "$BLENDER_PYTHON" || die "BLENDER_PYTHON=$BLENDER_PYTHON is not a working Python 3.13"
    PY=$BLENDER_PYTHON
  elif is313 "$(command -v python3.13 || true)"; then
    PY=$(command -v python3.13)
  else
    for cand in $(ls -d "${PYENV_ROOT:-$HOME/.pyenv}"/versions/3.13*/bin/python3.13 2>/dev/null | sort -V -r); do
      if is313 "$cand"; then PY=$cand; break; fi
    done
  fi
  [ -n "$PY" ] || die "no Python 3.13 found: set BLENDER_PYTHON, or install one (e.g. pyenv install 3.13)"
  say "creating $VENV with $("$PY" --version) ($PY)"
  mkdir -p "$(dirname "$VENV")"
  "$PY" -m venv "$VENV"
fi

# 3. bpy (a few hundred MB), only when the installed one is not the pinned version.
have=$("$VENV/bin/python" -c 'import importlib.metadata as m; print(m.version("bpy"))' 2>/dev/null || true)
if [ "$have" != "$BPY_VERSION" ]; then
  say "installing bpy==$BPY_VERSION into $VENV (a download of several hundred MB)"
  "$VENV/bin/python" -m pip install --disable-pip-version-check -q "bpy==$BPY_VERSION"
fi

# 4. The check: bpy imports and says its version.
version=$("$VENV/bin/python" -c 'import bpy; print(bpy.app.version_string)' 2>/dev/null | tail -n 1) \
  || die "bpy does not import in $VENV: run '$VENV/bin/python -c \"import bpy\"' to see why"
say "ok: Blender $version in $VENV"
