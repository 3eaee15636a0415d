"""Tiles detected in parallel worker processes (`detect_tiled(..., jobs=N)`, ``sonardet detect --jobs N``).

The detector here is a real one, if simple: mounds on a rough seabed found as local maxima of a height
grid, boxes fitted to the points above the local seabed. It is a deterministic function of its tile's
points (and of their order), so the parallel run must give the serial run's detections to the last bit,
in the same order. Hard cases: more tiles than workers, an empty planned tile, a detector failing in
one tile only (the error names it), a ValueError staying a ValueError, the numerical libraries of a
worker on one thread, the progress bar advancing per finished tile, bad ``jobs`` values.
"""

from __future__ import annotations

import json
import logging
import os
from pathlib import Path

import numpy as np
import pytest

import sonardet.survey.tiling as tiling
from sonardet.survey.tiling import check_jobs, detect_survey, detect_tiled, plan_tiles, tile_points

UTM = np.array([5.5e5, 4.18e6, 0.0])
#: Mound centres (m, local frame): inside tiles, on the seams of a 20 m plan (x or y = 20, 40, ...),
#: at a seam crossing and at the survey edge.
MOUNDS = [(10.0, 10.0), (20.1, 31.0), (39.9, 12.0), (40.0, 40.0), (55.0, 48.0), (70.0, 20.2), (79.5, 5.0),
          (90.0, 55.0), (33.0, 57.0), (0.8, 44.0)]


def _mounds_survey(seed: int = 11) -> np.ndarray:
    """An 95 m x 60 m survey in UTM coordinates: a sloping, rough seabed with Gaussian mounds (0.8-1.4 m
    high, sigma 0.6 m), soundings at random positions with 2 cm noise, in an order that is not sorted."""
    rng = np.random.default_rng(seed)
    xy = rng.uniform([0.0, 0.0], [95.0, 60.0], (120_000, 2))
    z = -11.5 + 0.01 * xy[:, 0] + 0.05 * np.sin(xy[:, 0] / 3.0) * np.cos(xy[:, 1] / 4.0)
    for k, (mx, my) in enumerate(MOUNDS):
        z += (0.8 + 0.06 * k) * np.exp(-((xy[:, 0] - mx) ** 2 + (xy[:, 1] - my) ** 2) / (2 * 0.6 ** 2))
    z += rng.normal(0.0, 0.02, len(z))
    return np.c_[xy, z] + UTM


def mound_detector(points: np.ndarray, cell_m: float = 0.5, min_height_m: float = 0.4):
    """Mounds of a tile: cells of a `cell_m` grid (anchored at the tile's minimum x, y) whose highest
    sounding stands `min_height_m` above the median of its 9 m x 9 m neighbourhood and is the highest of
    the 5 x 5 cells around it. A box per mound around the soundings above half its height (within 1.5 m),
    score = height / 2 capped at 1. Returns (detections, stats)."""
    p = np.asarray(points, dtype=np.float64)
    lo = p[:, :2].min(0)
    ij = np.floor((p[:, :2] - lo) / cell_m).astype(np.int64)
    shape = tuple(ij.max(0) + 1)
    top = np.full(shape, -np.inf)
    np.maximum.at(top, (ij[:, 0], ij[:, 1]), p[:, 2])
    pad = np.pad(top, 2, constant_values=-np.inf)
    window = np.max([pad[2 + di:2 + di + shape[0], 2 + dj:2 + dj + shape[1]]
                     for di in range(-2, 3) for dj in range(-2, 3)], axis=0)
    dets = []
    for i, j in zip(*np.nonzero(np.isfinite(top) & (top == window))):
        centre = lo + (np.array([i, j]) + 0.5) * cell_m
        near = np.all(np.abs(p[:, :2] - centre) <= 4.5, axis=1)
        base = float(np.median(p[near, 2]))
        height = float(top[i, j]) - base
        if height < min_height_m:
            continue
        r = np.hypot(*(p[:, :2] - centre).T)
        part = p[(r <= 1.5) & (p[:, 2] >= base + height / 2)]
        mn, mx = part.min(0), part.max(0)
        c = (mn + mx) / 2
        dets.append({"cls": "reef_cone", "box": [float(c[0]), float(c[1]), float(c[2]), float(mx[0] - mn[0]),
                                                 float(mx[1] - mn[1]), float(mx[2] - mn[2]), 0.0],
                     "score": min(1.0, height / 2.0), "extras": {"n_points": int(len(part))}})
    return dets, {"n_points": int(len(p)), "checksum": float(np.sum(p[:, :2] - lo) + np.sum(p[:, 2]))}


@pytest.fixture(scope="module")
def survey():
    return _mounds_survey()


def _no_seconds(rows):
    return [{k: v for k, v in r.items() if k != "seconds"} for r in rows]


def test_parallel_tiles_give_the_serial_detections_bit_for_bit(survey, caplog):
    """15 tiles of 20 m (5 x 3) on 2 and 3 workers: the same detections (JSON text equal, so the same
    values in the same order) and the same per-tile rows and stats (each worker got its tile's points,
    in the input's order) as one process; every mound found once."""
    serial, rows1 = detect_tiled(survey, mound_detector, 20.0, 3.0, progress=False)
    assert len(rows1) == 15 and sum(not r["skipped"] for r in rows1) == 15
    assert len(serial) == len(MOUNDS)
    for mx, my in MOUNDS:  # each mound once, its box within 20 cm of the mound's centre
        d = [np.hypot(b["box"][0] - UTM[0] - mx, b["box"][1] - UTM[1] - my) for b in serial]
        assert sum(x < 0.2 for x in d) == 1, (mx, my, sorted(d)[:2])
    for jobs in (2, 3):
        with caplog.at_level(logging.INFO, logger="sonardet.survey.tiling"):
            caplog.clear()
            dets, rows = detect_tiled(survey, mound_detector, 20.0, 3.0, jobs=jobs)
        assert json.dumps(dets) == json.dumps(serial)
        assert _no_seconds(rows) == _no_seconds(rows1) and all(r["seconds"] > 0 for r in rows)
        # Every tile logged once, as it finished, with its place in the plan.
        for k, r in enumerate(rows, 1):
            assert caplog.text.count(f"tile {k}/15 {r['tile']}:") == 1


def test_survey_with_an_empty_tile_and_detect_survey(survey, caplog):
    """A diagonal band of soundings leaves planned tiles without points (skipped, also in a worker), and
    `detect_survey` (what the command line runs) reports the workers it used."""
    x, y = (survey[:, :2] - UTM[:2]).T
    gappy = survey[np.abs(y - 0.6 * x) < 1.5]
    serial, rows1 = detect_tiled(gappy, mound_detector, 10.0, 3.0, progress=False)
    assert any(r["skipped"] for r in rows1)
    dets, rows = detect_tiled(gappy, mound_detector, 10.0, 3.0, progress=False, jobs=2)
    assert json.dumps(dets) == json.dumps(serial) and _no_seconds(rows) == _no_seconds(rows1)
    with caplog.at_level(logging.INFO, logger="sonardet.survey.tiling"):
        dets2, info = detect_survey(gappy, mound_detector, 10.0, 3.0, source="gappy.xyz", jobs=2)
    assert info["jobs"] == 2 and json.dumps(dets2) == json.dumps(serial)
    assert "2 at once" in caplog.text
    _, info1 = detect_survey(gappy, mound_detector, 10.0, 3.0, jobs=1)
    assert info1["jobs"] == 1
    # One tile: the detector runs once in this process, whatever jobs says.
    _, one = detect_survey(gappy, mound_detector, 200.0, 3.0, jobs=4)
    assert one["jobs"] == 1 and one["n_tiles"] == 1


def test_more_workers_than_tiles_uses_one_per_tile(survey, monkeypatch):
    seen = []
    real_pool = tiling.ProcessPoolExecutor

    def pool(workers, **kw):
        seen.append(workers)
        return real_pool(workers, **kw)

    monkeypatch.setattr(tiling, "ProcessPoolExecutor", pool)
    small = survey[(survey[:, 0] - UTM[0] < 35.0) & (survey[:, 1] - UTM[1] < 18.0)]
    tiles = plan_tiles((*small[:, :2].min(0), *small[:, :2].max(0)), 20.0, 3.0)
    assert len(tiles) == 2
    serial, _ = detect_tiled(small, mound_detector, 20.0, 3.0, progress=False)
    dets, _ = detect_tiled(small, mound_detector, 20.0, 3.0, progress=False, jobs=8)
    assert seen == [2] and json.dumps(dets) == json.dumps(serial)


def _failing_in(tile, exc):
    """The mound detector, except that it raises `exc` on the points of `tile` (all of them in its padded
    rectangle: a neighbouring tile's points reach beyond it)."""
    def detect(points):
        if np.all(tiling.Tile.in_core(_padded_as_core(tile), points[:, 0], points[:, 1])):
            raise exc
        return mound_detector(points)
    return detect


def _padded_as_core(tile):
    x0, y0, x1, y1 = tile.padded
    return tiling.Tile(tile.id, 0, 0, 1, 1, (x0, y0, x1, y1), tile.padded)


def test_a_failing_tile_is_named(survey):
    """The tile whose detector raised is named (id and core) and the original error is chained; a
    ValueError (a readable error of the command line) stays a ValueError."""
    tiles = plan_tiles((*survey[:, :2].min(0), *survey[:, :2].max(0)), 20.0, 3.0)
    bad = {t.id: t for t in tiles}
    detect = _failing_in(bad["t003_001"], ZeroDivisionError("no seabed under the mound"))
    with pytest.raises(RuntimeError, match=r"tile t003_001 \(core x 5500\d\d\.\d\d\.\.5500\d\d\.\d\d m, .*"
                                           r"ZeroDivisionError: no seabed under the mound") as err:
        detect_tiled(survey, detect, 20.0, 3.0, progress=False, jobs=2)
    assert isinstance(err.value.__cause__, ZeroDivisionError)
    with pytest.raises(ValueError, match=r"tile t004_002 .*ValueError: bad soundings"):
        detect_tiled(survey, _failing_in(bad["t004_002"], ValueError("bad soundings")), 20.0, 3.0, progress=False,
                     jobs=2)
    # Serially the detector's own error comes through unchanged, as before.
    with pytest.raises(ZeroDivisionError):
        detect_tiled(survey, detect, 20.0, 3.0, progress=False)
    # Nothing is left behind for the next call.
    assert tiling._FORKED == {}
    dets, _ = detect_tiled(survey, mound_detector, 20.0, 3.0, progress=False, jobs=2)
    assert len(dets) == len(MOUNDS)


def _threads(points):
    import torch

    from sonardet.detect.model_based.tasks import worker_pool

    dets, stats = mound_detector(points)
    with worker_pool(4) as pool:  # what the model-based detector would get for its fits
        detector_threads = 1 if pool is None else pool._max_workers
    return dets, {**stats, "torch_threads": torch.get_num_threads(), "omp": os.environ.get("OMP_NUM_THREADS"),
                  "detector_threads": detector_threads}


def test_workers_run_one_thread_each(survey):
    """PyTorch, loaded in the parent with 2 threads, and the model-based detector's worker threads (4
    asked) run on one thread in each worker; the parent keeps its settings."""
    torch = pytest.importorskip("torch")
    from sonardet.detect.model_based.tasks import worker_pool

    old = torch.get_num_threads()
    torch.set_num_threads(2)
    try:
        _, rows = detect_tiled(survey, _threads, 30.0, 3.0, progress=False, jobs=2)
        assert {r["stats"]["torch_threads"] for r in rows} == {1}
        assert {r["stats"]["omp"] for r in rows} == {"1"}
        assert {r["stats"]["detector_threads"] for r in rows} == {1}
        assert torch.get_num_threads() == 2
        with worker_pool(4) as pool:
            assert pool._max_workers == 4
    finally:
        torch.set_num_threads(old)


def test_the_bar_advances_as_tiles_finish(survey, monkeypatch):
    made = []

    class Bar:
        def __init__(self, *args, total=None, enabled=True, **kw):
            self.total, self.n, self.enabled = total, 0, enabled
            made.append(self)

        def __enter__(self):
            return self

        def __exit__(self, *exc):
            return False

        def update(self, n=1):
            self.n += n

    monkeypatch.setattr(tiling, "progress_bar", Bar)
    detect_tiled(survey, mound_detector, 20.0, 3.0, progress=False, jobs=2, bar=True)
    assert len(made) == 1 and made[0].total == 15 and made[0].n == 15 and made[0].enabled


@pytest.mark.parametrize("jobs", [0, -1, 1.5, True, "2"])
def test_bad_jobs_are_refused(survey, jobs):
    with pytest.raises(ValueError, match="jobs must be a whole number >= 1"):
        detect_tiled(survey[:100], mound_detector, 20.0, 3.0, jobs=jobs)
    with pytest.raises(ValueError, match="jobs must be"):
        check_jobs(jobs)


def test_tile_points_are_what_a_worker_cuts(survey):
    """The worker's cut (bisection in the x-sorted index, then y) selects exactly `tile_points`."""
    order, xs = tiling._column_index(survey, None)
    for t in plan_tiles((*survey[:, :2].min(0), *survey[:, :2].max(0)), 20.0, 3.0):
        assert np.array_equal(tiling._cut_tile(survey, order, xs, t), tile_points(survey, t))


NUMBA_SCRIPT = r'''
import json, sys
import numpy as np
from numba import njit, prange
from sonardet.survey.tiling import detect_survey

@njit(parallel=True)
def total(a):
    s = 0.0
    for i in prange(a.shape[0]):
        s += a[i]
    return s

def detect(points):
    import numba
    z = np.ascontiguousarray(points[:, 2])
    return ([{"cls": "reef_cone", "box": [float(points[0, 0]), float(points[0, 1]), total(z), 1.0, 1.0, 1.0, 0.0],
              "score": 0.5}], {"threads": numba.get_num_threads()})

xyz = np.random.default_rng(0).uniform([0, 0, -12], [60, 20, -11], (20000, 3))
if sys.argv[1] == "started":
    total(np.ones(1000))  # Numba's threading layer started in the parent before the fork
dets, info = detect_survey(xyz, detect, 20.0, 3.0, jobs=2)
import numba
if sys.argv[1] == "fresh":  # a parallel reduction sums in an order that depends on the threads: compare on one
    numba.set_num_threads(1)
serial, _ = detect_survey(xyz, detect, 20.0, 3.0, jobs=1)
print(json.dumps({"same": json.dumps(dets) == json.dumps(serial), "jobs": info["jobs"], "layer": numba.threading_layer(),
                  "threads": sorted({r["stats"]["threads"] for r in info["rows"]})}))
'''


@pytest.mark.parametrize("case", ["fresh", "started"])
def test_numba_parallel_code_in_workers(case, tmp_path):
    """A detector running Numba parallel code: in workers forked before Numba started its threads, on
    one thread each (the same detections as one process on one thread); once Numba's OpenMP layer runs in
    the parent (a forked child using it would be aborted by Numba), the tiles run in the parent instead,
    with a warning, and give the serial run's detections.
    In a separate process, so that this test's Numba state stays out of the others'."""
    pytest.importorskip("numba")
    import subprocess
    import sys

    import sonardet

    env = {**os.environ, "PYTHONPATH": str(Path(sonardet.__file__).parents[1])}
    env.pop("NUMBA_THREADING_LAYER", None)
    env.pop("NUMBA_NUM_THREADS", None)
    proc = subprocess.run([sys.executable, "-c", NUMBA_SCRIPT, case], capture_output=True, text=True, env=env,
                          timeout=300, cwd=tmp_path)
    assert proc.returncode == 0, proc.stderr[-3000:]
    res = json.loads(proc.stdout.strip().splitlines()[-1])
    assert res["same"]
    if case == "fresh" or res["layer"] != "omp":
        assert res["jobs"] == 2 and res["threads"] == [1]
        assert "Terminating" not in proc.stderr
    else:
        assert res["jobs"] == 1 and "Numba's OpenMP threading layer is already running" in proc.stderr
