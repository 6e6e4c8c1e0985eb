"""Quaternion, DCM and Euler-angle utilities: the one set used everywhere.

Conventions (ARCHITECTURE.md, DIGEST_000 §9, verified there numerically):

* Hamilton quaternion, scalar first ``q = [q0, q1, q2, q3]``.
* ``q_nb`` rotates body (FRD) vectors into the navigation frame (NED):
  ``v_n = q ⊗ v_b ⊗ q*``. This is the book's λ (eq. 2.10):
  ``λ̇ = ½ λ ⊗ (0, ω_b)``.
* ``dcm_from_quat(q)`` returns ``C_b^n``. The book's DCM ``A`` (eq. 2.5) is
  ``C_n^b = C_b^n.T``; use :func:`book_A` for it.
* Euler angles are roll φ, pitch θ, yaw ψ in the Z-Y-X sequence
  ``C_b^n = Rz(ψ) Ry(θ) Rx(φ)`` (book eq. 2.12/2.13). The book's printed
  quaternion-from-angles (2.3) is an X-Y-Z sequence (DIGEST_000 §10 item 2);
  :func:`quat_from_euler` uses the standard ZYX formula instead.

All functions take and return ``numpy`` float64 arrays; none allocate more
than their result. The scalar-heavy ones are written with plain floats
because numpy's per-call overhead dominates for 3- and 4-vectors.
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np

from ins_hil.types import Vec

__all__ = [
    "book_A",
    "dcm_from_euler",
    "dcm_from_quat",
    "euler_from_dcm",
    "euler_from_quat",
    "quat_angle_between",
    "quat_conj",
    "quat_from_dcm",
    "quat_from_euler",
    "quat_from_rotvec",
    "quat_mul",
    "quat_normalize",
    "quat_rotate",
    "quat_slerp",
    "rotvec_from_quat",
    "skew",
]


def skew(a: Vec) -> Vec:
    """Skew-symmetric matrix [a×] with [a×] b = a × b (DIGEST_000 §1.2)."""
    return np.array([[0.0, -a[2], a[1]], [a[2], 0.0, -a[0]], [-a[1], a[0], 0.0]], dtype=np.float64)


def quat_mul(p: Vec, q: Vec) -> Vec:
    """Hamilton product p ⊗ q (book eq. 2.16 is λ_{i-1} ⊗ δλ_i)."""
    p0, p1, p2, p3 = float(p[0]), float(p[1]), float(p[2]), float(p[3])
    q0, q1, q2, q3 = float(q[0]), float(q[1]), float(q[2]), float(q[3])
    return np.array(
        [
            p0 * q0 - p1 * q1 - p2 * q2 - p3 * q3,
            p0 * q1 + p1 * q0 + p2 * q3 - p3 * q2,
            p0 * q2 - p1 * q3 + p2 * q0 + p3 * q1,
            p0 * q3 + p1 * q2 - p2 * q1 + p3 * q0,
        ]
    )


def quat_conj(q: Vec) -> Vec:
    """Conjugate q* (the inverse for a unit quaternion)."""
    return np.array([q[0], -q[1], -q[2], -q[3]], dtype=np.float64)


def quat_normalize(q: Vec) -> Vec:
    """Unit quaternion with non-negative scalar part."""
    n = math.sqrt(float(q[0] * q[0] + q[1] * q[1] + q[2] * q[2] + q[3] * q[3]))
    if n == 0.0 or not math.isfinite(n):
        raise ValueError(f"cannot normalize quaternion {q!r}")
    s = 1.0 / n if q[0] >= 0.0 else -1.0 / n
    return np.asarray(q, dtype=np.float64) * s


def quat_from_rotvec(phi: Vec) -> Vec:
    """Exact quaternion of a rotation vector φ (axis·angle, rad)."""
    x, y, z = float(phi[0]), float(phi[1]), float(phi[2])
    a2 = x * x + y * y + z * z
    a = math.sqrt(a2)
    if a < 1e-6:
        # series: cos(a/2) ≈ 1 - a²/8 + a⁴/384, sin(a/2)/a ≈ 1/2 - a²/48 + a⁴/3840
        c = 1.0 - a2 / 8.0 + a2 * a2 / 384.0
        s = 0.5 - a2 / 48.0 + a2 * a2 / 3840.0
    else:
        c = math.cos(0.5 * a)
        s = math.sin(0.5 * a) / a
    return np.array([c, s * x, s * y, s * z])


def rotvec_from_quat(q: Vec) -> Vec:
    """Rotation vector (rad) of a quaternion; angle in [0, π]."""
    q = quat_normalize(q)
    v = q[1:]
    sn = float(np.linalg.norm(v))
    if sn < 1e-12:
        return 2.0 * v
    ang = 2.0 * math.atan2(sn, float(q[0]))
    return v * (ang / sn)


def quat_rotate(q: Vec, v: Vec) -> Vec:
    """Rotate vector v by q: q ⊗ (0, v) ⊗ q* = C(q) v."""
    return dcm_from_quat(q) @ v


def dcm_from_quat(q: Vec) -> Vec:
    """C_b^n of a unit quaternion q_nb (the transpose of the book's A, eq. 2.5)."""
    return np.array(dcm_rows(float(q[0]), float(q[1]), float(q[2]), float(q[3])))


def dcm_from_quat_many(q: Vec) -> Vec:
    """:func:`dcm_from_quat` of many quaternions at once: ``q`` (N, 4) → (N, 3, 3), element for element the same
    numbers (the same operations on the columns)."""
    q = np.asarray(q, dtype=np.float64).reshape(-1, 4)
    rows = dcm_rows(q[:, 0], q[:, 1], q[:, 2], q[:, 3])
    return np.stack([np.stack(r, axis=-1) for r in rows], axis=-2)


def dcm_rows(q0: Any, q1: Any, q2: Any, q3: Any) -> Any:
    """The rows of C_b^n of q_nb = (q0, q1, q2, q3) as tuples: of Python floats for floats (no array: the
    per-message MAVLink path), of arrays element-wise for arrays; :func:`dcm_from_quat`'s numbers."""
    q00, q11, q22, q33 = q0 * q0, q1 * q1, q2 * q2, q3 * q3
    return (
        (q00 + q11 - q22 - q33, 2.0 * (q1 * q2 - q0 * q3), 2.0 * (q1 * q3 + q0 * q2)),
        (2.0 * (q1 * q2 + q0 * q3), q00 - q11 + q22 - q33, 2.0 * (q2 * q3 - q0 * q1)),
        (2.0 * (q1 * q3 - q0 * q2), 2.0 * (q2 * q3 + q0 * q1), q00 - q11 - q22 + q33),
    )


def book_A(q: Vec) -> Vec:
    """The book's DCM A(λ) = C_n^b (eq. 2.5): fixed-frame components → body."""
    return dcm_from_quat(q).T


def quat_from_dcm(C: Vec) -> Vec:
    """Quaternion q_nb from C_b^n (Shepperd's method; robust for any rotation).

    For 1 + tr > 0 this is the book's eq. 2.7 applied to A = C_n^b = C.T.
    """
    C = np.asarray(C, dtype=np.float64)
    tr = C[0, 0] + C[1, 1] + C[2, 2]
    if tr > 0.0:
        s = 2.0 * math.sqrt(1.0 + tr)  # book eq. 2.7: λ0 = ½√(1+a11+a22+a33)
        q = np.array([0.25 * s, (C[2, 1] - C[1, 2]) / s, (C[0, 2] - C[2, 0]) / s, (C[1, 0] - C[0, 1]) / s])
    elif C[0, 0] > C[1, 1] and C[0, 0] > C[2, 2]:
        s = 2.0 * math.sqrt(1.0 + C[0, 0] - C[1, 1] - C[2, 2])
        q = np.array([(C[2, 1] - C[1, 2]) / s, 0.25 * s, (C[0, 1] + C[1, 0]) / s, (C[0, 2] + C[2, 0]) / s])
    elif C[1, 1] > C[2, 2]:
        s = 2.0 * math.sqrt(1.0 + C[1, 1] - C[0, 0] - C[2, 2])
        q = np.array([(C[0, 2] - C[2, 0]) / s, (C[0, 1] + C[1, 0]) / s, 0.25 * s, (C[1, 2] + C[2, 1]) / s])
    else:
        s = 2.0 * math.sqrt(1.0 + C[2, 2] - C[0, 0] - C[1, 1])
        q = np.array([(C[1, 0] - C[0, 1]) / s, (C[0, 2] + C[2, 0]) / s, (C[1, 2] + C[2, 1]) / s, 0.25 * s])
    return quat_normalize(q)


def quat_from_euler(roll: float, pitch: float, yaw: float) -> Vec:
    """q_nb from roll, pitch, yaw (rad), Z-Y-X sequence.

    Standard ZYX formula (DIGEST_000 §1.3), not the book's printed eq. 2.3,
    which is an X-Y-Z sequence (digest §10 item 2).
    """
    cr, sr = math.cos(0.5 * roll), math.sin(0.5 * roll)
    cp, sp = math.cos(0.5 * pitch), math.sin(0.5 * pitch)
    cy, sy = math.cos(0.5 * yaw), math.sin(0.5 * yaw)
    return np.array(
        [
            cr * cp * cy + sr * sp * sy,
            sr * cp * cy - cr * sp * sy,
            cr * sp * cy + sr * cp * sy,
            cr * cp * sy - sr * sp * cy,
        ]
    )


def euler_from_quat(q: Vec) -> Vec:
    """(roll, pitch, yaw) in rad from q_nb (book eq. 2.11, with atan2)."""
    q0, q1, q2, q3 = float(q[0]), float(q[1]), float(q[2]), float(q[3])
    n = q0 * q0 + q1 * q1 + q2 * q2 + q3 * q3
    roll = math.atan2(2.0 * (q2 * q3 + q0 * q1), q0 * q0 - q1 * q1 - q2 * q2 + q3 * q3)
    sp = max(-1.0, min(1.0, -2.0 * (q1 * q3 - q0 * q2) / n))
    pitch = math.asin(sp)
    yaw = math.atan2(2.0 * (q1 * q2 + q3 * q0), q0 * q0 + q1 * q1 - q2 * q2 - q3 * q3)
    return np.array([roll, pitch, yaw])


def dcm_from_euler(roll: float, pitch: float, yaw: float) -> Vec:
    """C_b^n = Rz(ψ) Ry(θ) Rx(φ) (book eq. 2.12)."""
    cf, sf = math.cos(roll), math.sin(roll)
    ct, st = math.cos(pitch), math.sin(pitch)
    cy, sy = math.cos(yaw), math.sin(yaw)
    return np.array(
        [
            [ct * cy, -cf * sy + sf * st * cy, sf * sy + cf * st * cy],
            [ct * sy, cf * cy + sf * st * sy, -sf * cy + cf * st * sy],
            [-st, sf * ct, cf * ct],
        ]
    )


def euler_from_dcm(C: Vec) -> Vec:
    """(roll, pitch, yaw) from C_b^n (book eq. 2.13, with atan2)."""
    roll = math.atan2(C[2, 1], C[2, 2])
    pitch = math.atan2(-C[2, 0], math.sqrt(max(0.0, 1.0 - C[2, 0] ** 2)))
    yaw = math.atan2(C[1, 0], C[0, 0])
    return np.array([roll, pitch, yaw])


def quat_angle_between(p: Vec, q: Vec) -> float:
    """Smallest rotation angle (rad) taking attitude p to attitude q."""
    d = quat_mul(quat_conj(quat_normalize(p)), quat_normalize(q))
    return 2.0 * math.atan2(float(np.linalg.norm(d[1:])), abs(float(d[0])))


def quat_slerp(q0: Vec, q1: Vec, t: float) -> Vec:
    """Spherical linear interpolation from attitude ``q0`` (t = 0) to ``q1`` (t = 1) along the shortest path.

    q(t) = q0 ⊗ exp(t·log(q0* ⊗ q1)) with the relative quaternion taken with a non-negative scalar part
    (q and −q are one attitude), i.e. a rotation by t·θ about the fixed axis of the relative rotation,
    θ ∈ [0, π]. This is seed 003's sin((1−t)θ)/sin θ·q0 + sin(tθ)/sin θ·q1, cos θ = q0·q1, when q0·q1 ≥ 0;
    the printed formula takes the long way otherwise and divides by sin θ → 0 for close attitudes
    (DIGEST_001_004 §3.6): here the rotation-vector series keeps small angles exact. Inputs need not be
    normalised; t outside [0, 1] extrapolates. Returns a unit Hamilton quaternion, scalar first.
    """
    a, b = quat_normalize(q0), quat_normalize(q1)
    d = quat_mul(quat_conj(a), b)
    if d[0] < 0.0:
        d = -d
    return quat_normalize(quat_mul(a, quat_from_rotvec(float(t) * rotvec_from_quat(d))))
