"""The SASA speed benchmark (benchmarks/sasa.py): a short CPU run with its switches, read back from
its JSON (the timings themselves are never asserted; README quotes full runs)."""

import json
import sys
from pathlib import Path

REPO = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(REPO / "benchmarks"))

import sasa as sasa_benchmark  # noqa: E402


def test_a_short_run_reports_its_settings(tmp_path, capsys):
    out = tmp_path / "sasa.json"
    sasa_benchmark.main(["--configs", "DEFAULTS", "--device", "cpu", "--synthetic", "--n-scenes", "4",
                         "--steps", "2", "--warmup", "0", "--threads", "1", "--system-malloc",
                         "--parallel-min-elements", "0", "--json", str(out)])
    (row,) = json.loads(out.read_text())["rows"]
    assert row["config"] == "DEFAULTS" and row["device"] == "cpu" and row["threads"] == 1
    assert row["freed_memory_kept"] is False  # --system-malloc
    assert row["kernels_parallel_min_elements"] == 0
    assert 0 < row["train_s_per_step_min"] <= row["train_s_per_step"]
    assert row["infer_s_per_scene"] > 0 and row["peak_rss_mb"] > 0
    printed = capsys.readouterr().out
    assert "freed memory returned to the system" in printed and "fused kernels parallel from 0 values" in printed
    assert "| fastest |" in printed


def test_the_profile_by_input_shape_names_each_product_size(capsys):
    sasa_benchmark.main(["--configs", "DEFAULTS", "--device", "cpu", "--synthetic", "--n-scenes", "4",
                         "--steps", "1", "--warmup", "0", "--threads", "1", "--profile", "400",
                         "--profile-shapes"])
    printed = capsys.readouterr().out
    assert "profile of one DEFAULTS step on cpu" in printed
    # the coordinate projection's weight gradient: a (3, R) x (R, C) product, not (C, R) x (R, 3)
    mm = [line for line in printed.splitlines() if line.lstrip().startswith("aten::mm") and "[[" in line]
    assert mm and any("[[3, " in line for line in mm)


def test_an_unknown_configuration_is_refused_before_any_work(capsys):
    import pytest

    with pytest.raises(SystemExit):
        sasa_benchmark.main(["--configs", "DEFAULTS,FAST", "--synthetic"])
    assert "unknown configuration(s) ['FAST']" in capsys.readouterr().err


def test_a_worker_that_fails_ends_the_run_instead_of_hanging():
    """A worker that raises (here: an unknown device) puts no row on the queue; the benchmark ends
    naming it, where it used to wait for the row forever."""
    import subprocess

    import torch

    if torch.cuda.is_available():
        device = "nodevice"
    else:
        device = "cuda"  # this PyTorch has no CUDA: the worker's device check raises
    proc = subprocess.run([sys.executable, str(REPO / "benchmarks" / "sasa.py"), "--configs", "DEFAULTS", "--device",
                           device, "--synthetic", "--n-scenes", "1", "--steps", "1", "--warmup", "0", "--threads",
                           "1"], capture_output=True, text=True, timeout=300)
    assert proc.returncode != 0
    assert f"the worker for DEFAULTS on {device} ended (exit code 1) without a result" in proc.stderr
