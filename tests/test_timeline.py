"""The run's time line (sonardet.report.timeline): each job's exact CPU record written at its end
(sonardet.workflow), read in place of Snakemake's sampled cpu_time; the idle core-time from the
jobs' threads; the blocking chain."""

import gc
import json
import os
import subprocess
import sys
import time
from pathlib import Path
from types import SimpleNamespace

import pytest

from sonardet.report.timeline import (
    blocking_chain,
    gantt_lanes,
    job_method,
    method_group,
    read_benchmarks,
    run_summary,
    summary_lines,
)
from sonardet.usage import job_usage, usage_path
from sonardet.workflow import rule_logging

HEADER = "s\th:m:s\tmax_rss\tmax_vms\tmax_uss\tmax_pss\tio_in\tio_out\tmean_load\tcpu_time\n"


def _bench(root, rel, wall_s, cpu_s, end):
    p = root / "benchmarks" / rel
    p.parent.mkdir(parents=True, exist_ok=True)
    p.write_text(HEADER + f"{wall_s}\t0:00:00\t100\t200\t90\t95\t0\t0\t50\t{cpu_s}\n")
    os.utime(p, (end, end))
    return p


def test_usage_path_mirrors_the_log():
    assert str(usage_path("results/logs/train/sasa_100.log")) == "results/logs/train/sasa_100.usage.json"
    assert str(usage_path("x/y")) == "x/y.usage.json"


def test_a_job_records_its_cpu_and_threads_at_its_end(tmp_path):
    log = tmp_path / "logs" / "rule" / "a.log"
    log.parent.mkdir(parents=True)
    before = job_usage(1)["cpu_s"]
    with rule_logging(SimpleNamespace(log=[str(log)], threads=3), "rule"):
        t = time.process_time()
        while time.process_time() - t < 0.2:  # burn some CPU inside the job
            pass
    rec = json.loads(usage_path(log).read_text())
    assert rec["threads"] == 3
    assert rec["cpu_s"] >= before + 0.2
    # the CPU before the job's work (here: this test process so far) excludes what the job burnt
    assert before - 0.05 <= rec["startup_cpu_s"] <= rec["cpu_s"] - 0.2
    assert "of CPU since it started" in log.read_text() and "before the job's work" in log.read_text()


def test_a_jobs_record_holds_its_end_time(tmp_path):
    log = tmp_path / "e.log"
    before = time.time()
    with rule_logging(SimpleNamespace(log=[str(log)], threads=1), "rule"):
        pass
    rec = json.loads(usage_path(log).read_text())
    assert before <= rec["end_epoch_s"] <= time.time()


def test_a_copy_that_lost_the_files_times_keeps_the_time_line_from_the_records(tmp_path):
    """Jobs timed by their records keep their times when a copy (cp -r) resets the files' modification
    times; jobs timed by the files alone are flagged, not reported as the run's time line."""
    t0 = 1_700_000_000.0
    jobs = [("simulate_scene/a.tsv", 30.0, t0 + 30), ("simulate_scene/b.tsv", 30.0, t0 + 30),
            ("train/m.tsv", 50.0, t0 + 80), ("report.tsv", 5.0, t0 + 85)]
    for rel, wall_s, end in jobs:
        _bench(tmp_path, rel, wall_s, wall_s, end)
        rec = usage_path(tmp_path / "logs" / rel.replace(".tsv", ".log"))
        rec.parent.mkdir(parents=True, exist_ok=True)
        rec.write_text(json.dumps({"cpu_s": wall_s, "threads": 1, "end_epoch_s": end}))
    before = run_summary(read_benchmarks(tmp_path / "benchmarks"), cores=2)
    assert before["wall_s"] == pytest.approx(85.0) and not before["overfull"] and before["ends_from_files"] == 0
    for p in (tmp_path / "benchmarks").rglob("*.tsv"):  # what a copy without times does
        os.utime(p, (t0 + 5000, t0 + 5000))
    df = read_benchmarks(tmp_path / "benchmarks")
    assert set(df["end_from"]) == {"record"}
    assert run_summary(df, cores=2)["wall_s"] == pytest.approx(85.0)
    for rec in (tmp_path / "logs").rglob("*.usage.json"):  # records from before the end time was kept
        rec.write_text(json.dumps({"cpu_s": 1.0, "threads": 1}))
    df = read_benchmarks(tmp_path / "benchmarks")
    assert set(df["end_from"]) == {"file"}
    s = run_summary(df, cores=2)
    assert s["overfull"] and s["ends_from_files"] == 4  # 115 s of jobs in 50 s on 2 cores: impossible
    lines = summary_lines(s)
    assert lines[1].startswith("NOT A TIME LINE OF THIS RUN") and "4 of 4 jobs" in lines[1] and "cp -p" in lines[1]
    assert not any(line.startswith("NOT A TIME LINE") for line in summary_lines(before))


def test_a_missing_benchmark_folder_is_named(tmp_path):
    with pytest.raises(FileNotFoundError, match="no benchmark folder"):
        read_benchmarks(tmp_path / "nothing" / "benchmarks")
    script = Path(__file__).resolve().parents[1] / "benchmarks" / "workflow.py"
    out = subprocess.run([sys.executable, str(script), "--results", str(tmp_path / "nothing")], capture_output=True,
                         text=True)
    assert out.returncode == 2 and "no benchmark folder" in out.stderr and "Traceback" not in out.stderr
    (tmp_path / "empty" / "benchmarks").mkdir(parents=True)
    out = subprocess.run([sys.executable, str(script), "--results", str(tmp_path / "empty")], capture_output=True,
                         text=True)
    assert out.returncode == 1 and "holds no benchmark file" in out.stderr and "Traceback" not in out.stderr


def test_a_failed_job_leaves_no_record(tmp_path):
    log = tmp_path / "b.log"
    with pytest.raises(RuntimeError):
        with rule_logging(SimpleNamespace(log=[str(log)], threads=1), "rule"):
            raise RuntimeError("boom")
    assert not usage_path(log).exists()


def test_exact_records_replace_the_sampled_cpu_and_threads_count_in_the_idle_time(tmp_path):
    t0 = 1_700_000_000.0
    _bench(tmp_path, "train/m.tsv", 100.0, 60.0, t0 + 100)  # sampled: 60 of its 95 s
    _bench(tmp_path, "detect/a.tsv", 40.0, 30.0, t0 + 40)
    _bench(tmp_path, "detect/b.tsv", 50.0, 30.0, t0 + 100)
    rec = usage_path(tmp_path / "logs" / "train" / "m.log")
    rec.parent.mkdir(parents=True)
    rec.write_text(json.dumps({"cpu_s": 95.0, "threads": 2, "startup_cpu_s": 1.5}))
    df = read_benchmarks(tmp_path / "benchmarks")
    row = df.set_index("job").loc["train/m"]
    assert row["cpu_s"] == 95.0 and bool(row["cpu_exact"]) and row["threads"] == 2
    assert not df.set_index("job").loc["detect/a", "cpu_exact"]
    s = run_summary(df, cores=3)
    assert s["wall_s"] == pytest.approx(100.0)
    assert s["job_core_s"] == pytest.approx(100 * 2 + 40 + 50)  # the training held two cores
    assert s["idle_core_s"] == pytest.approx(3 * 100 - 290)
    assert s["utilisation"] == pytest.approx(290 / 300)
    assert s["cpu_s"] == pytest.approx(95 + 30 + 30) and s["cpu_exact_jobs"] == 1
    assert s["job_core_off_cpu_s"] == pytest.approx(290 - 155)
    assert s["per_rule"]["detect"] == {"jobs": 2, "sum_s": 90.0, "max_s": 50.0, "cpu_s": 60.0, "startup_cpu_s": 0.0,
                                       "jit_s": 0.0}
    assert s["per_rule"]["train"]["cpu_s"] == 95.0 and s["per_rule"]["train"]["startup_cpu_s"] == 1.5
    assert s["startup_cpu_s"] == 1.5 and s["startup_jobs"] == 1  # the sampled jobs have no start-up figure
    # a record from before the compilation time was kept has none: no line claims a figure for it
    assert s["jit_recorded_jobs"] == 0 and not any("Numba" in line for line in summary_lines(s))
    assert any("before the jobs' own work" in line and "1 jobs recorded it" in line for line in summary_lines(s))
    assert list(blocking_chain(df)["job"])[-1] in {"train/m", "detect/b"}


def test_gantt_lanes_absorb_the_exit_skew_but_not_a_real_overlap():
    """A job that follows another seems to start up to about a second before it ended (the end is the
    record's time, before the interpreter exits): it shares that job's lane. Three jobs that ran
    together for a minute need three lanes."""
    import pandas as pd

    def lanes(rows):
        df = pd.DataFrame(rows, columns=["job", "start", "end"]).sort_values("start").reset_index(drop=True)
        return dict(zip(df["job"], gantt_lanes(df)))

    skewed = lanes([("scene_a", 0.0, 100.0), ("scene_b", 0.0, 60.0), ("train", 98.98, 600.0),
                    ("other", 60.2, 120.0), ("last", 599.5, 700.0)])
    assert max(skewed.values()) == 1, skewed  # two cores, two lanes
    assert skewed["train"] == skewed["scene_a"] and skewed["last"] == skewed["train"]
    real = lanes([("a", 0.0, 100.0), ("b", 0.0, 100.0), ("c", 50.0, 150.0)])
    assert max(real.values()) == 2, real
    assert len(gantt_lanes(pd.DataFrame(columns=["job", "start", "end"]))) == 0


def test_numba_compilation_is_summed_from_the_records(tmp_path):
    t0 = 1_700_000_000.0
    for k, (jit_s, end) in enumerate([(12.5, 50), (0.0, 60), (30.0, 100)]):
        _bench(tmp_path, f"detect/j{k}.tsv", 40.0, 39.0, t0 + end)
        rec = usage_path(tmp_path / "logs" / "detect" / f"j{k}.log")
        rec.parent.mkdir(parents=True, exist_ok=True)
        rec.write_text(json.dumps({"cpu_s": 39.0, "threads": 1, "startup_cpu_s": 1.0, "jit_n": int(jit_s > 0),
                                   "jit_s": jit_s}))
    _bench(tmp_path, "report.tsv", 3.0, 3.0, t0 + 110)  # no record: no compilation figure
    s = run_summary(read_benchmarks(tmp_path / "benchmarks"), cores=2)
    assert s["jit_s"] == pytest.approx(42.5) and s["jit_jobs"] == 2 and s["jit_recorded_jobs"] == 3
    assert s["per_rule"]["detect"]["jit_s"] == pytest.approx(42.5) and s["per_rule"]["report"]["jit_s"] == 0.0
    assert any("0.7 min compiling Numba kernels, in 2 jobs" in line and "3 jobs recorded it" in line
               for line in summary_lines(s))


def test_job_time_is_split_by_method(tmp_path):
    t0 = 1_700_000_000.0
    _bench(tmp_path, "train/sasa_100.tsv", 100.0, 90.0, t0 + 100)
    _bench(tmp_path, "detect_dataset/sasa_25/dev.tsv", 5.0, 4.0, t0 + 105)
    _bench(tmp_path, "detect_scenes/model_based_paper+model_based_paper_tight/synthetic.tsv", 60.0, 58.0, t0 + 60)
    _bench(tmp_path, "evaluate/model_based_paper_tight/synthetic.tsv", 1.0, 1.0, t0 + 61)
    _bench(tmp_path, "ablation/fewer_points.tsv", 30.0, 29.0, t0 + 130)
    _bench(tmp_path, "ablation/reference.tsv", 1.0, 1.0, t0 + 131)
    _bench(tmp_path, "simulate_scene/s0001.tsv", 8.0, 7.0, t0 + 8)
    _bench(tmp_path, "simulate_scenes/realism.tsv", 20.0, 19.0, t0 + 28)
    _bench(tmp_path, "report.tsv", 3.0, 3.0, t0 + 140)
    points = tmp_path / "ablation" / "points"
    points.mkdir(parents=True)
    # the point's name says nothing of its method: the point file does
    (points / "fewer_points.json").write_text(json.dumps({"name": "fewer_points", "method": "sasa", "fraction": 25}))
    df = read_benchmarks(tmp_path / "benchmarks")
    by_job = dict(zip(df["job"], df["method"]))
    assert by_job["train/sasa_100"] == "sasa_100"
    assert by_job["detect_scenes/model_based_paper+model_based_paper_tight/synthetic"] == "model_based_paper"
    assert by_job["ablation/fewer_points"] == "sasa"
    assert by_job["ablation/reference"] == "(other)" and by_job["report"] == "(other)"
    assert by_job["simulate_scene/s0001"] == by_job["simulate_scenes/realism"] == "(scenes)"
    s = run_summary(df, cores=2)
    pm = s["per_method"]
    assert list(pm)[:2] == ["sasa", "model_based_paper"]  # by job time, largest first
    assert pm["sasa"] == {"jobs": 3, "sum_s": 135.0, "cpu_s": 123.0, "methods": ["sasa", "sasa_100", "sasa_25"]}
    assert pm["model_based_paper_tight"]["sum_s"] == 1.0  # its evaluation; the shared job is paper's
    assert pm["(scenes)"]["sum_s"] == 28.0 and pm["(other)"]["jobs"] == 2
    assert sum(v["sum_s"] for v in pm.values()) == pytest.approx(s["job_s"])
    lines = summary_lines(s)
    assert lines[-1].startswith("blocking chain") and any(line.startswith("job time per method: sasa 2.2 min")
                                                           for line in lines)


def test_job_method_and_groups():
    assert job_method("train/sasa_dr_100") == "sasa_dr_100" and method_group("sasa_dr_100") == "sasa_dr"
    assert method_group("model_based_ours") == "model_based_ours" and method_group("sasa_25") == "sasa"
    assert job_method("ablation/unknown_point") == "(other)"  # no point file: not guessed from its name
    assert job_method("evaluate/model_based_ours/dev") == "model_based_ours"


def test_a_broken_ablation_point_file_is_refused_naming_it(tmp_path):
    _bench(tmp_path, "ablation/p.tsv", 1.0, 0.5, 1_700_000_000.0)
    points = tmp_path / "ablation" / "points"
    points.mkdir(parents=True)
    (points / "p.json").write_text(json.dumps({"name": "p"}))
    with pytest.raises(ValueError, match="p.json"):
        read_benchmarks(tmp_path / "benchmarks")


def test_a_broken_record_is_refused_naming_it(tmp_path):
    _bench(tmp_path, "r/x.tsv", 1.0, 0.5, 1_700_000_000.0)
    rec = usage_path(tmp_path / "logs" / "r" / "x.log")
    rec.parent.mkdir(parents=True)
    rec.write_text("{not json")
    with pytest.raises(ValueError, match="x.usage.json"):
        read_benchmarks(tmp_path / "benchmarks")


_SCRIPT = """
import gc, json, sys
from types import SimpleNamespace
from sonardet.workflow import rule_logging
snakemake = SimpleNamespace(log=[sys.argv[1]], threads=1)
before = gc.get_freeze_count()
with rule_logging({smk}, "rule"):
    pass
print(json.dumps([before, gc.get_freeze_count()]))
"""


@pytest.mark.parametrize("own", [True, False])
def test_only_a_jobs_own_script_process_skips_the_exit_collection(tmp_path, own):
    """In the process Snakemake runs a rule's script in, the job's end freezes the objects (the
    interpreter's last collection skips them); a test or library calling in is left alone."""
    src = Path(__file__).resolve().parents[1] / "src"
    smk = "snakemake" if own else "SimpleNamespace(log=[sys.argv[1]], threads=1)"
    out = subprocess.run([sys.executable, "-c", _SCRIPT.replace("{smk}", smk), str(tmp_path / "a.log")],
                         capture_output=True, text=True, check=True, env={**os.environ, "PYTHONPATH": str(src)})
    before, after = json.loads(out.stdout.strip().splitlines()[-1])
    assert before == 0
    assert (after > 0) == own
    assert usage_path(tmp_path / "a.log").exists()  # the record is written either way


def test_a_test_process_calling_a_job_is_not_frozen(tmp_path):
    before = gc.get_freeze_count()
    with rule_logging(SimpleNamespace(log=[str(tmp_path / "c.log")], threads=1), "rule"):
        pass
    assert gc.get_freeze_count() == before
