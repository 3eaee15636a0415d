"""The development split and the rule that the test split is read only by the final evaluation.

* `dev` scenes are generated in addition to the study's pool, disjoint from every training fraction
  and from `test`; adding them leaves the pool's split as it was (80 / 20);
* a real Snakemake dry run of the default workflow: no job other than a method's final detection and
  evaluation on a test set (and the report and dataset table, which only present them) reads a test
  scene.
"""

from __future__ import annotations

import re
import subprocess
import sys

import pytest

from conftest import REPO, copy_workflow
from sonardet.sim.dataset import make_splits, scene_ids

#: Jobs that may read test scenes: the final detection and evaluation (and comparison) of each method on a test set,
#: the report and the dataset table, which present them (they choose nothing), and the target rule
#: `all`, which runs nothing.
ALLOWED = re.compile(r"^(detect_(scenes|dataset)_(synthetic|realism|hybrid|mismatch)(_shared\d+)?|evaluate|compare|report"
                     r"|dataset_stats|all)$")


def test_dev_is_disjoint_and_leaves_the_pool_split_alone():
    sp = make_splits(scene_ids(110), 20, 10, [25, 50, 100], seed=3)
    assert len(sp["test"]) == 20 and len(sp["train"]) == 80 and len(sp["dev"]) == 10
    assert sp["dev"] == scene_ids(110)[100:]
    for name in ("train", "test", "train_25", "train_50", "train_100"):
        assert not set(sp["dev"]) & set(sp[name]), name
    old = make_splits(scene_ids(100) + ["x"], 20, 1, [25, 50, 100], seed=3)
    assert {k: v for k, v in old.items() if k != "dev"} == {k: v for k, v in sp.items() if k != "dev"}
    with pytest.raises(ValueError, match="split.n_test"):
        make_splits(scene_ids(6), 5, 1, [100], seed=3)


def _jobs(text: str) -> list[tuple[str, list[str]]]:
    """(rule, inputs) of every job a Snakemake dry run printed."""
    out, rule = [], None
    for line in text.splitlines():
        m = re.match(r"^(?:local)?(?:rule|checkpoint) (\S+):$", line.strip())
        if m:
            rule = m.group(1)
            continue
        m = re.match(r"^\s+input: (.*)$", line)
        if m and rule is not None:
            out.append((rule, [s.strip() for s in m.group(1).split(",")]))
            rule = None
    return out


@pytest.mark.slow
def test_only_the_final_evaluation_reads_test_scenes(tmp_path):
    copy_workflow(tmp_path)
    proc = subprocess.run([sys.executable, "-m", "snakemake", "-n", "--cores", "2"], cwd=tmp_path,
                          capture_output=True, text=True)
    assert proc.returncode == 0, proc.stderr[-3000:]
    sys.path.insert(0, str(tmp_path / "src"))
    from sonardet.config import read_config

    cfg = read_config(REPO / "config" / "config.yaml")
    ids = scene_ids(cfg["scenes"]["n_scenes"] + cfg["split"]["n_dev"])
    test = make_splits(ids, cfg["split"]["n_test"], cfg["split"]["n_dev"], cfg["split"]["fractions"],
                       cfg["seed"])["test"]
    test_files = {f"results/{d}/{s}.{e}" for d in ("scenes", "realism/scenes", "mismatch/scenes") for s in test
                  for e in ("npz", "json")}
    jobs = _jobs(proc.stdout + proc.stderr)
    rules = {r for r, _ in jobs}
    assert {"train_sasa_100", "ablation_point", "ablation_reference", "realism_ablation", "evaluate"} <= rules, rules
    bad = sorted({(r, f) for r, inputs in jobs for f in inputs if f in test_files and not ALLOWED.match(r)})
    assert not bad, f"jobs reading test scenes: {bad[:10]}"
    readers = {r for r, inputs in jobs if test_files & set(inputs)}
    # the check sees the test scenes being read at all (ours alone; paper with the ladder's step)
    assert {"detect_scenes_synthetic", "detect_scenes_synthetic_shared0", "evaluate"} <= readers
    # Every SASA model in one job per test set and on dev; a shared job runs only methods a target
    # reads: on the realism ablation's effect sets that is sasa_100 alone, so no shared job there.
    assert {"detect_dataset_synthetic_shared0", "detect_dataset_dev_shared0"} <= readers | rules
    assert "detect_dataset_realism_burial" in rules and "detect_dataset_realism_burial_shared0" not in rules
