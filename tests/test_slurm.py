"""The smoke workflow on a real one-node SLURM cluster (tests/local_slurm.py) through the cluster profile:
`snakemake --executor slurm` via `--workflow-profile profiles/slurm`, every job in `sacct` with the
threads, memory and runtime its rule and the profile ask for, and the results equal to the local run's.
One training job is run again through profiles/slurm-gpu: SLURM gives it the node's GPU resource.

Not part of `make test` (the smoke workflow a second time, through a scheduler): `make slurm-test`
installs the SLURM packages and runs this module (marker `slurm`)."""

import json
import os
import re
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest

from conftest import copy_workflow
from local_slurm import LocalSlurm, missing_binaries

pytestmark = [pytest.mark.slow, pytest.mark.slurm]

#: The plugin's first status check comes this many seconds after a submission (default 40).
STATUS_CHECK_S = "5"
SACCT_FIELDS = ("JobID", "JobName", "State", "ExitCode", "AllocCPUS", "ReqMem", "TimelimitRaw", "AllocTRES",
                "Comment", "Elapsed")


def _snakemake(work: Path, env: dict, *args: str) -> tuple[subprocess.CompletedProcess, float]:
    t0 = time.monotonic()
    proc = subprocess.run([sys.executable, "-m", "snakemake", "--configfile", "config_smoke.yaml",
                           "--slurm-init-seconds-before-status-checks", STATUS_CHECK_S, *args],
                          cwd=work, env=env, capture_output=True, text=True)
    assert proc.returncode == 0, proc.stdout[-3000:] + proc.stderr[-5000:]
    return proc, time.monotonic() - t0


def submitted_jobs(log: str) -> dict[str, dict]:
    """SLURM job id -> rule, threads and resources of the Snakemake job it ran, from Snakemake's log."""
    jobs = {}
    for block in re.split(r"\n(?=\[[^\]]+\]\n(?:local)?rule )", log):
        m = re.search(r"^(?:local)?rule (\w+):\n(.*?)(?:\n\S|\Z)", block, re.M | re.S)
        if not m:
            continue
        body = m.group(2)
        jobid = re.search(r"^\s+jobid: (\d+)", body, re.M)
        res = re.search(r"^\s+resources: (.*)$", body, re.M)
        threads = re.search(r"^\s+threads: (\d+)", body, re.M)
        if jobid and res:
            jobs[jobid.group(1)] = {"rule": m.group(1), "threads": int(threads.group(1)) if threads else 1,
                                    "resources": dict(kv.split("=", 1) for kv in res.group(1).split(", "))}
    out = {}
    for sm, slurm in re.findall(r"Job (\d+) has been submitted with SLURM jobid (\d+)", log):
        out[slurm] = jobs[sm]
    return out


@pytest.fixture(scope="module")
def slurm_run(smoke_run, tmp_path_factory):
    missing = missing_binaries()
    if missing or os.geteuid() != 0:
        msg = (f"SLURM is not installed (missing {', '.join(missing)}): make slurm-test installs it" if missing
               else "the test cluster needs root (slurmd runs jobs as their user)")
        if os.environ.get("CI", "").lower() == "true":
            raise RuntimeError(msg)
        pytest.skip(msg)
    root = tmp_path_factory.mktemp("slurm")
    (root / "work").mkdir()
    work = copy_workflow(root / "work")
    (work / "config_smoke.yaml").write_text((smoke_run / "config_smoke.yaml").read_text())
    t0 = time.monotonic()
    with LocalSlurm(root / "cluster") as cluster:
        t_up = time.monotonic() - t0
        run, t_run = _snakemake(work, cluster.env, "--workflow-profile", "profiles/slurm")
        # One training again through the GPU profile (the node has one generic GPU; torch finds no CUDA
        # device here and trains on the CPU, as the first time).
        gpu, t_gpu = _snakemake(work, cluster.env, "--workflow-profile", "profiles/slurm-gpu",
                                "--force", "results/models/sasa_25/model.pt")
        sacct = {r["JobID"]: r for r in cluster.sacct(*SACCT_FIELDS)}
    timing = {"cluster_start_s": round(t_up, 1), "workflow_s": round(t_run, 1), "gpu_job_s": round(t_gpu, 1),
              "total_s": round(time.monotonic() - t0, 1), "jobs": len(sacct)}
    print(f"\nSLURM run: {json.dumps(timing)}")
    (root / "timing.json").write_text(json.dumps(timing, indent=1))
    (root / "snakemake.log").write_text(run.stdout + run.stderr)
    (root / "snakemake_gpu.log").write_text(gpu.stdout + gpu.stderr)
    (root / "sacct.json").write_text(json.dumps(sacct, indent=1))
    return {"work": work, "log": run.stdout + run.stderr, "gpu_log": gpu.stdout + gpu.stderr, "sacct": sacct,
            "timing": timing}


def test_every_job_ran_through_slurm_with_its_resources(slurm_run):
    jobs = submitted_jobs(slurm_run["log"])
    total = int(re.findall(r"(\d+) of (\d+) steps \(100%\) done", slurm_run["log"])[-1][1])
    assert len(jobs) == total - 1  # every job but the target rule `all`, which runs in Snakemake itself
    rules = {j["rule"] for j in jobs.values()}
    assert {"object_mesh", "detect_scenes_synthetic", "report"} <= rules
    assert all(any(r.startswith(p) for r in rules) for p in ("simulate_scene_", "detect_dataset_", "train_"))
    sacct = slurm_run["sacct"]
    for slurm_id, job in jobs.items():
        row = sacct[slurm_id]
        assert row["State"] == "COMPLETED" and row["ExitCode"] == "0:0", row
        assert int(row["AllocCPUS"]) == job["threads"], (job, row)
        assert row["ReqMem"] == f"{job['resources']['mem_mb']}M", (job, row)
        assert row["TimelimitRaw"] == job["resources"]["runtime"], (job, row)
        assert row["Comment"].startswith(f"rule_{job['rule']}"), (job, row)
        assert "gres/gpu" not in row["AllocTRES"], row
    assert {j["resources"]["runtime"] for j in jobs.values() if j["rule"].startswith("train_")} == {"120"}


def test_gpu_profile_gives_training_a_gpu(slurm_run):
    jobs = submitted_jobs(slurm_run["gpu_log"])
    assert [j["rule"] for j in jobs.values()] == ["train_sasa_25"]
    (slurm_id, job), = jobs.items()
    row = slurm_run["sacct"][slurm_id]
    assert row["State"] == "COMPLETED" and "gres/gpu=1" in row["AllocTRES"], row
    assert job["resources"]["gpu"] == "1" and row["TimelimitRaw"] == job["resources"]["runtime"]


def _files(root: Path, patterns: tuple[str, ...]) -> list[str]:
    return sorted(str(p.relative_to(root)) for pat in patterns for p in root.glob(pat))


#: Files whose bytes must match: objects, templates, splits, the soundings of every scene of every
#: dataset, every detection.
SAME_BYTES = ("results/objects/*", "results/templates/*.npz", "results/splits/*.txt", "results/scenes/*.npz",
              "results/realism/scenes/*.npz", "results/hybrid/scenes/*.npz", "results/realism_ablation/*/scenes/*.npz",
              "results/detections/**/*.json")
#: Scene descriptions: equal but for the seconds each stage took (`timings_s`).
SCENE_JSON = ("results/scenes/*.json", "results/realism/scenes/*.json", "results/hybrid/scenes/*.json",
              "results/realism_ablation/*/scenes/*.json")
METRICS = ("results/eval/**/metrics.json", "results/eval/compare/*.json")


def _without_timings(doc):
    if isinstance(doc, dict):
        return {k: _without_timings(v) for k, v in doc.items() if k != "timings_s"}
    if isinstance(doc, list):
        return [_without_timings(v) for v in doc]
    return doc


def test_results_equal_the_local_run(slurm_run, smoke_run):
    import torch

    work = slurm_run["work"]
    files = _files(smoke_run, SAME_BYTES)
    assert any(f.startswith("results/scenes/") for f in files) and any("/detections/" in f for f in files)
    assert _files(work, SAME_BYTES) == files
    differ = [f for f in files if (work / f).read_bytes() != (smoke_run / f).read_bytes()]
    assert not differ, differ
    scenes = _files(smoke_run, SCENE_JSON)
    assert _files(work, SCENE_JSON) == scenes
    for f in scenes:
        a, b = (_without_timings(json.loads((root / f).read_text())) for root in (work, smoke_run))
        assert a == b, f
    # Evaluation metrics of every method on every dataset, the comparisons and the PR curves.
    metrics = _files(smoke_run, METRICS)
    assert len(metrics) > 30 and _files(work, METRICS) == metrics
    for f in metrics:
        assert json.loads((work / f).read_text()) == json.loads((smoke_run / f).read_text()), f
    for f in _files(smoke_run, ("results/eval/**/pr_curves.npz",)):
        a, b = np.load(work / f), np.load(smoke_run / f)
        assert sorted(a.files) == sorted(b.files) and all(np.array_equal(a[k], b[k]) for k in a.files), f
    # Trained models: the same weights (sasa_25 retrained through the GPU profile too) and the same
    # losses epoch by epoch (the seconds per epoch differ).
    models = _files(smoke_run, ("results/models/*/model.pt",))
    assert len(models) >= 4
    for f in models:
        a, b = (torch.load(root / f, map_location="cpu", weights_only=False)["state_dict"] for root in (work, smoke_run))
        assert a.keys() == b.keys() and all(torch.equal(a[k], b[k]) for k in a), f
    for f in _files(smoke_run, ("results/models/*/loss.csv",)):
        a, b = ((root / f).read_text().splitlines() for root in (work, smoke_run))
        drop = a[0].split(",").index("epoch_s")
        strip = [[",".join(c for i, c in enumerate(line.split(",")) if i != drop) for line in x] for x in (a, b)]
        assert strip[0] == strip[1], f
