#!/usr/bin/env bash
# SASA on a machine with an NVIDIA GPU: the CUDA tests (tests/test_sasa_cuda.py: the GPU paths of the
# operators against the CPU's, training and detection on the GPU), the operators' CUDA timings
# (benchmarks/sasa_ops.py) and the training step of both presets on CUDA (benchmarks/sasa.py), with
# FPS on the Triton kernel and, for comparison, on the PyTorch loop.
#
# Usage, from the repository root, with PyTorch's CUDA build (Triton comes with it):
#   bash benchmarks/cuda_check.sh [OUTDIR]
# Needs only torch, numpy, scipy, numba, tqdm and pyyaml besides the package's source (no Open3D, no
# Snakemake): the source is put on PYTHONPATH, and pytest runs without the suite's conftest.
set -uo pipefail
out=${1:-cuda_check}
mkdir -p "$out"
export PYTHONPATH="$PWD/src${PYTHONPATH:+:$PYTHONPATH}" PYTHONUNBUFFERED=1
py=${PYTHON:-python3}
status=0
step() {  # step NAME SECONDS COMMAND...: run with a time limit, log to OUTDIR/NAME.log
    local name=$1 limit=$2
    shift 2
    echo "== $name: $*"
    timeout "$limit" "$@" 2>&1 | tee "$out/$name.log"
    local rc=${PIPESTATUS[0]}
    echo "== $name: exit $rc"
    [ "$rc" -eq 0 ] || status=1
}
nvidia-smi --query-gpu=name,driver_version,memory.total --format=csv | tee "$out/gpu.txt"
$py -c "import sys, torch, numpy, numba; from sonardet.detect.sasa.ops import gpu_kernels as g; \
print('python', sys.version.split()[0], 'torch', torch.__version__, 'numpy', numpy.__version__, \
'numba', numba.__version__, 'triton', g.triton.__version__ if g.AVAILABLE else None)" | tee "$out/versions.txt"
step pytest 200 $py -m pytest -q --noconftest -p no:cacheprovider -m cuda tests/test_sasa_cuda.py
step sasa_cuda 150 $py benchmarks/sasa.py --device cuda --configs DEFAULTS,STUDY --synthetic --steps 10 --warmup 2 \
    --profile 30 --json "$out/sasa_cuda.json"
step sasa_cuda_fps_loop 100 $py benchmarks/sasa.py --device cuda --configs STUDY --synthetic --steps 5 --fps-loop \
    --json "$out/sasa_cuda_fps_loop.json"
step ops_cuda 100 $py benchmarks/sasa_ops.py --cuda-only --repeat 5 --json "$out/ops_cuda.json"
exit $status
