#!/usr/bin/env bash
# Set up neural-bake in a virtual environment: the system library open3d needs, the right torch build,
# then the package with its test extras (editable). Safe to run again: it only installs what is missing.
#   usage: scripts/setup.sh [VENV_DIR]      (default .venv; PYTHON=python3.11 to choose the interpreter)
set -euo pipefail
VENV=${1:-.venv}
PYTHON=${PYTHON:-python3}
cd "$(dirname "$0")/.."

say() { printf 'setup: %s\n' "$*"; }

# 1. open3d links against libusb-1.0 (Debian/Ubuntu package libusb-1.0-0).
if ! ldconfig -p 2>/dev/null | grep -q 'libusb-1.0.so.0'; then
  if command -v apt-get >/dev/null 2>&1; then
    SUDO=""; [ "$(id -u)" -ne 0 ] && SUDO="sudo"
    say "installing libusb-1.0-0 (needed by open3d)"
    $SUDO apt-get update -qq && DEBIAN_FRONTEND=noninteractive $SUDO apt-get install -y -qq libusb-1.0-0 >/dev/null
  else
    say "warning: libusb-1.0 not found and no apt-get; install it with your package manager (open3d needs it)"
  fi
fi

# 2. The virtual environment.
if [ ! -x "$VENV/bin/python" ]; then
  say "creating $VENV with $($PYTHON --version)"
  "$PYTHON" -m venv "$VENV"
fi
PIP=("$VENV/bin/python" -m pip install --disable-pip-version-check -q)

# 3. torch: the CPU build where no NVIDIA GPU is present (an unpinned torch pulls a CUDA build of GBs).
if ! "$VENV/bin/python" -c "import torch" >/dev/null 2>&1; then
  if command -v nvidia-smi >/dev/null 2>&1 && nvidia-smi -L >/dev/null 2>&1; then
    say "NVIDIA GPU found: installing torch with CUDA"
    "${PIP[@]}" "torch>=2.3"
  else
    say "no GPU: installing the CPU build torch==2.13.0+cpu"
    # PyTorch's CPU index is tried once (fast failure where it cannot be reached; a local or mirrored
    # torch==2.13.0+cpu wheel is then used, as on machines that carry one)
    "${PIP[@]}" --retries 0 --timeout 15 "torch==2.13.0" --extra-index-url https://download.pytorch.org/whl/cpu
  fi
fi

# 4. The package (editable, so the checkout is what runs), the test tools and the USD writer (the test
#    extras hold usd-core, so `make demo` writes asset.usd and the tests validate it).
say "installing neural-bake and its dependencies"
"${PIP[@]}" -e ".[test,usd]"
# The package's bytecode, as a wheel install writes it: an editable install leaves it to the first run, and
# where bytecode is never written (PYTHONDONTWRITEBYTECODE) every command would compile its sources again.
"$VENV/bin/python" -m compileall -q neural_bake cli pipelines samples >/dev/null \
  || say "warning: could not write the package's bytecode: commands start slower"
"$VENV/bin/python" -c "import open3d, torch, OpenImageIO, pymeshlab, xatlas; print('setup: ok: torch', torch.__version__)"

# 5. The visual checks: model-viewer (npm) beside the reports, the Khronos glTF validator (npm) for the GLB
#    tests, Chromium for the browser test.
MV_VERSION=4.4.0
MV_DIR=.cache/model-viewer
if [ ! -f "$MV_DIR/node_modules/@google/model-viewer/dist/model-viewer-umd.min.js" ]; then
  if command -v npm >/dev/null 2>&1; then
    say "fetching @google/model-viewer@$MV_VERSION into $MV_DIR (the reports' glTF viewer)"
    mkdir -p "$MV_DIR"
    npm install --prefix "$MV_DIR" --no-audit --no-fund --silent "@google/model-viewer@$MV_VERSION" >/dev/null \
      || say "warning: npm could not fetch @google/model-viewer: reports will show pictures without the viewer"
  else
    say "note: npm not found: reports will show pictures without the interactive glTF viewer"
  fi
fi
GV_VERSION=2.0.0-dev.3.10
GV_DIR=.cache/gltf-validator
if [ ! -f "$GV_DIR/node_modules/gltf-validator/package.json" ] && command -v npm >/dev/null 2>&1; then
  say "fetching gltf-validator@$GV_VERSION into $GV_DIR (the Khronos validator the GLB tests run)"
  mkdir -p "$GV_DIR"
  npm install --prefix "$GV_DIR" --no-audit --no-fund --silent "gltf-validator@$GV_VERSION" >/dev/null \
    || say "warning: npm could not fetch gltf-validator: the GLB validation test will be skipped"
fi
if ! command -v chromium >/dev/null 2>&1 && [ ! -x /usr/bin/chromium ]; then
  if command -v apt-get >/dev/null 2>&1; then
    SUDO=""; [ "$(id -u)" -ne 0 ] && SUDO="sudo"
    say "installing chromium (the browser test of the reports)"
    { $SUDO apt-get update -qq && DEBIAN_FRONTEND=noninteractive $SUDO apt-get install -y -qq chromium; } >/dev/null 2>&1 \
      || say "warning: could not install chromium: the browser test will be skipped (it fails under CI)"
  else
    say "note: no chromium and no apt-get: the browser test will be skipped"
  fi
fi
