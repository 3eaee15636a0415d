"""The SASA batch benchmark (benchmarks/sasa_batches.py): times the training batches with and without
domain randomisation on a run's training scenes and digests them (timings never asserted)."""

import json
import sys
from pathlib import Path

import pytest
from test_sasa_domain_randomisation import FOUR
from test_sasa_model import make_scene

REPO = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(REPO / "benchmarks"))

import sasa_batches  # noqa: E402

# The tiny scenes hold fewer points than a DEFAULTS sample: padded, as documented.
pytestmark = pytest.mark.filterwarnings("ignore:.*padding by resampling")


def _run(tmp_path, monkeypatch, results, out):
    monkeypatch.setattr(sys, "argv", ["sasa_batches.py", "--results", str(results), "--scenes", "2", "--steps", "2",
                                      "--repeat", "1", "--json", str(out)])
    sasa_batches.main()
    return json.loads(out.read_text())


def test_both_modes_are_timed_and_the_digests_repeat(tmp_path, monkeypatch):
    results = tmp_path / "results"
    (results / "splits").mkdir(parents=True)
    (results / "scenes").mkdir()
    for i, sid in enumerate(("s0000", "s0001")):
        make_scene(results / "scenes", sid, 11 + i, FOUR, extent=24.0, density=30.0)
    (results / "splits" / "train.txt").write_text("s0000\ns0001\n")
    a = _run(tmp_path, monkeypatch, results, tmp_path / "a.json")
    assert [(r["round"], r["mode"]) for r in a["rows"]] == [(1, "plain"), (1, "dr")]
    assert all(r["median_ms"] >= r["fastest_ms"] > 0 for r in a["rows"])
    b = _run(tmp_path, monkeypatch, results, tmp_path / "b.json")
    assert a["digests"] == b["digests"] and a["digests"]["plain"] != a["digests"]["dr"]


def test_a_results_folder_without_a_training_split_is_named(tmp_path, monkeypatch):
    monkeypatch.setattr(sys, "argv", ["sasa_batches.py", "--results", str(tmp_path)])
    with pytest.raises(SystemExit, match="no training split here"):
        sasa_batches.main()
