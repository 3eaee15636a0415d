"""`sonardet detect` on awkward real-world input and output paths, and the fliers of a survey.

* a sounding 100 km (or 10 km) off the survey is reported and dropped: the detections equal those of the
  survey alone, the plan holds tiles near the data only, memory stays bounded (no grid over the box);
  `--keep-fliers` keeps it (tiles of its own, none in between);
* an output that cannot be written stops the command before the detection, naming the path; the
  outputs are written all or none.
"""

from __future__ import annotations

import logging
import time
import tracemalloc

import numpy as np
import pytest

from sonardet.cli import main
from sonardet.io.annotations import read_detections
from sonardet.io.points import PointCloud, write_points
from sonardet.survey import CellStats, detect_survey, find_fliers, survey_layout

UTM = np.array([5.5e5, 4.18e6, 0.0])
PLUGIN = "tests/plugins/centroid_method.py"


def blobs(seed: int = 0) -> np.ndarray:
    """A 40 x 40 m seabed at UTM coordinates with three mounds (the centroid method's objects)."""
    rng = np.random.default_rng(seed)
    xyz = rng.uniform([0, 0, -11.5], [40, 40, -11.45], (40000, 3))
    for cx, cy in ((8, 9), (21, 30), (33, 12)):
        r = rng.uniform(0, 0.9, 600)
        a = rng.uniform(0, 2 * np.pi, 600)
        xyz = np.vstack([xyz, np.c_[cx + r * np.cos(a), cy + r * np.sin(a), -11.5 + 1.2 * (1 - r)]])
    return xyz + UTM


def _tiles_detector(points):
    """A detector per tile: one box per mound above the seabed (grid cells of 3 m with a high point)."""
    top = points[points[:, 2] > -10.8]
    if not len(top):
        return [], {}
    keys = np.floor(top[:, :2] / 3.0).astype(np.int64)
    out = []
    for k in np.unique(keys, axis=0):
        p = top[(keys == k).all(1)]
        c = p.mean(0)
        out.append({"cls": "reef_cone", "box": [float(c[0]), float(c[1]), float(c[2]), 1.0, 1.0, 1.0, 0.0],
                    "score": float(len(p))})
    return out, {"n": len(points)}


# ------------------------------------------------------------------------------------------ fliers
def test_find_fliers_on_occupied_cells():
    xyz = np.vstack([blobs(), UTM + [1e5, 20.0, -11.0], UTM + [-300.0, 5.0, -11.0], UTM + [-301.0, 6.0, -11.0]])
    cells = CellStats.of(xyz, 40.0)
    assert len(cells.keys) <= 8  # occupied cells only, whatever the 100 km box
    flier = find_fliers(cells)
    assert cells.select(flier).n_points == 3
    assert np.flatnonzero(cells.select(flier).contains(xyz)).tolist() == [len(xyz) - 3, len(xyz) - 2, len(xyz) - 1]
    # a second survey patch of real size far away is not a flier, however far
    far_patch = blobs(1) + [5e3, 0.0, 0.0]
    assert not find_fliers(CellStats.of(np.vstack([blobs(), far_patch]), 40.0)).any()
    # chunks give the same cells
    a = CellStats.of(xyz[:20000], 40.0).merge(CellStats.of(xyz[20000:], 40.0))
    assert np.array_equal(a.keys, cells.keys) and np.array_equal(a.count, cells.count)


@pytest.mark.parametrize("far_m", [1e5, 1e4])
def test_a_far_sounding_changes_nothing_in_bounded_time_and_memory(far_m, caplog):
    xyz = blobs()
    ref, ref_info = detect_survey(xyz, _tiles_detector, 40.0, 3.0, source="alone")
    flier = UTM + [far_m, 17.0, -11.2]
    both = np.vstack([xyz[:20000], flier, xyz[20000:]])
    tracemalloc.start()
    t = time.perf_counter()
    with caplog.at_level(logging.WARNING, logger="sonardet.survey"):
        dets, info = detect_survey(both, _tiles_detector, 40.0, 3.0, source="survey.xyz")
    seconds = time.perf_counter() - t
    peak = tracemalloc.get_traced_memory()[1]
    tracemalloc.stop()
    assert dets == ref and info["n_tiles"] == ref_info["n_tiles"] == 1
    assert info["fliers"]["n_points"] == 1 and info["fliers"]["points"] == [flier.tolist()]
    assert "survey.xyz: 1 isolated sounding(s) more than 100 m from the rest of the data" in caplog.text
    assert f"{flier[0]:.3f}" in caplog.text and "dropped" in caplog.text
    # Bounded: a few copies of the 42k points (about 1 MB each), not a grid over the box; seconds, not minutes.
    assert peak < 30e6 and seconds < 60


def test_keep_fliers_gives_them_tiles_of_their_own():
    xyz = np.vstack([blobs(), UTM + [1e5, 17.0, -11.2]])
    layout = survey_layout(xyz, 40.0, 3.0, keep_fliers=True)
    assert layout.keep is None and layout.fliers.kept
    # the 100 km box is 2500 x 1 tiles; the plan holds those near the survey and near the flier only
    assert layout.tiles[0].nx == 2500 and len(layout.tiles) <= 4
    dets, info = detect_survey(xyz, _tiles_detector, 40.0, 3.0, keep_fliers=True)
    ref, _ = detect_survey(blobs(), _tiles_detector, 40.0, 3.0)
    # two tiles hold the survey (its far edge lies in the next tile's padding), one the flier
    assert info["n_tiles"] == 3 and sorted(d["box"] for d in dets) == sorted(d["box"] for d in ref)


def test_split_survey_drops_and_reports_fliers(tmp_path):
    from sonardet.survey import read_tile_index, split_survey

    path = tmp_path / "s.xyz"
    write_points(path, PointCloud(np.vstack([blobs()[:5000], UTM + [1e5, 17.0, -11.2]])))
    doc = split_survey(path, tmp_path / "tiles", tmp_path / "i.json", survey="s", tile_m=40.0, chunk_points=1000)
    assert doc["fliers"]["n_points"] == 1 and not doc["fliers"]["kept"] and doc["n_points_used"] == 5000
    assert len(doc["tiles"]) == 1 and doc["bounds"][2] - doc["bounds"][0] < 41
    assert read_tile_index(tmp_path / "i.json")[0]["fliers"] == doc["fliers"]
    kept = split_survey(path, tmp_path / "t2", tmp_path / "i2.json", survey="s", tile_m=40.0, keep_fliers=True)
    assert kept["fliers"]["kept"] and kept["n_points_used"] == 5001 and len(kept["tiles"]) <= 4
    assert kept["tiles"][-1]["id"] == "t2499_000" and kept["tiles"][-1]["n_points"] == 1


# -------------------------------------------------------------------------------------------- CLI
@pytest.fixture
def cli_setup(tmp_path):
    cfg = tmp_path / "config.yaml"
    cfg.write_text(f"plugins: [{PLUGIN}]\nmethods:\n  centroid: {{min_height_m: 0.3}}\n")
    survey = tmp_path / "survey.xyz"
    write_points(survey, PointCloud(np.vstack([blobs(), UTM + [1e5, 17.0, -11.2]])))
    return cfg, survey


def _detect_args(cfg, survey, out, *extra):
    return ["detect", "--method", "centroid", "--config", str(cfg), "--input", str(survey), "--out", str(out),
            "--results", str(cfg.parent / "no_results"), *extra]


def test_cli_refuses_an_unwritable_output_before_detecting(cli_setup, capsys):
    cfg, survey = cli_setup
    out = cfg.parent / "det.json"
    blocker = cfg.parent / "a_file"
    blocker.write_text("x")
    rc = main(_detect_args(cfg, survey, out, "--csv", str(blocker / "det.csv"), "--geojson",
                           str(cfg.parent / "det.geojson")))
    err = capsys.readouterr().err
    assert rc == 2 and f"{blocker / 'det.csv'}: cannot be written" in err and ".staging" not in err
    assert not out.exists() and not (cfg.parent / "det.geojson").exists()


def test_cli_writes_every_output_and_drops_the_flier(cli_setup, capsys, caplog):
    cfg, survey = cli_setup
    out = cfg.parent / "det.json"
    with caplog.at_level(logging.WARNING):
        rc = main(_detect_args(cfg, survey, out, "--csv", str(cfg.parent / "det.csv")))
    assert rc == 0 and read_detections(out)["scene"] == "det" and (cfg.parent / "det.csv").exists()
    assert "1 isolated sounding(s)" in caplog.text and "41801 points, 1 tile(s), 1 detection" in capsys.readouterr().out
    assert not [p for p in cfg.parent.iterdir() if p.name.startswith(".staging")]
    # kept, the flier stretches the bounds and gets tiles of its own (3 tiles in all with 40 m tiles,
    # the plan this check was written for)
    rc = main(_detect_args(cfg, survey, cfg.parent / "kept.json", "--keep-fliers", "--tile-m", "40"))
    assert rc == 0 and "41801 points, 3 tile(s), 1 detection" in capsys.readouterr().out
