"""The run comparison (benchmarks/compare_runs.py): equal runs pass; a changed byte, a missing file or
a changed weight fails and is named; the timings stored beside a model's weights do not count."""

import sys
from pathlib import Path

import numpy as np
import pytest
import torch

REPO = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(REPO / "benchmarks"))

from compare_runs import compare_runs, equal, main  # noqa: E402


def _run(root: Path, weight: float = 1.0, train_s: float = 10.0) -> Path:
    (root / "detections" / "model_based_ours" / "synthetic").mkdir(parents=True)
    (root / "detections" / "model_based_ours" / "synthetic" / "s0100.json").write_text('{"boxes": [1.0, 2.0]}\n')
    (root / "eval" / "sasa_25" / "dev").mkdir(parents=True)
    (root / "eval" / "sasa_25" / "dev" / "metrics.json").write_text('{"mAP": 0.5}\n')
    (root / "scenes").mkdir()
    np.savez(root / "scenes" / "s0100.npz", xyz=np.arange(12.0).reshape(4, 3))
    (root / "scenes" / "s0100.json").write_text('{"timings_s": {"scan_s": %r}}' % train_s)  # not compared
    (root / "models" / "sasa_25").mkdir(parents=True)
    torch.save({"state_dict": {"w": torch.full((2, 3), weight), "b": torch.zeros(3)},
                "summary": {"train_s": train_s}}, root / "models" / "sasa_25" / "model.pt")
    return root


def test_equal_runs_pass_and_timings_do_not_count(tmp_path, capsys):
    a = _run(tmp_path / "a")
    b = _run(tmp_path / "b", train_s=99.0)  # other timings in the model file and the scene JSON
    report = compare_runs(a, b)
    assert equal(report)
    assert report["detections"]["files_a"] == 1 and report["scene soundings"]["files_b"] == 1
    assert report["SASA model weights"] == {"files_a": 1, "files_b": 1, "only_a": [], "only_b": [], "differ": [],
                                            "tensors": 2}
    assert main([str(a), str(b)]) == 0
    assert "equal: every compared output is the same" in capsys.readouterr().out


def test_a_changed_or_missing_output_fails_naming_it(tmp_path, capsys):
    a = _run(tmp_path / "a")
    b = _run(tmp_path / "b", weight=1.0 + 1e-7)  # one float32 step away
    (b / "detections" / "model_based_ours" / "synthetic" / "s0100.json").write_text('{"boxes": [1.0, 2.5]}\n')
    (a / "eval" / "sasa_25" / "dev" / "pr.csv").write_text("r,p\n")
    report = compare_runs(a, b)
    assert not equal(report)
    assert report["detections"]["differ"] == ["detections/model_based_ours/synthetic/s0100.json"]
    assert report["evaluations"]["only_a"] == ["eval/sasa_25/dev/pr.csv"]
    assert report["SASA model weights"]["differ"] == ["models/sasa_25/model.pt"]
    assert main([str(a), str(b)]) == 1
    out = capsys.readouterr().out
    assert "differ: detections/model_based_ours/synthetic/s0100.json" in out and "NOT equal" in out


def test_bad_input_is_named(tmp_path):
    a = _run(tmp_path / "a")
    with pytest.raises(FileNotFoundError, match="no such results folder"):
        compare_runs(a, tmp_path / "missing")
    assert main([str(tmp_path / "missing"), str(a)]) == 2  # the command names it, exit code 2, no traceback
    b = _run(tmp_path / "b")
    torch.save({"weights": {}}, b / "models" / "sasa_25" / "model.pt")
    with pytest.raises(ValueError, match="model.pt: not a SASA model file"):
        compare_runs(a, b)
