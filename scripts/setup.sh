#!/usr/bin/env bash
# Set up everything sonardet needs on a fresh Debian/Ubuntu machine with Python >= 3.11:
# the system library Open3D needs (libusb-1.0-0), a virtualenv in .venv, the small CPU build of
# torch (pinned: an unpinned torch pulls a multi-GB CUDA build) and the package with its test extras.
# Idempotent: a second run only reinstalls when pyproject.toml changed.
set -euo pipefail
cd "$(dirname "$0")/.."

PY=${PYTHON:-python3}
VENV=${VENV:-.venv}
TORCH_SPEC=${TORCH_SPEC:-torch==2.13.0}

if ! "$PY" -c 'import sys; sys.exit(0 if sys.version_info >= (3, 11) else 1)'; then
  echo "setup: $PY is $("$PY" --version 2>&1); sonardet needs Python >= 3.11 (set PYTHON=/path/to/python3.11)" >&2
  exit 1
fi

have_libusb() { ldconfig -p 2>/dev/null | grep -q 'libusb-1.0.so.0'; }
if ! have_libusb; then
  echo "setup: installing libusb-1.0-0 (needed by Open3D)"
  SUDO=""
  [ "$(id -u)" -ne 0 ] && command -v sudo >/dev/null && SUDO="sudo"
  if ! { $SUDO apt-get update -qq && $SUDO apt-get install -y -qq libusb-1.0-0; } >/tmp/sonardet-apt.log 2>&1 || ! have_libusb; then
    echo "setup: could not install the system library libusb-1.0-0, which Open3D needs to import." >&2
    echo "       Install it yourself (Debian/Ubuntu: sudo apt-get install libusb-1.0-0; conda: conda install -c conda-forge libusb)" >&2
    echo "       and run this script again. apt said:" >&2
    tail -n 5 /tmp/sonardet-apt.log >&2 || true
    exit 1
  fi
fi

if [ ! -x "$VENV/bin/python" ]; then
  "$PY" -m venv "$VENV"
fi
stamp="$VENV/.sonardet-installed"
want="$(sha256sum pyproject.toml | cut -c1-16) $TORCH_SPEC"
if [ ! -f "$stamp" ] || [ "$(cat "$stamp")" != "$want" ]; then
  quiet() { grep -v -E "WARNING: Location .* is ignored" || true; }
  "$VENV/bin/python" -m pip install -q --upgrade pip 2>&1 | quiet
  "$VENV/bin/python" -m pip install -q "$TORCH_SPEC" 2>&1 | quiet
  "$VENV/bin/python" -m pip install -q -e ".[test]" 2>&1 | quiet
  "$VENV/bin/python" -c "import open3d, torch, trimesh, mujoco, embreex, snakemake" \
    || { echo "setup: the environment in $VENV does not import; see the errors above" >&2; exit 1; }
  echo "$want" > "$stamp"
fi
echo "setup: ready ($("$VENV/bin/python" -c 'import torch, open3d; print("torch", torch.__version__, "open3d", open3d.__version__)'))"
