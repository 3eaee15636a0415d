"""The model-based speed benchmark's pass comparison (benchmarks/detect.py --repeat): two passes
must give the same detections, compared exactly, arrays included."""

import sys
from pathlib import Path

import numpy as np
import pytest

sys.path.insert(0, str(Path(__file__).resolve().parent.parent / "benchmarks"))

import detect as bench_detect


def _det(x):
    return [{"cls": "reef_cone", "box": np.array([x, 2.0, -11.0, 2.0, 2.0, 1.4, 0.3]), "score": 0.9}]


def test_fingerprint_tells_passes_apart_to_the_last_bit():
    a = bench_detect._fingerprint(_det(1.0))
    assert a == bench_detect._fingerprint(_det(1.0))
    assert a != bench_detect._fingerprint(_det(np.nextafter(1.0, 2.0)))  # one ulp off: another result
    assert a != bench_detect._fingerprint(_det(1.0) + _det(1.0))


def test_repeat_must_be_positive(monkeypatch, tmp_path):
    monkeypatch.setattr(sys, "argv", ["detect.py", "--results", str(tmp_path), "--repeat", "0"])
    with pytest.raises(SystemExit):
        bench_detect.main()


def test_a_results_folder_without_the_split_is_named(monkeypatch, tmp_path, capsys):
    monkeypatch.setattr(sys, "argv", ["detect.py", "--results", str(tmp_path)])
    with pytest.raises(SystemExit):
        bench_detect.main()
    assert "splits/dev.txt: no such split file" in capsys.readouterr().err


def test_a_results_folder_without_object_models_is_named(tmp_path):
    with pytest.raises(SystemExit, match="objects: no object models here"):
        bench_detect.read_inputs(tmp_path)
