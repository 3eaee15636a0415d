"""The numerical environment that makes the workflow's outputs the same bytes on another machine of the
same kind: fixed thread counts and fixed instruction-set paths of the numerical libraries.

Two runs on one machine give the same bytes; two machines can differ where a library picks its code
path from the CPU it finds at run time:

* OpenBLAS (numpy's and scipy's BLAS, used for every matrix product: mesh transforms, poses, ICP)
  chooses its kernels per CPU model (Haswell, Zen, SkylakeX with AVX-512, ...), and kernels sum in
  different orders. Measured here: forcing the Sandy Bridge kernels instead of the Haswell ones
  changes the object meshes, the templates and every scene; the settled poses then drift (MuJoCo's
  contact dynamics amplify last-bit differences). On an AVX-512 CPU OpenBLAS picks its SkylakeX
  kernels, and the meshes and scenes change too (measured with tests/repro_scene.py).
  ``OPENBLAS_CORETYPE=Haswell`` pins the kernels on every x86-64 CPU with AVX2 and FMA (all current
  server CPUs), ``OPENBLAS_NUM_THREADS`` the threads;
* numpy dispatches some loops (sorting, transcendental functions) to AVX-512 code when the CPU has it:
  ``NPY_DISABLE_CPU_FEATURES`` keeps the AVX2 loops everywhere;
* PyTorch (SASA): ATen's vector kernels (``ATEN_CPU_CAPABILITY``), MKL (``MKL_CBWR``, conditional
  numerical reproducibility) and oneDNN (``ONEDNN_MAX_CPU_ISA``) are pinned to AVX2 as well;
* OpenMP and MKL threads (Open3D, PyTorch) are fixed (``OMP_NUM_THREADS``, ``MKL_NUM_THREADS``).

Not pinned: Embree (Open3D's ray caster, float32) selects SSE/AVX2/AVX-512 kernels itself and reads
no environment variable; machines with the same instruction sets cast identically, an AVX2 and an
AVX-512 machine may differ in the last bit of a range. Measured: an Intel Xeon with AVX-512 FP16
gave other scene soundings and template scans than the AMD EPYC (AVX-512) the checked-in digests
come from, with equal meshes and settled poses (tests/data/repro_digests_cpu_kinds.json). Thread counts of Embree's BVH build and of the
casts did not change a byte (one and two cores, measured).

The variables act when a process starts (the libraries read them once, when loaded): the workflow
sets them in its main process (``rules/common.smk``) before any job starts, so every job inherits
them; for a single command, ``eval "$(python -m sonardet.determinism)"`` exports them in the shell.
This module imports nothing but the standard library.
"""

from __future__ import annotations

import os
import platform
import sys

__all__ = ["ISA_PINNED", "THREAD_VARIABLES", "apply", "cpu_flags", "describe", "pinned_environment"]

#: Variables that fix the thread counts of the numerical libraries (value: the job's threads).
THREAD_VARIABLES = ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS")

#: Variables that fix the instruction-set paths on x86-64 CPUs with AVX2 and FMA.
ISA_PINNED = {
    "OPENBLAS_CORETYPE": "Haswell",
    "NPY_DISABLE_CPU_FEATURES": "X86_V4 AVX512_ICL AVX512_SPR",
    "ATEN_CPU_CAPABILITY": "avx2",
    "MKL_CBWR": "AVX2",
    "ONEDNN_MAX_CPU_ISA": "AVX2",
}


def cpu_flags() -> set[str]:
    """The CPU's feature flags (Linux ``/proc/cpuinfo``, e.g. 'avx2', 'fma', 'avx512f'); empty where
    they cannot be read."""
    try:
        with open("/proc/cpuinfo", encoding="utf-8", errors="replace") as fh:
            for line in fh:
                if line.startswith("flags"):
                    return set(line.split(":", 1)[1].split())
    except OSError:
        pass
    return set()


def pinned_environment(threads: int = 1) -> dict[str, str]:
    """Environment variables (name -> value) that fix the numerical libraries' thread counts to
    `threads` and, on an x86-64 CPU with AVX2 and FMA, their instruction-set paths to AVX2 (see the
    module doc). On other CPUs only the thread counts are fixed (forcing AVX2 kernels there would crash)."""
    env = {name: str(int(threads)) for name in THREAD_VARIABLES}
    if platform.machine().lower() in ("x86_64", "amd64") and {"avx2", "fma"} <= cpu_flags():
        env.update(ISA_PINNED)
    return env


def apply(environ=None, threads: int = 1) -> dict[str, str]:
    """Set the variables of `pinned_environment` in `environ` (default: ``os.environ``) where they are
    not set already (a value the user set wins); returns the variables now in effect. Libraries loaded
    before the call are not affected; processes started afterwards are."""
    environ = os.environ if environ is None else environ
    for name, value in pinned_environment(threads).items():
        environ.setdefault(name, value)
    return {name: environ[name] for name in (*THREAD_VARIABLES, *ISA_PINNED) if name in environ}


def describe(environ=None) -> str:
    """The variables of `pinned_environment` set in `environ` (default: ``os.environ``; a workflow job
    inherits the run's) as 'NAME=value, ...', or 'not pinned': for job logs and the report."""
    environ = os.environ if environ is None else environ
    return ", ".join(f"{k}={environ[k]}" for k in (*THREAD_VARIABLES, *ISA_PINNED) if k in environ) or "not pinned"


if __name__ == "__main__":  # `eval "$(python -m sonardet.determinism)"`: export the variables in a shell
    for name, value in pinned_environment(int(sys.argv[1]) if len(sys.argv) > 1 else 1).items():
        print(f"export {name}='{value}'")
