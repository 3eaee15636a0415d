"""Rotations and boxes."""

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from sonardet.geometry import (
    box_corners,
    box_from_points,
    box_of_posed_vertices,
    matrix_to_quat,
    points_in_box,
    quat_from_yaw,
    quat_multiply,
    quat_normalize,
    quat_to_matrix,
    random_quat,
    wrap_angle,
    yaw_of_matrix,
)


def test_quat_matrix_round_trip():
    rng = np.random.default_rng(0)
    for _ in range(200):
        q = random_quat(rng)
        r = quat_to_matrix(q)
        assert np.allclose(r @ r.T, np.eye(3), atol=1e-12)
        assert np.isclose(np.linalg.det(r), 1.0)
        assert np.allclose(matrix_to_quat(r), q, atol=1e-10)


def test_matrix_to_quat_near_180_degrees_is_stable():
    # Hard case: rotations by ~pi, where the trace-based formula divides by ~0.
    for axis in np.eye(3):
        r = quat_to_matrix(np.r_[1e-9, axis])
        assert np.allclose(quat_to_matrix(matrix_to_quat(r)), r, atol=1e-9)


def test_zero_quaternion_rejected():
    with pytest.raises(ValueError):
        quat_normalize([0, 0, 0, 0])


def test_one_quaternion_converts_to_the_bit_as_a_batch_of_one():
    """A single quaternion takes a fast path on Python floats; a batch of one takes numpy's: the
    same matrix and unit quaternion bit for bit (signs of zeros included), and both refuse alike."""
    rng = np.random.default_rng(5)
    qs = rng.normal(size=(3000, 4)) * 10.0 ** rng.integers(-8, 5, size=(3000, 1))
    qs[::7, 0] = -np.abs(qs[::7, 0])                     # w < 0: the sign flip
    qs[1::7, rng.integers(4)] = 0.0                      # exact zeros
    qs[2::7] = np.round(qs[2::7], 1)
    qs = np.vstack([qs, [[1, 0, 0, 0], [0, 0, 0, -1], [-0.0, 1, 0, 0], [1e200, 1e200, 0, 0], [1e-13, 1e-13, 0, 0]]])
    for q in qs:
        try:
            want_m, want_q = quat_to_matrix(q[None])[0], quat_normalize(q[None])[0]
        except ValueError:
            for f in (quat_to_matrix, quat_normalize):
                with pytest.raises(ValueError):
                    f(q)
            continue
        got_m, got_q = quat_to_matrix(q), quat_normalize(q)
        for got, want in ((got_m, want_m), (got_q, want_q)):
            assert got.dtype == want.dtype and got.shape == want.shape
            assert np.array_equal(got, want, equal_nan=True) and np.array_equal(np.signbit(got), np.signbit(want))
    for bad in ([0, 0, 0, 0], [np.nan, 1, 0, 0], [np.inf, 0, 0, 0], [1e-13, 0, 0, 0]):
        for f in (quat_to_matrix, quat_normalize):
            with pytest.raises(ValueError, match="finite and non-zero"):
                f(bad)


def test_yaw_of_yaw_rotation_and_composition():
    for yaw in np.linspace(-3.1, 3.1, 13):
        assert np.isclose(yaw_of_matrix(quat_to_matrix(quat_from_yaw(yaw))), yaw)
    q = quat_multiply(quat_from_yaw(0.3), quat_from_yaw(0.4))
    assert np.isclose(yaw_of_matrix(quat_to_matrix(q)), 0.7)


def test_yaw_defined_when_x_axis_vertical():
    r = quat_to_matrix([np.cos(np.pi / 4), 0, -np.sin(np.pi / 4), 0])  # +x rotated to +z
    assert np.isfinite(yaw_of_matrix(r))


def test_wrap_angle_range():
    a = wrap_angle(np.linspace(-20, 20, 1001))
    assert a.min() >= -np.pi and a.max() < np.pi


@settings(max_examples=60, deadline=None)
@given(
    l=st.floats(0.1, 5), w=st.floats(0.1, 5), h=st.floats(0.1, 3), yaw=st.floats(-np.pi, np.pi),
    x=st.floats(-1e3, 1e3), y=st.floats(-1e3, 1e3), z=st.floats(-20, 0),
)
def test_box_of_rotated_cuboid_recovers_it(l, w, h, yaw, x, y, z):
    """Property: the box of a cuboid mesh posed by (t, yaw) is the cuboid itself."""
    corners = np.array([[sx * l / 2, sy * w / 2, sz * h] for sx in (-1, 1) for sy in (-1, 1) for sz in (0, 1)])
    box = box_of_posed_vertices(corners, [x, y, z], quat_from_yaw(yaw))
    assert np.allclose(box[:6], [x, y, z + h / 2, l, w, h], atol=1e-6)
    assert np.isclose(wrap_angle(box[6] - yaw), 0, atol=1e-9)
    # Every corner lies on the box; the corners function gives back the same cuboid.
    posed = corners @ quat_to_matrix(quat_from_yaw(yaw)).T + [x, y, z]
    assert points_in_box(posed, box, margin_m=1e-6).all()
    assert np.allclose(np.sort(box_corners(box), axis=0), np.sort(posed, axis=0), atol=1e-6)


def test_points_in_box_rejects_outside_points():
    box = np.array([0, 0, 0, 2, 1, 1, np.pi / 2])  # l along +y after the yaw
    pts = np.array([[0, 0.99, 0], [0.49, 0, 0], [0.6, 0, 0], [0, 1.1, 0], [0, 0, 0.6]])
    assert points_in_box(pts, box).tolist() == [True, True, False, False, False]


def test_box_from_points_rejects_empty():
    with pytest.raises(ValueError):
        box_from_points(np.zeros((0, 3)), 0.0)
