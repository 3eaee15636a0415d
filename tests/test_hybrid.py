"""Hybrid scenes: transducer track from slant ranges, object implanting along real rays, the real line."""

from __future__ import annotations

import gzip
import json

import numpy as np
import pytest
import trimesh

from conftest import REAL_DIR, needs_real
from sonardet.config import validate_config
from sonardet.sim.hybrid import (
    RealSurvey,
    estimate_sensor_positions,
    implant,
    read_real_survey,
    read_soundings,
    seabed_grid,
    simulate_hybrid_scene,
)
from sonardet.io.scenes import write_scene
from sonardet.sim.mbes import RaycastTarget, SensorConfig, scan, straight_line
from test_scene import _objects


def _flat_line(z_seabed=-10.0, sensor_z=0.0, length=12.0, n_beams=128, seed=0):
    """A noiseless survey line over a flat seabed with its true transducer positions."""
    sensor = SensorConfig.from_dict({"n_beams": n_beams, "swath_deg": 120, "range_sigma_m": 0.0,
                                     "dropout_prob": 0.0, "grazing_dropout_prob": 0.0})
    traj = straight_line((0.0, 15.0), (length, 15.0), sensor_z, sensor, sensor_z - z_seabed)
    plane = trimesh.creation.box(extents=(80, 80, 1.0))
    plane.apply_translation((10, 15, z_seabed - 0.5))
    snd = scan(RaycastTarget([(plane.vertices, plane.faces)]), traj, sensor, np.random.default_rng(seed))
    return snd, traj


def _survey(snd, traj) -> RealSurvey:
    pings = np.arange(len(traj))
    return RealSurvey(snd.xyz.copy(), snd.ping.astype(np.int64), snd.beam.astype(np.int64),
                      traj.position.copy(), pings, np.zeros(3), np.zeros(len(pings)), "synthetic", "", "")


def test_transducer_track_from_slant_ranges():
    snd, traj = _flat_line()
    true = traj.position[snd.ping]
    rng = np.random.default_rng(1)
    r = np.linalg.norm(snd.xyz - true, axis=1) + rng.normal(0, 0.003, len(snd.xyz))
    pings, pos, rms = estimate_sensor_positions(snd.xyz, snd.ping.astype(np.int64), r)
    assert np.array_equal(pings, np.unique(snd.ping))
    err = np.linalg.norm(pos - traj.position[pings], axis=1)
    assert np.percentile(err, 95) < 0.02, err.max()
    assert np.median(rms) == pytest.approx(0.003, rel=0.3)


def test_implanted_box_replaces_occluded_soundings_and_casts_a_shadow():
    snd, traj = _flat_line()
    survey = _survey(snd, traj)
    # A 1 m cube standing on the seabed 4 m to starboard of the track (track along +x at y = 15).
    cube = trimesh.creation.box(extents=(1.0, 1.0, 1.0))
    cube.apply_translation((6.0, 11.0, -9.5))
    xyz, label = implant(survey, [(cube.vertices, cube.faces)], 0.0, np.random.default_rng(0))
    hit = label == 0
    assert hit.sum() > 50
    # Every moved sounding lies on the cube's surface, every other one is untouched.
    cheb = np.abs(xyz[hit] - [6.0, 11.0, -9.5]).max(axis=1)  # 0.5 on the cube's surface
    assert np.abs(cheb - 0.5).max() < 1e-3
    assert np.array_equal(xyz[~hit], survey.xyz[~hit])
    # The top face is seen, no seabed sounding is left under the cube, and the seabed on the far side
    # (away from the track) is in shadow, the near side is not.
    assert np.sum(xyz[hit, 2] > -9.0 - 1e-3) > 10
    seabed = xyz[~hit]
    under = (np.abs(seabed[:, 0] - 6.0) < 0.5) & (np.abs(seabed[:, 1] - 11.0) < 0.5)
    assert not under.any()
    band = np.abs(seabed[:, 0] - 6.0) < 0.4
    far = band & (seabed[:, 1] < 10.5) & (seabed[:, 1] > 10.2)
    near = band & (seabed[:, 1] > 11.5) & (seabed[:, 1] < 11.8)
    assert far.sum() == 0 and near.sum() > 10


def test_implant_noise_is_along_the_ray():
    snd, traj = _flat_line()
    survey = _survey(snd, traj)
    cube = trimesh.creation.box(extents=(1.0, 1.0, 1.0))
    cube.apply_translation((6.0, 15.0, -9.5))  # under the track: top face seen near nadir
    xyz, label = implant(survey, [(cube.vertices, cube.faces)], 0.01, np.random.default_rng(0))
    top = (label == 0) & (np.abs(xyz[:, 2] + 9.0) < 0.05)
    assert top.sum() > 60
    assert np.std(xyz[top, 2]) == pytest.approx(0.01, rel=0.25)


def _soundings_csv(path, rows: str):
    with gzip.open(path, "wt") as fh:
        fh.write(rows)


def test_soundings_errors_name_file_column_and_row(tmp_path):
    p = tmp_path / "s.csv.gz"
    _soundings_csv(p, "ping,x,y,z\n0,1,2,3\n")
    with pytest.raises(ValueError, match=r"s\.csv\.gz: column\(s\) range_m missing"):
        read_soundings(p)
    rows = "ping,range_m,x,y,z\n" + "".join(f"{i // 10},10,{i},5,-10\n" for i in range(200))
    rows = rows.replace("\n7,10,77,5,-10\n", "\n7,10,77,nan,-10\n")
    _soundings_csv(p, rows)
    with pytest.raises(ValueError, match=r"column 'y' is not a finite number on data row 78 \(line 79"):
        read_soundings(p)
    with pytest.raises(FileNotFoundError, match="hybrid_test.soundings"):
        read_soundings(tmp_path / "missing.csv")


def test_seabed_grid_covers_the_soundings_only():
    rng = np.random.default_rng(0)
    xy = rng.uniform(0, 10, (20000, 2))
    xy = xy[xy[:, 0] + xy[:, 1] < 10]  # a triangle: the other half of the square is not covered
    z = -10 + 0.1 * xy[:, 0]
    hf, covered = seabed_grid(np.column_stack([xy, z]), 0.5)
    assert 0.4 < covered.mean() < 0.6
    assert np.allclose(hf.height_at(np.array([2.0]), np.array([2.0])), -9.8, atol=0.03)


@pytest.fixture(scope="module")
def real_survey():
    if REAL_DIR is None:
        pytest.skip("real survey data not available")
    return read_real_survey(REAL_DIR / "r2sonic_sfbay_soundings.csv.gz", "EPSG:32610")


@needs_real
def test_real_line_track(real_survey):
    s = real_survey
    assert len(s.xyz) == 236287 and len(s.pings) == 923
    assert s.xyz.dtype == np.float64 and s.origin.tolist() == [554808.0, 4178987.0, 0.0]
    # The README: transducer near z = 0 (heave +-0.075 m), seabed ~10.5 m below, 3.5 cm per ping.
    assert np.median(s.fit_rms_m) < 0.005
    assert np.all(np.abs(s.sensor[:, 2]) < 0.2)
    step = np.hypot(*np.diff(s.sensor[:, :2], axis=0).T)
    assert 0.02 < np.median(step) < 0.05


@needs_real
def test_real_hybrid_scene(real_survey, tmp_path):
    cfg = validate_config({"seed": 3, "objects": {"sections": 32},
                           "scenes": {"extent_m": [20, 20], "n_objects": [8, 10], "physics": {"max_time_s": 5.0}},
                           "hybrid_test": {"enabled": True, "n_scenes": 1}})
    objs = _objects(cfg)
    sc = simulate_hybrid_scene("s0000", cfg, objs, real_survey)
    meta = sc.meta
    assert len(meta["objects"]) >= 10
    assert meta["hybrid"]["n_replaced"] == int((sc.label >= 0).sum()) > 1000
    # No sounding is lost or invented: the real line's soundings, some moved onto objects.
    assert len(sc.xyz) == len(real_survey.xyz)
    assert np.array_equal(sc.xyz[sc.label < 0], real_survey.xyz[sc.label < 0])
    hf, covered = seabed_grid(real_survey.xyz, cfg["hybrid_test"]["cell_m"])
    for o in meta["objects"]:
        pts = sc.xyz[sc.label == o["id"]]
        assert len(pts) == o["n_points"]
        t = np.array(o["pose"]["t"])
        if o["layer"] == 0 and o["arrangement"] != "pile":
            # Settled on the real seabed: the object's lowest sounding is near the seabed under it.
            ground = float(hf.height_at(np.array([t[0]]), np.array([t[1]]))[0])
            assert pts[:, 2].min() - ground < 0.5, o
    # Same config and survey: the same bytes.
    again = simulate_hybrid_scene("s0000", cfg, objs, real_survey)
    write_scene(sc, tmp_path / "a.npz", tmp_path / "a.json")
    write_scene(again, tmp_path / "b.npz", tmp_path / "b.json")
    assert (tmp_path / "a.npz").read_bytes() == (tmp_path / "b.npz").read_bytes()
    ja = json.loads((tmp_path / "a.json").read_text())
    assert ja["hybrid"]["origin"] == [554808.0, 4178987.0, 0.0] and ja["hybrid"]["crs"] == "EPSG:32610"
