"""Tests of sonardet.sim.seabed: procedural seabed heightfield."""

import numpy as np
import pytest

from sonardet.sim.seabed import PERLIN_STD_2D, Heightfield, fbm_grid, make_seabed, perlin_grid, plane_slope


def _small(seed=0, **kw):
    args = dict(extent_m=(20.0, 16.0), cell_m=0.2, margin_m=1.0)
    args.update(kw)
    return make_seabed(rng=np.random.default_rng(seed), **args)


def test_determinism_same_seed_identical_bytes():
    a, b = _small(7), _small(7)
    assert a.z.tobytes() == b.z.tobytes()
    assert (a.x0, a.y0, a.cell_m) == (b.x0, b.y0, b.cell_m)
    assert not np.array_equal(a.z, _small(8).z)


def test_grid_covers_extent_plus_margin():
    hf = _small(extent_m=(20.0, 16.0), cell_m=0.2, margin_m=1.0, origin_xy=(5.0, -3.0))
    assert hf.x0 == pytest.approx(4.0) and hf.y0 == pytest.approx(-4.0)
    assert hf.x1 >= 5.0 + 20.0 + 1.0 - 1e-9 and hf.y1 >= -3.0 + 16.0 + 1.0 - 1e-9
    assert hf.z.dtype == np.float64 and hf.z.shape == (hf.ny, hf.nx)


@pytest.mark.parametrize("slope_deg,azimuth_deg", [(1.0, 135.0), (2.0, 30.0), (0.5, 270.0)])
def test_statistics_mean_depth_and_slope_recovered(slope_deg, azimuth_deg):
    ext = (30.0, 30.0)
    hf = make_seabed(extent_m=ext, cell_m=0.2, mean_depth_m=-11.5, slope_deg=slope_deg,
                     slope_azimuth_deg=azimuth_deg, amplitude_m=0.15, margin_m=2.0, rng=np.random.default_rng(3))
    mean, slope, az = plane_slope(hf, (0.0, ext[0], 0.0, ext[1]))
    assert mean == pytest.approx(-11.5, abs=0.02)
    assert slope == pytest.approx(slope_deg, abs=0.2)
    assert (az - azimuth_deg + 180.0) % 360.0 - 180.0 == pytest.approx(0.0, abs=2.0)


def test_relief_amplitude_is_half_rms():
    # amplitude_m is ~2 sigma of the relief about the plane (roughness off)
    hf = make_seabed(extent_m=(60.0, 60.0), cell_m=0.25, slope_deg=0.0, amplitude_m=0.2, roughness_m=0.0,
                     margin_m=0.0, rng=np.random.default_rng(5))
    resid = hf.z - hf.z.mean()
    assert 0.05 < resid.std() < 0.15  # expected 0.1; one 60 m field holds few 10 m wavelengths
    assert np.abs(resid).max() < 0.6


def test_flat_seabed_without_relief():
    hf = make_seabed(extent_m=(10.0, 10.0), cell_m=0.5, slope_deg=0.0, amplitude_m=0.0, roughness_m=0.0,
                     mean_depth_m=-7.0, rng=np.random.default_rng(0))
    assert np.allclose(hf.z, -7.0)


def test_perlin_noise_properties():
    rng = np.random.default_rng(11)
    xs = np.linspace(0, 200, 801)
    n = perlin_grid(xs, xs, 2.0, rng)
    assert np.abs(n).max() < 0.75
    assert n.std() == pytest.approx(PERLIN_STD_2D, rel=0.15)
    f = fbm_grid(xs, xs, 8.0, 4, 0.5, np.random.default_rng(1))
    assert f.std() == pytest.approx(1.0, rel=0.25)


def test_fbm_octave_skipping_keeps_coarse_octaves():
    # a finer grid adds octaves but must not change the coarse ones' random draws
    xs_c = np.arange(0, 20.01, 0.5)
    a = fbm_grid(xs_c, xs_c, 8.0, 2, 0.5, np.random.default_rng(2), min_wavelength_m=1.0)
    b = fbm_grid(xs_c, xs_c, 8.0, 6, 0.5, np.random.default_rng(2), min_wavelength_m=1.0 * 2**10)
    assert np.all(b == 0.0)  # every octave skipped
    c = fbm_grid(xs_c, xs_c, 8.0, 6, 0.5, np.random.default_rng(2), min_wavelength_m=3.0)
    assert np.allclose(a, c)  # same two octaves (8, 4 m) used, same normalisation


def _planar(a=-11.0, b=0.03, c=-0.02, cell=0.5, shape=(9, 13), x0=2.0, y0=-1.0):
    ys = y0 + np.arange(shape[0]) * cell
    xs = x0 + np.arange(shape[1]) * cell
    X, Y = np.meshgrid(xs, ys)
    return Heightfield(x0, y0, cell, a + b * X + c * Y), (a, b, c)


def test_height_at_bilinear_exact_on_planar_field():
    hf, (a, b, c) = _planar()
    rng = np.random.default_rng(0)
    x = rng.uniform(hf.x0, hf.x1, 500)
    y = rng.uniform(hf.y0, hf.y1, 500)
    assert np.allclose(hf.height_at(x, y), a + b * x + c * y, atol=1e-12)
    # nodes and the far corner exactly
    assert hf.height_at(hf.x1, hf.y1) == pytest.approx(hf.z[-1, -1])
    assert hf.height_at(hf.x0, hf.y0) == pytest.approx(hf.z[0, 0])
    n = hf.normal_at(x[:3], y[:3])
    expect = np.array([-b, -c, 1.0]) / np.linalg.norm([-b, -c, 1.0])
    assert np.allclose(n, expect, atol=1e-12)


def test_height_at_bilinear_inside_a_cell_and_nan_outside():
    z = np.array([[0.0, 1.0], [2.0, 4.0]])
    hf = Heightfield(0.0, 0.0, 1.0, z)
    assert hf.height_at(0.5, 0.5) == pytest.approx(np.mean(z))
    assert hf.height_at(0.25, 0.0) == pytest.approx(0.25)
    assert hf.height_at(0.0, 0.75) == pytest.approx(1.5)
    out = hf.height_at([-0.1, 0.5, 1.2], [0.5, 1.01, 0.5])
    assert np.isnan(out).all()
    assert hf.height_at(np.zeros((2, 3)), np.zeros((2, 3))).shape == (2, 3)


def test_heightfield_validation():
    with pytest.raises(ValueError):
        Heightfield(0, 0, 1.0, np.zeros(5))
    with pytest.raises(ValueError):
        Heightfield(0, 0, 1.0, np.array([[0.0, np.nan], [0.0, 0.0]]))
    with pytest.raises(ValueError):
        Heightfield(0, 0, 0.0, np.zeros((2, 2)))


def test_to_trimesh_counts_vertices_and_orientation():
    hf = _small(1, extent_m=(6.0, 4.0), cell_m=0.5, margin_m=0.5)
    m = hf.to_trimesh()
    assert m.vertices.dtype == np.float64
    assert len(m.vertices) == hf.nx * hf.ny
    assert len(m.faces) == 2 * (hf.nx - 1) * (hf.ny - 1)
    # vertices are the grid nodes, on the heightfield
    assert np.allclose(m.vertices[:, 2], hf.height_at(m.vertices[:, 0], m.vertices[:, 1]), atol=1e-12)
    assert np.array_equal(m.vertices[hf.nx + 2], [hf.x0 + 2 * hf.cell_m, hf.y0 + hf.cell_m, hf.z[1, 2]])
    # every face points up; the surface is a manifold sheet: interior edges shared by 2 faces
    assert (m.face_normals[:, 2] > 0).all()
    assert m.area == pytest.approx(m.area_faces.sum())
    assert np.isclose(m.area, (hf.x1 - hf.x0) * (hf.y1 - hf.y0), rtol=0.01)
    edges = np.sort(m.edges, axis=1)
    _, counts = np.unique(edges, axis=0, return_counts=True)
    assert counts.max() == 2
    n_boundary = 2 * (hf.nx - 1) + 2 * (hf.ny - 1)
    assert (counts == 1).sum() == n_boundary


def test_mesh_diagonal_matches_mujoco_split():
    # cell split along (i, j)-(i+1, j+1): a saddle cell's centre lies on that diagonal's midpoint
    z = np.array([[0.0, 1.0], [1.0, 0.0]])  # z(0,0)=0, z(1,0)=1, z(0,1)=1, z(1,1)=0
    m = Heightfield(0.0, 0.0, 1.0, z).to_trimesh()
    hit = m.ray.intersects_location([[0.5, 0.5, 5.0]], [[0.0, 0.0, -1.0]])[0]
    assert hit[0, 2] == pytest.approx(0.0)  # bilinear would give 0.5


def test_crop_shares_nodes_and_covers_rectangle():
    hf = _small(2)
    c = hf.crop(3.05, 7.3, 2.0, 5.55)
    assert c.x0 <= 3.05 and c.x1 >= 7.3 and c.y0 <= 2.0 and c.y1 >= 5.55
    assert c.x1 - c.x0 < 7.3 - 3.05 + 2 * hf.cell_m + 1e-9
    i0 = int(round((c.x0 - hf.x0) / hf.cell_m))
    j0 = int(round((c.y0 - hf.y0) / hf.cell_m))
    assert np.array_equal(c.z, hf.z[j0:j0 + c.ny, i0:i0 + c.nx])
    x = np.linspace(3.05, 7.3, 7)
    assert np.allclose(c.height_at(x, 4.0), hf.height_at(x, 4.0), atol=1e-12)
    # clipped to the grid; missing the grid is an error
    full = hf.crop(-100, 100, -100, 100)
    assert full.z.shape == hf.z.shape
    with pytest.raises(ValueError):
        hf.crop(500, 600, 0, 1)


def test_resample_coarser_keeps_surface():
    hf = _small(4, roughness_m=0.0)
    r = hf.resample(0.6)
    assert r.cell_m == 0.6
    x = np.linspace(r.x0, r.x1, 50)
    assert np.abs(r.height_at(x, 5.0) - hf.height_at(x, 5.0)).max() < 0.02


def test_make_seabed_rejects_bad_arguments():
    rng = np.random.default_rng(0)
    with pytest.raises(ValueError):
        make_seabed(extent_m=(0, 10), rng=rng)
    with pytest.raises(ValueError):
        make_seabed(cell_m=0.0, rng=rng)
    with pytest.raises(ValueError):
        make_seabed(slope_deg=60.0, rng=rng)
    with pytest.raises(ValueError):
        make_seabed(extent_m=(5, 5), persistence=1.5, rng=rng)
