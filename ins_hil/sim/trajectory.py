"""Reference trajectories and exact (error-free) IMU increments for them.

A profile gives, at any time t (s), the attitude as roll/pitch/yaw (rad)
with their rates, and the NED velocity with its derivative. Position is
integrated from the velocity on the WGS84 ellipsoid. The ideal sensor
outputs follow from the NED mechanization equations (seed 001 eq. 57/59,
DIGEST_001_004 §1.5) run backwards:

    ω_ib^b = ω_nb^b + C_n^b (ω_ie^n + ω_en^n)                (gyro)
    f^b    = C_n^b (v̇^n + (2ω_ie^n + ω_en^n) × v^n − g^n)      (accelerometer)

with ω_nb^b from the Euler rates by the book's eq. 2.9. The increments
Δθ = ∫ω_ib^b dt and Δv = ∫f^b dt over each IMU interval are computed by
5-point Gauss–Legendre quadrature (exact for polynomials of degree 9), so the
error-free IMU is accurate far below any sensor noise.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass

import numpy as np

from ins_hil.nav import earth
from ins_hil.nav.rotation import quat_from_euler
from ins_hil.types import Vec

# Gauss–Legendre nodes/weights on [0, 1], 5 points
_GL_X, _GL_W = np.polynomial.legendre.leggauss(5)
_GL_X = 0.5 * (_GL_X + 1.0)
_GL_W = 0.5 * _GL_W


@dataclass(frozen=True)
class Kinematics:
    """Arrays over M instants: roll/pitch/yaw (rad) and their rates (rad/s), shape (M, 3);
    NED velocity (m/s) and its derivative (m/s^2), shape (M, 3)."""

    euler: Vec
    euler_rate: Vec
    vel_ned: Vec
    acc_ned: Vec


# A profile maps an array of times (s), shape (M,), to Kinematics with (M, 3) arrays.
Profile = Callable[[Vec], Kinematics]


def body_rate_from_euler_rates(euler: Vec, euler_rate: Vec) -> Vec:
    """ω_nb^b from roll/pitch/yaw and their rates (book eq. 2.9); arrays (..., 3)."""
    phi, theta = euler[..., 0], euler[..., 1]
    dphi, dtheta, dpsi = euler_rate[..., 0], euler_rate[..., 1], euler_rate[..., 2]
    sf, cf = np.sin(phi), np.cos(phi)
    st, ct = np.sin(theta), np.cos(theta)
    return np.stack([dphi - dpsi * st, dpsi * ct * sf + dtheta * cf, dpsi * ct * cf - dtheta * sf], axis=-1)


def static_profile(roll: float = 0.0, pitch: float = 0.0, yaw: float = 0.0) -> Profile:
    """A vehicle at rest with a fixed attitude (rad)."""
    e = np.array([roll, pitch, yaw])

    def prof(t: Vec) -> Kinematics:
        m = np.size(t)
        z = np.zeros((m, 3))
        return Kinematics(np.tile(e, (m, 1)), z, z, z.copy())

    return prof


def _smoothstep(x: Vec) -> tuple[Vec, Vec, Vec]:
    """C² ramp 0→1 on [0, 1] (quintic) with first and second derivatives."""
    x = np.clip(x, 0.0, 1.0)
    s = x**3 * (10 - 15 * x + 6 * x * x)
    ds = 30 * x * x * (1 - x) ** 2
    d2s = 60 * x * (1 - x) * (1 - 2 * x)
    return s, ds, d2s


def uav_profile(
    speed: float = 20.0,
    turn_period: float = 120.0,
    climb_rate: float = 1.0,
    t_takeoff: float = 10.0,
    ramp: float = 20.0,
) -> Profile:
    """A smooth UAV flight: at rest until ``t_takeoff``, then a C² ramp (``ramp`` s)
    into sweeping coordinated turns (yaw oscillating ±90°·s(t) with period
    ``turn_period``), speed ``speed`` and a climb/descent oscillation of
    amplitude ``climb_rate``.

    The vehicle flies along its nose (body x): coordinated bank
    roll = atan(V ψ̇ / g); pitch = s(t)·flight-path angle. Euler rates are
    by central differences of these closed forms (step 1e-4 s; error ~1e-9).
    """
    g = 9.81
    w = 2 * math.pi / turn_period

    def base(t: Vec) -> tuple[Vec, Vec, Vec]:
        t = np.asarray(t, dtype=np.float64)
        s, ds, d2s = _smoothstep((t - t_takeoff) / ramp)
        ds, d2s = ds / ramp, d2s / ramp**2
        tt = np.maximum(0.0, t - t_takeoff)
        A = math.pi / 2
        yaw = s * A * np.sin(w * tt)
        dyaw = ds * A * np.sin(w * tt) + s * A * w * np.cos(w * tt)
        V = speed * s
        dV = speed * ds
        c = np.cos(0.5 * w * tt)
        vz = -climb_rate * s * c
        dvz = -climb_rate * (ds * c - s * 0.5 * w * np.sin(0.5 * w * tt))
        cy, sy = np.cos(yaw), np.sin(yaw)
        vel = np.stack([V * cy, V * sy, vz], axis=-1)
        acc = np.stack([dV * cy - V * sy * dyaw, dV * sy + V * cy * dyaw, dvz], axis=-1)
        pitch = s * np.arctan2(climb_rate * c, speed)
        roll = np.arctan(V * dyaw / g)
        return np.stack([roll, pitch, yaw], axis=-1), vel, acc

    def prof(t: Vec) -> Kinematics:
        e, vel, acc = base(t)
        hh = 1e-4
        ep, _, _ = base(np.asarray(t) + hh)
        em, _, _ = base(np.asarray(t) - hh)
        rate = (ep - em) / (2 * hh)
        return Kinematics(e, rate, vel, acc)

    return prof


@dataclass
class TruthSeries:
    """Truth at the IMU sample times (end of each interval) and the ideal increments.

    t, q_nb, euler, vel_ned, lat, lon, h have N+1 rows (row 0 = initial state
    at t0); dtheta, dvel have N rows (interval k ends at t[k+1]).
    """

    t: Vec
    q_nb: Vec
    euler: Vec
    vel_ned: Vec
    lat: Vec
    lon: Vec
    h: Vec
    dtheta: Vec
    dvel: Vec
    dt: float


def _ideal_rates(kin: Kinematics, lat: Vec, h: Vec) -> tuple[Vec, Vec]:
    """Ideal gyro ω_ib^b and accelerometer f^b at M instants (arrays (M, 3))."""
    e = kin.euler
    sf, cf = np.sin(e[:, 0]), np.cos(e[:, 0])
    st, ct = np.sin(e[:, 1]), np.cos(e[:, 1])
    sy, cy = np.sin(e[:, 2]), np.cos(e[:, 2])
    # C_b^n (book eq. 2.12), shape (M, 3, 3)
    C = np.empty((len(e), 3, 3))
    C[:, 0, 0] = ct * cy
    C[:, 0, 1] = -cf * sy + sf * st * cy
    C[:, 0, 2] = sf * sy + cf * st * cy
    C[:, 1, 0] = ct * sy
    C[:, 1, 1] = cf * cy + sf * st * sy
    C[:, 1, 2] = -sf * cy + cf * st * sy
    C[:, 2, 0] = -st
    C[:, 2, 1] = sf * ct
    C[:, 2, 2] = cf * ct
    w_nb_b = body_rate_from_euler_rates(e, kin.euler_rate)
    slat, clat = np.sin(lat), np.cos(lat)
    w_ie = np.stack([earth.OMEGA_E * clat, np.zeros_like(lat), -earth.OMEGA_E * slat], axis=-1)
    w2 = 1.0 - earth.E2_WGS84 * slat**2
    rn = earth.A_WGS84 / np.sqrt(w2)
    rm = earth.A_WGS84 * (1.0 - earth.E2_WGS84) / (w2 * np.sqrt(w2))
    v = kin.vel_ned
    w_en = np.stack([v[:, 1] / (rn + h), -v[:, 0] / (rm + h), -v[:, 1] * np.tan(lat) / (rn + h)], axis=-1)
    w_ib_b = w_nb_b + np.einsum("mji,mj->mi", C, w_ie + w_en)
    s2 = slat**2
    g0 = earth.GAMMA_A * (1.0 + earth.K_SOMIGLIANA * s2) / np.sqrt(1.0 - earth.E2_WGS84 * s2)
    g = g0 - (3.0877e-6 - 4.4e-9 * s2) * h + 0.72e-12 * h * h  # seed 001 eqs. 12, 16
    f_n = kin.acc_ned + np.cross(2.0 * w_ie + w_en, v)
    f_n[:, 2] -= g
    return w_ib_b, np.einsum("mji,mj->mi", C, f_n)


def generate(
    profile: Profile,
    duration: float,
    dt: float,
    lat0: float,
    lon0: float,
    h0: float,
    t0: float = 0.0,
) -> TruthSeries:
    """Truth trajectory and ideal IMU increments at a fixed step ``dt`` (s).

    lat0/lon0 in rad, h0 in m. Position: Simpson's rule on the geodetic rates
    per step (radii at the step start); sensors: 5-node Gauss–Legendre
    quadrature per interval, vectorised over the whole run.
    """
    n = round(duration / dt)
    if n < 1:
        raise ValueError("duration must cover at least one IMU interval")
    t = t0 + dt * np.arange(n + 1)
    # velocity at step ends and midpoints for position integration
    vk = profile(t).vel_ned
    vm = profile(t[:-1] + 0.5 * dt).vel_ned
    lat = np.empty(n + 1)
    lon = np.empty(n + 1)
    h = np.empty(n + 1)
    lat[0], lon[0], h[0] = lat0, lon0, h0
    la, lo, hh = lat0, lon0, h0
    for k in range(n):
        m, nn = earth.radii(la)
        vn = (vk[k, 0] + 4.0 * vm[k, 0] + vk[k + 1, 0]) / 6.0
        ve = (vk[k, 1] + 4.0 * vm[k, 1] + vk[k + 1, 1]) / 6.0
        vd = (vk[k, 2] + 4.0 * vm[k, 2] + vk[k + 1, 2]) / 6.0
        hm = hh - 0.5 * vd * dt
        dlat = vn / (m + hm) * dt
        lo += ve / ((nn + hm) * math.cos(la + 0.5 * dlat)) * dt
        la += dlat
        hh -= vd * dt
        lat[k + 1], lon[k + 1], h[k + 1] = la, lo, hh
    # Gauss nodes of every interval, position linearly interpolated
    tg = (t[:-1, None] + _GL_X[None, :] * dt).ravel()
    kin = profile(tg)
    xg = np.tile(_GL_X, n)
    kk = np.repeat(np.arange(n), len(_GL_X))
    latg = lat[kk] + xg * (lat[kk + 1] - lat[kk])
    hg = h[kk] + xg * (h[kk + 1] - h[kk])
    w, f = _ideal_rates(kin, latg, hg)
    wts = np.tile(_GL_W, n)[:, None]
    dth = (w * wts).reshape(n, len(_GL_X), 3).sum(axis=1) * dt
    dv = (f * wts).reshape(n, len(_GL_X), 3).sum(axis=1) * dt
    kin_k = profile(t)
    q = np.array([quat_from_euler(*e) for e in kin_k.euler])
    return TruthSeries(t, q, kin_k.euler, kin_k.vel_ned, lat, lon, h, dth, dv, dt)


def _rates_by_difference(base: Callable[[Vec], tuple[Vec, Vec, Vec]]) -> Profile:
    """Profile from closed-form (euler, vel, acc); Euler rates by central differences (step 1e-4 s)."""

    def prof(t: Vec) -> Kinematics:
        t = np.asarray(t, dtype=np.float64)
        e, vel, acc = base(t)
        hh = 1e-4
        ep, _, _ = base(t + hh)
        em, _, _ = base(t - hh)
        d = ep - em
        d = (d + np.pi) % (2 * np.pi) - np.pi  # yaw wrap
        return Kinematics(e, d / (2 * hh), vel, acc)

    return prof


def circle_profile(
    period: float = 300.0, speed: float = 60.0, roll_amp: float = 0.3, roll_mult: float = 10.0
) -> Profile:
    """The book's Example 3.2 circle (DIGEST_000 §3.8), intended motion.

    Interpretation (DIGEST_000 §10 item 18): the book's classic z-x-z angles with ϑ = 0 are
    gimbal-locked; we implement the intended manoeuvre with aircraft angles (book eq. 2.9):
    a level circle of period ``period`` s at ``speed`` m/s, heading ψ = 2πt/T along the
    tangent (starting north, turning right, radius VT/2π = 2864.79 m), pitch 0, and the
    roll oscillation φ = 0.3 sin(10ψ) rad superposed (not the coordinated bank). The book's
    x-South/y-East/z-Zenith frame is replaced by NED.
    """
    w = 2 * math.pi / period

    def base(t: Vec) -> tuple[Vec, Vec, Vec]:
        psi = w * t
        z = np.zeros_like(t)
        e = np.stack([roll_amp * np.sin(roll_mult * psi), z, psi], axis=-1)
        c, s = np.cos(psi), np.sin(psi)
        vel = np.stack([speed * c, speed * s, z], axis=-1)
        acc = np.stack([-speed * w * s, speed * w * c, z], axis=-1)
        return e, vel, acc

    return _rates_by_difference(base)


def coning_profile(amplitude: float = 0.05, freq: float = 2.0, phase: float = math.pi / 2) -> Profile:
    """Coning at rest (DIGEST_001_004 §2.6 setup): yaw 0, pitch a sin ωt, roll a sin(ωt + ε);
    with ε = 90° the body axis describes a cone (the classic coning motion)."""
    om = 2 * math.pi * freq

    def prof(t: Vec) -> Kinematics:
        t = np.asarray(t, dtype=np.float64)
        z = np.zeros_like(t)
        e = np.stack([amplitude * np.sin(om * t + phase), amplitude * np.sin(om * t), z], axis=-1)
        r = np.stack([amplitude * om * np.cos(om * t + phase), amplitude * om * np.cos(om * t), z], axis=-1)
        zz = np.zeros((len(t), 3))
        return Kinematics(e, r, zz, zz.copy())

    return prof


def _ramp_sum(t: Vec, items: list[tuple[float, float, float]]) -> tuple[Vec, Vec]:
    """Σ amount·s((t − start)/length) and its time derivative (C² quintic ramps)."""
    v = np.zeros_like(t)
    dv = np.zeros_like(t)
    for start, length, amount in items:
        s, ds, _ = _smoothstep((t - start) / length)
        v = v + amount * s
        dv = dv + amount * ds / length
    return v, dv


def mission_profile(
    cruise_speed: float = 20.0,
    climb_rate: float = 3.0,
    t_takeoff: float = 10.0,
    g: float = 9.81,
) -> Profile:
    """A UAV mission, 240 s: rest until ``t_takeoff``; take-off run and climb at ``climb_rate``
    to 96 m; cruise at ``cruise_speed`` with a 90° right turn, a 180° left turn and a 90°
    right turn (coordinated bank φ = atan(V ψ̇ / g)); descent of 60 m at 2 m/s; deceleration and rest.
    Pitch = flight-path angle. All segments are C² quintic ramps (closed form)."""
    T0 = t_takeoff
    speed_items = [(T0, 10.0, 15.0), (T0 + 40.0, 5.0, cruise_speed - 15.0), (T0 + 190.0, 15.0, -cruise_speed)]
    climb_items = [(T0 + 5.0, 5.0, climb_rate), (T0 + 37.0, 5.0, -climb_rate), (T0 + 150.0, 5.0, -2.0),
                   (T0 + 180.0, 5.0, 2.0)]  # fmt: skip
    yaw_items = [(T0 + 55.0, 15.0, math.pi / 2), (T0 + 85.0, 30.0, -math.pi), (T0 + 125.0, 15.0, math.pi / 2)]

    def base(t: Vec) -> tuple[Vec, Vec, Vec]:
        t = np.asarray(t, dtype=np.float64)
        V, dV = _ramp_sum(t, speed_items)
        up, dup = _ramp_sum(t, climb_items)
        yaw, r = _ramp_sum(t, yaw_items)
        cy, sy = np.cos(yaw), np.sin(yaw)
        vel = np.stack([V * cy, V * sy, -up], axis=-1)
        acc = np.stack([dV * cy - V * sy * r, dV * sy + V * cy * r, -dup], axis=-1)
        roll = np.arctan(V * r / g)
        pitch = np.arctan2(up, np.maximum(V, 1.0)) * np.clip(V, 0.0, 1.0)
        return np.stack([roll, pitch, yaw], axis=-1), vel, acc

    return _rates_by_difference(base)


def car_profile(speed: float = 10.0, t_start: float = 2.0, t_stop: float = 40.0, ramp: float = 5.0) -> Profile:
    """A level ground vehicle: at rest (heading 0), accelerates to ``speed`` (C² ramp of ``ramp`` s) while it
    starts to weave (yaw a(t)·0.5 sin 0.2(t − t_start), a = the speed ramp), decelerates to rest at
    ``t_stop``. No sideslip (velocity along body x)."""

    def base(t: Vec) -> tuple[Vec, Vec, Vec]:
        t = np.asarray(t, dtype=np.float64)
        s, ds, _ = _smoothstep((t - t_start) / ramp)
        s2, ds2, _ = _smoothstep((t - t_stop) / ramp)
        V = speed * (s - s2)
        dV = speed * (ds - ds2) / ramp
        A, dA = s - s2, (ds - ds2) / ramp
        yaw = A * 0.5 * np.sin(0.2 * (t - t_start))
        w = dA * 0.5 * np.sin(0.2 * (t - t_start)) + A * 0.1 * np.cos(0.2 * (t - t_start))
        cy, sy = np.cos(yaw), np.sin(yaw)
        z = np.zeros_like(t)
        vel = np.stack([V * cy, V * sy, z], axis=-1)
        acc = np.stack([dV * cy - V * sy * w, dV * sy + V * cy * w, z], axis=-1)
        return np.stack([z, z, yaw], axis=-1), vel, acc

    return _rates_by_difference(base)


def pivot_profile(
    yaw0: float = 0.5, turn: float = math.pi / 2, t_turn: float = 4.0, t_drive: float = 8.0, speed: float = 5.0
) -> Profile:
    """A level ground vehicle at rest (heading ``yaw0``), pivoting on the spot by ``turn`` rad (C² ramp over
    [t_turn, t_turn + 2 s]), then accelerating straight ahead to ``speed`` (ramp over [t_drive, t_drive + 4 s])."""

    def base(t: Vec) -> tuple[Vec, Vec, Vec]:
        t = np.asarray(t, dtype=np.float64)
        s, _, _ = _smoothstep((t - t_turn) / 2.0)
        v, dv, _ = _smoothstep((t - t_drive) / 4.0)
        yaw = yaw0 + turn * s
        cy, sy = np.cos(yaw), np.sin(yaw)
        z = np.zeros_like(t)
        V, A = speed * v, speed * dv / 4.0
        vel, acc = np.stack([V * cy, V * sy, z], axis=-1), np.stack([A * cy, A * sy, z], axis=-1)
        return np.stack([z, z, yaw], axis=-1), vel, acc

    return _rates_by_difference(base)
