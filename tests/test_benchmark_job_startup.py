"""The job start-up benchmark (benchmarks/job_startup.py): every rule of the workflow maps to the
script it runs, the imports it times are the script's own, and a timing run gives positive seconds."""

import re
import sys
from pathlib import Path

REPO = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(REPO / "benchmarks"))

from job_startup import main, script_imports, script_of_rule  # noqa: E402


def test_every_rule_maps_to_the_script_it_runs():
    """Read the rules' names and scripts from rules/*.smk (loop-made rules by their name pattern) and
    check the benchmark's mapping against them."""
    checked = 0
    for smk in (REPO / "rules").glob("*.smk"):
        text = smk.read_text()
        for block in re.split(r"\n(?=\S)|\n(?=    rule:)", text):
            name = re.search(r"^(?:rule|checkpoint) (\w+):|name:\s+f\"(\w+)\{", block, re.M)
            script = re.search(r"workflow_scripts/(\w+)\.py", block)
            if not (name and script):
                continue
            rule = name.group(1) or name.group(2) + "x"  # a loop-made rule: its prefix and any suffix
            assert script_of_rule(rule) == script.group(1), (smk.name, rule)
            checked += 1
    assert checked >= 20  # every rule of the workflow (23 when written)


def test_imports_are_the_scripts_own_plus_the_detector():
    lines = script_imports("detect_scenes")
    assert "from common import job, job_resources" in lines
    assert lines[-1] == "from sonardet.detect.model_based import ModelBasedDetector"
    assert not any(line.startswith("from sonardet.detect") for line in script_imports("evaluate"))


def test_timing_run(tmp_path):
    out = main(["--repeat", "1", "--scripts", "evaluate", "--json", str(tmp_path / "t.json")])
    row = out["per_script"]["evaluate"]
    assert row["wall_s"] > 0 and row["cpu_s"] > 0
    assert (tmp_path / "t.json").read_text().count("evaluate") == 1


def test_exit_timing_run():
    """--exit times the interpreter's end after a script's imports, default and with frozen objects:
    both positive and short (a script of light imports)."""
    row = main(["--repeat", "1", "--scripts", "evaluate", "--exit"])["per_script"]["evaluate"]
    assert 0 < row["exit_s"] < 5 and 0 < row["exit_frozen_s"] < 5
