"""The cluster profiles (profiles/slurm, profiles/slurm-gpu) and what every rule tells a cluster executor.

Cheap checks (dry runs); the real SLURM run is tests/test_slurm.py (`make slurm-test`)."""

import os
import re
import subprocess
import sys
from pathlib import Path

import pytest
import yaml

from conftest import REPO, copy_workflow

PROFILES = ("slurm", "slurm-gpu")
#: The study preset's training: seconds per epoch over 80 scenes on 2 CPU threads (benchmarks/sasa.py,
#: README "Speed", docs/speed_log.md); a GPU is faster, so a runtime covering this covers a GPU.
STUDY_EPOCH_S_CPU = 165


def _profile(name: str) -> dict:
    return yaml.safe_load((REPO / "profiles" / name / "config.yaml").read_text())


def _rule_blocks() -> dict[str, str]:
    """Every rule and checkpoint of rules/*.smk: name -> its text (rules made in a loop by their
    `name:` f-string)."""
    blocks = {}
    for smk in sorted((REPO / "rules").glob("*.smk")):
        text = smk.read_text()
        assert not re.search(r"^\s*use rule", text, re.M), f"{smk.name}: `use rule` copies rules; declare them"
        heads = list(re.finditer(r"^(\s*)(rule|checkpoint)\s*(\w*)\s*:\s*$", text, re.M))
        for i, m in enumerate(heads):
            body = text[m.end(): heads[i + 1].start() if i + 1 < len(heads) else len(text)]
            name = m.group(3) or re.search(r"name:\s*\n\s*f?\"([^\"]+)\"", body).group(1)
            blocks[f"{smk.name}:{name}"] = body
    return blocks


def test_every_rule_declares_threads_memory_and_runtime():
    """Cluster executors size a job from its rule: threads (-> --cpus-per-task), resources.mem_mb
    (-> --mem) and resources.runtime (-> --time) on every rule, from the config (the methods' threads,
    workflow.mem_mb and workflow.runtime_min of the rule's group)."""
    blocks = _rule_blocks()
    assert any("detect_dataset_" in k for k in blocks)  # the per-dataset rules made in a loop
    for name, body in blocks.items():
        assert re.search(r"^\s*threads:", body, re.M), f"{name}: no threads"
        resources = re.search(r"^\s*resources:\s*\n((?:\s+\w+=.*\n)+)", body, re.M)
        assert resources, f"{name}: no resources"
        mem = re.search(r"mem_mb=MEM_MB\[\"(\w+)\"\]", resources.group(1))
        runtime = re.search(r"runtime=RUNTIME_MIN\[\"(\w+)\"\]", resources.group(1))
        assert mem and runtime and mem.group(1) == runtime.group(1), \
            f"{name}: resources.mem_mb and .runtime not from the config's workflow section (same group)"


def test_profiles_are_complete_workflow_profiles():
    """Each SLURM profile is meant for --workflow-profile, so it replaces profiles/default: it must set
    what the default sets. No account placeholder (sbatch rejects an unknown account), no paths, no
    default-resources (a user's account and partition there would be replaced as a whole)."""
    default = _profile("default")
    # rule names; those made in a loop from f-strings ("train_{_method}") as patterns
    rules = [re.compile(re.sub(r"\\\{[^}]*\\\}", r"\\w+", re.escape(k.split(":")[1])) + "$") for k in _rule_blocks()]
    for name in PROFILES:
        p = _profile(name)
        text = (REPO / "profiles" / name / "config.yaml").read_text()
        assert p["executor"] == "slurm" and p["latency-wait"] >= 60 and p["jobs"] >= 1
        assert set(default) - {"cores", "latency-wait"} <= set(p), name
        assert "default-resources" not in p and "slurm_account" not in yaml.safe_dump(p) and "your_" not in text
        assert not re.search(r"(^|\s)/\w", yaml.safe_dump(p)), f"{name}: a machine path"
        for rule in p.get("set-resources", {}):
            assert any(r.match(rule) for r in rules), f"{name}: set-resources names an unknown rule {rule}"
        assert "--workflow-profile profiles/" + name in text
    gpu, cpu = _profile("slurm-gpu"), _profile("slurm")
    trainings = gpu.pop("set-resources")
    assert trainings and all(r.startswith("train_") and v == {"gpu": 1} for r, v in trainings.items())
    assert "set-resources" not in cpu and gpu == cpu


def _dry_run(work: Path, profile: str, configfile: str) -> dict[str, list[dict]]:
    """rule -> the resources of each of its jobs, from a dry run with the profile."""
    proc = subprocess.run([sys.executable, "-m", "snakemake", "-n", "--workflow-profile", f"profiles/{profile}",
                           "--configfile", configfile], cwd=work, capture_output=True, text=True)
    assert proc.returncode == 0, proc.stdout[-3000:] + proc.stderr[-3000:]
    jobs: dict[str, list[dict]] = {}
    for block in re.split(r"\n(?=(?:local)?(?:rule|checkpoint) \w+:\n)", proc.stdout + proc.stderr):
        head = re.match(r"(?:local)?(?:rule|checkpoint) (\w+):\n", block)
        res = re.search(r"^\s+resources: (.*)$", block, re.M)
        if head and res:
            jobs.setdefault(head.group(1), []).append(dict(kv.split("=", 1) for kv in res.group(1).split(", ")))
    return jobs


@pytest.fixture(scope="module")
def workflow_copy(tmp_path_factory) -> Path:
    try:
        import snakemake_executor_plugin_slurm  # noqa: F401  (the profiles' executor)
    except ImportError:
        if os.environ.get("CI", "").lower() == "true":
            raise
        pytest.skip('the SLURM executor plugin is not installed (pip install -e ".[cluster]")')
    work = copy_workflow(tmp_path_factory.mktemp("profiles"))
    (work / "tests" / "config").mkdir(parents=True)
    (work / "tests" / "config" / "smoke.yaml").write_text((REPO / "tests" / "config" / "smoke.yaml").read_text())
    return work


def test_slurm_profile_sizes_every_job(workflow_copy):
    from sonardet.config import read_config

    scheduling = read_config(REPO / "tests" / "config" / "smoke.yaml")["workflow"]
    jobs = _dry_run(workflow_copy, "slurm", "tests/config/smoke.yaml")
    train = [r for rule, rs in jobs.items() if rule.startswith("train_") for r in rs]
    assert len(train) >= 4 and "ablation_point" in jobs
    assert any(r.startswith("detect_dataset_synthetic") for r in jobs)  # every SASA model in one job, or one each
    for rule, resources in jobs.items():
        if rule == "all":  # the target: no job of its own
            continue
        for r in resources:
            assert int(r["mem_mb"]) in scheduling["mem_mb"].values(), (rule, r)
            assert int(r["runtime"]) in scheduling["runtime_min"].values() and "gpu" not in r, (rule, r)
    assert {(r["mem_mb"], r["runtime"]) for r in train} == {
        (str(scheduling["mem_mb"]["train"]), str(scheduling["runtime_min"]["train"]))}


def test_gpu_profile_covers_the_study_training(workflow_copy):
    """config/paper.yaml on profiles/slurm-gpu: every training job asks for a GPU, for the study
    training's memory, and for a runtime covering its epochs even at CPU speed."""
    from sonardet.config import read_config
    from sonardet.detect.sasa.config import STUDY

    paper = read_config(REPO / "config" / "paper.yaml")
    assert paper["sasa"]["preset"] == "study"
    jobs = _dry_run(workflow_copy, "slurm-gpu", "config/paper.yaml")
    trainings = sorted(rule for rule in jobs if rule.startswith("train_"))
    # the profile names exactly the study's training rules (one per trained method)
    assert trainings == sorted(_profile("slurm-gpu")["set-resources"]) and len(trainings) >= 3
    for r in (r for rule in trainings for r in jobs[rule]):
        assert r["gpu"] == "1", r
        assert int(r["runtime"]) == paper["workflow"]["runtime_min"]["train"], r
        assert int(r["runtime"]) * 60 >= 1.5 * STUDY["epochs"] * STUDY_EPOCH_S_CPU, r
        assert int(r["mem_mb"]) == paper["workflow"]["mem_mb"]["train"] >= 6600, r  # 6.6 GB measured peak
    for rule, resources in jobs.items():
        if rule not in trainings:
            assert all("gpu" not in r for r in resources), rule
