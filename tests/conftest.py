"""Shared fixtures."""

from __future__ import annotations

import json
import os
import shutil
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from sonardet.config import validate_config

REPO = Path(__file__).resolve().parents[1]


def _real_data_dir() -> Path | None:
    """Folder of the real R2Sonic survey line: $SONARDET_REAL_DATA, or ../shared/data/real beside the
    repository. In CI the data must be there (a silent skip would hide a broken checkout)."""
    for folder in (os.environ.get("SONARDET_REAL_DATA", ""), str(REPO.parent / "shared" / "data" / "real")):
        if folder and (Path(folder) / "r2sonic_sfbay.xyz.gz").is_file():
            return Path(folder)
    if os.environ.get("CI", "").lower() == "true":
        raise RuntimeError("CI: the real survey data ../shared/data/real/r2sonic_sfbay.xyz.gz is missing")
    return None


#: The real-data folder, or None when it is not available (tests using it are skipped locally).
REAL_DIR = _real_data_dir()
REAL_FILE = REAL_DIR / "r2sonic_sfbay.xyz.gz" if REAL_DIR else None
needs_real = pytest.mark.skipif(REAL_DIR is None, reason="real survey data not available")


@pytest.fixture(scope="session")
def default_config() -> dict:
    """The default config with every schema default filled in."""
    from sonardet.config import read_config

    return read_config(REPO / "config" / "config.yaml")


@pytest.fixture(scope="session")
def smoke_config() -> dict:
    from sonardet.config import read_config

    return read_config(REPO / "tests" / "config" / "smoke.yaml")


@pytest.fixture(scope="session")
def built_objects(default_config):
    """The four default class models (built once per session)."""
    from sonardet.objects import build_object

    return {c: build_object(c, default_config["objects"]) for c in default_config["classes"]}


@pytest.fixture
def one_torch_thread():
    """Tiny models issue many small ops: one thread is fastest and immune to a busy machine."""
    import torch

    old = torch.get_num_threads()
    torch.set_num_threads(1)
    yield
    torch.set_num_threads(old)


def copy_workflow(work: Path) -> Path:
    """Copy what a Snakemake run needs (Snakefile, rules, scripts, config, profiles, library, the test
    plugins) into `work`.

    The `__pycache__` folders come along: Python's bytecode and Numba's compiled kernels (which
    `scripts/setup.sh` compiles into them, `sonardet.warm`) are checked against their source file's
    modification time and size, which the copy keeps, so the run's jobs load the kernels as a workflow
    run after the setup does, instead of compiling them again (minutes of a test run)."""
    for name in ("Snakefile", "rules", "workflow_scripts", "config", "profiles", "src", "environment.yml",
                 "tests/plugins"):
        src = REPO / name
        if src.is_dir():
            shutil.copytree(src, work / name, symlinks=True, dirs_exist_ok=True)
        else:
            shutil.copy(src, work / name)
    return work


def smoke_config_file(work: Path) -> Path:
    """tests/config/smoke.yaml copied into `work` as config_smoke.yaml, with the real survey line for the
    noise characterisation and the hybrid test set when the real data is there."""
    path = work / "config_smoke.yaml"
    shutil.copy(REPO / "tests" / "config" / "smoke.yaml", path)
    if REAL_FILE is not None:
        soundings = REAL_FILE.parent / "r2sonic_sfbay_soundings.csv.gz"
        with open(path, "a") as fh:
            fh.write(f"noise: {{survey: {json.dumps(str(REAL_FILE))}}}\n")
            fh.write(f"hybrid_test: {{n_scenes: 1, soundings: {json.dumps(str(soundings))}}}\n")
    return path


@pytest.fixture(scope="session")
def smoke_run(tmp_path_factory) -> Path:
    """A real `snakemake --cores 2` run of the whole DAG on the smoke config (once per session: the
    workflow tests, the report in a browser and the SLURM comparison read it)."""
    work = tmp_path_factory.mktemp("smoke")
    copy_workflow(work)
    smoke_config_file(work)
    cmd = [sys.executable, "-m", "snakemake", "--cores", "2", "--configfile", "config_smoke.yaml"]
    proc = subprocess.run(cmd, cwd=work, capture_output=True, text=True)
    (work / "snakemake_output.txt").write_text(proc.stdout + proc.stderr)
    assert proc.returncode == 0, proc.stdout[-3000:] + proc.stderr[-3000:]
    return work


def match_by_centre(a: list, b: list) -> list[tuple[dict, dict, float]]:
    """Greedy one-to-one matching of detections by box-centre distance (m), closest pairs first."""
    pairs = sorted((float(np.linalg.norm(np.subtract(x["box"][:3], y["box"][:3]))), i, j)
                   for i, x in enumerate(a) for j, y in enumerate(b))
    used_a, used_b, out = set(), set(), []
    for d, i, j in pairs:
        if i not in used_a and j not in used_b:
            used_a.add(i)
            used_b.add(j)
            out.append((a[i], b[j], d))
    return out


__all__ = ["REAL_DIR", "REAL_FILE", "REPO", "copy_workflow", "match_by_centre", "needs_real", "smoke_config_file",
           "validate_config"]
