"""Platform (gimballed) INS correction with gyro precession-angle sensors (seed 004).

Chen, Neusypin, Selezneva, Mu, *New Algorithms for Autonomous INS Correction with
Precession Angle Sensors in Aircrafts* (Sensors 2019); DIGEST_001_004 §4.

Frames: geographic East–North–Up (the seed's frame, *not* the project's NED: this module
models a gyro-stabilised platform, not the strapdown core). Φ_E, Φ_N, Φ_up are the
platform's deviation angles from the geographic frame (rad); the seed's Φ1, Φ2, Φ3 are
read as Φ_E, Φ_N, Φ_up (platform x = East, y = North; DIGEST §4.2, inferred from
eqs. 1, 6–8). SI units throughout.

Contents:

* :func:`error_rates` — the nonlinear error model, eq. (1), in the corrected reading;
* :func:`precession_accel` — the gyros' precession dynamics, eq. (2);
* :func:`reconstruct_angles` — platform angles from the precession angles to first
  (eq. 4) and second (eq. 5) approximation, with moving-average pre-smoothing;
* :func:`platform_accel`, :func:`level_flight_measurement` — the classical level-flight
  accelerometer measurement, eqs. (6)–(10), with the sign of eq. (10) corrected;
* :func:`north_channel_F`, :func:`observability_matrix`, :func:`s_inverse`,
  :func:`reduced_measurements` — the simplified north channel with a first-order
  Gauss–Markov drift, eqs. (11)–(13), and the reduced measurements S⁻¹z*, eqs. (14)–(21);
The adaptive Kalman filter is :mod:`ins_hil.platform_ins.adaptive`, the simulated test bed that
compares the corrections :mod:`ins_hil.platform_ins.testbed`.
"""

from __future__ import annotations

import math
from collections.abc import Sequence

import numpy as np

from ins_hil.types import Vec

VecLike = Vec | Sequence[float]  # an array or a tuple of floats

__all__ = [
    "EARTH_RATE",
    "H_NORTH",
    "R_EARTH",
    "G",
    "error_rates",
    "level_flight_measurement",
    "moving_average",
    "north_channel_F",
    "observability_matrix",
    "platform_accel",
    "precession_accel",
    "reconstruct_angles",
    "reduced_measurements",
    "s_inverse",
]

EARTH_RATE = 7.292115e-5  # u, rad/s
R_EARTH = 6.371e6  # R, m (spherical Earth of the seed)
G = 9.81  # g, m/s²
H_NORTH = np.array([[0.0, 1.0, 0.0]])  # §4.2: the measurement is Φ_E (from eq. 5)


# --------------------------------------------------------------------------- eq. (1)
def error_rates(
    x: VecLike,
    f: VecLike,
    v: VecLike,
    lat: float,
    drift: VecLike,
    bias: VecLike = (0.0, 0.0),
    mu: VecLike = (0.0, 0.0),
    dlat: float = 0.0,
    dv_up: float = 0.0,
    R: float = R_EARTH,
    u: float = EARTH_RATE,
    reading: str = "corrected",
) -> Vec:
    """Rates (δv̇_E, δv̇_N, Φ̇_E, Φ̇_N) of the nonlinear platform-INS error model, eq. (1).

    ``x`` = (δv_E, δv_N [m/s], Φ_E, Φ_N, Φ_up [rad]); ``f`` specific force and ``v`` velocity
    (E, N, up) in geographic axes [m/s², m/s]; ``lat`` φ and ``dlat`` δφ [rad]; ``drift``
    platform drift ω^dr (E, N, up) [rad/s]; ``bias`` B_E, B_N [m/s²]; ``mu`` accelerometer
    scale-factor errors μ_E, μ_N; ``dv_up`` δv_up [m/s]. The seed gives no equations for
    Φ̇_up, δφ̇, δv̇_up.

    ``reading="corrected"`` (default) implements the digest's reading of three printing errors:

    * δv̇_E: the bracket opened after v_N closes after the sec²φ δφ term,
      v_N (δv_E/R tgφ + u cosφ δφ + v_E/R sec²φ δφ) = v_N δω_up; the Coriolis/transport terms
      −δv_up(2u cosφ + v_E/R) + δv_N(2u sinφ + v_E/R tgφ) and the specific-force terms stand
      outside it (the printed LaTeX closes it only after the f_N term);
    * Φ̇_E: the first bracket reads (−v_N/R − δv_N/R + ω_E^dr) — with the printed −v_E/R the
      error-free state (all errors 0) would not be an equilibrium (Φ̇_E = (v_N − v_E)/R);
    * Φ̇_N: the first drift term is ω_N^dr (printed ω_up^dr), as in the stationary part eq. (11).

    ``reading="printed"`` takes −v_E/R and ω_up^dr literally (for the tests that show why not).
    """
    dve, dvn, pe, pn, pu = (float(a) for a in x)
    fe, fn, fu = (float(a) for a in f)
    ve, vn, vu = (float(a) for a in v)
    we, wn, wu = (float(a) for a in drift)
    be, bn = float(bias[0]), float(bias[1])
    me, mn = float(mu[0]), float(mu[1])
    if reading not in ("corrected", "printed"):
        raise ValueError(f"reading must be 'corrected' or 'printed', not {reading!r}")
    s, c, t = math.sin(lat), math.cos(lat), math.tan(lat)
    sec2 = 1.0 / (c * c)
    sE, cE, sN, cN, sU, cU = math.sin(pe), math.cos(pe), math.sin(pn), math.cos(pn), math.sin(pu), math.cos(pu)
    # δω_up: error of the platform's commanded vertical rate (v_E/R) tgφ + u sinφ
    dw_up = dve / R * t + u * c * dlat + ve / R * sec2 * dlat
    dve_dot = (
        -fe
        - vu * (dve / R - u * s * dlat)
        + vn * dw_up
        - dv_up * (2.0 * u * c + ve / R)
        + dvn * (2.0 * u * s + ve / R * t)
        - fu * cE * sN
        + fe * cN * cU
        + fn * (cN * sU + sE * sN * cU)
        - fe * sE * sN * sU
        + fe * me
        + be
    )
    dvn_dot = (
        -fn
        - vu * dvn / R
        - ve * dw_up
        - dv_up * vn / R
        - dve * (2.0 * u * s + ve / R * t)
        + fn * cE * cU
        - fe * cE * sU
        + fu * sE
        + fn * mn
        + bn
    )
    v_first = vn if reading == "corrected" else ve
    w_first = wn if reading == "corrected" else wu
    w_up_total = ve / R * t + u * s + dw_up + wu  # commanded vertical rate + its error + drift
    pe_dot = (-v_first / R - dvn / R + we) * cN + vn / R * cU - (ve / R + u * c) * sU + w_up_total * sN
    pn_dot = (
        ve / R
        + u * c
        + dve / R
        - u * s * dlat
        + w_first
        - vn * sU / (R * cE)
        - (ve / R + u * c) * cU / cE
        + (-vn / R - dvn / R + we) * math.tan(pe) * sN
        - w_up_total * math.tan(pe) * cN
    )
    return np.array([dve_dot, dvn_dot, pe_dot, pn_dot])


# --------------------------------------------------------------------------- eq. (2)
def precession_accel(
    angles: VecLike,
    rates: VecLike,
    phi: VecLike,
    phi_dot: VecLike,
    J: float,
    H: float,
    h: float,
    M: VecLike = (0.0, 0.0, 0.0),
) -> Vec:
    """(δ̈, λ̈, ϑ̈) of the three gyros' precession angles, eq. (2) [rad/s²].

    ``angles`` (δ, λ, ϑ) [rad], ``rates`` their derivatives [rad/s]; ``phi`` (Φ1, Φ2, Φ3) and
    ``phi_dot`` the platform angles and rates [rad, rad/s]; J moment of inertia about the
    precession axis [kg m²], H angular momentum [N m s], h viscous-friction coefficient
    [N m s]; M small random moments [N m].
    """
    d, lam, th = angles
    dd, dl, dt_ = rates
    p1, p2, _ = phi
    w1, w2, w3 = phi_dot
    return np.array(
        [
            (-h * dd - H * w1 + H * w2 * d + H * w3 * p2 + M[0]) / J,
            (-h * dl + H * w2 + H * w1 * lam - H * w3 * p1 + M[1]) / J,
            (-h * dt_ - H * w3 + H * w2 * th - H * w1 * p2 + M[2]) / J,
        ]
    )


def moving_average(x: Vec, window: int) -> Vec:
    """Centred moving average over ``window`` samples along axis 0 (shorter at the ends).

    The seed pre-smooths the sensor signals by a moving average (window not given)."""
    x = np.asarray(x, dtype=float)
    if window < 1:
        raise ValueError(f"moving-average window must be ≥ 1 sample, not {window}")
    if window == 1:
        return x.copy()
    n = x.shape[0]
    c = np.cumsum(np.concatenate([np.zeros((1, *x.shape[1:])), x]), axis=0)
    lo = np.clip(np.arange(n) - (window - 1) // 2, 0, n)
    hi = np.clip(np.arange(n) + window // 2 + 1, 0, n)
    shape = (n,) + (1,) * (x.ndim - 1)
    return (c[hi] - c[lo]) / (hi - lo).reshape(shape)


def _cumtrapz(y: Vec, dt: float) -> Vec:
    out = np.zeros_like(y)
    out[1:] = np.cumsum(0.5 * (y[1:] + y[:-1]), axis=0) * dt
    return out


def reconstruct_angles(angles: Vec, dt: float, J: float, H: float, h: float, order: int = 2, window: int = 1) -> Vec:
    """Platform angles (Φ1, Φ2, Φ3) [rad] from sampled precession angles (δ, λ, ϑ), eqs. (3)–(5).

    ``angles`` is (n, 3), sampled every ``dt`` s from t = 0, when the platform angles and the
    precession angles and rates are zero (the integrals of eqs. 4–5 start there). The signals
    are first smoothed by a centred moving average of ``window`` samples, then differentiated
    numerically (central differences). ``order=1``: eq. (4), Φ1 = −(Jδ̇ + hδ)/H,
    Φ2 = (Jλ̇ + hλ)/H, Φ3 = −(Jϑ̇ + hϑ)/H. ``order=2``: eq. (5), which adds the integrals of
    the cross terms of eq. (2) evaluated with the first approximation.
    """
    a = moving_average(np.asarray(angles, dtype=float), window)
    if a.ndim != 2 or a.shape[1] != 3 or a.shape[0] < 3:
        raise ValueError("angles must be an (n ≥ 3, 3) array of (δ, λ, ϑ)")
    if order not in (1, 2):
        raise ValueError(f"order must be 1 or 2, not {order}")
    rate = np.gradient(a, dt, axis=0)
    m = J * rate + h * a  # (Jδ̇ + hδ, Jλ̇ + hλ, Jϑ̇ + hϑ)
    phi = np.column_stack([-m[:, 0], m[:, 1], -m[:, 2]]) / H  # eq. (4)
    if order == 1:
        return phi
    md = np.gradient(m, dt, axis=0)  # (Jδ̈ + hδ̇, …)
    d, lam, th = a[:, 0], a[:, 1], a[:, 2]
    i1 = md[:, 1] * d - md[:, 2] * m[:, 1] / H
    i2 = md[:, 0] * lam + md[:, 2] * m[:, 0] / H
    i3 = md[:, 1] * th + md[:, 0] * m[:, 1] / H
    return phi + _cumtrapz(np.column_stack([i1, i2, i3]), dt) / H  # eq. (5)


# --------------------------------------------------------------------------- eqs. (6)–(10)
def platform_accel(a_o: VecLike, phi: VecLike) -> Vec:
    """Accelerations in platform axes from reference-frame ones, small-angle matrix of eq. (6)."""
    p1, p2, p3 = phi
    C = np.array([[1.0, p3, -p2], [-p3, 1.0, p1], [p2, -p1, 1.0]])
    return C @ np.asarray(a_o, dtype=float)


def level_flight_measurement(
    phi1: float, phi2: float, g: float = G, da: VecLike = (0.0, 0.0), printed: bool = False
) -> tuple[float, float]:
    """(z1, z2) = (a_x^p, a_y^p) of the classical correction in level, unaccelerated flight, eqs. (8)–(10).

    z1 = −Φ2 g + δa_x, z2 = +Φ1 g + δa_y: eq. (8) and eq. (7) with a^o = (0, 0, g) give +Φ1 g;
    the printed eq. (10) has −Φ1 g (``printed=True``), which contradicts (8) (DIGEST §4.3).
    """
    s = -1.0 if printed else 1.0
    return -phi2 * g + da[0], s * phi1 * g + da[1]


# --------------------------------------------------------------------------- eqs. (11)–(21)
def north_channel_F(
    T: float, g: float = G, R: float = R_EARTH, beta: float = 1.0 / 3600.0, cos_phi_n: float = 1.0
) -> Vec:
    """Euler-discretised north channel, eq. (13): x = (δv_N, Φ_E, ω_E^dr), step T [s].

    Continuous model eq. (12): δv̇_N = gΦ_E + B_N, Φ̇_E = −(δv_N/R) cosΦ_N + ω_E^dr cosΦ_N,
    ω̇_E^dr = −β ω_E^dr + A √(2β) w (first-order Gauss–Markov, RMS A, 1/β correlation time).
    """
    return np.array([[1.0, T * g, 0.0], [-T / R * cos_phi_n, 1.0, T * cos_phi_n], [0.0, 0.0, 1.0 - T * beta]])


def observability_matrix(F: Vec, H: Vec = H_NORTH) -> Vec:
    """S = [H; HF; …; HF^{n−1}], eq. (18)."""
    n = F.shape[0]
    rows = [H]
    for _ in range(n - 1):
        rows.append(rows[-1] @ F)
    return np.vstack(rows)


def s_inverse(T: float, g: float = G, R: float = R_EARTH, beta: float = 1.0 / 3600.0, cos_phi_n: float = 1.0) -> Vec:
    """S⁻¹ of the north channel in closed form, eq. (20) (undefined for β = 0: det S = −T³β cos²Φ_N / R)."""
    if beta <= 0.0:
        raise ValueError("the reduced measurements need β > 0: S is singular for β = 0 (det S = −T³ β cos²Φ_N / R)")
    c = cos_phi_n
    d = beta * T * T * c
    return np.array(
        [
            [(-g * T * T * c + R * (beta * T - 1.0)) / d, R * (2.0 - T * beta) / d, -R / d],
            [1.0, 0.0, 0.0],
            [-(g * T * T * c + R) / (R * d), 2.0 / d, -1.0 / d],
        ]
    )


def reduced_measurements(
    z: Vec, T: float, g: float = G, R: float = R_EARTH, beta: float = 1.0 / 3600.0, cos_phi_n: float = 1.0
) -> Vec:
    """Reduced measurements, eq. (21): row k = S⁻¹ (z_k, z_{k+1}, z_{k+2}) ≈ x_k = (δv_N, Φ_E, ω_E^dr).

    ``z`` = the (pre-smoothed) Φ_E samples every T s; returns (len(z) − 2, 3).
    """
    z = np.asarray(z, dtype=float)
    if z.ndim != 1 or len(z) < 3:
        raise ValueError("reduced measurements need at least three angle samples")
    zs = np.column_stack([z[:-2], z[1:-1], z[2:]])
    return zs @ s_inverse(T, g, R, beta, cos_phi_n).T
