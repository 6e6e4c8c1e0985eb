"""Inertial-frame (i) and Earth-frame (e) strapdown mechanizations on delta-angle / delta-velocity inputs.

Seed 001 §3.2.1–3.2.2 (DIGEST_001_004 §1.6), the two alternatives to the local-level (NED) mechanization of
:class:`~ins_hil.nav.mechanization.StrapdownNED` that the navigation core runs:

* i-frame, eq. 45: ṙ^i = v^i, v̇^i = C_b^i f^b + ḡ^i, Ċ_b^i = C_b^i [ω_ib^b×]. ḡ is the gravitation (seed 001
  eq. 10 solved for ḡ: gravity plus the centripetal term, :func:`~ins_hil.nav.earth.gravitation_ecef`); eq. 44
  writes the l-frame gravity of eq. 11 there, which would count the centrifugal acceleration twice. The i-frame
  coincides with the e-frame at t = 0 (C_e^i = R_z(ω_e t)^T maps ECEF to ECI).
* e-frame, eq. 51: ṙ^e = v^e, v̇^e = C_b^e f^b − 2 Ω_ie^e v^e + g^e, Ċ_b^e = C_b^e [ω_ib^b×] − Ω_ie^e C_b^e. The
  seed prints Ċ_b^e = C_b^e (Ω_ie^b − Ω_ib^b), the sign reversed (DIGEST_001_004 item 6); the corrected form
  is used.

The increment algorithm is :class:`StrapdownNED`'s with the frame's own rotation: the body rotation vector with the
coning term, Δv + ½Δθ×Δv + sculling, the frame rotation ζ (ω_ie Δt about z for the e-frame, none for the i-frame)
applied as (I − ½[ζ×]); gravity at the mid-interval position (extrapolated with the step's acceleration),
Coriolis at the mid-interval velocity (predicted), position by the trapezoid rule. Gravity is the same model
as the NED mechanization's ("normal" or "j2", rotated from NED at the point's geodetic coordinates), so the
three mechanizations integrate one set of equations in three frames; tests/test_mechanization_ie.py holds them
against each other on one trajectory.

Analysis and reproduction tools; not used by the real-time core.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from ins_hil.types import Vec

from . import earth
from .mechanization import StrapdownState
from .rotation import dcm_from_quat, quat_from_dcm, quat_from_rotvec, quat_mul, quat_normalize

__all__ = [
    "FrameState",
    "StrapdownECEF",
    "StrapdownECI",
    "dcm_ecef_to_eci",
    "ecef_from_eci",
    "ecef_from_ned",
    "eci_from_ecef",
    "ned_from_ecef",
]

_WZ = np.array([0.0, 0.0, earth.OMEGA_E])  # ω_ie in ECEF (and ECI), rad/s


def _cross(a: Vec, b: Vec) -> Vec:
    """a × b of two 3-vectors (np.cross costs ~10x more on 3-vectors)."""
    a0, a1, a2 = float(a[0]), float(a[1]), float(a[2])
    b0, b1, b2 = float(b[0]), float(b[1]), float(b[2])
    return np.array((a1 * b2 - a2 * b1, a2 * b0 - a0 * b2, a0 * b1 - a1 * b0))


@dataclass
class FrameState:
    """Strapdown state in a Cartesian frame (ECEF or ECI): q_xb body(FRD)→frame quaternion (Hamilton, scalar
    first), position r (m) and velocity v (m/s) in the frame, t (s; the i-frame and e-frame coincide at t = 0)."""

    q_xb: Vec
    r: Vec
    v: Vec
    t: float = 0.0

    def copy(self) -> FrameState:
        return FrameState(self.q_xb.copy(), self.r.copy(), self.v.copy(), self.t)


def dcm_ecef_to_eci(t: float) -> Vec:
    """C_e^i at time t (s): a rotation by ω_e t about z (the frames coincide at t = 0)."""
    c, s = math.cos(earth.OMEGA_E * t), math.sin(earth.OMEGA_E * t)
    return np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])


def ecef_from_ned(s: StrapdownState) -> FrameState:
    """The NED state's position, velocity and attitude in ECEF (r^e, v^e = C_n^e v^n, C_b^e = C_n^e C_b^n)."""
    C_ne = earth.dcm_ecef_to_ned(s.lat, s.lon).T
    return FrameState(quat_normalize(quat_mul(quat_from_dcm(C_ne), s.q_nb)),
                      earth.geodetic_to_ecef(s.lat, s.lon, s.h), C_ne @ s.vel_ned, s.t)  # fmt: skip


def ned_from_ecef(e: FrameState) -> StrapdownState:
    """Inverse of :func:`ecef_from_ned`."""
    lat, lon, h = earth.ecef_to_geodetic(e.r)
    C_en = earth.dcm_ecef_to_ned(lat, lon)
    q = quat_normalize(quat_mul(quat_from_dcm(C_en), e.q_xb))
    return StrapdownState(q if q[0] >= 0.0 else -q, C_en @ e.v, lat, lon, h, e.t)


def eci_from_ecef(e: FrameState) -> FrameState:
    """ECEF → ECI at e.t: r^i = C_e^i r^e, v^i = C_e^i (v^e + ω_ie × r^e) (seed 001 eq. 47), C_b^i = C_e^i C_b^e."""
    C = dcm_ecef_to_eci(e.t)
    return FrameState(quat_normalize(quat_mul(quat_from_dcm(C), e.q_xb)), C @ e.r,
                      C @ (e.v + _cross(_WZ, e.r)), e.t)  # fmt: skip


def ecef_from_eci(i: FrameState) -> FrameState:
    """Inverse of :func:`eci_from_ecef`."""
    C = dcm_ecef_to_eci(i.t).T
    r = C @ i.r
    return FrameState(quat_normalize(quat_mul(quat_from_dcm(C), i.q_xb)), r, C @ i.v - _cross(_WZ, r), i.t)


@dataclass
class _CartesianStrapdown:
    """The body-frame part of one step shared by the i- and e-frame mechanizations."""

    state: FrameState
    coning: bool = True
    sculling: bool = True
    gravity: str = "normal"
    _dth_prev: Vec = field(default_factory=lambda: np.zeros(3))
    _dv_prev: Vec = field(default_factory=lambda: np.zeros(3))
    _have_prev: bool = False

    def __post_init__(self) -> None:
        if self.gravity not in earth.GRAVITY_MODELS:
            raise ValueError(f"{type(self).__name__}: gravity={self.gravity!r}: expected one of {earth.GRAVITY_MODELS}")

    def _body(self, dtheta: Vec, dvel: Vec) -> tuple[Vec, Vec]:
        """(φ, Δv'): the body rotation vector with the coning term (1/12)Δθ_{k−1}×Δθ_k, and
        Δv + ½Δθ×Δv + (1/12)(Δθ_{k−1}×Δv + Δv_{k−1}×Δθ) (rotation and sculling; as StrapdownNED)."""
        dth = np.asarray(dtheta, dtype=np.float64)
        dv = np.asarray(dvel, dtype=np.float64)
        phi = dth.copy()
        dvb = dv + 0.5 * _cross(dth, dv)
        if self._have_prev:
            if self.coning:
                phi += _cross(self._dth_prev, dth) / 12.0
            if self.sculling:
                dvb += (_cross(self._dth_prev, dv) + _cross(self._dv_prev, dth)) / 12.0
        self._dth_prev, self._dv_prev, self._have_prev = dth, dv, True
        return phi, dvb

    def reset_history(self) -> None:
        """Forget the previous increments (after a gap)."""
        self._have_prev = False


@dataclass
class StrapdownECEF(_CartesianStrapdown):
    """e-frame mechanization (seed 001 eq. 51, attitude sign corrected): state in ECEF."""

    def step(self, dtheta: Vec, dvel: Vec, dt: float) -> FrameState:
        """Advance by one IMU interval: dtheta (rad) and dvel (m/s) body FRD increments over dt (s)."""
        s = self.state
        phi, dvb = self._body(dtheta, dvel)
        zeta = _WZ * dt  # the e-frame's rotation over the interval
        dvf = dcm_from_quat(s.q_xb) @ dvb
        dvf = dvf - 0.5 * _cross(zeta, dvf)
        a0 = dvf / dt + earth.gravity_ecef(s.r, self.gravity) - 2.0 * _cross(_WZ, s.v)
        r_mid = s.r + 0.5 * dt * s.v + 0.125 * dt * dt * a0
        g = earth.gravity_ecef(r_mid, self.gravity)
        v_mid = s.v + 0.5 * (dvf + (g - 2.0 * _cross(_WZ, s.v)) * dt)
        v1 = s.v + dvf + (g - 2.0 * _cross(_WZ, v_mid)) * dt
        r1 = s.r + 0.5 * (s.v + v1) * dt
        q = quat_mul(quat_mul(quat_from_rotvec(-zeta), s.q_xb), quat_from_rotvec(phi))
        self.state = FrameState(quat_normalize(q), r1, v1, s.t + dt)
        return self.state


@dataclass
class StrapdownECI(_CartesianStrapdown):
    """i-frame mechanization (seed 001 eq. 45 with the gravitation ḡ): state in ECI (≡ ECEF at t = 0)."""

    def _gravitation(self, r_i: Vec, t: float) -> Vec:
        C = dcm_ecef_to_eci(t)
        return C @ earth.gravitation_ecef(C.T @ r_i, self.gravity)

    def step(self, dtheta: Vec, dvel: Vec, dt: float) -> FrameState:
        """Advance by one IMU interval: dtheta (rad) and dvel (m/s) body FRD increments over dt (s)."""
        s = self.state
        phi, dvb = self._body(dtheta, dvel)
        dvf = dcm_from_quat(s.q_xb) @ dvb
        a0 = dvf / dt + self._gravitation(s.r, s.t)
        r_mid = s.r + 0.5 * dt * s.v + 0.125 * dt * dt * a0
        v1 = s.v + dvf + self._gravitation(r_mid, s.t + 0.5 * dt) * dt
        r1 = s.r + 0.5 * (s.v + v1) * dt
        q = quat_mul(s.q_xb, quat_from_rotvec(phi))
        self.state = FrameState(quat_normalize(q), r1, v1, s.t + dt)
        return self.state
