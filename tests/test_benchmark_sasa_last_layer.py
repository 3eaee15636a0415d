"""benchmarks/sasa_last_layer.py: DEFAULTS training steps with the grouped MLPs' last layer fused with
their pooling and as two steps, from the same state, give the same bits (timings never asserted)."""

import json
import sys
from pathlib import Path

import pytest

REPO = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(REPO / "benchmarks"))

import sasa_last_layer  # noqa: E402

pytestmark = pytest.mark.usefixtures("one_torch_thread")


def test_paired_steps_agree_bit_for_bit_and_restore_the_switch(tmp_path):
    from sonardet.detect.sasa import backbone

    out = tmp_path / "ab.json"
    res = sasa_last_layer.main(["--pairs", "2", "--scenes", "4", "--json", str(out)])
    assert json.loads(out.read_text())["summary"] == res["summary"]
    assert res["summary"]["pairs"] == 2 and res["summary"]["all_same_bits"] is True
    assert all(r["fused_s"] > 0 and r["two_steps_s"] > 0 for r in res["rows"])
    assert backbone.FUSE_LAST_MAX is True


def test_a_results_folder_without_a_training_split_is_named(tmp_path):
    with pytest.raises(SystemExit, match="no training split here"):
        sasa_last_layer.main(["--results", str(tmp_path), "--pairs", "1"])
