"""Local-level (NED) strapdown mechanization on delta-angle / delta-velocity inputs.

The l-frame mechanization of seed 001 (eqs. 55–59, DIGEST_001_004 §1.5–1.7),
re-expressed in NED, with the standard two-sample corrections for increment
inputs:

* attitude: q_nb(k) = q(−ζ) ⊗ q_nb(k−1) ⊗ q(φ), with the body rotation vector
  φ = Δθ_k + (1/12) Δθ_{k−1} × Δθ_k (coning correction; the same
  non-commutativity term as the book's eq. 2.17/2.18 written for rotation
  vectors) and the navigation-frame rotation ζ = ω_in^n Δt
  (ω_in = ω_ie + ω_en, Earth rate + transport rate);
* velocity: Δv_n = (I − ½[ζ×]) C_b^n(k−1) (Δv + ½ Δθ × Δv + (1/12)(Δθ_{k−1} × Δv + Δv_{k−1} × Δθ))
  (rotation + sculling correction), then the Coriolis/transport and gravity
  terms −(2ω_ie + ω_en) × v + g (seed 001 eq. 57);
* position: trapezoidal integration of φ̇ = v_N/(M+h), λ̇ = v_E/((N+h)cos φ),
  ḣ = −v_D (seed 001 eq. 55/56).

ω_ie, ω_en, g and the radii M, N are taken at the mid-interval state, as in Savage's and KF-GINS's
mechanizations: the mid-interval latitude and height extrapolated with the start velocity, the
mid-interval velocity predicted over half the step (specific force, gravity and the start-velocity
Coriolis term). Each is then second order in the step: the mechanization agrees with the e- and
i-frame ones (:mod:`ins_hil.nav.mechanization_ie`) to O(Δt²) (tests/test_mechanization_ie.py).

The state is mutated in place; one step allocates only a handful of small
arrays. Pure: no I/O, no clock.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Any, NamedTuple

import numpy as np

from ins_hil.types import Vec

from . import earth


@dataclass
class StrapdownState:
    """Strapdown navigation state.

    q_nb: body→NED quaternion (Hamilton, scalar first); vel_ned m/s;
    lat/lon rad; h m (ellipsoidal); t s (sensor time).
    """

    q_nb: Vec
    vel_ned: Vec
    lat: float
    lon: float
    h: float
    t: float = 0.0

    def copy(self) -> StrapdownState:
        return StrapdownState(self.q_nb.copy(), self.vel_ned.copy(), self.lat, self.lon, self.h, self.t)


#: builds a NamedTuple from a tuple without its generated ``__new__`` (half the cost: a snapshot per IMU step)
_new = tuple.__new__


class StrapdownSnapshot(NamedTuple):
    """The strapdown integrator's state at one step (:meth:`StrapdownNED.snapshot`): references only."""

    q_nb: Vec
    vel_ned: Vec
    lat: float
    lon: float
    h: float
    t: float
    dth_prev: Vec
    dv_prev: Vec
    have_prev: bool
    n: int
    f_ned: Vec
    omega_ie: Vec
    omega_en: Vec


@dataclass
class StrapdownNED:
    """NED strapdown integrator (see module docstring for the equations).

    ``coning``/``sculling`` switch the two-sample corrections;
    ``earth_rate`` switches Earth rate, transport rate and Coriolis off for
    flat-Earth tests. ``renorm_every`` renormalises the quaternion every N
    steps (the exact rotation-vector update keeps the norm to round-off).
    ``gravity``: ``"normal"`` (default) Somigliana normal gravity with the height series (seed 001 eqs. 12,
    16), or ``"j2"`` the J2 field plus centrifugal term with its north component
    (:func:`~ins_hil.nav.earth.gravity_j2_ned`, seed 003 eq. 1.9).
    """

    state: StrapdownState
    coning: bool = True
    sculling: bool = True
    earth_rate: bool = True
    renorm_every: int = 1
    _dth_prev: Vec = field(default_factory=lambda: np.zeros(3))
    _dv_prev: Vec = field(default_factory=lambda: np.zeros(3))
    _have_prev: bool = False
    _n: int = 0
    # last specific force in NED (m/s^2), for the error-state filter's F matrix
    f_ned: Vec = field(default_factory=lambda: np.zeros(3))
    omega_ie: Vec = field(default_factory=lambda: np.zeros(3))
    omega_en: Vec = field(default_factory=lambda: np.zeros(3))
    attitude: str = "rotvec"
    gravity: str = "normal"
    _att: Any = field(default=None, init=False, repr=False)
    _j2: bool = field(default=False, init=False, repr=False)

    def __post_init__(self) -> None:
        if self.gravity not in earth.GRAVITY_MODELS:
            raise ValueError(f"StrapdownNED: gravity={self.gravity!r}: expected one of {earth.GRAVITY_MODELS}")
        self._j2 = self.gravity == "j2"
        if self.attitude != "rotvec":
            from .attitude import make_attitude

            self._att = make_attitude(self.attitude)

    def snapshot(self) -> StrapdownSnapshot:
        """The state and the previous increments by reference: :meth:`step` replaces these arrays, never
        mutates them in place, so a snapshot stays valid (delayed fusion takes one per step)."""
        st = self.state
        return _new(StrapdownSnapshot, (
            st.q_nb, st.vel_ned, st.lat, st.lon, st.h, st.t, self._dth_prev, self._dv_prev, self._have_prev,
            self._n, self.f_ned, self.omega_ie, self.omega_en,
        ))  # fmt: skip

    def restore(self, d: StrapdownSnapshot) -> None:
        """Put back the state of a :meth:`snapshot`."""
        st = self.state
        (st.q_nb, st.vel_ned, st.lat, st.lon, st.h, st.t, self._dth_prev, self._dv_prev, self._have_prev,
         self._n, self.f_ned, self.omega_ie, self.omega_en) = d  # fmt: skip

    def reset_history(self) -> None:
        """Forget the previous increments (after a gap or a reset)."""
        self._have_prev = False
        if self._att is not None:
            self._att.reset()

    def step(self, dtheta: Vec, dvel: Vec, dt: float) -> StrapdownState:
        """Advance the state by one IMU interval.

        dtheta: delta angle (rad, body FRD); dvel: delta velocity (m/s, body
        FRD); dt: interval (s). Returns the (mutated) state.

        Written in scalar float arithmetic: numpy's per-call overhead on
        3-vectors would cost ~4x more on this hot path.
        """
        s = self.state
        lat, h = s.lat, s.h
        vN, vE, vD = float(s.vel_ned[0]), float(s.vel_ned[1]), float(s.vel_ned[2])
        ax, ay, az = float(dtheta[0]), float(dtheta[1]), float(dtheta[2])
        ux, uy, uz = float(dvel[0]), float(dvel[1]), float(dvel[2])

        # body rotation vector φ with coning correction (1/12) Δθ_{k-1} × Δθ_k
        px, py, pz = ax, ay, az
        if self._have_prev:
            bx, by, bz = float(self._dth_prev[0]), float(self._dth_prev[1]), float(self._dth_prev[2])
            cx, cy, cz = float(self._dv_prev[0]), float(self._dv_prev[1]), float(self._dv_prev[2])
            if self.coning:
                px += (by * az - bz * ay) / 12.0
                py += (bz * ax - bx * az) / 12.0
                pz += (bx * ay - by * ax) / 12.0
        # Δv_b + ½ Δθ × Δv (rotation) + sculling (1/12)(Δθ_{k-1} × Δv + Δv_{k-1} × Δθ)
        dx = ux + 0.5 * (ay * uz - az * uy)
        dy = uy + 0.5 * (az * ux - ax * uz)
        dz = uz + 0.5 * (ax * uy - ay * ux)
        if self.sculling and self._have_prev:
            dx += ((by * uz - bz * uy) + (cy * az - cz * ay)) / 12.0
            dy += ((bz * ux - bx * uz) + (cz * ax - cx * az)) / 12.0
            dz += ((bx * uy - by * ux) + (cx * ay - cy * ax)) / 12.0

        # C_b^n(k-1) Δv_b
        q0, q1, q2, q3 = float(s.q_nb[0]), float(s.q_nb[1]), float(s.q_nb[2]), float(s.q_nb[3])
        q00, q11, q22, q33 = q0 * q0, q1 * q1, q2 * q2, q3 * q3
        nN = (q00 + q11 - q22 - q33) * dx + 2.0 * (q1 * q2 - q0 * q3) * dy + 2.0 * (q1 * q3 + q0 * q2) * dz
        nE = 2.0 * (q1 * q2 + q0 * q3) * dx + (q00 - q11 + q22 - q33) * dy + 2.0 * (q2 * q3 - q0 * q1) * dz
        nD = 2.0 * (q1 * q3 - q0 * q2) * dx + 2.0 * (q2 * q3 + q0 * q1) * dy + (q00 - q11 - q22 + q33) * dz

        # mid-interval position, extrapolated with the start velocity and the start meridian radius (an
        # O(dt²) position error: the rates, gravity and radii taken there are second order in the step)
        slat = math.sin(lat)
        w2 = 1.0 - earth.E2_WGS84 * slat * slat
        rm0 = earth.A_WGS84 * (1.0 - earth.E2_WGS84) / (w2 * math.sqrt(w2))  # seed 001 eq. 3
        hm0 = h - 0.5 * vD * dt
        latm = lat + 0.5 * vN / (rm0 + h) * dt
        slat, clat = math.sin(latm), math.cos(latm)
        w2 = 1.0 - earth.E2_WGS84 * slat * slat
        rn = earth.A_WGS84 / math.sqrt(w2)  # seed 001 eq. 2
        rm = rn * (1.0 - earth.E2_WGS84) / w2  # seed 001 eq. 3
        # gravity at the mid-interval point (seed 001 eqs. 12, 16; or seed 003 eq. 1.9, J2 field + centrifugal)
        s2 = slat * slat
        gN = 0.0
        if self._j2:
            gN, g = earth.j2_gravity_nd(slat, clat, hm0)
        else:
            g = (
                earth.GAMMA_A * (1.0 + earth.K_SOMIGLIANA * s2) / math.sqrt(w2)
                - (3.0877e-6 - 4.4e-9 * s2) * hm0
                + 0.72e-12 * hm0 * hm0
            )
        if self.earth_rate:
            ieN, ieD = earth.OMEGA_E * clat, -earth.OMEGA_E * slat  # ω_ie^n (seed 001 eq. 67, NED)
            # mid-interval velocity predicted with the start velocity's transport rate (frame rotation, Coriolis)
            rnh, rmh, tlat = rn + hm0, rm + hm0, slat / clat
            enN, enE, enD = vE / rnh, -vN / rmh, -vE * tlat / rnh
            zN, zE, zD = (ieN + enN) * dt, enE * dt, (ieD + enD) * dt
            fN = nN - 0.5 * (zE * nD - zD * nE)
            fE = nE - 0.5 * (zD * nN - zN * nD)
            fD = nD - 0.5 * (zN * nE - zE * nN)
            cN, cE, cD = 2.0 * ieN + enN, enE, 2.0 * ieD + enD
            wN = vN + 0.5 * (fN + (gN - (cE * vD - cD * vE)) * dt)
            wE = vE + 0.5 * (fE - (cD * vN - cN * vD) * dt)
            wD = vD + 0.5 * (fD + (g - (cN * vE - cE * vN)) * dt)
            enN = wE / rnh  # ω_en^n, transport rate, at the mid-interval state
            enE = -wN / rmh
            enD = -wE * tlat / rnh
        else:
            ieN = ieD = enN = enE = enD = wN = wE = wD = 0.0
        inN, inE, inD = ieN + enN, enE, ieD + enD

        # nav-frame rotation over the interval: (I − ½[ζ×]), ζ = ω_in^n Δt
        zN, zE, zD = inN * dt, inE * dt, inD * dt
        fN = nN - 0.5 * (zE * nD - zD * nE)
        fE = nE - 0.5 * (zD * nN - zN * nD)
        fD = nD - 0.5 * (zN * nE - zE * nN)
        self.f_ned = np.array((fN / dt, fE / dt, fD / dt))

        # Coriolis/transport −(2ω_ie + ω_en) × v at the mid-interval state, plus gravity (seed 001 eq. 57)
        cN, cE, cD = 2.0 * ieN + enN, enE, 2.0 * ieD + enD
        vN1 = vN + fN + (gN - (cE * wD - cD * wE)) * dt
        vE1 = vE + fE - (cD * wN - cN * wD) * dt
        vD1 = vD + fD + (g - (cN * wE - cE * wN)) * dt

        # attitude: q(−ζ) ⊗ q ⊗ q(φ)  (book eq. 2.15/2.16 for the body part)
        if self._att is None:
            r0, r1, r2, r3 = _rotvec_quat(px, py, pz)
            a0 = q0 * r0 - q1 * r1 - q2 * r2 - q3 * r3
            a1 = q0 * r1 + q1 * r0 + q2 * r3 - q3 * r2
            a2 = q0 * r2 - q1 * r3 + q2 * r0 + q3 * r1
            a3 = q0 * r3 + q1 * r2 - q2 * r1 + q3 * r0
        else:  # a named algorithm from the registry (ins_hil.nav.attitude)
            a0, a1, a2, a3 = (float(x) for x in self._att.step_increment(s.q_nb, dtheta, dt))
        if self.earth_rate:
            e0, e1, e2, e3 = _rotvec_quat(-zN, -zE, -zD)
            a0, a1, a2, a3 = (
                e0 * a0 - e1 * a1 - e2 * a2 - e3 * a3,
                e0 * a1 + e1 * a0 + e2 * a3 - e3 * a2,
                e0 * a2 - e1 * a3 + e2 * a0 + e3 * a1,
                e0 * a3 + e1 * a2 - e2 * a1 + e3 * a0,
            )
        self._n += 1
        if self.renorm_every > 0 and self._n % self.renorm_every == 0:
            nq = 1.0 / math.sqrt(a0 * a0 + a1 * a1 + a2 * a2 + a3 * a3)
            if a0 < 0.0:
                nq = -nq
            a0, a1, a2, a3 = a0 * nq, a1 * nq, a2 * nq, a3 * nq

        # position: trapezoidal in velocity, radii at the mid-interval latitude (seed 001 eq. 55/56 in NED)
        mN, mE, mD = 0.5 * (vN + vN1), 0.5 * (vE + vE1), 0.5 * (vD + vD1)
        h1 = h - mD * dt
        hm = 0.5 * (h + h1)
        lat1 = lat + mN / (rm + hm) * dt
        lon1 = s.lon + mE / ((rn + hm) * clat) * dt

        s.q_nb = np.array((a0, a1, a2, a3))
        s.vel_ned = np.array((vN1, vE1, vD1))
        s.lat, s.lon, s.h = lat1, lon1, h1
        s.t += dt
        self._dth_prev = dtheta
        self._dv_prev = dvel
        self._have_prev = True
        self.omega_ie = np.array((ieN, 0.0, ieD))
        self.omega_en = np.array((enN, enE, enD))
        return s


def _rotvec_quat(x: float, y: float, z: float) -> tuple[float, float, float, float]:
    """Exact quaternion of a rotation vector (scalar version of rotation.quat_from_rotvec)."""
    a2 = x * x + y * y + z * z
    if a2 < 1e-12:
        c = 1.0 - a2 / 8.0 + a2 * a2 / 384.0
        k = 0.5 - a2 / 48.0 + a2 * a2 / 3840.0
    else:
        a = math.sqrt(a2)
        c = math.cos(0.5 * a)
        k = math.sin(0.5 * a) / a
    return c, k * x, k * y, k * z
