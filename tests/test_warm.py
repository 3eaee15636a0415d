"""`python -m sonardet.warm` (run by scripts/setup.sh) fills Numba's cache so that later processes compile
nothing: on the network and input sizes of the warm-up and on others (the DEFAULTS network), for the SASA
training (with and without domain randomisation), its inference and the model-based detector.

Each step is its own process over an empty cache folder (NUMBA_CACHE_DIR), so the first one compiles
every kernel (about 90 s on the 2-core machine, its SASA and model-based parts in two processes)."""

from __future__ import annotations

import json
import os
import subprocess
import sys

from conftest import REPO

_AFTER_WARM = """
import json, tempfile
from pathlib import Path
from sonardet import warm
from sonardet.detect.sasa import train
from sonardet.jit import compile_stats
from sonardet.sim.boxes import write_box_scenes

with tempfile.TemporaryDirectory() as tmp:
    scenes = write_box_scenes(Path(tmp), 2, extent_m=20.0, points_per_m2=50.0, n_objects=8, first_seed=5)
    train(scenes, scenes[1:], {"epochs": 1, "batch_size": 2, "n_points": 2048, "num_threads": 1, "progress": False,
                               "val_every_epochs": 1}, Path(tmp) / "model", device="cpu", resume=False)
    train(scenes, scenes[1:], {"epochs": 1, "batch_size": 2, "n_points": 2048, "num_threads": 1, "progress": False,
                               "dr_enabled": True}, Path(tmp) / "model_dr", device="cpu", resume=False)
sasa = compile_stats()
warm.warm_model_based()
print(json.dumps({"sasa": sasa, "all": compile_stats()}))
"""


def _run(args, cache_dir) -> subprocess.CompletedProcess:
    env = {**os.environ, "NUMBA_CACHE_DIR": str(cache_dir), "PYTHONPATH": str(REPO / "src")}
    env.update(json.loads(subprocess.run([sys.executable, "-c", "import json; from sonardet.determinism import "
                                          "pinned_environment; print(json.dumps(pinned_environment()))"],
                                         capture_output=True, text=True, check=True, env=env).stdout))
    proc = subprocess.run([sys.executable, *args], capture_output=True, text=True, env=env, cwd=REPO)
    assert proc.returncode == 0, proc.stdout[-2000:] + proc.stderr[-2000:]
    return proc


def test_warm_up_compiles_every_kernel_later_processes_use(tmp_path):
    first = _run(["-m", "sonardet.warm"], tmp_path)
    n_first = int(first.stdout.split("sonardet.warm: ")[1].split()[0])
    assert n_first > 0, first.stdout
    # The first run compiled its two parts side by side (two processes on the 2-core machine); the second
    # runs them one after the other in one process and finds every kernel in the cache.
    second = _run(["-m", "sonardet.warm", "--jobs", "1"], tmp_path)
    assert "sonardet.warm: 0 Numba compilations" in second.stdout, second.stdout
    after = json.loads(_run(["-c", _AFTER_WARM], tmp_path).stdout.strip().splitlines()[-1])
    assert after["sasa"]["n"] == 0, f"the DEFAULTS network compiled kernels the warm-up did not: {after}"
    assert after["all"]["n"] == 0, after


def test_jobs_below_one_is_refused_before_any_work():
    proc = subprocess.run([sys.executable, "-m", "sonardet.warm", "--jobs", "0"], capture_output=True, text=True,
                          env={**os.environ, "PYTHONPATH": str(REPO / "src")}, cwd=REPO)
    assert proc.returncode == 2 and "--jobs 0: at least 1" in proc.stderr, proc.stderr
