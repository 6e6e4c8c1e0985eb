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
