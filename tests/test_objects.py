"""Object meshes: watertight, dimensions and volume to specification, symmetry, metadata on disk."""

import json

import numpy as np
import pytest

from sonardet.geometry import quat_from_yaw, quat_multiply, random_quat
from sonardet.objects import build_object, canonical_box, read_object, write_object
from sonardet.objects.meshes import tetrapod_leg_directions

SPEC_HEIGHT = {"tetrapod_s": 1.42, "tetrapod_b": 2.08, "reef_cone": 1.37, "reef_ring": 0.75}


@pytest.mark.parametrize("cls", list(SPEC_HEIGHT))
def test_mesh_watertight_height_volume(built_objects, cls):
    m = built_objects[cls]
    assert m.mesh.is_watertight and m.mesh.is_winding_consistent
    assert m.mesh.volume > 0
    assert abs(m.mesh.extents[2] - SPEC_HEIGHT[cls]) <= 0.02 * SPEC_HEIGHT[cls]
    assert abs(m.mesh.volume - m.spec_volume_m3) <= 0.02 * m.spec_volume_m3
    # Canonical frame: lowest point at z = 0, symmetry axis through x = y = 0.
    assert abs(m.mesh.bounds[0, 2]) < 1e-6


def test_tetrapod_masses_and_shape(built_objects):
    for cls, mass in (("tetrapod_s", 2000), ("tetrapod_b", 6000)):
        m = built_objects[cls]
        assert abs(m.mesh.volume * 2400 - mass) <= 0.02 * mass
        assert m.symmetry_order == 3
        # It stands on three legs: the lowest points lie in the three down-leg directions.
        v = np.asarray(m.mesh.vertices)
        low = v[v[:, 2] < 0.02]
        dirs = tetrapod_leg_directions()[1:, :2]
        az = np.arctan2(low[:, 1], low[:, 0])
        for d in dirs:
            assert np.any(np.abs(np.angle(np.exp(1j * (az - np.arctan2(d[1], d[0]))))) < 0.5)
    # The big one is the same shape at a larger scale.
    ratio = built_objects["tetrapod_b"].mesh.extents / built_objects["tetrapod_s"].mesh.extents
    assert np.allclose(ratio, 2.08 / 1.42, rtol=0.03)


def test_cone_and_ring_extents(built_objects):
    cone, ring = built_objects["reef_cone"], built_objects["reef_ring"]
    assert np.allclose(cone.mesh.extents[:2], 2.0, atol=0.02)
    assert np.allclose(ring.mesh.extents[:2], 2.68, atol=0.02)
    assert cone.symmetry_order == 0 and ring.symmetry_order == 0
    assert len(cone.spec["holes"]) == 30
    d = np.array([h["diameter_m"] for h in cone.spec["holes"]])
    assert d.min() >= 0.10 and d.max() <= 0.25


def test_holes_reduce_volume_and_can_be_switched_off(default_config):
    cfg = dict(default_config["objects"], holes=False)
    for cls in ("reef_cone", "reef_ring"):
        plain = build_object(cls, cfg)
        holed = build_object(cls, default_config["objects"])
        assert plain.mesh.is_watertight
        assert plain.mesh.volume > holed.mesh.volume
        assert len(plain.mesh.faces) < len(holed.mesh.faces)


def test_impossible_dimensions_raise_with_key(default_config):
    cfg = json.loads(json.dumps(default_config["objects"]))
    cfg["reef_ring"]["gap_m"] = 2.0
    with pytest.raises(ValueError, match="gap_m"):
        build_object("reef_ring", cfg)
    cfg = json.loads(json.dumps(default_config["objects"]))
    cfg["tetrapod_s"]["mass_kg"] = 50000
    with pytest.raises(ValueError, match="tetrapod_s"):
        build_object("tetrapod_s", cfg)


def test_convex_parts_cover_the_mesh(built_objects):
    """Physics parts: every part inside the mesh's bounds, and together spanning its extents."""
    for m in built_objects.values():
        allv = np.vstack(m.convex_parts)
        assert np.all(allv.min(0) >= m.mesh.bounds[0] - 0.02)
        assert np.all(allv.max(0) <= m.mesh.bounds[1] + 0.02)
        assert np.allclose(allv.max(0) - allv.min(0), m.mesh.extents, atol=0.05)


def test_canonical_box_independent_of_symmetric_pose(built_objects):
    """The box of a symmetric object depends on its placement, not on which equivalent pose is given."""
    rng = np.random.default_rng(3)
    for m in built_objects.values():
        v = np.asarray(m.mesh.vertices)
        for _ in range(5):
            q = random_quat(rng)
            t = rng.normal(size=3) * 10
            n = m.symmetry_order if m.symmetry_order > 0 else 7  # any angle is a symmetry if continuous
            spin = quat_from_yaw(2 * np.pi / n)
            b0 = canonical_box(v, t, q, m.symmetry_order)
            b1 = canonical_box(v, t, quat_multiply(q, spin), m.symmetry_order)
            assert np.allclose(b0[:6], b1[:6], atol=0.03 if m.symmetry_order == 0 else 2e-3)  # tessellation


def test_save_load_round_trip(tmp_path, built_objects):
    m = built_objects["tetrapod_s"]
    meta = write_object(m, 2400, tmp_path / "t.ply", tmp_path / "t.json")
    info = read_object(tmp_path / "t.json")
    assert info.cls == "tetrapod_s" and info.symmetry_order == 3
    assert np.isclose(info.mass_kg, meta["mass_kg"])
    assert len(info.mesh.faces) == meta["n_faces"]
    assert len(info.convex_parts) == 5
    box = info.box([1, 2, -11.5], [1, 0, 0, 0])
    assert np.isclose(box[5], 1.42, atol=0.01) and np.isclose(box[2], -11.5 + box[5] / 2)
    bad = json.loads((tmp_path / "t.json").read_text())
    bad["schema_version"] = 99
    (tmp_path / "t.json").write_text(json.dumps(bad))
    with pytest.raises(ValueError, match="schema_version"):
        read_object(tmp_path / "t.json")


# ------------------------------------------------------------------ meshes as written and read back
@pytest.mark.parametrize("cls", ["reef_ring", "reef_cone", "tetrapod_b", "tetrapod_s"])
def test_written_meshes_read_back_watertight_and_manifold(tmp_path, built_objects, cls):
    """The PLY as written: trimesh (default loading, which merges coincident vertices) and Open3D both
    call it watertight, no edge has more than two faces, and the JSON's `watertight` says what the file
    is, not what the in-memory mesh was."""
    import json

    import open3d as o3d
    import trimesh

    from sonardet.objects import mesh_file_check, write_object

    ply, js = tmp_path / f"{cls}.ply", tmp_path / f"{cls}.json"
    meta = write_object(built_objects[cls], 2400.0, ply, js)
    mesh = trimesh.load(ply)
    assert mesh.is_watertight and mesh.is_winding_consistent
    _, counts = np.unique(mesh.edges_sorted, axis=0, return_counts=True)
    assert counts.max() == 2  # every edge shared by exactly two faces: no place where the solid touches itself
    o3d_mesh = o3d.io.read_triangle_mesh(str(ply))
    assert o3d_mesh.is_watertight() and o3d_mesh.is_edge_manifold() and o3d_mesh.is_vertex_manifold()
    assert not o3d_mesh.is_self_intersecting()
    on_disk = json.loads(js.read_text())
    assert on_disk["watertight"] is True and meta["watertight"] is True
    assert on_disk["watertight_trimesh"] and on_disk["watertight_open3d"]
    assert mesh_file_check(ply)["watertight"] and abs(mesh.volume - on_disk["volume_m3"]) < 1e-9


def test_an_open_mesh_is_written_as_not_watertight_with_a_warning(tmp_path, built_objects):
    import dataclasses
    import json

    import trimesh

    from sonardet.objects import write_object

    m = built_objects["tetrapod_s"]
    open_mesh = trimesh.Trimesh(m.mesh.vertices, m.mesh.faces[:-3], process=False)
    with pytest.warns(UserWarning, match="does not read back watertight"):
        meta = write_object(dataclasses.replace(m, mesh=open_mesh), 2400.0, tmp_path / "t.ply", tmp_path / "t.json")
    assert meta["watertight"] is False and json.loads((tmp_path / "t.json").read_text())["watertight"] is False


@pytest.mark.parametrize("damage", ["truncate", "garbage"])
def test_object_files_damaged(tmp_path, built_objects, damage):
    from sonardet.io.artifacts import FileReadError
    from sonardet.objects import read_object, write_object

    def truncate(p):
        p.write_bytes(p.read_bytes()[: len(p.read_bytes()) // 2])

    def garbage(p):
        p.write_bytes(np.random.default_rng(0).integers(0, 256, 300, dtype=np.uint8).tobytes())

    ply, js = tmp_path / "reef_ring.ply", tmp_path / "reef_ring.json"
    write_object(built_objects["reef_ring"], 2400.0, ply, js)
    hurt = truncate if damage == "truncate" else garbage
    hurt(ply)
    with pytest.raises(FileReadError) as exc:
        read_object(js)
    assert str(ply) in str(exc.value) and "delete it" in str(exc.value)
    write_object(built_objects["reef_ring"], 2400.0, ply, js)
    hurt(js)
    with pytest.raises(FileReadError) as exc:
        read_object(js)
    assert str(js) in str(exc.value) and "delete it" in str(exc.value)
