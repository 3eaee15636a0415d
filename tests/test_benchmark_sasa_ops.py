"""The SASA operator benchmark's sampling rows (benchmarks/sasa_ops.py --sampling-only): the FPS and
ball-query kernels at the DEFAULTS step's shapes, read back from its JSON (timings never asserted)."""

import json
import sys
from pathlib import Path

import pytest

REPO = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(REPO / "benchmarks"))

import sasa_ops  # noqa: E402


def test_sampling_rows_time_fps_and_the_ball_query_at_the_step_shapes(tmp_path, monkeypatch):
    out = tmp_path / "ops.json"
    monkeypatch.setattr(sys, "argv", ["sasa_ops.py", "--sampling-only", "--repeat", "1", "--threads", "1",
                                      "--json", str(out)])
    sasa_ops.main()
    rows = json.loads(out.read_text())["rows"]
    ops = [(r["op"], r["shape"]) for r in rows]
    assert ("D-FPS [compiled]", "B=4 8192->2048") in ops and ("S-FPS (gamma=1) [compiled]", "B=4 2048->512") in ops
    assert ("ball_query_shells x3 dil. [compiled]", "B=4 N=8192 M=2048") in ops
    assert all(r["device"] == "cpu" and r["ms"] > 0 for r in rows)


def test_a_results_folder_without_a_training_split_is_named(tmp_path, monkeypatch):
    monkeypatch.setattr(sys, "argv", ["sasa_ops.py", "--sampling-only", "--repeat", "1", "--results", str(tmp_path)])
    with pytest.raises(SystemExit, match="no training split here"):
        sasa_ops.main()


def test_rows_only_times_the_fused_last_layer_against_the_two_steps(tmp_path, monkeypatch):
    """--rows-only: the batch norm, the segment max and the last layer's fused function against its two
    steps, every row timed (the fused switch restored after)."""
    from sonardet.detect.sasa import backbone

    out = tmp_path / "rows.json"
    monkeypatch.setattr(sys, "argv", ["sasa_ops.py", "--rows-only", "--repeat", "1", "--threads", "1",
                                      "--json", str(out)])
    sasa_ops.main()
    ops = {r["op"] for r in json.loads(out.read_text())["rows"]}
    assert {"last BN+ReLU+max fwd+bwd [fused]", "last BN+ReLU+max fwd+bwd [two steps]"} <= ops
    assert {"segment max fwd [fused]", "weighted BN+ReLU fwd [fused]"} <= ops
    assert backbone.FUSE_LAST_MAX is True
