"""The package's Numba set-up (sonardet.jit): its compilation clock, which the workflow's jobs record
(sonardet.usage) and `sonardet detect` prints."""

import json
import os
import subprocess
import sys
import textwrap
from types import SimpleNamespace

from sonardet.jit import compile_stats, numba
from sonardet.usage import job_usage, numba_compilations, usage_path
from sonardet.workflow import rule_logging


def test_the_clock_counts_each_compilation_once_with_the_kernels_it_calls():
    @numba.njit
    def inner(x):
        return x + 1

    @numba.njit
    def outer(x):
        return 2 * inner(x)

    before = compile_stats()
    assert outer(1) == 4
    first = compile_stats()
    assert first["n"] == before["n"] + 1  # inner compiled inside outer's compilation: not counted again
    assert first["s"] > before["s"]
    assert outer(5) == 12 and compile_stats() == first  # compiled once per argument types
    assert outer(1.5) == 5.0 and compile_stats()["n"] == first["n"] + 1
    assert numba_compilations() == compile_stats()


def test_loads_from_the_disk_cache_are_not_compilations(tmp_path):
    (tmp_path / "cached_kernel.py").write_text(textwrap.dedent("""
        from sonardet.jit import compile_stats, numba

        @numba.njit(cache=True)
        def twice(x):
            return 2.0 * x

        twice(1.0)
        print(compile_stats()["n"])
        """))
    env = {**os.environ, "NUMBA_CACHE_DIR": str(tmp_path / "cache"), "PYTHONPATH": str(tmp_path)}

    def run():
        out = subprocess.run([sys.executable, "-c", "import cached_kernel"], env=env, capture_output=True, text=True,
                             check=True)
        return int(out.stdout.split()[-1])

    assert run() == 1  # compiled, then written to the cache
    assert run() == 0  # loaded from it


def test_a_job_records_and_logs_its_compilations(tmp_path):
    log = tmp_path / "logs" / "rule" / "a.log"
    log.parent.mkdir(parents=True)
    with rule_logging(SimpleNamespace(log=[str(log)], threads=1), "rule"):
        n0 = compile_stats()["n"]

        @numba.njit
        def square(x):
            return x * x

        assert square(3) == 9
    rec = json.loads(usage_path(log).read_text())
    assert rec["jit_n"] == n0 + 1 and rec["jit_s"] > 0  # the process's compilations so far
    assert "Numba compilations took" in log.read_text()
    assert "jit_s" not in job_usage(1) and job_usage(1, jit={"n": 2, "s": 1.5})["jit_s"] == 1.5
