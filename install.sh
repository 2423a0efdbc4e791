#!/usr/bin/env bash
# One command installs everything thrsim needs on a fresh Debian machine:
# the system libraries gmsh's wheel links against, Mesa's EGL (the offscreen
# renderer, thrsim.render), CalculiX (the solver cross-check), a C++ compiler
# (torch.compile builds the trainer's reaming network with it), PyTorch's CPU
# build (pinned), thrsim itself, and for the browser trainer Chromium (its
# end-to-end tests) and three.js from the npm registry (npm ci, locked; with
# the iwer WebXR emulator, a development dependency the headset tests load).
set -euo pipefail
cd "$(dirname "$0")"

SUDO=""
if [ "$(id -u)" -ne 0 ]; then SUDO="sudo"; fi
if command -v apt-get >/dev/null 2>&1; then
  $SUDO apt-get update -qq
  DEBIAN_FRONTEND=noninteractive $SUDO apt-get install -y -qq \
    libglu1-mesa libxcursor1 libxft2 libxinerama1 libxrender1 libxi6 libgl1 \
    libegl1 libegl-mesa0 libgl1-mesa-dri \
    calculix-ccx chromium g++ >/dev/null
  if ! command -v npm >/dev/null 2>&1; then
    DEBIAN_FRONTEND=noninteractive $SUDO apt-get install -y -qq nodejs npm >/dev/null
  fi
fi
(cd thrsim/app/static && npm ci --no-audit --no-fund --loglevel=error)

PY="${PYTHON:-python3}"
# torch: always the pinned CPU build; a local wheel is used when the machine has one.
TORCH_WHEEL=$(ls /opt/wheels/torch-2.13.0+cpu-*.whl 2>/dev/null | head -n 1 || true)
if [ -n "$TORCH_WHEEL" ]; then
  "$PY" -m pip install -q "$TORCH_WHEEL"
else
  "$PY" -m pip install -q "torch==2.13.0"
fi
"$PY" -m pip install -q -e ".[dev]"
if command -v pyenv >/dev/null 2>&1; then pyenv rehash; fi
echo "thrsim installed: $(command -v thrsim || echo "$("$PY" -c 'import sys;print(sys.prefix)')/bin/thrsim")"
