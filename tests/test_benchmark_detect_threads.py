"""The thread benchmark's round records (`tasks.recording`, benchmarks/detect_threads.py): every
`run_tasks` call is recorded with its items and each piece's seconds, results and statistics as
without recording; the summary's bound and the outside seconds follow from the records."""

import sys
import time
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path

import pytest

from sonardet.detect.model_based import tasks

sys.path.insert(0, str(Path(__file__).resolve().parent.parent / "benchmarks"))

import detect_threads


def _piece(item, part):
    time.sleep(0.01 * item)
    part["icp_runs"] += item
    return item * 10


def test_recording_times_each_piece_and_changes_no_result():
    stats = tasks.task_stats()
    with ThreadPoolExecutor(2) as pool, tasks.recording() as records:
        out = tasks.run_tasks(pool, _piece, [1, 2, 3], stats)
        one = tasks.run_tasks(None, _piece, [4])
    assert out == [10, 20, 30] and one == [40] and stats["icp_runs"] == 6
    assert [(r.name, r.items, len(r.task_s)) for r in records] == [("_piece", 3, 3), ("_piece", 1, 1)]
    assert sorted(round(s, 2) for s in records[0].task_s) == pytest.approx([0.01, 0.02, 0.03], abs=0.01)
    assert all(r.wall_s >= max(r.task_s) for r in records)
    assert tasks.run_tasks(None, _piece, [1]) == [10]  # not recorded after the block
    assert len(records) == 2


def test_recording_does_not_nest():
    with tasks.recording():
        with pytest.raises(RuntimeError, match="already being recorded"):
            with tasks.recording():
                pass
    with tasks.recording() as again:  # usable again after the error
        tasks.run_tasks(None, _piece, [0])
    assert len(again) == 1


def test_summary_bound_and_outside_seconds():
    recs = [tasks.RoundRecord("a", 3, 0.5, [0.1, 0.2, 0.4]), tasks.RoundRecord("b", 2, 0.3, [0.2, 0.2])]
    s = detect_threads.summarise(recs, 2, 1.0)
    assert s["kinds"]["a"]["bound_s"] == pytest.approx(0.4)  # the longest piece
    assert s["kinds"]["b"]["bound_s"] == pytest.approx(0.2)  # half the sum
    assert s["rounds_wall_s"] == pytest.approx(0.8) and s["outside_s"] == pytest.approx(0.2)
    assert s["task_s"] == pytest.approx(1.1)


def test_the_test_split_is_refused(monkeypatch, tmp_path, capsys):
    monkeypatch.setattr(sys, "argv", ["detect_threads.py", "--results", str(tmp_path), "--split", "test"])
    with pytest.raises(SystemExit):
        detect_threads.main()
    assert "final evaluation only" in capsys.readouterr().err
