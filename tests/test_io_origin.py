"""Tests for sonardet.io.origin: the local-origin shift that keeps float32 work away from UTM values."""

from __future__ import annotations

import json

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from sonardet.io.origin import (
    LOCAL_LIMIT_M,
    GlobalCoordinatesError,
    LocalFrame,
    as_float32,
    assert_local,
    choose_origin,
    to_global,
    to_local,
)
from conftest import REAL_FILE, needs_real
from sonardet.io.points import PointCloud, read_points


REAL = REAL_FILE


@pytest.fixture(scope="module")
def real_cloud() -> PointCloud:
    return read_points(REAL)


def utm_cloud(n: int = 500, seed: int = 0) -> np.ndarray:
    rng = np.random.default_rng(seed)
    return np.column_stack(
        [554800.0 + rng.uniform(0, 50, n), 4178990.0 + rng.uniform(0, 50, n), rng.uniform(-11.5, -9.5, n)]
    )


# ---------------------------------------------------------------------------- choose_origin
def test_choose_origin_floors_min_xy_and_keeps_z_zero():
    xyz = np.array([[554808.866, 4178987.788, -11.466], [554845.392, 4179038.161, -9.675]])
    origin = choose_origin(xyz)
    assert origin.dtype == np.float64 and origin.shape == (3,)
    np.testing.assert_array_equal(origin, [554808.0, 4178987.0, 0.0])
    np.testing.assert_array_equal(choose_origin(xyz, round_m=100.0), [554800.0, 4178900.0, 0.0])


def test_choose_origin_negative_coordinates_floor_down():
    xyz = np.array([[-10.5, -0.2, 3.0], [5.0, 2.0, 4.0]])
    np.testing.assert_array_equal(choose_origin(xyz), [-11.0, -1.0, 0.0])


def test_choose_origin_is_deterministic_and_order_invariant():
    xyz = utm_cloud()
    np.testing.assert_array_equal(choose_origin(xyz), choose_origin(xyz[::-1]))


@pytest.mark.parametrize(
    "bad, match",
    [
        (np.zeros((0, 3)), "no points"),
        (np.array([[np.nan, 1.0, 2.0]]), "NaN or Inf"),
        (np.zeros((4, 2)), r"\(N, 3\)"),
    ],
    ids=["empty", "nan", "wrong-shape"],
)
def test_choose_origin_refuses_degenerate_input(bad, match):
    with pytest.raises(ValueError, match=match):
        choose_origin(bad)


def test_choose_origin_refuses_bad_rounding():
    with pytest.raises(ValueError, match="round_m"):
        choose_origin(utm_cloud(), round_m=0.0)


# ---------------------------------------------------------------------------- shifts
def test_to_local_to_global_round_trip_float64():
    xyz = utm_cloud()
    origin = choose_origin(xyz)
    local = to_local(xyz, origin)
    assert local.dtype == np.float64
    assert np.abs(local[:, :2]).max() < 60
    np.testing.assert_allclose(to_global(local, origin), xyz, rtol=0, atol=1e-9)


def test_to_local_float32_result_and_back_within_a_micrometre():
    xyz = utm_cloud()
    frame = LocalFrame.from_points(xyz, crs="EPSG:32610")
    local32 = frame.to_local(xyz, dtype=np.float32)
    assert local32.dtype == np.float32
    back = frame.to_global(local32)
    assert back.dtype == np.float64
    assert np.abs(back - xyz).max() < 1e-5


def test_to_local_refuses_float32_global_input():
    """The precision is gone before the shift: refuse rather than pretend."""
    xyz32 = utm_cloud().astype(np.float32)
    with pytest.raises(GlobalCoordinatesError, match="float64"):
        to_local(xyz32, choose_origin(utm_cloud()))


def test_to_local_float32_with_far_origin_is_refused():
    xyz = utm_cloud()
    with pytest.raises(GlobalCoordinatesError, match="local-frame limit"):
        to_local(xyz, np.zeros(3), dtype=np.float32)


def test_to_local_rejects_integer_dtype_and_bad_origin():
    xyz = utm_cloud()
    with pytest.raises(ValueError, match="floating"):
        to_local(xyz, choose_origin(xyz), dtype=np.int32)
    with pytest.raises(ValueError, match="origin"):
        to_local(xyz, [1.0, 2.0])
    with pytest.raises(ValueError, match="finite"):
        to_local(xyz, [np.nan, 0.0, 0.0])


# ---------------------------------------------------------------------------- guard
def test_assert_local_accepts_local_and_refuses_utm():
    assert_local(np.array([[12.0, -40.0, -11.0]]))
    assert_local(np.array([[LOCAL_LIMIT_M, 0.0, 0.0]]))  # the limit itself is allowed
    with pytest.raises(GlobalCoordinatesError, match="UTM"):
        assert_local(utm_cloud())
    with pytest.raises(GlobalCoordinatesError):
        as_float32(utm_cloud())
    assert as_float32(np.array([[1.5, 2.5, -3.0]])).dtype == np.float32


def test_assert_local_ignores_non_finite_values_and_empty_arrays():
    assert_local(np.array([[np.nan, 1.0, np.inf]]))
    assert_local(np.zeros((0, 3)))


# ---------------------------------------------------------------------------- LocalFrame
def test_local_frame_json_round_trip_is_exact():
    frame = LocalFrame(np.array([554808.0, 4178987.123456789, 0.0]), "EPSG:32610")
    again = LocalFrame.from_dict(json.loads(json.dumps(frame.to_dict())))
    assert again == frame
    assert hash(again) == hash(frame)
    with pytest.raises(ValueError):
        frame.origin[0] = 1.0  # read-only: a frame cannot drift after results were computed in it
    with pytest.raises(ValueError, match="origin"):
        LocalFrame.from_dict({"crs": None})


def test_pointcloud_frame_uses_stored_origin():
    xyz = utm_cloud()
    cloud = PointCloud(xyz, origin=np.array([554000.0, 4178000.0, 0.0]), crs="EPSG:32610")
    frame = cloud.frame()
    np.testing.assert_array_equal(frame.origin, [554000.0, 4178000.0, 0.0])
    assert frame.crs == "EPSG:32610"
    assert cloud.local(np.float32).dtype == np.float32
    np.testing.assert_array_equal(PointCloud(xyz).frame().origin, choose_origin(xyz))


# ---------------------------------------------------------------------------- the real survey line
@needs_real
def test_real_file_float32_local_round_trip_loses_less_than_a_millimetre(real_cloud):
    """UTM offsets, the hard case: shift, float32, shift back must lose < 1 mm."""
    frame = real_cloud.frame()
    np.testing.assert_array_equal(frame.origin, [554808.0, 4178987.0, 0.0])
    local32 = real_cloud.local(np.float32)
    assert local32.dtype == np.float32
    assert np.abs(local32).max() < 60.0
    err = np.abs(frame.to_global(local32) - real_cloud.xyz).max()
    assert err < 1e-3, err
    assert err < 1e-5  # in fact micrometres: float32 spacing at 50 m is 3.8e-6 m


@needs_real
def test_real_file_raw_float32_would_lose_decimetres_and_the_guard_refuses(real_cloud):
    raw32_err = np.abs(real_cloud.xyz.astype(np.float32).astype(np.float64) - real_cloud.xyz)
    # float32 spacing is 0.0625 m near 5.5e5 and 0.5 m near 4.18e6: up to ~0.25 m of rounding.
    assert 0.1 < raw32_err[:, 1].max() <= 0.25
    assert raw32_err[:, 0].max() > 0.02
    with pytest.raises(GlobalCoordinatesError, match="UTM"):
        assert_local(real_cloud.xyz)
    with pytest.raises(GlobalCoordinatesError):
        as_float32(real_cloud.xyz)
    with pytest.raises(GlobalCoordinatesError):
        PointCloud(real_cloud.xyz.astype(np.float32))


# ---------------------------------------------------------------------------- property
@settings(max_examples=40, deadline=None)
@given(
    east=st.floats(166_000, 834_000),
    north=st.floats(0, 9_300_000),
    extent=st.floats(0.5, 2_000.0),
    seed=st.integers(0, 2**32 - 1),
)
def test_float32_local_round_trip_within_a_millimetre_anywhere_in_utm(east, north, extent, seed):
    rng = np.random.default_rng(seed)
    xyz = np.column_stack(
        [east + rng.uniform(0, extent, 64), north + rng.uniform(0, extent, 64), rng.uniform(-200, 10, 64)]
    )
    frame = LocalFrame.from_points(xyz)
    back = frame.to_global(frame.to_local(xyz, dtype=np.float32))
    assert np.abs(back - xyz).max() < 1e-3
