"""Model-based detector: small synthetic scans built with the project's own sonar model.

Hard cases named in the tests: an object alone, a steep (10 deg) bare seabed, two touching objects,
degenerate ICP input (3 points, collinear, planar, a window of only seabed), UTM offsets, empty and
NaN input, a class without templates, clouds with nothing to fit (one point, one spot, a line, a
noisy plane) and the RANSAC seabed of a strip narrower than its inlier band.
"""

from __future__ import annotations

import contextlib

import numpy as np
import pytest

from sonardet.config import validate_config
from sonardet.detect.model_based import DEFAULTS, DESCRIPTIONS, PAPER, ModelBasedDetector, detect, resolve_params
from sonardet.detect.model_based.proposals import sliding_windows, window_counts
from sonardet.detect.model_based.registration import icp_point_to_point, icp_scene_to_model, SurfaceTarget
from sonardet.geometry import quat_from_yaw, quat_to_matrix
from sonardet.objects import build_object, canonical_box, object_info
from sonardet.sim.mbes import RaycastTarget, SensorConfig, scan, straight_line
from sonardet.sim.templates import scan_templates

CLASSES = ["reef_ring", "reef_cone", "tetrapod_b", "tetrapod_s"]
SEABED_Z = -11.5
TEMPLATE_CFG = {"yaw_deg": [0, 60], "directions": ["x", "y"], "offsets_m": [-7.5, 0.0, 7.5], "altitude_m": 11.5}


@pytest.fixture(scope="module")
def cfg():
    return validate_config({})


@pytest.fixture(scope="module")
def objects(cfg):
    """ObjectInfo of the four default classes, built from the validated default config."""
    out = {}
    for cls in CLASSES:
        m = build_object(cls, cfg["objects"])
        out[cls] = object_info(m, cfg["objects"]["density_kg_m3"])
    return out


@pytest.fixture(scope="module")
def sensor(cfg):
    return SensorConfig.from_dict(cfg["sensor"])


@pytest.fixture(scope="module")
def templates(objects, sensor):
    """Template scans (a reduced set of views, to keep the tests fast) of every class."""
    return {c: scan_templates(c, o.mesh.vertices, o.mesh.faces, o.symmetry_order, TEMPLATE_CFG, sensor,
                              np.random.default_rng(1)) for c, o in objects.items()}


def seabed_mesh(extent_m: float, slope_deg: float = 0.0):
    """A plane z = SEABED_Z + tan(slope) x over [-2, extent+2]^2 (vertices, faces)."""
    lo, hi = -2.0, extent_m + 2.0
    xy = np.array([[lo, lo], [hi, lo], [hi, hi], [lo, hi]])
    z = SEABED_Z + np.tan(np.deg2rad(slope_deg)) * xy[:, 0]
    return np.c_[xy, z], np.array([[0, 1, 2], [0, 2, 3]])


def place(obj, x, y, yaw_rad):
    """Pose (t, q) of an upright object resting on the flat seabed at (x, y) with the given yaw."""
    q = quat_from_yaw(yaw_rad)
    zmin = (np.asarray(obj.mesh.vertices) @ quat_to_matrix(q).T)[:, 2].min()
    return np.array([x, y, SEABED_Z - zmin]), q


def survey(placed, sensor, extent_m=14.0, slope_deg=0.0, seed=0, track_y=None):
    """Points (N,3) of one survey line along x over a seabed with the posed objects [(obj, t, q)]."""
    meshes = [seabed_mesh(extent_m, slope_deg)]
    for obj, t, q in placed:
        meshes.append((np.asarray(obj.mesh.vertices) @ quat_to_matrix(q).T + t, np.asarray(obj.mesh.faces)))
    target = RaycastTarget(meshes)
    ty = 0.5 * extent_m + 4.0 if track_y is None else track_y
    traj = straight_line((-1.0, ty), (extent_m + 1.0, ty), 0.0, sensor, -SEABED_Z)
    xyz = scan(target, traj, sensor, np.random.default_rng(seed)).xyz
    keep = (xyz[:, 0] >= 0) & (xyz[:, 0] <= extent_m) & (xyz[:, 1] >= 0) & (xyz[:, 1] <= extent_m)
    return xyz[keep]


def accepted(dets):
    return [d for d in dets if d["extras"]["accepted"]]


@pytest.mark.parametrize("variant,params", [("ours", {}), ("ours", {"icp_grid_cell_m": 0}), ("paper", {})],
                         ids=["ours", "ours-open3d-icp", "paper"])
@pytest.mark.parametrize("cls,yaw", [("reef_cone", 0.3), ("tetrapod_s", 0.7), ("reef_ring", 0.0), ("tetrapod_b", 1.9)])
def test_object_alone_on_flat_seabed_is_found(objects, templates, sensor, variant, params, cls, yaw):
    """Each class alone, by each variant; `ours` with its ICP on the nearest-sample grids (default) and
    with Open3D's ICP (`icp_grid_cell_m` 0)."""
    obj = objects[cls]
    t, q = place(obj, 7.0, 6.5, yaw)
    xyz = survey([(obj, t, q)], sensor)
    dets, stats = detect(xyz, templates, objects, params, variant=variant)
    assert dets, f"{variant}: nothing found"
    best = dets[0]
    truth = canonical_box(obj.mesh.vertices, t, q, obj.symmetry_order)
    assert best["cls"] == cls
    assert np.linalg.norm(np.asarray(best["box"][:3]) - truth[:3]) < 0.1
    # Every output is finite and the stats account for the work done.
    assert all(np.all(np.isfinite(d["box"])) and np.isfinite(d["score"]) for d in dets)
    assert stats["icp_runs"] > 0 and stats["windows"] >= stats["windows_skipped"]
    assert stats["seconds"]["total"] > 0


@pytest.mark.parametrize("variant", ["ours", "paper"])
def test_sloped_bare_seabed_gives_no_detection(objects, templates, sensor, variant):
    xyz = survey([], sensor, slope_deg=10.0)
    dets, stats = detect(xyz, templates, objects, variant=variant)
    assert dets == []
    assert stats["n_candidate_points"] < 0.01 * stats["n_points"]


def test_flat_bare_seabed_window_gives_no_detection(objects, templates, sensor):
    """A window of only seabed (the paper variant registers every window when skipping is off)."""
    xyz = survey([], sensor, extent_m=8.0)
    dets, stats = detect(xyz, templates, objects, {"skip_empty_windows": False, "ground_min_height_m": -1.0},
                         variant="paper")
    assert dets == []
    assert stats["windows_skipped"] == 0 and stats["icp_runs"] > 0
    dets, _ = detect(xyz, templates, objects, variant="ours")
    assert dets == []


def test_paper_reuses_the_fit_of_a_window_with_the_same_points(objects, templates, sensor):
    """Overlapping windows around a lone object often hold exactly its points: the later ones get the
    first one's fit, and the detections (and every fit) equal those of registering every window."""
    cone = objects["reef_cone"]
    t, q = place(cone, 7.0, 7.0, 0.3)
    xyz = survey([(cone, t, q)], sensor)
    params = {"window_overlap": 0.75}
    dets, stats = detect(xyz, templates, objects, params, variant="paper")
    every, stats_every = detect(xyz, templates, objects, {**params, "reuse_identical_windows": False},
                                variant="paper")
    assert stats["windows_reused"] > 0 and stats_every["windows_reused"] == 0
    # Each reused window saves one ICP run per template of its class (one nadir view here).
    assert stats["icp_runs"] + stats["windows_reused"] == stats_every["icp_runs"]
    assert dets and repr(dets) == repr(every)


def test_two_touching_objects_give_two_detections(objects, templates, sensor):
    cone = objects["reef_cone"]
    t1, q1 = place(cone, 6.0, 6.0, 0.0)
    t2, q2 = place(cone, 6.0 + 2.02, 6.3, 0.4)  # bases 2 cm apart
    xyz = survey([(cone, t1, q1), (cone, t2, q2)], sensor)
    dets = accepted(detect(xyz, templates, objects)[0])
    cones = [d for d in dets if d["cls"] == "reef_cone"]
    assert len(cones) == 2
    for t, q in ((t1, q1), (t2, q2)):
        truth = canonical_box(cone.mesh.vertices, t, q, 0)
        assert min(np.hypot(*(np.asarray(d["box"][:2]) - truth[:2])) for d in cones) < 0.15
    # Nothing else is claimed there.
    assert len(dets) == 2


def test_two_touching_tetrapods_give_two_detections(objects, templates, sensor):
    tet = objects["tetrapod_s"]
    t1, q1 = place(tet, 6.0, 6.0, 0.2)
    t2, q2 = place(tet, 7.55, 6.6, 1.3)
    xyz = survey([(tet, t1, q1), (tet, t2, q2)], sensor)
    dets = [d for d in accepted(detect(xyz, templates, objects)[0]) if d["cls"] == "tetrapod_s"]
    assert len(dets) == 2
    for t, q in ((t1, q1), (t2, q2)):
        truth = canonical_box(tet.mesh.vertices, t, q, 3)
        assert min(np.hypot(*(np.asarray(d["box"][:2]) - truth[:2])) for d in dets) < 0.2


def test_icp_degenerate_input_returns_none(objects):
    obj = objects["reef_cone"]
    v = np.asarray(obj.mesh.vertices)
    tgt = SurfaceTarget(v, np.tile([0.0, 0.0, 1.0], (len(v), 1)))
    stages = DEFAULTS["icp_stages"]
    three = np.array([[0.0, 0.0, 0.0], [1.0, 0.0, 0.0], [0.0, 1.0, 0.0]])
    line = np.c_[np.linspace(0, 1, 50), np.zeros(50), np.zeros(50)]
    for pts in (three, line, np.zeros((0, 3)), np.full((30, 3), np.nan)):
        assert icp_scene_to_model(pts, tgt, np.eye(3), np.zeros(3), stages) is None
        assert icp_point_to_point(v[:100], pts, 0.3, 30) is None
        assert icp_point_to_point(pts, v[:100], 0.3, 30) is None


def test_planar_patch_gives_no_detection(objects, templates):
    """A flat 1.5 m x 1.5 m table 0.5 m above a flat seabed: planar input registers to nothing."""
    rng = np.random.default_rng(0)
    g = np.mgrid[0:10:0.08, 0:10:0.08].reshape(2, -1).T
    seabed = np.c_[g, SEABED_Z + rng.normal(0, 0.01, len(g))]
    p = np.mgrid[4:5.5:0.04, 4:5.5:0.04].reshape(2, -1).T
    table = np.c_[p, SEABED_Z + 0.5 + rng.normal(0, 0.005, len(p))]
    xyz = np.vstack([seabed, table])
    for variant in ("ours", "paper"):
        dets, _ = detect(xyz, templates, objects, variant=variant)
        assert accepted(dets) == [], variant
        assert all(np.isfinite(d["score"]) for d in dets)


@pytest.mark.parametrize("variant", ["ours", "paper"])
def test_utm_offset_gives_the_same_detections(objects, templates, sensor, variant):
    tet = objects["tetrapod_s"]
    cone = objects["reef_cone"]
    placed = [(tet, *place(tet, 4.0, 5.0, 0.5)), (cone, *place(cone, 9.5, 8.0, 0.0))]
    xyz = survey(placed, sensor)
    offset = np.array([5.0e5, 4.0e6, 0.0])
    local, st_local = detect(xyz, templates, objects, variant=variant)
    utm, st_utm = detect(xyz + offset, templates, objects, variant=variant)
    assert len(local) == len(utm) > 0
    assert st_utm["origin"][:2] == [5.0e5, 4.0e6]
    for a, b in zip(local, utm):
        assert a["cls"] == b["cls"]
        assert np.allclose(np.asarray(b["box"][:3]) - offset, a["box"][:3], atol=1e-6)
        assert np.allclose(b["box"][3:], a["box"][3:], atol=1e-6)
        assert np.allclose(np.asarray(b["pose"]["t"]) - offset, a["pose"]["t"], atol=1e-6)
        assert abs(a["score"] - b["score"]) < 1e-6


def test_deterministic(objects, templates, sensor):
    tet = objects["tetrapod_b"]
    xyz = survey([(tet, *place(tet, 6.0, 6.0, 1.0))], sensor)
    a, _ = detect(xyz, templates, objects)
    b, _ = detect(xyz, templates, objects)
    assert a == b


@pytest.mark.parametrize("variant", ["ours", "paper"])
def test_detector_object_is_reusable_and_equals_detect(objects, templates, sensor, variant):
    """A detector built once gives, call after call and whatever it ran on before, the detections of
    `detect` on each cloud (no state carried from one cloud to the next)."""
    cone, ring = objects["reef_cone"], objects["reef_ring"]
    clouds = [survey([(cone, *place(cone, 6.0, 6.0, 0.0))], sensor),
              survey([(ring, *place(ring, 5.0, 7.0, 0.0))], sensor, seed=3)]
    detector = ModelBasedDetector(templates, objects, variant=variant)
    assert detector.classes == list(objects) and detector.build_seconds > 0
    for xyz in clouds + clouds[::-1]:
        dets, stats = detector(xyz)
        assert dets == detect(xyz, templates, objects, variant=variant)[0]
        assert stats["seconds"]["models"] == 0.0 and stats["variant"] == variant


def test_tumbled_rotations_are_proper_and_from_the_parameters(objects, templates):
    from sonardet.detect.model_based.detector import class_models
    from sonardet.detect.model_based.ours import tumbled_rotations

    models = class_models(templates, {c: objects[c] for c in ("reef_cone", "tetrapod_s")}, DEFAULTS)
    tet = tumbled_rotations(models["tetrapod_s"], DEFAULTS)
    # upright yaws, then tilts x azimuths x yaws
    assert len(tet) == 2 + 2 * 6 * 2
    cone = tumbled_rotations(models["reef_cone"], DEFAULTS)
    assert len(cone) > 0 and len(cone) % DEFAULTS["tumbled_azimuths_n"] == 0
    fewer = tumbled_rotations(models["reef_cone"], {**DEFAULTS, "tumbled_azimuths_n": 4})
    assert len(fewer) == len(cone) // 2
    for R in tet + cone:
        assert np.allclose(R @ R.T, np.eye(3)) and np.isclose(np.linalg.det(R), 1.0)
    tilts = np.degrees(np.arccos(np.clip([R[2, 2] for R in cone], -1, 1)))
    lo, hi = DEFAULTS["tumbled_stable_tilt_range_deg"]
    assert np.all((tilts >= lo - 1e-6) & (tilts <= hi + 1e-6))


def test_empty_nan_and_bad_input(objects, templates):
    with pytest.warns(UserWarning, match="nothing to detect"):
        dets, stats = detect(np.zeros((0, 3)), templates, objects)
    assert dets == [] and stats["n_points"] == 0
    bad = np.zeros((10, 3))
    bad[3, 1] = np.nan
    with pytest.raises(ValueError, match="NaN/Inf"):
        detect(bad, templates, objects)
    bad[3, 1] = np.inf
    with pytest.raises(ValueError, match="NaN/Inf"):
        detect(bad, templates, objects, variant="paper")
    with pytest.raises(ValueError, match=r"\(N,3\)"):
        detect(np.zeros((10, 2)), templates, objects)
    with pytest.raises(ValueError, match="variant"):
        detect(np.zeros((10, 3)), templates, objects, variant="best")
    with pytest.raises(ValueError, match="unknown model-based detector parameter"):
        detect(np.zeros((10, 3)), templates, objects, {"voxel": 0.1})


def _degenerate_cloud(kind: str) -> np.ndarray:
    """Valid (finite) clouds that hold no object and give the pipeline's stages nothing to fit: one
    point, eight points, many copies of one point, a straight line, and a 20 x 20 m plane with 1 cm
    of noise and a UTM-sized offset."""
    rng = np.random.default_rng(3)
    if kind == "one_point":
        return np.array([[1.0, 2.0, -11.0]])
    if kind == "few_points":  # a 1 x 1 m patch of 8 soundings, one 1 m up: fewer than any fit needs
        return np.column_stack([rng.uniform(0.0, 1.0, (8, 2)), np.r_[-10.0, np.full(7, -11.0)]])
    if kind == "one_point_repeated":
        return np.tile([[1.0, 2.0, -11.0]], (1000, 1))
    if kind == "line":
        return np.column_stack([np.linspace(0.0, 50.0, 5000), np.zeros(5000), np.full(5000, -11.0)])
    xy = rng.uniform(0.0, 20.0, (20000, 2)) + np.array([500000.0, 6000000.0])
    return np.column_stack([xy, -11.0 + 0.01 * rng.standard_normal(20000)])


@pytest.mark.parametrize("variant", ["ours", "paper"])
@pytest.mark.parametrize("kind", ["one_point", "few_points", "one_point_repeated", "line", "noisy_plane_utm"])
def test_degenerate_clouds_give_no_detection_and_no_error(objects, templates, variant, kind):
    """A cloud with nothing to fit runs through every stage (seabed, proposals, ICP, scoring) without
    an exception or a non-finite box, and detects nothing (fewer points than one fit needs: with the
    documented "nothing to detect" warning)."""
    cloud = _degenerate_cloud(kind)
    few = kind in ("one_point", "few_points")
    warns = pytest.warns(UserWarning, match="nothing to detect") if few else contextlib.nullcontext()
    with warns:
        dets, stats = detect(cloud, templates, objects, variant=variant)
    assert [d for d in dets if d["extras"].get("accepted", True)] == []  # `paper` outputs only accepted ones
    assert all(np.all(np.isfinite(d["box"])) for d in dets)
    assert stats["n_points"] == len(cloud)


def test_missing_template_class_is_a_clear_error(objects, templates):
    partial = {c: t for c, t in templates.items() if c != "reef_ring"}
    with pytest.raises(ValueError, match="no template scans for class 'reef_ring'"):
        detect(np.zeros((10, 3)), partial, objects)


def test_every_parameter_is_described():
    for variant in (DEFAULTS, PAPER):
        for k in variant:
            unit, meaning = DESCRIPTIONS[k]
            assert unit and meaning, k
    assert set(DESCRIPTIONS) == set(DEFAULTS) | set(PAPER)


def test_params_defaults_and_overrides():
    p = resolve_params({"window_overlap": 0.25}, "paper")
    assert p["window_overlap"] == 0.25 and p["ground_method"] == "ransac"
    assert resolve_params(None, "ours") == DEFAULTS and resolve_params({}, "paper") == PAPER
    with pytest.raises(ValueError):
        resolve_params({"window_overlap": 1.0}, "paper")


def test_windows_cover_the_area_and_count_points():
    wins = sliding_windows((0.0, 0.0), (10.0, 6.0), 2.0, 0.5)
    assert np.isclose(wins[:, 2].max(), 10.0) and np.isclose(wins[:, 3].max(), 6.0)
    assert np.allclose(wins[:, 2] - wins[:, 0], 2.0)
    rng = np.random.default_rng(0)
    xy = rng.uniform(0, 10, (2000, 2)) * [1.0, 0.6]
    counts = window_counts(xy, wins)
    exact = [int(np.sum((xy[:, 0] >= w[0]) & (xy[:, 0] < w[2]) & (xy[:, 1] >= w[1]) & (xy[:, 1] < w[3])))
             for w in wins]
    assert np.all(np.abs(counts - exact) <= 0.05 * np.maximum(exact, 20))


def test_paper_duplicates_keep_stacked_objects_and_drop_parts_of_larger_ones():
    """Paper duplicate removal: an upper object of a pile, centred over the gap below (0.8 m off its
    neighbour), survives; a fit of another class inside a better-scored ring's footprint (a small
    template on the ring's rim) is a duplicate; so is a fit of the same class closer than
    duplicate_dist_m."""
    from sonardet.detect.model_based.paper import is_duplicate
    from sonardet.detect.model_based.scoring import Hypothesis

    p = resolve_params(None, "paper")
    radius = {"reef_ring": 1.34, "tetrapod_s": 0.93}

    def hyp(cls, x):
        return Hypothesis(cls=cls, R=np.eye(3), t=np.zeros(3), box=np.array([x, 0.0, -11.0, 1.0, 1.0, 1.0, 0.0]))

    lower = hyp("tetrapod_s", 0.0)
    assert not is_duplicate(hyp("tetrapod_s", 0.8), [lower], radius, p)
    assert is_duplicate(hyp("tetrapod_s", 0.9 * p["duplicate_dist_m"]), [lower], radius, p)
    ring = hyp("reef_ring", 0.0)
    rim = p["duplicate_other_class_frac"] * radius["reef_ring"]
    assert is_duplicate(hyp("tetrapod_s", 0.95 * rim), [ring], radius, p)
    assert not is_duplicate(hyp("tetrapod_s", 1.05 * rim), [ring], radius, p)
    # The other class's radius sets the limit: a ring next to a better-scored small tetrapod.
    assert not is_duplicate(hyp("reef_ring", 0.95 * rim), [lower], radius, p)
    assert is_duplicate(hyp("reef_ring", 0.95 * p["duplicate_other_class_frac"] * radius["tetrapod_s"]), [lower],
                        radius, p)


def test_paper_refinement_and_tight_fitness(templates):
    """ICP refinement from a 5 cm / 3 deg offset of an exact copy recovers the pose, with fitness and
    RMSE measured at icp_max_corr_m; off (0 iterations) it returns the fit unchanged. Tight fitness is
    1 for the aligned template and drops when it is shifted by more than score_corr_m."""
    from scipy.spatial import cKDTree

    from sonardet.detect.model_based.paper import refine_point_to_point, thin, tight_fitness
    from sonardet.detect.model_based.registration import IcpResult

    p = resolve_params(None, "paper")
    tpl = thin(np.asarray(templates["tetrapod_s"].points(0), dtype=np.float64), p["template_voxel_m"])
    R_true, t_true = quat_to_matrix(quat_from_yaw(0.4)), np.array([3.0, 2.0, -11.0])
    window = tpl @ R_true.T + t_true
    start = IcpResult(quat_to_matrix(quat_from_yaw(0.45)), t_true + [0.05, -0.03, 0.02], 0.0, 1.0)
    res = refine_point_to_point(tpl, window, start, p)
    assert np.allclose(res.t, t_true, atol=0.01) and np.allclose(res.R, R_true, atol=0.01)
    assert res.fitness == pytest.approx(1.0) and res.rmse_m < 0.01
    assert refine_point_to_point(tpl, window, start, dict(p, icp_refine_iter=0)) is start
    tree = cKDTree(window)
    assert tight_fitness(tpl, tree, res, p["score_corr_m"]) == pytest.approx(1.0)
    shifted = IcpResult(res.R, res.t + [3 * p["score_corr_m"], 0.0, 0.0], 1.0, 0.0)
    assert tight_fitness(tpl, tree, shifted, p["score_corr_m"]) < 0.5
    assert tight_fitness(np.zeros((0, 3)), tree, res, p["score_corr_m"]) == 0.0


def test_paper_icp_backends_give_the_same_detections(objects, templates, sensor):
    """The compiled point-to-point ICP (default) and Open3D's: the same detections on a scene of two
    touching cones and a tetrapod (boxes and scores to rounding), the same counts of windows and ICP
    runs."""
    cone, tet = objects["reef_cone"], objects["tetrapod_s"]
    placed = [(cone, *place(cone, 5.0, 6.0, 0.0)), (cone, *place(cone, 7.02, 6.3, 0.4)),
              (tet, *place(tet, 9.5, 8.0, 0.7))]
    xyz = survey(placed, sensor)
    a, sa = detect(xyz, templates, objects, variant="paper")
    b, sb = detect(xyz, templates, objects, {"icp_backend": "open3d"}, variant="paper")
    assert len(a) == len(b) >= 3
    for x, y in zip(a, b):
        assert x["cls"] == y["cls"] and np.abs(np.subtract(x["box"], y["box"])).max() < 1e-9
        assert x["score"] == pytest.approx(y["score"], abs=1e-9)
    assert (sa["icp_runs"], sa["windows"], sa["icp_declined"]) == (sb["icp_runs"], sb["windows"], sb["icp_declined"])
    with pytest.raises(ValueError, match="icp_backend"):
        resolve_params({"icp_backend": "pcl"}, "paper")


def test_paper_ring_alone_gives_one_detection(objects, templates, sensor):
    """A ring alone: the smaller templates fitted to parts of its rim are duplicates of it, not objects."""
    ring = objects["reef_ring"]
    t, q = place(ring, 7.0, 6.5, 0.0)
    xyz = survey([(ring, t, q)], sensor)
    dets, _ = detect(xyz, templates, objects, variant="paper")
    truth = canonical_box(ring.mesh.vertices, t, q, 0)
    near = [d for d in dets if np.hypot(*(np.asarray(d["box"][:2]) - truth[:2])) < 2.5]
    assert [d["cls"] for d in near] == ["reef_ring"]
    assert np.hypot(*(np.asarray(near[0]["box"][:2]) - truth[:2])) < 0.1


def test_paper_unknown_score_is_a_clear_error(objects, templates, sensor):
    xyz = survey([], sensor, extent_m=8.0)
    with pytest.raises(ValueError, match="score"):
        detect(xyz, templates, objects, {"score": "best"}, variant="paper")


def test_paper_rankings_share_one_registration_and_equal_the_detectors_alone(objects, templates, sensor):
    """Settings that differ only in the ranking keys (the study's RMSE ranking, the ladder's tight
    fitness, a stricter acceptance and duplicate distance) run in one registration pass: each gets the
    detections of its own detector, and the shared stages' counts; a difference outside the ranking
    keys, or the 'ours' variant, is refused."""
    cone, ring, tet = objects["reef_cone"], objects["reef_ring"], objects["tetrapod_b"]
    placed = [(cone, *place(cone, 3.5, 5.0, 0.3)), (ring, *place(ring, 8.0, 5.5, 0.0)),
              (tet, *place(tet, 6.0, 9.5, 1.1)), (cone, *place(cone, 5.52, 5.0, 0.9))]
    xyz = survey(placed, sensor, extent_m=12.0)
    overrides = [{}, {"score": "tight_fitness"}, {"score": "fitness_rmse", "fitness_min": 0.8, "duplicate_dist_m": 1.5,
                                                  "rmse_max_m": {"*": 0.12}}]
    shared = ModelBasedDetector(templates, objects, variant="paper").rankings(xyz, overrides)
    assert len(shared) == 3
    for o, (dets, stats) in zip(overrides, shared):
        alone, alone_stats = ModelBasedDetector(templates, objects, o, variant="paper")(xyz)
        assert dets == alone and len(dets) > 0
        for key in ("windows", "windows_skipped", "icp_runs", "icp_declined", "hypotheses", "n_candidate_points"):
            assert stats[key] == alone_stats[key], key
        assert stats["seconds"]["registration"] > 0 and stats["seconds"]["total"] > 0
    assert [d["score"] for d in shared[0][0]] != [d["score"] for d in shared[1][0]]  # the rankings differ
    assert shared[2][1]["hypotheses"] < shared[0][1]["hypotheses"]  # the stricter one accepts fewer fits
    with pytest.raises(ValueError, match="window_overlap"):
        ModelBasedDetector(templates, objects, variant="paper").rankings(xyz, [{"window_overlap": 0.25}])
    with pytest.raises(ValueError, match="paper"):
        ModelBasedDetector(templates, objects, variant="ours").rankings(xyz, [{}])
    with pytest.raises(ValueError, match="score"):
        ModelBasedDetector(templates, objects, variant="paper").rankings(xyz, [{"score": "best"}])


def test_rankings_benchmark_checks_the_shared_run(objects, templates, sensor, monkeypatch):
    """benchmarks/detect.py --rankings: a shared run whose detections differ from a detector's alone is
    an error (here made to differ by a detector that drops its last detection)."""
    import sys
    from pathlib import Path

    sys.path.insert(0, str(Path(__file__).resolve().parent.parent / "benchmarks"))
    import detect as bench_detect

    cone = objects["reef_cone"]
    xyz = survey([(cone, *place(cone, 4.0, 4.0, 0.2))], sensor, extent_m=8.0)
    overrides = [{}, {"score": "tight_fitness"}]
    row = bench_detect.compare_rankings(overrides, {}, templates, objects, {"s": xyz})
    assert row["n_scenes"] == 1 and row["overrides"] == overrides
    rankings = ModelBasedDetector.rankings
    monkeypatch.setattr(ModelBasedDetector, "rankings",
                        lambda self, x, o: [(d[:-1], st) for d, st in rankings(self, x, o)])
    with pytest.raises(SystemExit, match="differ"):
        bench_detect.compare_rankings(overrides, {}, templates, objects, {"s": xyz})


# ------------------------------------------------------------------ time bounds on dense input
def _dense_noise(extent_m: float = 10.0, n: int = 15000, seed: int = 5) -> np.ndarray:
    """A flat seabed and a 3 m thick box of uniform noise above it (N points each): shapes everywhere."""
    rng = np.random.default_rng(seed)
    ground = rng.uniform([0, 0, SEABED_Z], [extent_m, extent_m, SEABED_Z + 0.01], (n, 3))
    return np.vstack([ground, rng.uniform([0, 0, SEABED_Z], [extent_m, extent_m, SEABED_Z + 3.0], (n, 3))])


def test_dense_pathological_cloud_is_capped_counted_and_logged(objects, templates, caplog):
    """A cloud of noise: the proposals a round fits are capped (proposal_max_per_round_n), the statistics
    say how many were left, and every stage logs its counts; the ICP work is bounded by the cap."""
    import logging

    cap = 3
    params = {"proposal_max_per_round_n": cap, "proposal_max_rounds_n": 2}
    with caplog.at_level(logging.INFO, logger="sonardet.detect.model_based"):
        _, stats = detect(_dense_noise(), templates, objects, params, "ours")
    assert stats["capped"]["proposals"] > 0 and stats["capped"]["tumbled_rounds"] == 1
    assert "seabed: 30000 points" in caplog.text and "round 1:" in caplog.text
    assert "only the 3 correlating best are fitted (proposal_max_per_round_n)" in caplog.text
    upright = sum(n for k, n in stats["icp_runs_by_kind"].items() if k.startswith("upright"))
    # Per proposal: at most 2 start heights x n_yaw_init yaws, 4 shifted restarts, then one refit each.
    assert upright <= 2 * cap * (2 * DEFAULTS["n_yaw_init"] + 4)
    assert stats["windows"] <= 2 * 2 * cap  # upright proposals and tumbled tries, each capped, per round


def test_paper_windows_are_capped(objects, templates, caplog):
    import logging

    with caplog.at_level(logging.INFO, logger="sonardet.detect.model_based"):
        _, stats = detect(_dense_noise(), templates, objects, {"window_max_n": 2}, "paper")
    assert stats["capped"]["windows"] > 0
    assert stats["icp_runs"] <= len(CLASSES) * 2 * len(templates["reef_ring"].yaw_rad)
    assert "only the 2 holding the most points are (window_max_n)" in caplog.text


def test_caps_that_do_not_bite_change_nothing(objects, templates, sensor):
    """The default caps are far above what a scene needs: lowering them to what this scene uses gives
    the same detections, byte for byte."""
    placed = [(objects["reef_ring"], *place(objects["reef_ring"], 4.0, 5.0, 0.0)),
              (objects["tetrapod_s"], *place(objects["tetrapod_s"], 9.0, 8.0, 0.4))]
    xyz = survey(placed, sensor)
    ref, s = detect(xyz, templates, objects, None, "ours")
    tight = {"proposal_max_per_round_n": max(s["windows"], 1)}
    again, s2 = detect(xyz, templates, objects, tight, "ours")
    assert again == ref and s2["capped"] == {"proposals": 0, "tumbled_rounds": 0}


def test_a_sounding_100_km_away_changes_no_detection(objects, templates, sensor):
    """A scene plus one sounding 100 km off (a survey export's flier): `sonardet detect`'s path (fliers
    dropped, tiles near the data) gives the detections of the scene alone, byte for byte."""
    import json
    import tracemalloc

    from sonardet.survey import detect_survey

    placed = [(objects["reef_cone"], *place(objects["reef_cone"], 5.0, 6.0, 0.0)),
              (objects["tetrapod_b"], *place(objects["tetrapod_b"], 10.0, 8.0, 0.3))]
    xyz = survey(placed, sensor) + [5.5e5, 4.18e6, 0.0]
    detector = ModelBasedDetector(templates, objects)
    ref, _ = detect_survey(xyz, detector, 40.0, 3.0, 2.7)
    far = np.vstack([xyz[:100], xyz[0] + [1e5, 0.0, 0.0], xyz[100:]])
    tracemalloc.start()
    dets, info = detect_survey(far, detector, 40.0, 3.0, 2.7)
    peak = tracemalloc.get_traced_memory()[1]
    tracemalloc.stop()
    assert json.dumps(dets) == json.dumps(ref) and len(ref) == 2
    assert info["fliers"]["n_points"] == 1 and info["n_tiles"] == 1
    assert peak < 200e6  # the detector's own working set; no grid over the 100 km box


def test_worker_threads_give_the_same_detections_and_counts(objects, templates, sensor, monkeypatch):
    """`threads` changes only the time: a crowded patch (touching objects, a cone on its side) gives the
    same detections and counts with 1 and with 3 worker threads, and the fits did run on the workers."""
    import threading

    import sonardet.detect.model_based.ours as ours
    from sonardet.geometry import matrix_to_quat

    cone, ring, tb, ts = (objects[c] for c in ("reef_cone", "reef_ring", "tetrapod_b", "tetrapod_s"))
    R = np.array([[1.0, 0.0, 0.0], [0.0, 0.0, -1.0], [0.0, 1.0, 0.0]])  # the cone on its side
    q_side = matrix_to_quat(R)
    z_side = SEABED_Z - (np.asarray(cone.mesh.vertices) @ R.T)[:, 2].min()
    placed = [(ring, *place(ring, 3.5, 4.0, 0.0)), (cone, *place(cone, 5.9, 4.2, 0.0)),
              (tb, *place(tb, 9.0, 9.5, 0.4)), (ts, *place(ts, 10.6, 8.2, 1.3)),
              (cone, np.array([4.0, 10.0, z_side]), q_side)]
    xyz = survey(placed, sensor, extent_m=14.0, seed=5)
    names = set()
    coarse = ours._Job.coarse

    def recording(self, *a, **k):
        names.add(threading.current_thread().name)
        return coarse(self, *a, **k)

    monkeypatch.setattr(ours._Job, "coarse", recording)
    one, s1 = ModelBasedDetector(templates, objects, threads=1)(xyz)
    assert names == {threading.current_thread().name}
    names.clear()
    three, s3 = ModelBasedDetector(templates, objects, threads=3)(xyz)
    assert any(n.startswith("sonardet-detect") for n in names)
    assert one == three and len(accepted(one)) >= 4
    s1.pop("seconds"), s3.pop("seconds")
    assert s1 == s3 and s1["icp_runs_by_kind"].get("tumbled", 0) > 0
    with pytest.raises(ValueError, match="threads"):
        ModelBasedDetector(templates, objects, threads=0)


@pytest.mark.parametrize("width_m", [0.0, 0.01, 0.1])
@pytest.mark.parametrize("raised_frac", [0.0, 0.2])
def test_ransac_seabed_of_a_narrow_strip_is_level_across_it(width_m, raised_frac):
    """Soundings in a strip narrower than twice the RANSAC distance (here along a 30 deg heading, on a
    2 % slope, 1 cm of vertical noise, a share of them raised 0.2-2 m as by objects) fit a vertical
    plane along the strip as well as the seabed; the seabed model must still be the sloped seabed,
    not the wall (which stopped the detection before), and the raised soundings above it."""
    from sonardet.detect.model_based.ground import ransac_plane_ground

    rng = np.random.default_rng(5)
    n = 4000
    along, across = rng.uniform(0.0, 40.0, n), rng.uniform(-0.5, 0.5, n) * width_m
    u, v = np.array([np.cos(np.pi / 6), np.sin(np.pi / 6)]), np.array([-np.sin(np.pi / 6), np.cos(np.pi / 6)])
    xy = along[:, None] * u + across[:, None] * v + np.array([500000.0, 6000000.0])
    z = -11.0 + 0.02 * along + 0.01 * rng.standard_normal(n)
    raised = rng.random(n) < raised_frac
    z[raised] += rng.uniform(0.2, 2.0, raised.sum())
    g = ransac_plane_ground(np.column_stack([xy, z]), 0.15, 200, 0)
    slope = np.hypot(g.plane[0], g.plane[1]) / g.plane[2]
    assert g.plane[2] > 0.99 and abs(slope - 0.02) < 0.002
    assert np.abs(g.hab[~raised]).max() < 0.06  # the noise only: every other sounding is seabed
    assert np.all(g.hab[raised] > 0.14)
    # Soundings at one spot: a level plane through them.
    spot = ransac_plane_ground(np.tile([[3.0, 4.0, -11.0]], (50, 1)), 0.15, 200, 0)
    assert np.allclose(spot.plane, [0.0, 0.0, 1.0, 11.0]) and np.allclose(spot.hab, 0.0)


def test_ransac_seabed_of_a_wide_cloud_is_unchanged_by_the_strip_rule():
    """A cloud wider than the strip rule's bound goes to RANSAC as before: the same plane as Open3D's
    seeded RANSAC gives on its own."""
    from sonardet.detect.model_based.ground import ransac_plane_ground
    from sonardet.ransac import segment_plane

    rng = np.random.default_rng(6)
    pts = np.column_stack([rng.uniform(0, 30, 3000), rng.uniform(0, 0.31, 3000), -11 + 0.01 * rng.standard_normal(3000)])
    plane, _ = segment_plane(pts, 0.15, 3, 200, 0, probability=1.0)
    plane = plane / np.linalg.norm(plane[:3])
    plane = -plane if plane[2] < 0 else plane
    assert np.array_equal(ransac_plane_ground(pts, 0.15, 200, 0).plane, plane)


def test_ransac_seabed_in_front_of_a_quay_wall():
    """A vertical wall holding twice the seabed's soundings is RANSAC's largest plane: it is set aside
    and the seabed in front of it found; a cloud of walls only is refused, naming the walls."""
    from sonardet.detect.model_based.ground import ransac_plane_ground

    rng = np.random.default_rng(7)
    bed = np.column_stack([rng.uniform(0, 20, 2000), rng.uniform(0, 20, 2000), -11 + 0.01 * rng.standard_normal(2000)])
    wall = np.column_stack([rng.uniform(0, 20, 4000), 20 + 0.01 * rng.standard_normal(4000), rng.uniform(-11, 0, 4000)])
    g = ransac_plane_ground(np.vstack([bed, wall]), 0.15, 300, 0)
    assert g.plane[2] > 0.999 and np.abs(g.hab[:2000]).max() < 0.06
    assert np.all(g.hab[2000:] > -0.2)  # the wall stands on the seabed
    walls = np.vstack([wall, wall[:, [1, 0, 2]]])  # two walls at right angles
    with pytest.raises(ValueError, match="no seabed plane flatter than 60 deg"):
        ransac_plane_ground(walls, 0.15, 300, 0)
