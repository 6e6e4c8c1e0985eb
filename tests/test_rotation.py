"""Quaternion / DCM / Euler conventions (book eqs. 2.5, 2.7, 2.10–2.13; DIGEST_000 §9)."""

from __future__ import annotations

import math

import numpy as np
from hypothesis import given
from hypothesis import strategies as st

from ins_hil.nav import rotation as R

angle = st.floats(-math.pi, math.pi, allow_nan=False)
pitch_s = st.floats(-1.5, 1.5, allow_nan=False)
vec3 = st.lists(st.floats(-3.0, 3.0, allow_nan=False), min_size=3, max_size=3).map(np.array)


@given(angle, pitch_s, angle)
def test_euler_quat_dcm_round_trip(roll: float, pitch: float, yaw: float) -> None:
    q = R.quat_from_euler(roll, pitch, yaw)
    assert abs(np.linalg.norm(q) - 1) < 1e-14
    C = R.dcm_from_quat(q)
    np.testing.assert_allclose(C, R.dcm_from_euler(roll, pitch, yaw), atol=1e-14)
    # angles compared modulo 2π: ±π are the same roll/yaw (hypothesis found yaw = −π → +π)
    for e in (R.euler_from_quat(q), R.euler_from_dcm(C)):
        d = np.asarray(e) - [roll, pitch, yaw]
        np.testing.assert_allclose(np.angle(np.exp(1j * d)), 0.0, atol=1e-9)
    assert R.quat_angle_between(R.quat_from_dcm(C), q) < 1e-7


@given(vec3, vec3)
def test_quat_rotation_matches_dcm(phi: np.ndarray, v: np.ndarray) -> None:
    q = R.quat_from_rotvec(phi)
    qv = R.quat_mul(R.quat_mul(q, np.r_[0.0, v]), R.quat_conj(q))
    np.testing.assert_allclose(qv[1:], R.dcm_from_quat(q) @ v, atol=1e-12)
    np.testing.assert_allclose(R.quat_rotate(q, v), R.dcm_from_quat(q) @ v, atol=1e-12)


@given(vec3)
def test_rotvec_round_trip(phi: np.ndarray) -> None:
    q = R.quat_from_rotvec(phi)
    back = R.rotvec_from_quat(q)
    assert R.quat_angle_between(R.quat_from_rotvec(back), q) < 1e-9


def test_book_A_is_eq_2_5() -> None:
    """A(λ) of eq. 2.5, element by element, equals C_n^b."""
    l0, l1, l2, l3 = R.quat_normalize(np.array([0.7, 0.2, -0.4, 0.5]))
    A = np.array(
        [
            [l0**2 + l1**2 - l2**2 - l3**2, 2 * (l1 * l2 + l0 * l3), 2 * (l1 * l3 - l0 * l2)],
            [2 * (l1 * l2 - l0 * l3), l0**2 - l1**2 + l2**2 - l3**2, 2 * (l2 * l3 + l0 * l1)],
            [2 * (l1 * l3 + l0 * l2), 2 * (l2 * l3 - l0 * l1), l0**2 - l1**2 - l2**2 + l3**2],
        ]
    )
    q = np.array([l0, l1, l2, l3])
    np.testing.assert_allclose(R.book_A(q), A, atol=1e-15)
    # eq. 2.7 applied to A recovers λ
    s = math.sqrt(1 + A[0, 0] + A[1, 1] + A[2, 2])
    lam = np.array([s / 2, (A[1, 2] - A[2, 1]) / (2 * s), (A[2, 0] - A[0, 2]) / (2 * s), (A[0, 1] - A[1, 0]) / (2 * s)])
    np.testing.assert_allclose(lam, q, atol=1e-14)
    np.testing.assert_allclose(R.quat_from_dcm(A.T), q, atol=1e-14)


def test_kinematics_eq_2_10_is_right_product() -> None:
    """λ̇ = ½ Ω λ (eq. 2.10) equals ½ λ ⊗ (0, ω_body)."""
    lam = R.quat_normalize(np.array([0.9, 0.1, 0.3, -0.2]))
    w1, w2, w3 = 0.3, -0.7, 1.1
    Om = np.array([[0, -w1, -w2, -w3], [w1, 0, w3, -w2], [w2, -w3, 0, w1], [w3, w2, -w1, 0]])
    np.testing.assert_allclose(0.5 * Om @ lam, 0.5 * R.quat_mul(lam, np.array([0, w1, w2, w3])), atol=1e-15)


def test_yaw_90_maps_body_x_to_east() -> None:
    q = R.quat_from_euler(0.0, 0.0, math.pi / 2)
    np.testing.assert_allclose(R.quat_rotate(q, np.array([1.0, 0, 0])), [0, 1, 0], atol=1e-15)
    # pitch up: nose (body x) points up, i.e. negative down
    q = R.quat_from_euler(0.0, 0.3, 0.0)
    assert R.quat_rotate(q, np.array([1.0, 0, 0]))[2] < 0


def _seed003_slerp(q0: np.ndarray, q1: np.ndarray, t: float) -> np.ndarray:
    """Seed 003's printed formula (lines 896–902): sin((1−t)θ)/sin θ·q0 + sin(tθ)/sin θ·q1, cos θ = q0·q1."""
    th = math.acos(float(np.clip(q0 @ q1, -1.0, 1.0)))
    return (math.sin((1 - t) * th) * q0 + math.sin(t * th) * q1) / math.sin(th)


def _rand_quat(rng: np.random.Generator) -> np.ndarray:
    q = rng.normal(size=4)
    return q / np.linalg.norm(q)


def test_slerp_matches_scipy_and_the_seed_formula() -> None:
    """Against scipy's Slerp (scalar-last, an independent implementation) and, for q0·q1 ≥ 0, against the seed's
    own formula component by component (up to the sign of the whole quaternion)."""
    from scipy.spatial.transform import Rotation, Slerp

    rng = np.random.default_rng(3)
    ts = np.linspace(0.0, 1.0, 11)
    for _ in range(100):
        q0, q1 = _rand_quat(rng), _rand_quat(rng)
        ref = Slerp([0.0, 1.0], Rotation.from_quat(np.array([q0, q1])[:, [1, 2, 3, 0]]))(ts).as_quat()[:, [3, 0, 1, 2]]
        for t, r in zip(ts, ref, strict=True):
            q = R.quat_slerp(q0, q1, t)
            assert abs(np.linalg.norm(q) - 1.0) < 1e-14
            assert R.quat_angle_between(q, r) < 1e-7  # quat_angle_between's own floor (atan2 of |vec| ~ 1e-8)
            assert min(np.max(np.abs(q - r)), np.max(np.abs(q + r))) < 1e-12
            if q0 @ q1 > 0.0:  # ours is returned with a non-negative scalar part (quat_normalize): ± the seed's
                s = _seed003_slerp(q0, q1, t)
                assert min(np.max(np.abs(q - s)), np.max(np.abs(q + s))) < 1e-12


def test_slerp_takes_the_shortest_path_and_endpoints() -> None:
    rng = np.random.default_rng(5)
    for _ in range(50):
        q0, q1 = _rand_quat(rng), _rand_quat(rng)
        th = R.quat_angle_between(q0, q1)
        for t in (0.0, 0.25, 0.5, 1.0):
            a, b = R.quat_slerp(q0, q1, t), R.quat_slerp(q0, -q1, t)  # −q1 is the same attitude
            assert min(np.max(np.abs(a - b)), np.max(np.abs(a + b))) < 1e-12
            assert abs(R.quat_angle_between(q0, a) - t * th) < 1e-9
            assert abs(R.quat_angle_between(a, q1) - (1 - t) * th) < 1e-9
        # the seed's formula with q0·q1 < 0 goes the long way: 2π − θ about the axis
        if q0 @ q1 > 0.0:
            mid = _seed003_slerp(q0, -q1, 0.5)
            assert R.quat_angle_between(q0, mid / np.linalg.norm(mid)) > th / 2 + 1e-3 or th < 2e-3


def test_slerp_is_small_angle_safe() -> None:
    """Attitudes 1e-10 rad apart (the seed's formula divides by sin θ ~ 1e-10): exact rotation t·φ, no NaN."""
    q0 = R.quat_from_euler(0.3, -0.2, 1.0)
    phi = np.array([3e-11, -4e-11, 0.0]) * 2  # |φ| = 1e-10 rad
    q1 = R.quat_mul(q0, R.quat_from_rotvec(phi))
    for t in (0.0, 0.3, 1.0):
        q = R.quat_slerp(q0, q1, t)
        assert np.all(np.isfinite(q))
        np.testing.assert_allclose(q, R.quat_mul(q0, R.quat_from_rotvec(t * phi)), atol=1e-15)
    assert np.array_equal(R.quat_slerp(q0, q0, 0.5), R.quat_normalize(q0))


def test_dcm_rows_are_dcm_from_quat_as_floats() -> None:
    """The per-message MAVLink path's C_b^n (Python floats) is dcm_from_quat's, number for number."""
    rng = np.random.default_rng(5)
    for _ in range(200):
        q = R.quat_normalize(rng.normal(size=4))
        rows = R.dcm_rows(*q.tolist())
        assert all(type(x) is float for r in rows for x in r)
        assert [list(r) for r in rows] == R.dcm_from_quat(q).tolist()


def test_dcm_from_quat_many_is_dcm_from_quat_per_row() -> None:
    """The stacked DCMs are each quaternion's :func:`dcm_from_quat`, bit for bit (the replay's scoring relies on it)."""
    rng = np.random.default_rng(7)
    q = rng.normal(size=(500, 4))
    q /= np.linalg.norm(q, axis=1)[:, None]
    C = R.dcm_from_quat_many(q)
    assert C.shape == (500, 3, 3)
    for i in range(len(q)):
        assert np.array_equal(C[i], R.dcm_from_quat(q[i]))
    assert R.dcm_from_quat_many(np.zeros((0, 4))).shape == (0, 3, 3)
