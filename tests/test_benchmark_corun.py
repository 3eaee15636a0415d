"""benchmarks/corun.sh: without a run's results it stops at once and says what to run."""

import subprocess
from pathlib import Path

REPO = Path(__file__).resolve().parent.parent


def test_corun_without_results_names_the_workflow(tmp_path):
    proc = subprocess.run(["bash", str(REPO / "benchmarks" / "corun.sh")], cwd=tmp_path, capture_output=True,
                          text=True, timeout=60)
    assert proc.returncode == 2
    assert "results/scenes" in proc.stderr and "snakemake --cores 2" in proc.stderr


def test_corun_is_valid_bash():
    assert subprocess.run(["bash", "-n", str(REPO / "benchmarks" / "corun.sh")]).returncode == 0
