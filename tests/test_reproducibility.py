"""A small scene made from scratch gives the checked-in digests (tests/data/repro_digests.json).

It runs in a fresh process with the pinned numerical environment of `sonardet.determinism` (as every
workflow job does), so the digests are those of any x86-64 machine with AVX2 running the same package
versions, where the ray caster picks the same code path (on some CPUs its last bits differ:
`tests/data/repro_digests_cpu_kinds.json` records, per kind of CPU measured, the digests that differ
there, and the test accepts a kind's digests only all together). A changed digest means the simulator, the meshes or a numerical library now behave
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
sys.path.insert(0, str(SCRIPT.parent))

from repro_scene import EXPECTED, KINDS, differing, matching_kind  # noqa: E402


def run_digests(extra_env: dict | None = None) -> dict:
    env = {**os.environ, **pinned_environment(1), **(extra_env or {})}
    res = subprocess.run([sys.executable, str(SCRIPT)], capture_output=True, text=True, env=env, cwd=ROOT,
                         timeout=900)
    assert res.returncode == 0, res.stderr[-3000:]
    return json.loads(res.stdout)


@pytest.mark.slow
def test_small_scene_matches_the_checked_in_digests():
    expected = json.loads(EXPECTED.read_text())
    kinds = json.loads(KINDS.read_text()) if KINDS.exists() else {}
    got = run_digests()
    if matching_kind(expected, kinds, got) is not None:
        return
    changed = {k: (expected.get(k), got[k]) for k in sorted(differing(expected, got))}
    raise AssertionError(
        "the simulation of the smoke scene changed (reference digests, now; no recorded CPU kind of "
        f"{KINDS.name} explains it): {json.dumps(changed, indent=1)}; if intended, run "
        "`python tests/repro_scene.py --update` on the reference kind of machine and "
        "`--record-kind NAME` on each other kind")


def test_a_cpu_kind_explains_a_difference_only_as_a_whole():
    expected = {"mesh/a": "1", "scene/s": "2", "templates/t": "3"}
    kinds = {"kinds": {"other": {"cpu": "x", "digests": {"scene/s": "9", "templates/t": "8"}}}}
    assert matching_kind(expected, kinds, dict(expected)) == "reference"
    assert matching_kind(expected, kinds, {**expected, "scene/s": "9", "templates/t": "8"}) == "other"
    assert matching_kind(expected, kinds, {**expected, "scene/s": "9"}) is None  # half a kind
    assert matching_kind(expected, kinds, {**expected, "scene/s": "9", "templates/t": "8", "mesh/a": "7"}) is None
    assert matching_kind(expected, kinds, {**expected, "scene/s": "5"}) is None  # a new difference


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
