"""Tiled detection: tile plans, per-tile point selection, merging across seams, and equivalence of a
tiled run with one run over the whole survey.

Hard cases named in the tests: UTM offsets, an overlap smaller than the largest object, a survey
extent that is not a multiple of the tile size, an object straddling a seam (reported by two tiles),
two distinct objects 1 m apart on either side of a seam, fits centred a millimetre to each side of a
seam, an object whose box centre lies outside the points' bounds, empty tiles.
"""

from __future__ import annotations

import itertools
import logging

import numpy as np
import pytest
from conftest import match_by_centre

from sonardet.survey.tiling import detect_tiled, merge_tile_detections, plan_tiles, tile_points

UTM = np.array([5.5e5, 4.18e6, 0.0])


def _area(r) -> float:
    return max(0.0, r[2] - r[0]) * max(0.0, r[3] - r[1])


def _intersection(a, b) -> float:
    return _area((max(a[0], b[0]), max(a[1], b[1]), min(a[2], b[2]), min(a[3], b[3])))


# ----------------------------------------------------------------------------------------- plan_tiles
@pytest.mark.parametrize("offset", [np.zeros(3), UTM], ids=["local", "utm"])
@pytest.mark.parametrize("extent,tile_m,shape", [((120.0, 120.0), 40.0, (3, 3)), ((101.3, 37.9), 40.0, (3, 1)),
                                                 ((12.0, 80.01), 40.0, (1, 3)), ((5.0, 5.0), 40.0, (1, 1))])
def test_cores_partition_the_bounds(offset, extent, tile_m, shape):
    b = (offset[0], offset[1], offset[0] + extent[0], offset[1] + extent[1])
    tiles = plan_tiles(b, tile_m, 3.0)
    assert len(tiles) == shape[0] * shape[1]
    assert {(t.nx, t.ny) for t in tiles} == {shape}
    assert tiles[0].id == "t000_000" and tiles[-1].id == f"t{shape[0] - 1:03d}_{shape[1] - 1:03d}"
    # Areas sum to the bounds' area; no two cores overlap; every core is at most tile_m wide.
    assert sum(_area(t.core) for t in tiles) == pytest.approx(_area(b), rel=1e-12)
    for s, t in itertools.combinations(tiles, 2):
        assert _intersection(s.core, t.core) == 0.0
    for t in tiles:
        assert t.core[2] - t.core[0] <= tile_m + 1e-9 and t.core[3] - t.core[1] <= tile_m + 1e-9
        assert np.allclose(np.subtract(t.padded, t.core), [-3.0, -3.0, 3.0, 3.0], rtol=0, atol=1e-9)
    # Neighbours share their borders bit for bit; the outer borders are the bounds exactly.
    by = {(t.ix, t.iy): t for t in tiles}
    for (ix, iy), t in by.items():
        if (ix + 1, iy) in by:
            assert t.core[2] == by[ix + 1, iy].core[0]
        if (ix, iy + 1) in by:
            assert t.core[3] == by[ix, iy + 1].core[1]
    assert min(t.core[0] for t in tiles) == b[0] and max(t.core[2] for t in tiles) == b[2]
    assert min(t.core[1] for t in tiles) == b[1] and max(t.core[3] for t in tiles) == b[3]
    # Every position of the bounds (borders and corners included) lies in exactly one core.
    rng = np.random.default_rng(0)
    x = np.r_[rng.uniform(b[0], b[2], 2000), [t.core[0] for t in tiles], [t.core[2] for t in tiles], b[0], b[2]]
    y = np.r_[rng.uniform(b[1], b[3], 2000), [t.core[1] for t in tiles], [t.core[3] for t in tiles], b[1], b[3]]
    counts = sum(t.in_core(x, y).astype(int) for t in tiles)
    assert np.all(counts == 1)


def test_equal_cores_and_no_sliver_tile():
    """101 m at 40 m: three cores of 33.67 m, not 40 + 40 + 21."""
    tiles = plan_tiles((0.0, 0.0, 101.0, 10.0), 40.0, 3.0)
    widths = [t.core[2] - t.core[0] for t in tiles]
    assert len(tiles) == 3 and np.allclose(widths, 101.0 / 3)


def test_too_small_overlap_raises():
    with pytest.raises(ValueError, match="overlap_m"):
        plan_tiles((0.0, 0.0, 100.0, 100.0), 40.0, 2.0, min_overlap_m=2.7)
    assert len(plan_tiles((0.0, 0.0, 100.0, 100.0), 40.0, 2.7, min_overlap_m=2.7)) == 9
    for bad in (dict(tile_m=0.0), dict(tile_m=np.nan), dict(overlap_m=-1.0)):
        with pytest.raises(ValueError):
            plan_tiles((0.0, 0.0, 10.0, 10.0), **{"tile_m": 40.0, "overlap_m": 3.0, **bad})
    for b in ((0.0, 0.0, -1.0, 5.0), (0.0, np.nan, 1.0, 1.0), (0.0, 0.0, 1.0)):
        with pytest.raises(ValueError, match="bounds_xy"):
            plan_tiles(b, 40.0, 3.0)


def test_degenerate_bounds_give_one_tile():
    """All points on one line (zero extent in y) or one point: one tile, nothing divided by zero."""
    assert len(plan_tiles((0.0, 5.0, 30.0, 5.0), 40.0, 3.0)) == 1
    t = plan_tiles((UTM[0], UTM[1], UTM[0], UTM[1]), 40.0, 3.0)
    assert len(t) == 1 and t[0].in_core(UTM[0], UTM[1])


@pytest.mark.parametrize("offset", [np.zeros(3), UTM], ids=["local", "utm"])
def test_tile_points_selects_the_padded_rectangle(offset):
    rng = np.random.default_rng(1)
    xyz = rng.uniform([0, 0, -12], [90, 50, -10], (20000, 3)) + offset
    tiles = plan_tiles((*xyz[:, :2].min(0), *xyz[:, :2].max(0)), 40.0, 3.0)
    seen = np.zeros(len(xyz), dtype=int)
    for t in tiles:
        idx = tile_points(xyz, t)
        assert np.all(np.diff(idx) > 0)
        p = xyz[idx]
        assert np.all((p[:, 0] >= t.padded[0]) & (p[:, 0] <= t.padded[2]))
        assert np.all((p[:, 1] >= t.padded[1]) & (p[:, 1] <= t.padded[3]))
        seen[idx] += 1
        core = t.in_core(xyz[:, 0], xyz[:, 1])
        assert np.all(np.isin(np.flatnonzero(core), idx))  # the core's points are all in the padded set
    assert seen.min() >= 1
    # A point exactly on the padded border is included.
    t = tiles[0]
    edge = np.array([[t.padded[2], t.padded[3], -11.0]])
    assert len(tile_points(edge, t)) == 1


# ------------------------------------------------------------------------------------------- merging
def _det(cls, x, y, score, z=-11.0):
    return {"cls": cls, "box": [x, y, z, 2.0, 2.0, 1.0, 0.0], "score": score, "extras": {}}


@pytest.fixture
def two_tiles():
    """Two tiles side by side, seam at x = 5.5e5 + 40 (UTM-sized coordinates)."""
    x0, y0 = UTM[:2]
    return plan_tiles((x0, y0, x0 + 80.0, y0 + 40.0), 40.0, 3.0)


def test_object_straddling_a_seam_is_reported_once(two_tiles):
    a, b = two_tiles
    seam = a.core[2]
    y = UTM[1] + 20.0
    # Tile a sees the whole object (its padded area reaches 3 m past the seam) and so does b; both fit it
    # with the centre 0.2 m past the seam, in b's core. a also reports a partial fit elsewhere.
    per_tile = {a.id: [_det("reef_ring", seam + 0.2, y, 0.9), _det("reef_ring", seam - 0.6, y, 0.4)],
                b.id: [_det("reef_ring", seam + 0.2001, y, 0.88)]}
    out = merge_tile_detections(per_tile, two_tiles)
    assert len(out) == 2  # the partial fit of a lies in a's core: the safety net alone decides it
    out = merge_tile_detections({a.id: per_tile[a.id][:1], b.id: per_tile[b.id]}, two_tiles)
    assert len(out) == 1 and out[0]["score"] == 0.88  # reported by b, whose core holds the centre
    assert out[0]["box"][0] == seam + 0.2001


def test_fits_a_millimetre_either_side_of_the_seam_are_one_object(two_tiles):
    a, b = two_tiles
    seam, y = a.core[2], UTM[1] + 20.0
    per_tile = {a.id: [_det("tetrapod_s", seam - 0.0005, y, 0.7)], b.id: [_det("tetrapod_b", seam + 0.0005, y, 0.8)]}
    out = merge_tile_detections(per_tile, two_tiles)
    assert len(out) == 1 and out[0]["cls"] == "tetrapod_b"  # any class: the better fit stays
    # Equal scores: the tile listed first wins (deterministic).
    per_tile[b.id][0]["score"] = 0.7
    assert merge_tile_detections(per_tile, two_tiles)[0]["cls"] == "tetrapod_s"


def test_two_objects_1m_apart_across_a_seam_both_survive(two_tiles):
    a, b = two_tiles
    seam, y = a.core[2], UTM[1] + 20.0
    left, right = _det("reef_cone", seam - 0.5, y, 0.9), _det("reef_cone", seam + 0.5, y, 0.85)
    # Each tile sees both (the overlap is 3 m) and reports both; each keeps the one in its core.
    per_tile = {a.id: [left, dict(right, score=0.6)], b.id: [dict(left, score=0.7), right]}
    out = merge_tile_detections(per_tile, two_tiles)
    assert [d["box"][0] for d in out] == [seam - 0.5, seam + 0.5]
    assert [d["score"] for d in out] == [0.9, 0.85]


def test_close_detections_of_one_tile_are_left_alone(two_tiles):
    """The safety net works across tiles only: a pile the detector split into two stays two."""
    a, _ = two_tiles
    x, y = UTM[0] + 10.0, UTM[1] + 10.0
    per_tile = {a.id: [_det("tetrapod_s", x, y, 0.9), _det("tetrapod_s", x + 0.3, y, 0.8)]}
    assert len(merge_tile_detections(per_tile, two_tiles)) == 2
    # Stacked objects of two tiles (same x, y; 1 m apart in z) are not duplicates either.
    seam = a.core[2]
    per_tile = {a.id: [_det("tetrapod_s", seam - 0.001, y, 0.9)],
                two_tiles[1].id: [_det("tetrapod_s", seam + 0.001, y, 0.8, z=-10.0)]}
    assert len(merge_tile_detections(per_tile, two_tiles)) == 2


def test_centre_outside_the_bounds_is_kept_by_the_border_tile(two_tiles):
    """A partly scanned object at the survey edge can have its box centre outside the points' bounds."""
    a, b = two_tiles
    per_tile = {a.id: [_det("reef_ring", a.core[0] - 0.4, a.core[1] - 0.3, 0.6)],
                b.id: [_det("reef_ring", b.core[2] + 0.5, b.core[3] + 0.2, 0.6)]}
    assert len(merge_tile_detections(per_tile, two_tiles)) == 2
    # ... but only by the tile next to it.
    assert merge_tile_detections({b.id: per_tile[a.id]}, two_tiles) == []


def test_unknown_tile_id_raises(two_tiles):
    with pytest.raises(ValueError, match="unknown tile"):
        merge_tile_detections({"t009_009": []}, two_tiles)


# -------------------------------------------------------------------------------------- detect_tiled
def test_detect_tiled_feeds_each_tile_its_points_and_skips_empty_tiles(caplog):
    rng = np.random.default_rng(2)
    # Two patches 100 m apart: the tiles between them hold no points.
    xyz = np.vstack([rng.uniform([0, 0, -12], [30, 30, -11], (3000, 3)),
                     rng.uniform([130, 0, -12], [160, 30, -11], (3000, 3))]) + UTM
    calls = []

    def fake_detect(points):
        calls.append(points)
        # One "object" at the patch's mean; plus the number of points, as stats.
        c = points.mean(0)
        return [_det("reef_cone", c[0], c[1], float(len(points)), z=c[2])], {"n": len(points)}

    tiles = plan_tiles((*xyz[:, :2].min(0), *xyz[:, :2].max(0)), 40.0, 3.0)
    with caplog.at_level(logging.INFO, logger="sonardet.survey.tiling"):
        dets, rows = detect_tiled(xyz, fake_detect, 40.0, 3.0)
    # Only the tiles near data are planned: the two between the patches are not even listed.
    assert len(tiles) == 4 and [r["tile"] for r in rows] == ["t000_000", "t003_000"]
    assert [r["skipped"] for r in rows] == [False, False]
    assert len(calls) == 2
    for r, t in zip(rows, (tiles[0], tiles[3])):
        idx = tile_points(xyz, t)
        assert r["n_points"] == len(idx) and r["stats"] == {"n": len(idx)}
    # Each call got its tile's points in the input order (the detector may depend on the order).
    assert np.array_equal(calls[0], xyz[tile_points(xyz, tiles[0])])
    assert len(dets) == 2
    assert "tile 1/2 t000_000" in caplog.text and "tile 2/2 t003_000" in caplog.text
    # An empty planned tile (near data, its padded area without points) is skipped and logged.
    t = np.linspace(0.0, 30.0, 3000)
    diagonal = np.c_[t, t, np.full_like(t, -11.0)] + UTM  # t002_000 meets the data's cells but holds no point
    caplog.clear()
    with caplog.at_level(logging.INFO, logger="sonardet.survey.tiling"):
        _, rows = detect_tiled(diagonal, fake_detect, 10.0, 3.0)
    skipped = [r["tile"] for r in rows if r["skipped"]]
    assert skipped and f"{skipped[0]}: no points, skipped" in caplog.text


def test_detect_tiled_plain_list_and_empty_input():
    xyz = np.random.default_rng(3).uniform([0, 0, -12], [10, 10, -11], (100, 3))
    dets, rows = detect_tiled(xyz, lambda p: [_det("reef_cone", 5.0, 5.0, 1.0)], 40.0, 3.0, progress=False)
    assert len(dets) == 1 and rows[0]["stats"] is None
    assert detect_tiled(np.zeros((0, 3)), lambda p: [], 40.0, 3.0) == ([], [])
    with pytest.raises(ValueError, match=r"\(N,3\)"):
        detect_tiled(np.zeros((5, 2)), lambda p: [], 40.0, 3.0)
    with pytest.raises(ValueError, match="overlap_m"):
        detect_tiled(xyz, lambda p: [], 40.0, 1.0, min_overlap_m=2.7)


# ------------------------------------------------------------------ equivalence with one big tile
TEMPLATE_CFG = {"yaw_deg": [0, 60], "directions": ["x", "y"], "offsets_m": [-7.5, 0.0, 7.5], "altitude_m": 11.5}
EXTENT_M = 120.0


@pytest.fixture(scope="module")
def models(built_objects, default_config):
    """ObjectInfo and (reduced) template scans of the four classes."""
    from sonardet.objects import object_info
    from sonardet.sim.mbes import SensorConfig
    from sonardet.sim.templates import scan_templates

    dens = default_config["objects"]["density_kg_m3"]
    objects = {c: object_info(m, dens) for c, m in built_objects.items()}
    sensor = SensorConfig.from_dict(default_config["sensor"])
    templates = {c: scan_templates(c, o.mesh.vertices, o.mesh.faces, o.symmetry_order, TEMPLATE_CFG, sensor,
                                   np.random.default_rng(1)) for c, o in objects.items()}
    return objects, templates, sensor


def _survey(objects, sensor, extent_m: float):
    """A 120 m x 120 m survey cast the way `sim.scene` casts one (fBm seabed heightfield + posed object
    meshes, parallel MBES lines, Embree ray casting with the sensor's noise and dropouts), without the
    layout and physics stages: objects stand upright on the seabed where the test puts them, most of
    them on the seams (x or y = 40, 80 m) of a 40 m tile plan, two at seam crossings, two touching cones
    across a seam, and some inside tiles and at the survey edge. Returns (points (N,3), truth [(cls, box)])."""
    from sonardet.geometry import quat_from_yaw, quat_to_matrix
    from sonardet.objects import canonical_box
    from sonardet.sim.mbes import RaycastTarget, scan, survey_lines
    from sonardet.sim.seabed import make_seabed

    rng = np.random.default_rng(7)
    hf = make_seabed((extent_m, extent_m), cell_m=0.2, mean_depth_m=-11.5, slope_deg=1.5, amplitude_m=0.1, rng=rng)
    classes = ["reef_ring", "reef_cone", "tetrapod_b", "tetrapod_s"]
    cls_of = itertools.cycle(classes)
    layout = []
    for seam in (40.0, 80.0):
        for along in (12.0, 60.0, 100.0):
            layout.append((next(cls_of), seam - rng.uniform(0.0, 0.3), along - 6.0))  # on x seams
            layout.append((next(cls_of), along + 6.0, seam + rng.uniform(0.0, 0.3)))  # on y seams
    layout += [(next(cls_of), 40.05, 39.9), (next(cls_of), 79.9, 80.1)]  # seam crossings
    layout += [("reef_cone", 38.99, 30.0), ("reef_cone", 41.01, 30.0)]  # bases 2 cm apart across x = 40
    layout += [(next(cls_of), x, y) for x, y in ((20, 20), (60, 25), (100, 45), (25, 95), (65, 70), (105, 110),
                                                 (2.0, 60.0), (118.2, 20.0))]
    meshes, truth = [(hf.vertices(), hf.faces())], []
    for cls, x, y in layout:
        o = objects[cls]
        q = quat_from_yaw(rng.uniform(0, 2 * np.pi))
        v = np.asarray(o.mesh.vertices) @ quat_to_matrix(q).T
        base = v[:, 2] < v[:, 2].min() + 0.05
        t = np.array([x, y, float(np.max(hf.height_at(v[base, 0] + x, v[base, 1] + y))) - v[:, 2].min()])
        meshes.append((v + t, np.asarray(o.mesh.faces)))
        truth.append((cls, canonical_box(o.mesh.vertices, t, q, o.symmetry_order)))
    traj = survey_lines((0, extent_m, 0, extent_m), "x", 0.0, 11.5, 0.3, sensor, run_in_m=1.0)
    xyz = scan(RaycastTarget(meshes), traj, sensor, np.random.default_rng(5)).xyz
    inside = np.all((xyz[:, :2] >= 0) & (xyz[:, :2] <= extent_m), axis=1)
    return xyz[inside], truth


@pytest.fixture(scope="module")
def whole_and_tiled(models):
    """The 120 m survey detected once as a whole (local coordinates) and once in 3 x 3 tiles of 40 m
    with 3 m overlap (UTM coordinates, shifted back): (truth, whole, tiled, per-tile rows)."""
    from sonardet.detect.model_based import ModelBasedDetector

    objects, templates, sensor = models
    xyz, truth = _survey(objects, sensor, EXTENT_M)
    detector = ModelBasedDetector(templates, objects)
    whole, _ = detector(xyz)
    tiled, rows = detect_tiled(xyz + UTM, detector, 40.0, 3.0, progress=False, min_overlap_m=2.7)
    for d in tiled:
        d["box"][:3] = list(np.asarray(d["box"][:3]) - UTM)
    return truth, whole, tiled, rows


def _accepted(dets):
    return [d for d in dets if d["extras"]["accepted"]]


#: Why tiled and whole runs differ at all (measured on this survey when the tiling was written): the
#: detector anchors its grids (seabed DTM cells in ground.grid_ground, the 0.1 m height
#: raster of the proposals in ours._State, the residual clusters in proposals.clusters) at the minimum
#: x, y of the points it is given, so a tile sees them shifted by a fraction of a cell. Most fits do not
#: care (centres within 2 mm), but the ring at the seam crossing (40.05, 39.9) settles 7.1 cm apart:
#: the whole run is the odd one out (7 cm from the truth), and the whole run with a 3 cm strip cut off
#: its edge (grids shifted, nothing tiled) lands where the tiled run does. With those three grids
#: anchored at multiples of their cell (in the detector's whole-metre local frame) the tiled run gives
#: the whole run's detections exactly (all 25, centres and scores equal to 1e-5).
@pytest.mark.slow
def test_tiled_run_finds_the_objects_of_one_big_tile(whole_and_tiled):
    """A 120 m x 120 m survey (3 million soundings) in 3 x 3 tiles of 40 m with 3 m overlap, in UTM
    coordinates, gives the accepted detections of one run over the whole survey in local coordinates:
    same number, same classes, one-to-one matched centres, each object reported once.

    Checks the seams (each object once) and the score ordering of accepted against non-accepted
    hypotheses; `test_tiled_run_equals_one_big_tile` checks the 0.05 m equivalence.
    """
    from sonardet.detect.model_based import DEFAULTS

    truth, whole, tiled, rows = whole_and_tiled
    assert len(rows) == 9 and not any(r["skipped"] for r in rows)
    acc_w, acc_t = _accepted(whole), _accepted(tiled)
    # The scene is detectable (else the comparison says nothing): every object found by the whole run.
    assert len(acc_w) == len(truth)
    assert all(d < 0.1 and a["cls"] == t["cls"] for a, t, d in
               match_by_centre(acc_w, [{"cls": c, "box": list(b)} for c, b in truth]))
    assert len(acc_t) == len(acc_w)
    pairs = match_by_centre(acc_w, acc_t)
    assert all(a["cls"] == b["cls"] for a, b, _ in pairs)
    worst = max(d for _, _, d in pairs)
    assert worst < 0.1, f"tiled vs whole: a centre moved {worst:.3f} m"
    # Seam objects are reported once: no two accepted tiled detections closer than an object radius.
    c = np.array([d["box"][:2] for d in acc_t])
    dist = np.hypot(*(c[:, None] - c[None]).transpose(2, 0, 1))
    assert dist[np.triu_indices(len(c), 1)].min() > 1.0
    floor = DEFAULTS["rejected_score_factor"]
    for dets in (whole, tiled):
        assert all(d["score"] <= floor for d in dets if not d["extras"]["accepted"])
        assert min(d["score"] for d in _accepted(dets)) > floor


@pytest.mark.slow
def test_tiled_run_equals_one_big_tile(whole_and_tiled):
    """The issue's criterion: the tiled run gives the same detections as one big tile, centres within
    0.05 m. Holds because the detector anchors its grids (seabed, height raster, clusters) at multiples
    of their cell, so a tile sees the same cells as the whole survey (anchored at the crop's corner, a
    ring fit moved 7.1 cm between the two runs)."""
    _, whole, tiled, _ = whole_and_tiled
    assert len(tiled) == len(whole)
    pairs = match_by_centre(whole, tiled)
    assert all(a["cls"] == b["cls"] and d < 0.05 for a, b, d in pairs)
