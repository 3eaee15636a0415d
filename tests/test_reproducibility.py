"""A small scene made from scratch gives the checked-in digests (tests/data/repro_digests.json).

It runs in a fresh process with the pinned numerical environment of `sonardet.determinism` (as every
workflow job does), so the digests are those of any x86-64 machine with AVX2 running the same package
versions. A changed digest means the simulator, the meshes or a numerical library now behave
differently: if that was intended, regenerate the file with ``python tests/repro_scene.py --update``
and say in the commit which outputs changed.
"""

from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

import pytest

from sonardet.determinism import pinned_environment

ROOT = Path(__file__).resolve().parents[1]
SCRIPT = ROOT / "tests" / "repro_scene.py"
EXPECTED = ROOT / "tests" / "data" / "repro_digests.json"


def run_digests(extra_env: dict | None = None) -> dict:
    env = {**os.environ, **pinned_environment(1), **(extra_env or {})}
    res = subprocess.run([sys.executable, str(SCRIPT)], capture_output=True, text=True, env=env, cwd=ROOT,
                         timeout=900)
    assert res.returncode == 0, res.stderr[-3000:]
    return json.loads(res.stdout)


@pytest.mark.slow
def test_small_scene_matches_the_checked_in_digests():
    expected = json.loads(EXPECTED.read_text())
    got = run_digests()
    changed = {k: (expected.get(k), v) for k, v in got.items() if k != "bytes" and expected.get(k) != v}
    assert not changed, (
        "the simulation of the smoke scene changed (expected, now): "
        f"{json.dumps(changed, indent=1)}; if intended, run `python tests/repro_scene.py --update`")


def test_pinned_environment_fixes_threads_and_avx2_paths(monkeypatch):
    import sonardet.determinism as det

    monkeypatch.setattr(det, "cpu_flags", lambda: {"avx2", "fma", "avx512f"})
    monkeypatch.setattr(det.platform, "machine", lambda: "x86_64")
    env = det.pinned_environment(2)
    assert env["OPENBLAS_CORETYPE"] == "Haswell" and env["OMP_NUM_THREADS"] == "2"
    assert "X86_V4" in env["NPY_DISABLE_CPU_FEATURES"] and env["ATEN_CPU_CAPABILITY"] == "avx2"
    monkeypatch.setattr(det, "cpu_flags", lambda: {"sse4_2"})  # no AVX2: forcing it would crash
    assert "OPENBLAS_CORETYPE" not in det.pinned_environment(1)
    environ = {"OMP_NUM_THREADS": "4"}
    det.apply(environ)
    assert environ["OMP_NUM_THREADS"] == "4" and environ["OPENBLAS_NUM_THREADS"] == "1"  # the user's value wins
