"""Tests for sonardet.io.points (the format table and its text/las/ply/npz modules): round trips at UTM scale,
the real R2Sonic survey line, and every bad input named in the design (wrong column count, NaN,
empty files, LAS without points, unknown suffix, reordered headers)."""

from __future__ import annotations

import gzip
import os
import tempfile
import warnings
from pathlib import Path

import laspy
import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from sonardet.io.origin import GlobalCoordinatesError
from conftest import REAL_DIR, needs_real
from sonardet.io.points import (
    FORMAT_TABLE,
    SUPPORTED_SUFFIXES,
    PointCloud,
    PointCloudError,
    UnsupportedFormatError,
    format_module,
    iter_chunks,
    point_format,
    read_points,
    write_points,
)



ALL_FORMATS = [".xyz", ".xyz.gz", ".txt", ".pts", ".csv", ".csv.gz", ".las", ".laz", ".ply", ".npz"]
EXACT = {".xyz", ".xyz.gz", ".txt", ".pts", ".csv", ".csv.gz", ".ply", ".npz"}
KEEPS_CRS = {".las", ".laz", ".ply", ".npz"}


def utm_points(n: int = 300, seed: int = 0) -> np.ndarray:
    """UTM-scale points (easting 5e5, northing 4e6, elevation near -11 m), not on any grid."""
    rng = np.random.default_rng(seed)
    return np.column_stack(
        [5e5 + rng.uniform(0, 80, n), 4e6 + rng.uniform(0, 120, n), rng.uniform(-11.5, -9.5, n)]
    )


def scene_cloud(n: int = 300, seed: int = 0) -> PointCloud:
    rng = np.random.default_rng(seed)
    attrs = {
        "ping": np.arange(n, dtype=np.int64) // 8,
        "beam": rng.integers(0, 256, n),
        "line": np.full(n, 3, dtype=np.int32),
        "label": rng.integers(-1, 4, n),
        "intensity": rng.integers(0, 3000, n),
    }
    return PointCloud(utm_points(n, seed), attrs, crs="EPSG:32610", origin=np.array([5e5, 4e6, 0.0]))


def write_text(path: Path, text: str, gz: bool = False) -> Path:
    data = text.encode("utf-8")
    path.write_bytes(gzip.compress(data, mtime=0) if gz else data)
    return path


# ---------------------------------------------------------------------------- round trips
@pytest.mark.parametrize("suffix", ALL_FORMATS)
def test_round_trip_every_format_at_utm_scale(tmp_path, suffix):
    cloud = scene_cloud()
    path = tmp_path / f"scene{suffix}"
    assert write_points(path, cloud) == path
    back = read_points(path, crs=None if suffix in KEEPS_CRS else "EPSG:32610")
    assert back.xyz.dtype == np.float64 and back.xyz.shape == cloud.xyz.shape
    if suffix in EXACT:
        np.testing.assert_array_equal(back.xyz, cloud.xyz)
    else:  # LAS: 1 mm scale, so at most half a millimetre of quantisation
        assert np.abs(back.xyz - cloud.xyz).max() <= 0.0005 + 1e-9
    assert back.crs == "EPSG:32610"
    assert back.source == str(path)
    names = [f"col{i}" for i in range(3, 8)] if suffix == ".pts" else list(cloud.attributes)
    assert sorted(back.attributes) == sorted(names)
    for name, original in zip(names, cloud.attributes.values()):
        np.testing.assert_array_equal(back.attributes[name], original)
    if suffix in KEEPS_CRS:
        np.testing.assert_array_equal(back.origin, cloud.origin)
    assert os.listdir(tmp_path) == [path.name]  # no temporary file left behind


@pytest.mark.parametrize("suffix", ALL_FORMATS)
def test_chunks_are_the_points_read_points_gives(tmp_path, suffix):
    cloud = scene_cloud(n=1000)
    path = write_points(tmp_path / f"scene{suffix}", cloud)
    crs = None if suffix in KEEPS_CRS else "epsg:32610"
    whole = read_points(path, crs=crs)
    chunks = list(iter_chunks(path, crs=crs, chunk_points=333))
    assert [len(c) for c in chunks] == [333, 333, 333, 1]
    np.testing.assert_array_equal(np.concatenate([c.xyz for c in chunks]), whole.xyz)
    for c in chunks:
        assert isinstance(c, PointCloud) and c.xyz.dtype == np.float64 and c.attributes == {}
        assert c.crs == "EPSG:32610" and c.source == str(path)
        if whole.origin is None:
            assert c.origin is None
        else:
            np.testing.assert_array_equal(c.origin, whole.origin)
    assert format_module(path).STREAMED == (suffix not in (".ply", ".npz"))


def test_format_table_maps_every_suffix_to_a_complete_format_module(tmp_path):
    assert tuple(FORMAT_TABLE) == SUPPORTED_SUFFIXES
    for suffix, module in FORMAT_TABLE.items():
        assert suffix in module.SUFFIXES and point_format(f"a{suffix.upper()}") == module.NAME
        for name in ("read", "write", "iter_chunks", "STREAMED", "READ_OPTIONS", "WRITE_OPTIONS"):
            assert hasattr(module, name), (module.__name__, name)
    with pytest.raises(ValueError, match="chunk_points must be >= 1"):
        iter_chunks(write_points(tmp_path / "a.xyz", scene_cloud()), chunk_points=0)
    with pytest.raises(FileNotFoundError):
        iter_chunks(tmp_path / "nope.las")
    with pytest.raises(UnsupportedFormatError):
        iter_chunks(tmp_path / "a.e57")


def test_text_writer_without_attributes_writes_bare_xyz_lines(tmp_path):
    cloud = PointCloud(np.array([[554808.866, 4178987.788, -11.466], [1.0, 2.0, 3.0]]))
    path = write_points(tmp_path / "bare.xyz", cloud)
    assert path.read_text() == "554808.866 4178987.788 -11.466\n1.0 2.0 3.0\n"
    assert write_points(tmp_path / "fixed.xyz", cloud, decimals=3).read_text().splitlines()[1] == "1.000 2.000 3.000"
    assert (tmp_path / "h.csv").exists() is False
    assert write_points(tmp_path / "h.csv", cloud).read_text().splitlines()[0] == "x,y,z"


def test_pts_writes_count_line_and_checks_it(tmp_path):
    cloud = PointCloud(utm_points(5))
    path = write_points(tmp_path / "scan.pts", cloud)
    assert path.read_text().splitlines()[0] == "5"
    np.testing.assert_array_equal(read_points(path).xyz, cloud.xyz)
    lines = path.read_text().splitlines()
    (tmp_path / "short.pts").write_text("\n".join(lines[:-1]) + "\n")
    with pytest.raises(PointCloudError, match="count line says 5 points but 4"):
        read_points(tmp_path / "short.pts")


def test_float32_and_bool_attributes_survive_text_as_values(tmp_path):
    cloud = PointCloud(
        utm_points(20), {"amp": np.linspace(0, 1, 20, dtype=np.float32), "hit": np.arange(20) % 3 == 0}
    )
    back = read_points(write_points(tmp_path / "a.xyz", cloud))
    np.testing.assert_array_equal(back.attributes["amp"].astype(np.float32), cloud.attributes["amp"])
    np.testing.assert_array_equal(back.attributes["hit"], cloud.attributes["hit"].astype(int))


def test_ply_and_npz_keep_attribute_dtypes_and_open3d_reads_our_ply(tmp_path):
    import open3d as o3d

    cloud = PointCloud(
        utm_points(50),
        {"amp": np.linspace(0, 1, 50, dtype=np.float32), "cls": np.arange(50, dtype=np.uint8), "t": np.arange(50.0)},
    )
    for suffix in (".ply", ".npz"):
        back = read_points(write_points(tmp_path / f"a{suffix}", cloud))
        for name, values in cloud.attributes.items():
            assert back.attributes[name].dtype == values.dtype
            np.testing.assert_array_equal(back.attributes[name], values)
    o3d_points = np.asarray(o3d.io.read_point_cloud(str(tmp_path / "a.ply")).points)
    np.testing.assert_array_equal(o3d_points, cloud.xyz)


@settings(max_examples=25, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(
    xyz=st.lists(
        st.tuples(
            st.floats(-1e7, 1e7, allow_nan=False, allow_infinity=False),
            st.floats(-1e7, 1e7, allow_nan=False, allow_infinity=False),
            st.floats(-1e4, 1e4, allow_nan=False, allow_infinity=False),
        ),
        min_size=1,
        max_size=30,
    )
)
def test_text_ply_npz_round_trip_any_float64_exactly(xyz):
    arr = np.array(xyz, dtype=np.float64)
    cloud = PointCloud(arr)
    with tempfile.TemporaryDirectory() as folder:
        for suffix in (".xyz", ".csv.gz", ".ply", ".npz"):
            back = read_points(write_points(Path(folder) / f"p{suffix}", cloud))
            np.testing.assert_array_equal(back.xyz, arr)


def test_writes_are_deterministic(tmp_path, monkeypatch):
    monkeypatch.setenv("SOURCE_DATE_EPOCH", "1700000000")
    cloud = scene_cloud()
    for suffix in (".xyz.gz", ".csv", ".ply", ".npz", ".las", ".laz"):
        a = write_points(tmp_path / f"a{suffix}", cloud).read_bytes()
        b = write_points(tmp_path / f"b{suffix}", cloud).read_bytes()
        assert a == b, suffix


# ---------------------------------------------------------------------------- the real survey line
@needs_real
def test_real_survey_line_reads_with_readme_bounds():
    # Read speed is measured by benchmarks/io_read.py, not asserted here.
    path = REAL_DIR / "r2sonic_sfbay.xyz.gz"
    cloud = read_points(path)
    assert len(cloud) == 236_287
    assert cloud.xyz.dtype == np.float64
    assert cloud.attributes == {} and cloud.crs is None
    lo, hi = cloud.bounds()
    np.testing.assert_allclose(lo, [554808.866, 4178987.788, -11.466], rtol=0, atol=5e-7)
    np.testing.assert_allclose(hi, [554845.392, 4179038.161, -9.675], rtol=0, atol=5e-7)
    assert abs(np.median(cloud.xyz[:, 2]) - (-10.51)) < 0.01


@needs_real
def test_real_soundings_csv_maps_header_and_keeps_attributes():
    cloud = read_points(REAL_DIR / "r2sonic_sfbay_soundings.csv.gz", crs="EPSG:32610")
    assert len(cloud) == 236_288
    assert cloud.crs == "EPSG:32610"
    assert set(cloud.attributes) == {
        "ping", "time_s", "beam", "angle_deg", "range_m", "twtt_s", "quality", "intensity", "accepted",
    }
    assert cloud.attributes["ping"].dtype == np.int64
    assert cloud.attributes["ping"].max() == 922 and cloud.attributes["beam"].max() == 255
    accepted = cloud.select(cloud.attributes["accepted"] == 1)
    assert len(accepted) == 236_287
    xyz = read_points(REAL_DIR / "r2sonic_sfbay.xyz.gz").xyz
    np.testing.assert_array_equal(accepted.xyz, xyz)


# ---------------------------------------------------------------------------- header mapping
def test_csv_header_in_other_order_maps_by_name(tmp_path):
    text = "Z,Easting (m),northing_m,intensity\n-11.5,554808.866,4178987.788,12\n-10.0,554809.5,4178990.25,7\n"
    cloud = read_points(write_text(tmp_path / "order.csv", text))
    np.testing.assert_array_equal(cloud.xyz, [[554808.866, 4178987.788, -11.5], [554809.5, 4178990.25, -10.0]])
    assert list(cloud.attributes) == ["intensity"]
    np.testing.assert_array_equal(cloud.attributes["intensity"], [12, 7])


def test_whitespace_header_comments_blank_lines_and_cloudcompare_header(tmp_path):
    text = "# exported by QINSy\n\n x\ty  z  q\n1 2 3 4\n\n# a comment\n5 6 7 8  # trailing comment\n"
    cloud = read_points(write_text(tmp_path / "c.txt", text))
    np.testing.assert_array_equal(cloud.xyz, [[1, 2, 3], [5, 6, 7]])
    np.testing.assert_array_equal(cloud.attributes["q"], [4, 8])
    cc = read_points(write_text(tmp_path / "cc.txt", "//X,Y,Z,R\n1,2,3,9\n4,5,6,9\n"))
    np.testing.assert_array_equal(cc.xyz, [[1, 2, 3], [4, 5, 6]])
    semi = read_points(write_text(tmp_path / "s.csv", "x;y;z\n1;2;3\n"))
    np.testing.assert_array_equal(semi.xyz, [[1, 2, 3]])


def test_headerless_extra_columns_and_columns_override(tmp_path):
    path = write_text(tmp_path / "h.xyz", "1 2 3 10 20\n4 5 6 11 21\n")
    cloud = read_points(path)
    assert list(cloud.attributes) == ["col3", "col4"]
    named = read_points(path, columns=["z", "x", "y", "ping", "beam"])
    np.testing.assert_array_equal(named.xyz, [[2, 3, 1], [5, 6, 4]])
    np.testing.assert_array_equal(named.attributes["beam"], [20, 21])


def test_depth_column_is_positive_down(tmp_path):
    """A `depth` column is read as z = -depth; depths that are mostly negative are elevations already
    and refused naming --z-positive up, which reads them as z."""
    path = write_text(tmp_path / "d.csv", "x,y,depth\n1,2,10.5\n3,4,11.0\n")
    cloud = read_points(path)
    np.testing.assert_array_equal(cloud.xyz[:, 2], [-10.5, -11.0])
    assert "depth" not in cloud.attributes
    np.testing.assert_array_equal(read_points(path, z_positive="down").xyz[:, 2], [-10.5, -11.0])
    up = write_text(tmp_path / "u.csv", "x,y,depth\n1,2,-10.5\n3,4,-11.0\n")
    with pytest.raises(PointCloudError, match=r"u\.csv: .*read as depths.*--z-positive up"):
        read_points(up)
    np.testing.assert_array_equal(read_points(up, z_positive="up").xyz[:, 2], [-10.5, -11.0])
    both = read_points(write_text(tmp_path / "b.csv", "x,y,z,depth\n1,2,-3,3\n"))
    np.testing.assert_array_equal(both.xyz, [[1, 2, -3]])
    np.testing.assert_array_equal(both.attributes["depth"], [3])


@pytest.mark.parametrize(
    "text, match",
    [
        ("lon,z\n-122.37,-10\n", r"cannot find column\(s\) \['x', 'y'\]"),
        ("x,easting,y,z\n1,2,3,4\n", "all name x"),
        ("a,b,c\n1,2,3\n", r"cannot find column\(s\) \['x', 'y', 'z'\]"),
        ("x,y,z,x\n1,2,3,4\n", "duplicate column names"),
    ],
    ids=["lonlat", "ambiguous", "unnamed", "duplicate"],
)
def test_bad_headers_are_explained(tmp_path, text, match):
    with pytest.raises(PointCloudError, match=match):
        read_points(write_text(tmp_path / "bad.csv", text))


def test_text_column_in_header_file_is_dropped_with_warning(tmp_path):
    path = write_text(tmp_path / "t.csv", "x,y,z,when\n1,2,3,2015-07-08\n4,5,6,2015-07-09\n")
    with pytest.warns(UserWarning, match="'when' is not numeric"):
        cloud = read_points(path)
    assert cloud.attributes == {}


# ---------------------------------------------------------------------------- bad inputs
def _lines(n: int, bad_at: int, bad: str) -> str:
    rows = [f"{5e5 + i * 0.01:.3f} {4e6 + i * 0.02:.3f} -11.{i:03d}" for i in range(n)]
    rows[bad_at - 1] = bad
    return "\n".join(rows) + "\n"


@pytest.mark.parametrize("gz", [False, True], ids=["plain", "gz"])
def test_too_few_columns_names_file_and_line(tmp_path, gz):
    path = write_text(tmp_path / ("survey.xyz.gz" if gz else "survey.xyz"), _lines(40, 17, "500000.1 4000000.2"), gz)
    with pytest.raises(PointCloudError) as err:
        read_points(path)
    assert str(err.value).startswith(f"{path} line 17: expected 3 columns, found 2")


def test_too_many_columns_names_line(tmp_path):
    path = write_text(tmp_path / "survey.xyz", _lines(40, 23, "1 2 3 4"))
    with pytest.raises(PointCloudError, match=r"survey\.xyz line 23: expected 3 columns, found 4"):
        read_points(path)


def test_wrong_column_count_counts_header_and_comment_lines(tmp_path):
    text = "# comment\nx,y,z,ping\n1,2,3,0\n4,5,6,1\n7,8,9\n"
    with pytest.raises(PointCloudError, match=r"line 5: expected 4 columns, found 3"):
        read_points(write_text(tmp_path / "h.csv", text))


def test_non_numeric_value_names_line_and_column(tmp_path):
    path = write_text(tmp_path / "survey.xyz", _lines(30, 12, "500000.1 4000000.2 -11.x"))
    with pytest.raises(PointCloudError, match=r"line 12, column 3 \(z\): cannot parse '-11.x'"):
        read_points(path)
    csv = write_text(tmp_path / "s.csv", "x,y,z,ping\n1,2,3,0\n4,5,6,oops\n")
    with pytest.raises(PointCloudError, match=r"line 3, column 4 \(ping\): cannot parse 'oops'"):
        read_points(csv)
    empty_field = write_text(tmp_path / "e.csv", "x,y,z\n1,2,3\n4,,6\n")
    with pytest.raises(PointCloudError, match=r"line 3, column 2 \(y\): cannot parse ''"):
        read_points(empty_field)


def test_nan_coordinates_name_file_line_and_row(tmp_path):
    path = write_text(tmp_path / "survey.xyz", "# header comment\n" + _lines(30, 9, "500000.1 nan -11.0"))
    with pytest.raises(PointCloudError) as err:
        read_points(path)
    message = str(err.value)
    assert str(path) in message and "line 10 (point 8)" in message and "non-finite" in message
    inf = write_text(tmp_path / "inf.xyz", _lines(5, 5, "1 2 inf"))
    with pytest.raises(PointCloudError, match=r"line 5 \(point 4\)"):
        read_points(inf)


def test_nan_coordinates_in_npz_name_the_point(tmp_path):
    xyz = utm_points(10)
    xyz[6, 0] = np.nan
    np.savez(tmp_path / "scene.npz", xyz=xyz)
    with pytest.raises(PointCloudError, match=r"scene\.npz point 6 \(0-based\): non-finite"):
        read_points(tmp_path / "scene.npz")


@pytest.mark.parametrize(
    "text", ["", "\n\n", "# only a comment\n", "x y z\n"], ids=["empty", "blank", "comment", "header-only"]
)
def test_empty_text_files_have_no_points(tmp_path, text):
    with pytest.raises(PointCloudError, match="no points"):
        read_points(write_text(tmp_path / "empty.xyz", text))


def test_las_without_points_is_refused(tmp_path):
    path = tmp_path / "empty.las"
    laspy.LasData(laspy.LasHeader(point_format=6, version="1.4")).write(path)
    with pytest.raises(PointCloudError, match=r"empty\.las: no points"):
        read_points(path)


def test_garbage_files_are_refused_with_the_file_name(tmp_path):
    for name in ("junk.las", "junk.laz", "junk.ply", "junk.npz"):
        (tmp_path / name).write_bytes(b"this is not a point cloud\n")
        with pytest.raises(PointCloudError, match=name.replace(".", r"\.")):
            read_points(tmp_path / name)
    (tmp_path / "cut.xyz.gz").write_bytes(gzip.compress(b"1 2 3\n4 5 6\n" * 100)[:-20])
    with pytest.raises(PointCloudError, match=r"cut\.xyz\.gz"):
        read_points(tmp_path / "cut.xyz.gz")


def test_unknown_suffix_lists_supported_ones(tmp_path):
    path = tmp_path / "cloud.e57"
    path.write_bytes(b"")
    with pytest.raises(UnsupportedFormatError, match=r"\.xyz, \.txt, .*\.las, \.laz, \.ply, \.npz"):
        read_points(path)
    with pytest.raises(UnsupportedFormatError, match="supported"):
        write_points(tmp_path / "cloud.bin", scene_cloud())
    assert point_format("A.XYZ.GZ") == "text" and point_format("b.LAZ") == "las"
    assert set(SUPPORTED_SUFFIXES) >= {".xyz", ".xyz.gz", ".csv", ".las", ".laz", ".ply", ".npz"}


def test_missing_file_and_text_only_options(tmp_path):
    with pytest.raises(FileNotFoundError):
        read_points(tmp_path / "nope.xyz")
    path = write_points(tmp_path / "a.npz", scene_cloud())
    with pytest.raises(PointCloudError, match=r"columns \(--columns\) do\(es\) not apply to npz files"):
        read_points(path, columns=["x", "y", "z"])
    with pytest.raises(PointCloudError, match=r"z_positive \(--z-positive\) do\(es\) not apply to npz files"):
        read_points(path, z_positive="down")


# ---------------------------------------------------------------------------- npz contract
def test_npz_contract_validation(tmp_path):
    xyz = utm_points(10)
    np.savez(tmp_path / "noxyz.npz", points=xyz)
    with pytest.raises(PointCloudError, match="no 'xyz' entry"):
        read_points(tmp_path / "noxyz.npz")
    np.savez(tmp_path / "len.npz", xyz=xyz, ping=np.arange(9))
    with pytest.raises(PointCloudError, match=r"field 'ping' has shape \(9,\)"):
        read_points(tmp_path / "len.npz")
    np.savez(tmp_path / "f32.npz", xyz=xyz.astype(np.float32))
    with pytest.raises(GlobalCoordinatesError, match="float32"):
        read_points(tmp_path / "f32.npz")
    np.savez(tmp_path / "empty.npz", xyz=np.zeros((0, 3)))
    with pytest.raises(PointCloudError, match="no points"):
        read_points(tmp_path / "empty.npz")
    np.savez(tmp_path / "ok.npz", xyz=xyz, label=np.full(10, -1), crs=np.array("epsg:32610"))
    cloud = read_points(tmp_path / "ok.npz")
    assert cloud.crs == "EPSG:32610" and cloud.origin is None
    np.testing.assert_array_equal(cloud.xyz, xyz)


# ---------------------------------------------------------------------------- CRS handling
def test_crs_argument_sets_and_must_agree(tmp_path):
    cloud = scene_cloud()
    las = write_points(tmp_path / "a.las", cloud)
    assert read_points(las, crs="epsg:32610").crs == "EPSG:32610"
    with pytest.raises(PointCloudError, match="declares CRS 'EPSG:32610' but crs='EPSG:32611'"):
        read_points(las, crs="EPSG:32611")
    txt = write_points(tmp_path / "a.xyz", cloud)
    assert read_points(txt).crs is None
    assert read_points(txt, crs="EPSG:32610").crs == "EPSG:32610"


def test_las_crs_is_a_standard_wkt1_record(tmp_path):
    path = write_points(tmp_path / "a.las", scene_cloud())
    las = laspy.read(path)
    assert las.header.version == laspy.header.Version(1, 4) and las.header.point_format.id == 6
    np.testing.assert_array_equal(las.header.scales, [0.001] * 3)
    np.testing.assert_array_equal(las.header.offsets, np.floor(scene_cloud().xyz.min(axis=0)))
    assert las.header.global_encoding.wkt
    wkt = [v for v in las.header.vlrs if isinstance(v, laspy.vlrs.known.WktCoordinateSystemVlr)]
    assert len(wkt) == 1 and '"central_meridian",-123' in wkt[0].string
    assert wkt[0].string.endswith('AUTHORITY["EPSG","32610"]]')
    assert set(np.unique(las.return_number)) == {1}


def test_las_crs_from_geotiff_keys_and_other_crs_fallback(tmp_path):
    header = laspy.LasHeader(point_format=3, version="1.2")
    header.offsets = [5e5, 4e6, 0]
    header.scales = [0.01, 0.01, 0.01]
    geokeys = laspy.vlrs.known.GeoKeyDirectoryVlr()
    geokeys.geo_keys_header.number_of_keys = 1
    geokeys.geo_keys[0].id = 3072
    geokeys.geo_keys[0].value_offset = 32611
    header.vlrs.append(geokeys)
    las = laspy.LasData(header)
    las.x, las.y, las.z = np.array([5e5 + 1.0]), np.array([4e6 + 2.0]), np.array([-11.0])
    las.classification = np.array([2], dtype=np.uint8)
    las.write(tmp_path / "old.las")
    cloud = read_points(tmp_path / "old.las")
    assert cloud.crs == "EPSG:32611"
    assert list(cloud.attributes) == ["classification"]  # all-zero standard fields are left out
    np.testing.assert_allclose(cloud.xyz, [[5e5 + 1.0, 4e6 + 2.0, -11.0]], rtol=0, atol=1e-9)

    other = PointCloud(utm_points(5), crs="EPSG:2193")
    write_points(tmp_path / "nz.laz", other)
    assert read_points(tmp_path / "nz.laz").crs == "EPSG:2193"
    compound = PointCloud(utm_points(5), crs="EPSG:32610+5703")
    write_points(tmp_path / "navd88.laz", compound)
    assert read_points(tmp_path / "navd88.laz").crs == "EPSG:32610+5703"
    with pytest.raises(PointCloudError, match="pyproj does not understand"):
        write_points(tmp_path / "bad.las", PointCloud(utm_points(5), crs="EPSG:99999999"))


def test_las_standard_field_must_fit(tmp_path):
    cloud = PointCloud(utm_points(5), {"intensity": np.linspace(0, 1, 5)})
    with pytest.raises(PointCloudError, match="'intensity' has values that do not fit"):
        write_points(tmp_path / "a.las", cloud)
    assert not list(tmp_path.iterdir())
    ok = PointCloud(utm_points(5), {"classification": np.array([2, 2, 1, 7, 2])})
    back = read_points(write_points(tmp_path / "b.las", ok))
    np.testing.assert_array_equal(back.attributes["classification"], [2, 2, 1, 7, 2])


def test_las_span_too_large_for_scale(tmp_path):
    cloud = PointCloud(np.array([[0.0, 0.0, 0.0], [3e6, 0.0, 0.0]]))
    with pytest.raises(PointCloudError, match="coarser las_scale_m"):
        write_points(tmp_path / "big.las", cloud)
    back = read_points(write_points(tmp_path / "big.las", cloud, las_scale_m=0.01))
    np.testing.assert_array_equal(back.xyz, cloud.xyz)


# ---------------------------------------------------------------------------- PLY specifics
def test_ascii_ply_and_float32_ply(tmp_path):
    header = (
        "ply\nformat ascii 1.0\ncomment crs EPSG:32610\nelement vertex 2\n"
        "property double x\nproperty double y\nproperty double z\nproperty uchar label\nend_header\n"
    )
    path = tmp_path / "a.ply"
    path.write_text(header + "554808.866 4178987.788 -11.466 3\n554845.392 4179038.161 -9.675 4\n")
    cloud = read_points(path)
    np.testing.assert_array_equal(cloud.xyz, [[554808.866, 4178987.788, -11.466], [554845.392, 4179038.161, -9.675]])
    assert cloud.crs == "EPSG:32610"
    np.testing.assert_array_equal(cloud.attributes["label"], [3, 4])

    f32 = "ply\nformat ascii 1.0\nelement vertex 1\nproperty float x\nproperty float y\nproperty float z\nend_header\n"
    (tmp_path / "utm32.ply").write_text(f32 + "554808.866 4178987.788 -11.466\n")
    with pytest.raises(GlobalCoordinatesError, match=r"utm32\.ply.*float32"):
        read_points(tmp_path / "utm32.ply")
    (tmp_path / "local32.ply").write_text(f32 + "8.5 7.25 -11.5\n")
    local = read_points(tmp_path / "local32.ply")
    assert local.xyz.dtype == np.float64
    np.testing.assert_array_equal(local.xyz, [[8.5, 7.25, -11.5]])


def test_ply_without_points_or_coordinates(tmp_path):
    empty = "ply\nformat ascii 1.0\nelement vertex 0\nproperty double x\nproperty double y\nproperty double z\nend_header\n"
    (tmp_path / "e.ply").write_text(empty)
    with pytest.raises(PointCloudError, match="no points"):
        read_points(tmp_path / "e.ply")
    noz = "ply\nformat ascii 1.0\nelement vertex 1\nproperty double x\nproperty double y\nend_header\n1 2\n"
    (tmp_path / "noz.ply").write_text(noz)
    with pytest.raises(PointCloudError, match=r"lacks properties \['z'\]"):
        read_points(tmp_path / "noz.ply")


def test_ply_refuses_int64_beyond_int32(tmp_path):
    cloud = PointCloud(utm_points(2), {"big": np.array([0, 2**40])})
    with pytest.raises(PointCloudError, match="no 64-bit"):
        write_points(tmp_path / "a.ply", cloud)


# ---------------------------------------------------------------------------- atomic writes
@pytest.mark.parametrize("suffix", [".xyz.gz", ".npz", ".ply", ".laz"])
def test_failed_write_leaves_no_partial_file_and_keeps_the_old_one(tmp_path, monkeypatch, suffix):
    target = tmp_path / f"out{suffix}"
    write_points(target, scene_cloud(seed=1))
    before = target.read_bytes()

    def boom(*args, **kwargs):
        raise RuntimeError("disk full")

    import numpy.lib.format
    import pandas as pd

    if suffix == ".npz":
        monkeypatch.setattr(numpy.lib.format, "write_array", boom)
    elif suffix == ".xyz.gz":
        monkeypatch.setattr(pd.DataFrame, "to_csv", boom)
    elif suffix == ".ply":
        real_open = open

        class HalfWritten:
            """Writes the header, then fails on the vertex data."""

            def __init__(self, *args, **kwargs):
                self.fh = real_open(*args, **kwargs)
                self.calls = 0

            def __enter__(self):
                return self

            def __exit__(self, *exc):
                self.fh.close()

            def write(self, data):
                self.calls += 1
                if self.calls > 1:
                    boom()
                return self.fh.write(data)

        monkeypatch.setattr("sonardet.io.points.ply.open", HalfWritten, raising=False)
    else:
        monkeypatch.setattr(laspy.LasData, "write", boom)
    with pytest.raises(RuntimeError, match="disk full"):
        write_points(target, scene_cloud(seed=2))
    assert target.read_bytes() == before
    assert sorted(os.listdir(tmp_path)) == [target.name]


def test_write_refuses_empty_cloud(tmp_path):
    with pytest.raises(PointCloudError, match="no points"):
        write_points(tmp_path / "e.npz", PointCloud(np.zeros((0, 3))))
    assert not list(tmp_path.iterdir())


# ---------------------------------------------------------------------------- PointCloud object
def test_pointcloud_validates_its_fields():
    xyz = utm_points(4)
    with pytest.raises(PointCloudError, match=r"shape \(N, 3\)"):
        PointCloud(xyz[:, :2])
    with pytest.raises(PointCloudError, match="4 values"):
        PointCloud(xyz, {"ping": np.arange(3)})
    with pytest.raises(PointCloudError, match="reserved"):
        PointCloud(xyz, {"origin": np.arange(4)})
    with pytest.raises(PointCloudError, match="origin"):
        PointCloud(xyz, origin=np.array([1.0, 2.0]))
    with pytest.raises(GlobalCoordinatesError):
        PointCloud(xyz.astype(np.float32))
    bad = xyz.copy()
    bad[2, 2] = np.inf
    with pytest.raises(PointCloudError, match=r"point 2 \(0-based\)"):
        PointCloud(bad, source="mem.npz")
    local32 = PointCloud(np.array([[1.5, 2.5, -3.0]], dtype=np.float32))
    assert local32.xyz.dtype == np.float64
    cloud = PointCloud(xyz, {"ping": np.arange(4)}, crs=" epsg:32610 ")
    assert cloud.crs == "EPSG:32610" and len(cloud) == cloud.n_points == 4
    sub = cloud.select(np.array([True, False, True, False]))
    np.testing.assert_array_equal(sub.attributes["ping"], [0, 2])
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        assert cloud.local(np.float32).dtype == np.float32
