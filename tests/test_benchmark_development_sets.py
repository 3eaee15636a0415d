"""Benchmarks that read the development sets name the workflow target that makes them (`development`:
the default target leaves the mismatch_dev scenes and most development-set detections out)."""

import sys
from pathlib import Path

import pytest

REPO = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(REPO / "benchmarks"))

import piles as bench_piles
import sasa_dr_shape as bench_dr_shape

CONFIG = str(REPO / "config" / "config.yaml")


def _results(tmp_path) -> Path:
    """A results folder of a default run as far as these benchmarks look: the splits, no mismatch_dev."""
    res = tmp_path / "results"
    (res / "splits").mkdir(parents=True)
    (res / "splits" / "dev.txt").write_text("s0100\ns0101\n")
    (res / "splits" / "train_25.txt").write_text("s0000\n")
    return res


def test_piles_on_mismatch_dev_names_the_development_target(monkeypatch, tmp_path):
    res = _results(tmp_path)
    monkeypatch.setattr(sys, "argv", ["piles.py", "--results", str(res), "--config", CONFIG,
                                      "--dataset", "mismatch_dev"])
    with pytest.raises(SystemExit, match="no detections.*snakemake --cores 2 development"):
        bench_piles.main()


def test_piles_on_dev_has_no_such_hint(monkeypatch, tmp_path):
    res = _results(tmp_path)
    monkeypatch.setattr(sys, "argv", ["piles.py", "--results", str(res), "--config", CONFIG, "--dataset", "dev"])
    with pytest.raises(SystemExit) as err:
        bench_piles.main()
    assert "no detections" in str(err.value) and "development" not in str(err.value)


def test_dr_shape_without_mismatch_dev_scenes_stops_before_training(monkeypatch, tmp_path):
    res = _results(tmp_path)
    monkeypatch.setattr(sys, "argv", ["sasa_dr_shape.py", "--results", str(res), "--config", CONFIG,
                                      "--work", str(tmp_path / "work")])
    with pytest.raises(SystemExit, match=r"mismatch/scenes/s0100.npz: no such mismatch_dev scene \(2 of 2 missing\)"):
        bench_dr_shape.main()
    assert not (tmp_path / "work").exists()
