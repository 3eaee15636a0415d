"""End-to-end: a real `snakemake --cores 2` run of the whole DAG on the tiny smoke config."""

import json
import shutil
import subprocess
import sys

import numpy as np
import pytest

from conftest import REPO
from sonardet.objects import load_object
from sonardet.sim.templates import load_templates

pytestmark = pytest.mark.slow


@pytest.fixture(scope="module")
def smoke_run(tmp_path_factory):
    work = tmp_path_factory.mktemp("smoke")
    for name in ("Snakefile", "rules", "workflow_scripts", "config", "profiles", "src", "environment.yml"):
        src = REPO / name
        if src.is_dir():
            shutil.copytree(src, work / name, symlinks=True, ignore=shutil.ignore_patterns("__pycache__"))
        else:
            shutil.copy(src, work / name)
    cmd = [sys.executable, "-m", "snakemake", "--cores", "2", "--configfile", "config_smoke.yaml"]
    shutil.copy(REPO / "tests" / "config" / "smoke.yaml", work / "config_smoke.yaml")
    proc = subprocess.run(cmd, cwd=work, capture_output=True, text=True)
    assert proc.returncode == 0, proc.stdout[-3000:] + proc.stderr[-3000:]
    return work


CLASSES = ["reef_ring", "reef_cone", "tetrapod_b", "tetrapod_s"]


def test_objects_well_formed(smoke_run):
    for cls in CLASSES:
        meta = json.loads((smoke_run / f"results/objects/{cls}.json").read_text())
        assert meta["watertight"] and meta["cls"] == cls
        info = load_object(smoke_run / f"results/objects/{cls}.json")
        assert info.mesh.is_watertight
        assert (smoke_run / f"results/logs/object_mesh/{cls}.log").exists()
        assert (smoke_run / f"results/benchmarks/object_mesh/{cls}.tsv").exists()


def test_templates_well_formed(smoke_run):
    for cls in CLASSES:
        tv = load_templates(smoke_run / f"results/templates/{cls}.npz")
        assert tv.cls == cls and len(tv.xyz) > 100 and np.isfinite(tv.xyz).all()
        assert tv.scan_params["sensor"]["n_beams"] == 128  # from the smoke config


def test_rerun_is_a_no_op_and_deterministic(smoke_run):
    before = (smoke_run / "results/templates/tetrapod_s.npz").read_bytes()
    proc = subprocess.run([sys.executable, "-m", "snakemake", "-n", "--configfile", "config_smoke.yaml"],
                          cwd=smoke_run, capture_output=True, text=True)
    assert proc.returncode == 0 and "Nothing to be done" in proc.stdout + proc.stderr
    tv = load_templates(smoke_run / "results/templates/tetrapod_s.npz")
    subprocess.run([sys.executable, "-m", "snakemake", "--cores", "1", "--configfile", "config_smoke.yaml",
                    "--forcerun", "template_scan", "results/templates/tetrapod_s.npz"],
                   cwd=smoke_run, capture_output=True, text=True, check=True)
    again = load_templates(smoke_run / "results/templates/tetrapod_s.npz")
    assert np.array_equal(tv.xyz, again.xyz)
    assert len(before) > 0
