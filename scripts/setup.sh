#!/usr/bin/env bash
# Set up everything sonardet needs on a Linux machine with Python >= 3.11: the system library Open3D
# needs (libusb-1.0-0, installed with apt on Debian/Ubuntu), a virtualenv in .venv, torch (pinned;
# which build, below) and the package with its test and cluster extras.
# Idempotent: a second run only reinstalls when pyproject.toml or the torch choice changed.
#
# Which torch build (environment variables):
#   SONARDET_TORCH=cpu (default)  the CPU-only build from PyTorch's CPU wheel index (about 200 MB,
#                                 runs everywhere; the study preset's training is then slow)
#   SONARDET_TORCH=cu128 (cu126, ...)  a CUDA build from PyTorch's index for that CUDA version
#   SONARDET_TORCH=default        whatever pip's configured index serves (PyPI: the CUDA build on
#                                 Linux x86_64, several GB; the CPU build elsewhere)
#   TORCH_INDEX_URL=URL           install torch from this index (overrides SONARDET_TORCH)
#   TORCH_SPEC=torch==X           the pin (default torch==2.13.0)
# When the chosen PyTorch index cannot be reached, torch comes from pip's configured index instead,
# with a note saying so. `bash scripts/setup.sh --print-torch-plan` prints the decision and stops.
set -euo pipefail
cd "$(dirname "$0")/.."

PY=${PYTHON:-python3}
VENV=${VENV:-.venv}
TORCH_SPEC=${TORCH_SPEC:-torch==2.13.0}
SONARDET_TORCH=${SONARDET_TORCH:-cpu}
PYTORCH_INDEX=https://download.pytorch.org/whl

# The torch plan: TORCH_FROM is the index URL to install from, or "" for pip's configured index.
torch_plan() {
  local index=""
  if [ -n "${TORCH_INDEX_URL:-}" ]; then
    index=$TORCH_INDEX_URL
  elif [ "$SONARDET_TORCH" != "default" ]; then
    case "$SONARDET_TORCH" in
      cpu | cu[0-9]* | rocm[0-9]*) index="$PYTORCH_INDEX/$SONARDET_TORCH" ;;
      *)
        echo "setup: SONARDET_TORCH=$SONARDET_TORCH is none of cpu, cuNNN (e.g. cu128), rocmX.Y, default" >&2
        exit 2
        ;;
    esac
  fi
  TORCH_FROM=""
  if [ -z "$index" ]; then
    TORCH_NOTE="setup: torch ($TORCH_SPEC) from pip's configured index (SONARDET_TORCH=default)"
  elif "$PY" - "$index" <<'EOF'; then
import sys, urllib.request
url = sys.argv[1].rstrip("/") + "/torch/"
try:
    urllib.request.urlopen(urllib.request.Request(url, method="HEAD"), timeout=10)
except Exception:
    sys.exit(1)
EOF
    TORCH_FROM=$index
    TORCH_NOTE="setup: torch ($TORCH_SPEC) from $index"
  else
    TORCH_NOTE="setup: note: $index cannot be reached; torch ($TORCH_SPEC) comes from pip's configured
      index instead. From PyPI that is the CUDA build on Linux x86_64 (several GB; it runs without a
      GPU too) and the CPU build elsewhere; a local index or wheel folder (pip's find-links) may
      serve a CPU build. TORCH_INDEX_URL=URL picks a reachable mirror of the PyTorch index."
  fi
}

if ! "$PY" -c 'import sys; sys.exit(0 if sys.version_info >= (3, 11) else 1)'; then
  echo "setup: $PY is $("$PY" --version 2>&1); sonardet needs Python >= 3.11 (set PYTHON=/path/to/python3.11)" >&2
  exit 1
fi

if [ "${1:-}" = "--print-torch-plan" ]; then
  torch_plan
  echo "$TORCH_NOTE"
  echo "index: ${TORCH_FROM:-pip-default}"
  exit 0
fi

have_libusb() { ldconfig -p 2>/dev/null | grep -q 'libusb-1.0.so.0'; }
if ! have_libusb; then
  echo "setup: installing libusb-1.0-0 (needed by Open3D)"
  SUDO=""
  [ "$(id -u)" -ne 0 ] && command -v sudo >/dev/null && SUDO="sudo"
  if ! command -v apt-get >/dev/null \
    || ! { $SUDO apt-get update -qq && $SUDO apt-get install -y -qq libusb-1.0-0; } >/tmp/sonardet-apt.log 2>&1 \
    || ! have_libusb; then
    echo "setup: could not install the system library libusb-1.0-0, which Open3D needs to import." >&2
    echo "       Install it yourself (Debian/Ubuntu: sudo apt-get install libusb-1.0-0; Fedora: sudo dnf" >&2
    echo "       install libusb1; conda: conda install -c conda-forge libusb) and run this script again." >&2
    tail -n 5 /tmp/sonardet-apt.log >&2 2>/dev/null || true
    exit 1
  fi
fi

if [ ! -x "$VENV/bin/python" ]; then
  "$PY" -m venv "$VENV"
fi
stamp="$VENV/.sonardet-installed"
want="$(sha256sum pyproject.toml | cut -c1-16) $TORCH_SPEC ${TORCH_INDEX_URL:-$SONARDET_TORCH}"
if [ ! -f "$stamp" ] || [ "$(cat "$stamp")" != "$want" ]; then
  quiet() { grep -v -E "WARNING: Location .* is ignored" || true; }
  "$VENV/bin/python" -m pip install -q --upgrade pip 2>&1 | quiet
  torch_plan
  echo "$TORCH_NOTE"
  if [ -n "$TORCH_FROM" ]; then
    "$VENV/bin/python" -m pip install -q --index-url "$TORCH_FROM" "$TORCH_SPEC" 2>&1 | quiet
  else
    "$VENV/bin/python" -m pip install -q "$TORCH_SPEC" 2>&1 | quiet
  fi
  "$VENV/bin/python" -m pip install -q -e ".[test,cluster]" 2>&1 | quiet
  "$VENV/bin/python" -c "import open3d, torch, trimesh, mujoco, embreex, snakemake" \
    || { echo "setup: the environment in $VENV does not import; see the errors above" >&2; exit 1; }
  echo "$want" > "$stamp"
fi
# Compile the Numba kernels into their on-disk cache now, in the pinned numerical environment the
# workflow's jobs run in, so that no job compiles them (python -m sonardet.warm; seconds once cached).
(eval "$("$VENV/bin/python" -m sonardet.determinism)" && "$VENV/bin/python" -m sonardet.warm) \
  || { echo "setup: compiling the package's kernels failed (python -m sonardet.warm, errors above)" >&2; exit 1; }
echo "setup: ready ($("$VENV/bin/python" -c '
import torch, open3d
build = f"CUDA {torch.version.cuda}" if torch.version.cuda else "CPU-only"
gpu = "a GPU is visible" if torch.cuda.is_available() else "no GPU visible: SASA runs on the CPU"
print(f"torch {torch.__version__} ({build}; {gpu}), open3d {open3d.__version__}")'))"
