"""Initial alignment (book §4.1, DIGEST_000 §4.1–4.2).

* Coarse levelling (book eq. 4.1, after Shin 2005) from the mean specific force at rest.
  The book prints roll from a_x and pitch from a_y (DIGEST_000 §10 item 31); in the
  body FRD frame used here f^b = C_n^b (0, 0, −g), so
  pitch θ = atan2(f_x, √(f_y² + f_z²)) and roll φ = atan2(−f_y, −f_z).
* Gyrocompassing (book eq. 4.2): ψ = atan2(−ω_y, ω_x) on the levelled rates; only for
  Earth-rate-grade gyros (MEMS gyros cannot resolve 15 °/h).
* Refined alignment from two reference vectors (book eqs. 4.3–4.8, Example 4.1):
  Z = [a m d], Z1 = [a1 m1 d1] with d = a × m, A = Z1 Z^{−1} (A = C_n^b, the book's
  fixed→body DCM), orthogonalised by SVD A = U S V^T → Ã = U V^T, with a determinant
  guard (flip the last column of U if det < 0; DIGEST_000 §4.2 note).
* Magnetic heading at rest (:func:`mag_heading`): roll and pitch from the accelerometer alone,
  yaw from the tilt-compensated magnetometer direction against the reference's declination. Both
  vectors are used as directions, so any consistent unit (or none) works, and an error in the
  reference's dip or magnitude moves no tilt: the accelerometer's direction (~1 mrad at rest) is
  far better known than the magnetometer's (degrees), so this is the limit of the σ-weighted
  two-vector solution when σ_a ≪ σ_m. The book's A = Z1 Z⁻¹ weighs both vectors equally and takes
  their magnitudes as given.
* In-motion yaw from the GNSS course: ψ = atan2(v_E, v_N) (no sideslip assumed).
"""

from __future__ import annotations

import math

import numpy as np

from ins_hil.nav.rotation import dcm_from_euler, quat_from_dcm
from ins_hil.types import Vec


def coarse_level(f_b: Vec) -> tuple[float, float]:
    """(roll, pitch) in rad from the mean specific force f_b (m/s², body FRD) at rest."""
    fx, fy, fz = float(f_b[0]), float(f_b[1]), float(f_b[2])
    return math.atan2(-fy, -fz), math.atan2(fx, math.hypot(fy, fz))


def gyrocompass_yaw(w_level: Vec) -> float:
    """Book eq. (4.2): yaw (rad) from the Earth rate measured by levelled gyros (ω_x, ω_y)."""
    return math.atan2(-float(w_level[1]), float(w_level[0]))


def mag_heading(roll: float, pitch: float, field_b: Vec, ref_ned: Vec) -> float:
    """Yaw (rad) from the magnetometer at a known roll and pitch (rad).

    field_b: measured field (body FRD, any unit); ref_ned: reference field (NED, any unit, its
    horizontal direction gives the declination). The measured field is levelled with roll and pitch
    (C_b^l = R_y(θ) R_x(φ), book eq. 2.12 with ψ = 0); its horizontal angle in that level frame is D − ψ,
    with D = atan2(m_E, m_N).
    Raises ValueError when either field has no horizontal component (at a magnetic pole)."""
    lx, ly, _ = (float(x) for x in dcm_from_euler(roll, pitch, 0.0) @ np.asarray(field_b, float))  # heading frame
    rn, re = float(ref_ned[0]), float(ref_ned[1])
    if math.hypot(lx, ly) == 0.0 or math.hypot(rn, re) == 0.0:
        raise ValueError("magnetic heading: the field has no horizontal component")
    yaw = math.atan2(re, rn) - math.atan2(ly, lx)
    return math.atan2(math.sin(yaw), math.cos(yaw))


def refined_alignment(ref_nav: Vec, meas_body: Vec, orthogonalize: bool = True) -> Vec:
    """Book eqs. (4.3)–(4.8): the book's A = C_n^b from two vectors known in the nav frame.

    ref_nav: rows a, m (nav frame); meas_body: rows a1, m1 (body frame). Returns the
    orthogonalised Ã (or the raw Z1 Z^{−1} with ``orthogonalize=False``).
    """
    a, m = np.asarray(ref_nav[0], float), np.asarray(ref_nav[1], float)
    a1, m1 = np.asarray(meas_body[0], float), np.asarray(meas_body[1], float)
    Z = np.column_stack([a, m, np.cross(a, m)])
    Z1 = np.column_stack([a1, m1, np.cross(a1, m1)])
    A = Z1 @ np.linalg.inv(Z)  # eq. 4.4
    if not orthogonalize:
        return A
    return orthogonalize_dcm(A)


def orthogonalize_dcm(A: Vec) -> Vec:
    """Book eqs. (4.7)–(4.8): nearest rotation U V^T of A = U S V^T (det guard added)."""
    U, _, Vt = np.linalg.svd(A)
    if np.linalg.det(U @ Vt) < 0:
        U[:, -1] = -U[:, -1]
    return U @ Vt


def singular_values(A: Vec) -> Vec:
    """S of A = U S V^T (book prints S for Example 4.1)."""
    return np.linalg.svd(A, compute_uv=False)


def quat_from_book_A(A: Vec) -> Vec:
    """q_nb from the book's A = C_n^b (the inverse formula 2.7 applied to A^T = C_b^n)."""
    return quat_from_dcm(np.asarray(A).T)


def yaw_from_course(vel_ned: Vec) -> float:
    """Yaw (rad) from the horizontal GNSS velocity (course over ground)."""
    return math.atan2(float(vel_ned[1]), float(vel_ned[0]))


def book_A_classic(psi: float, theta: float, phi: float) -> Vec:
    """The book's A (fixed → body) from classic z-x-z angles (eqs. 2.2 + 2.5): A = R3(φ) R1(ϑ) R3(ψ)
    with passive elementary rotations. Example 4.1 uses ψ = ϑ = φ = π/4."""

    def r3(a: float) -> Vec:
        c, s = math.cos(a), math.sin(a)
        return np.array(((c, s, 0.0), (-s, c, 0.0), (0.0, 0.0, 1.0)))

    def r1(a: float) -> Vec:
        c, s = math.cos(a), math.sin(a)
        return np.array(((1.0, 0.0, 0.0), (0.0, c, s), (0.0, -s, c)))

    return r3(phi) @ r1(theta) @ r3(psi)


def coarse_alignment_enu(f_b: Vec, w_b: Vec, lat: float, g: float) -> Vec:
    """Seed 001 eqs. (64)–(69): R_b^l (body → ENU) from mean specific force f_b [m/s²] and rate w_b [rad/s] at rest.

    Row 3 (Up in body axes) = +f_b/g: the sign for specific-force accelerometers (a static IMU measures
    f^l = (0, 0, +g) in ENU); the printed (65) has −f/g, which holds only if the output has gravity's
    sign (DIGEST_001_004 §1.8). Row 2 (North) by (68), row 1 (East) = North × Up by (69). Raises
    ValueError near the poles (cos φ → 0), where Earth rate has no horizontal component to resolve.
    """
    c = math.cos(lat)
    if abs(c) < 1e-3:
        raise ValueError("gyrocompass alignment needs |latitude| < 89.9°: Earth rate has no horizontal component")
    up = np.asarray(f_b, dtype=float) / g
    north = np.asarray(w_b, dtype=float) / (7.292115e-5 * c) - math.tan(lat) * up
    east = np.cross(north, up)
    return np.vstack([east, north, up])
