"""Start-up cost of the workflow's jobs: the seconds a job spends importing before it does its work.

Snakemake runs every job's script in a new Python process, so each of a run's jobs pays for its
imports again. For each workflow script this times, in fresh interpreters (``--repeat`` times, after
one untimed run that warms the disk cache), the import of what a job of that rule loads before its
work: the script's own top-level imports (read from the file) and, for the rules that run a method,
the detector module its family loads (``EXTRA``). It prints the mean wall and CPU seconds per script;
with ``--dag`` it also counts the jobs of each rule in the configured workflow's whole DAG
(``snakemake -n --forceall``, run from the repository root) and gives the start-up CPU of a full run.

With ``--exit`` it also times how long each interpreter takes to end after those imports, as it ends
by default and with the objects frozen first (``gc.freeze()``, what a job's own script process does
at its end: ``sonardet.workflow.rule_logging``): the interpreter's last garbage collection walks every
object the imports made. A job's exit also has the objects of its work, so these are the part the
imports alone account for.

Usage: ``python benchmarks/job_startup.py [--repeat 5] [--scripts detect_scenes,evaluate] [--exit]
[--dag [--configfile c.yaml]] [--json out.json]``. Seconds depend on the machine and its load.
"""

from __future__ import annotations

import argparse
import ast
import json
import re
import resource
import subprocess
import sys
import time
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]
SCRIPTS = REPO / "workflow_scripts"

#: What a job of these scripts imports lazily before its work: the detector of its method family.
EXTRA = {
    "detect_scenes": ["from sonardet.detect.model_based import ModelBasedDetector"],
    "ablation_point": ["from sonardet.detect.model_based import ModelBasedDetector"],
    "detect_survey_tile": ["from sonardet.detect.model_based import ModelBasedDetector"],
    "detect_dataset": ["from sonardet.detect.sasa import TrainedSASA"],
    "train": ["from sonardet.detect.sasa import train"],
}

#: Which script each rule runs, for rules not named after their script (rules/*.smk).
RULE_SCRIPT = [(r"^simulate_scenes_hybrid$", "simulate_hybrid_scene"), (r"^simulate_scenes?_", "simulate_scene"),
               (r"^detect_dataset_", "detect_dataset"), (r"^detect_scenes_", "detect_scenes"),
               (r"^train_", "train")]


def script_imports(name: str) -> list[str]:
    """The top-level import statements of workflow_scripts/{name}.py, as source lines, plus EXTRA."""
    tree = ast.parse((SCRIPTS / f"{name}.py").read_text())
    lines = [ast.unparse(node) for node in tree.body if isinstance(node, (ast.Import, ast.ImportFrom))]
    return lines + EXTRA.get(name, [])


def time_imports(lines: list[str]) -> tuple[float, float]:
    """Wall and CPU seconds (user + system) of a fresh interpreter running the import lines."""
    code = f"import sys; sys.path.insert(0, {str(SCRIPTS)!r}); sys.path.insert(0, {str(REPO / 'src')!r})\n"
    code += "\n".join(lines)
    before = resource.getrusage(resource.RUSAGE_CHILDREN)
    t0 = time.perf_counter()
    subprocess.run([sys.executable, "-c", code], check=True, cwd=REPO)
    wall = time.perf_counter() - t0
    after = resource.getrusage(resource.RUSAGE_CHILDREN)
    return wall, (after.ru_utime - before.ru_utime) + (after.ru_stime - before.ru_stime)


def time_exit(lines: list[str], freeze: bool) -> float:
    """Wall seconds a fresh interpreter takes to end once the import lines ran (from its last
    statement to its end as seen by this process), with the objects frozen first or not."""
    code = f"import sys; sys.path.insert(0, {str(SCRIPTS)!r}); sys.path.insert(0, {str(REPO / 'src')!r})\n"
    code += "\n".join(lines) + "\nimport gc, time\n" + ("gc.freeze()\n" if freeze else "")
    code += "sys.stdout.write(repr(time.time()) + '\\n'); sys.stdout.flush()\n"
    out = subprocess.run([sys.executable, "-c", code], check=True, cwd=REPO, capture_output=True, text=True)
    end = time.time()
    return end - float(out.stdout.strip().splitlines()[-1])


def script_of_rule(rule: str) -> str | None:
    """The workflow script a rule runs (the rule's own name where a script has it)."""
    if (SCRIPTS / f"{rule}.py").is_file():
        return rule
    for pattern, script in RULE_SCRIPT:
        if re.match(pattern, rule):
            return script
    return None


def dag_job_counts(configfile: str | None) -> dict[str, int]:
    """Jobs per rule in the whole DAG of the configured workflow (a dry run of every job)."""
    cmd = [sys.executable, "-m", "snakemake", "-n", "--forceall", "--cores", "2"]
    if configfile:
        cmd += ["--configfile", configfile]
    text = subprocess.run(cmd, capture_output=True, text=True, check=True, cwd=REPO).stdout
    counts: dict[str, int] = {}
    for line in text.splitlines():
        if m := re.match(r"^(?:local)?(?:rule|checkpoint) (\S+):$", line.strip()):
            counts[m.group(1)] = counts.get(m.group(1), 0) + 1
    return counts


def main(argv=None) -> dict:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--repeat", type=int, default=5)
    ap.add_argument("--scripts", default=None, help="comma-separated script names (default: all)")
    ap.add_argument("--exit", action="store_true",
                    help="also time the interpreter's exit after the imports, default and frozen")
    ap.add_argument("--dag", action="store_true", help="also count the DAG's jobs per rule (snakemake -n)")
    ap.add_argument("--configfile", default=None)
    ap.add_argument("--json", default=None)
    args = ap.parse_args(argv)
    names = args.scripts.split(",") if args.scripts else sorted(
        p.stem for p in SCRIPTS.glob("*.py") if p.stem != "common")
    per_script = {}
    for name in names:
        lines = script_imports(name)
        time_imports(lines)  # warm the disk cache
        runs = [time_imports(lines) for _ in range(args.repeat)]
        per_script[name] = {"wall_s": sum(r[0] for r in runs) / len(runs), "cpu_s": sum(r[1] for r in runs) / len(runs)}
        line = (f"{name:26s} {per_script[name]['wall_s']:5.2f} s wall {per_script[name]['cpu_s']:5.2f} s CPU "
                f"(mean of {args.repeat})")
        if args.exit:
            for key, freeze in (("exit_s", False), ("exit_frozen_s", True)):
                per_script[name][key] = sum(time_exit(lines, freeze) for _ in range(args.repeat)) / args.repeat
            line += f"; exit {per_script[name]['exit_s']:.2f} s, frozen {per_script[name]['exit_frozen_s']:.2f} s"
        print(line, flush=True)
    out = {"repeat": args.repeat, "per_script": per_script}
    if args.dag:
        counts = dag_job_counts(args.configfile)
        total, exit_s, exit_frozen_s, jobs = 0.0, 0.0, 0.0, 0
        for rule, n in sorted(counts.items(), key=lambda kv: -kv[1]):
            script = script_of_rule(rule)
            if script in per_script:
                total += n * per_script[script]["cpu_s"]
                exit_s += n * per_script[script].get("exit_s", 0.0)
                exit_frozen_s += n * per_script[script].get("exit_frozen_s", 0.0)
                jobs += n
        out.update({"dag_jobs_per_rule": counts, "startup_cpu_s": total, "jobs_counted": jobs})
        print(f"whole DAG: {sum(counts.values())} jobs, {jobs} of them of the scripts timed: "
              f"{total / 60:.1f} min of start-up CPU")
        if args.exit:
            out.update({"exit_s": exit_s, "exit_frozen_s": exit_frozen_s})
            print(f"whole DAG: {exit_s / 60:.1f} min of exits after the imports, {exit_frozen_s / 60:.1f} min frozen")
    if args.json:
        Path(args.json).write_text(json.dumps(out, indent=1) + "\n")
    return out


if __name__ == "__main__":
    main()
