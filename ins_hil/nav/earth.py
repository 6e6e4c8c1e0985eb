"""WGS84 Earth model: constants, radii, normal gravity, Earth and transport rates,
and geodetic / ECEF / NED conversions (seed 001 §2.3–2.5, DIGEST_001_004 §1.2–1.5).

Frames: NED local level; positions as geodetic latitude/longitude (rad) and
ellipsoidal height (m). Seed 001 writes its l-frame as ENU; the formulas below
are the same relations re-expressed in NED (north, east, down).
"""

from __future__ import annotations

import math
from typing import Any, cast

import numpy as np

from ins_hil.types import Vec

# seed 001 Table 1 (WGS84)
A_WGS84 = 6_378_137.0  # semi-major axis a [m]
F_WGS84 = 1.0 / 298.257223563  # flattening f = (a-b)/a
B_WGS84 = A_WGS84 * (1.0 - F_WGS84)  # semi-minor axis b [m]
E2_WGS84 = F_WGS84 * (2.0 - F_WGS84)  # first eccentricity squared, seed 001 eq. 1
OMEGA_E = 7.292115e-5  # Earth rate ω_e [rad/s]
GM_WGS84 = 3.986004418e14  # [m^3/s^2] (seed 001 prints "3.986004.418", digest §1.3)
GAMMA_A = 9.7803253359  # normal gravity at the equator [m/s^2]
GAMMA_B = 9.8321849378  # normal gravity at the pole [m/s^2]
K_SOMIGLIANA = B_WGS84 * GAMMA_B / (A_WGS84 * GAMMA_A) - 1.0  # seed 001 eq. 12

G0 = 9.80665  # standard gravity, used only for unit conversions (g → m/s^2)
J2_WGS84 = 1.082629821e-3  # second zonal harmonic (seed 003 eq. 1.9 prints μ = 1.09e-10: a typo, DIGEST_001_004 §3)
GRAVITY_MODELS = ("normal", "j2")  # StrapdownNED.gravity / NavConfig.gravity


def radii(lat: float) -> tuple[float, float]:
    """Meridian radius M and prime-vertical radius N (m) at geodetic latitude (rad).

    seed 001 eqs. 2 and 3.
    """
    s = math.sin(lat)
    w2 = 1.0 - E2_WGS84 * s * s
    w = math.sqrt(w2)
    n = A_WGS84 / w
    m = A_WGS84 * (1.0 - E2_WGS84) / (w2 * w)
    return m, n


def normal_gravity(lat: float, h: float = 0.0) -> float:
    """Normal gravity magnitude γ (m/s^2) at latitude (rad) and height (m).

    Somigliana (seed 001 eq. 12) plus the height series (eq. 16).
    """
    s2 = math.sin(lat) ** 2
    g0 = GAMMA_A * (1.0 + K_SOMIGLIANA * s2) / math.sqrt(1.0 - E2_WGS84 * s2)
    return g0 - (3.0877e-6 - 4.4e-9 * s2) * h + 0.72e-12 * h * h


def gravity_ned(lat: float, h: float = 0.0) -> Vec:
    """Gravity vector in NED, (0, 0, +γ) (seed 001 eq. 11 in NED; no deflection)."""
    return np.array([0.0, 0.0, normal_gravity(lat, h)])


def j2_gravity_nd(slat: float, clat: float, h: float) -> tuple[float, float]:
    """(north, down) gravity (m/s²) of the J2 field plus the centrifugal term at sin/cos of the geodetic
    latitude and height h (m); see :func:`gravity_j2_ned`. Scalar: the mechanization's hot path."""
    n = A_WGS84 / math.sqrt(1.0 - E2_WGS84 * slat * slat)
    x, z = (n + h) * clat, (n * (1.0 - E2_WGS84) + h) * slat  # ECEF in the meridian plane (seed 001 eq. 8)
    r2 = x * x + z * z
    k = 1.5 * J2_WGS84 * A_WGS84 * A_WGS84 / r2
    u = 5.0 * z * z / r2
    gm_r3 = GM_WGS84 / (r2 * math.sqrt(r2))
    gx = -gm_r3 * x * (1.0 + k * (1.0 - u)) + OMEGA_E * OMEGA_E * x
    gz = -gm_r3 * z * (1.0 + k * (3.0 - u))
    return -slat * gx + clat * gz, -clat * gx - slat * gz


def gravity_j2_ned(lat: float, h: float = 0.0) -> Vec:
    """Gravity in NED (m/s²) from the J2 gravitational field plus the centrifugal acceleration.

    In ECEF, g = −GM/r³ (x (1 + k(1 − 5z²/r²)), y (1 + k(1 − 5z²/r²)), z (1 + k(3 − 5z²/r²))) + ω_e² (x, y, 0),
    k = 1.5 J2 (a/r)², rotated to NED at the geodetic latitude. Its radial part is seed 003's eq. 1.9 (with μ =
    J2); unlike :func:`normal_gravity` (the ellipsoid's closed form, the navigation's default) it holds at any
    height, and it has a small north component (the J2 field is not exactly normal to the ellipsoid; the
    truncated J4… terms leave ~1e-5 m/s² against Somigliana at the surface).
    """
    g_n, g_d = j2_gravity_nd(math.sin(lat), math.cos(lat), h)
    return np.array([g_n, 0.0, g_d])


def gravity_model_ned(lat: float, h: float, model: str = "normal") -> Vec:
    """Gravity in NED (m/s²) of a named model (:data:`GRAVITY_MODELS`): "normal" :func:`gravity_ned`, "j2"
    :func:`gravity_j2_ned`."""
    if model == "normal":
        return gravity_ned(lat, h)
    if model == "j2":
        return gravity_j2_ned(lat, h)
    raise ValueError(f"gravity model {model!r}: expected one of {GRAVITY_MODELS}")


def gravity_ecef(r_e: Vec, model: str = "normal") -> Vec:
    """Gravity g^e (m/s², ECEF) at the ECEF point r_e (m): the NED model at its geodetic latitude and height,
    rotated to ECEF (seed 001 eq. 10 with the normal gravity of eq. 11: gravitation minus the centripetal term)."""
    lat, lon, h = ecef_to_geodetic(r_e)
    return dcm_ecef_to_ned(lat, lon).T @ gravity_model_ned(lat, h, model)


def gravitation_ecef(r_e: Vec, model: str = "normal") -> Vec:
    """Gravitation ḡ^e = g^e + Ω_ie Ω_ie r^e (m/s², ECEF; seed 001 eq. 10 solved for ḡ): gravity without the
    centrifugal part, what an inertial-frame mechanization integrates."""
    w2 = OMEGA_E * OMEGA_E
    return gravity_ecef(r_e, model) - w2 * np.array([float(r_e[0]), float(r_e[1]), 0.0])


def earth_rate_ned(lat: float) -> Vec:
    """ω_ie^n in NED (rad/s): (ω_e cos φ, 0, −ω_e sin φ) (seed 001 eq. 67 in NED)."""
    return np.array([OMEGA_E * math.cos(lat), 0.0, -OMEGA_E * math.sin(lat)])


def transport_rate_ned(lat: float, h: float, v_ned: Vec) -> Vec:
    """ω_en^n in NED (rad/s): (v_E/(N+h), −v_N/(M+h), −v_E tanφ/(N+h)).

    NED form of the ENU transport rate implied by seed 001 eqs. 93/94/98
    (DIGEST_001_004 §1.5).
    """
    m, n = radii(lat)
    vn, ve = float(v_ned[0]), float(v_ned[1])
    return np.array([ve / (n + h), -vn / (m + h), -ve * math.tan(lat) / (n + h)])


def geodetic_rates(lat: float, h: float, v_ned: Vec) -> tuple[float, float, float]:
    """(φ̇, λ̇, ḣ) from NED velocity (seed 001 eqs. 55/56 in NED)."""
    m, n = radii(lat)
    return (
        float(v_ned[0]) / (m + h),
        float(v_ned[1]) / ((n + h) * math.cos(lat)),
        -float(v_ned[2]),
    )


def ecef_xyz(lat: float, lon: float, h: float) -> tuple[float, float, float]:
    """ECEF position (m) of a geodetic point as Python floats (no array: the per-message MAVLink path)."""
    return cast(tuple[float, float, float], _ecef(lat, lon, h, math))


def _ecef(lat: Any, lon: Any, h: Any, m: Any) -> tuple[Any, Any, Any]:
    """ECEF x, y, z (m) of geodetic points (rad, rad, m) with the functions of ``m``: ``math`` for floats,
    ``numpy`` for arrays (element-wise the same operations; N as in :func:`radii`)."""
    sl = m.sin(lat)
    n = A_WGS84 / m.sqrt(1.0 - E2_WGS84 * sl * sl)
    ncl = (n + h) * m.cos(lat)
    return ncl * m.cos(lon), ncl * m.sin(lon), (n * (1.0 - E2_WGS84) + h) * sl


def geodetic_to_ecef(lat: float, lon: float, h: float) -> Vec:
    """ECEF position (m) of a geodetic point."""
    return np.array(ecef_xyz(lat, lon, h))


def ecef_to_geodetic(r: Vec) -> tuple[float, float, float]:
    """Geodetic (lat rad, lon rad, h m) of an ECEF point (iterative, < 1e-9 m)."""
    x, y, z = float(r[0]), float(r[1]), float(r[2])
    lon = math.atan2(y, x)
    p = math.hypot(x, y)
    lat = math.atan2(z, p * (1.0 - E2_WGS84))
    h = 0.0
    for _ in range(10):
        _, n = radii(lat)
        h = p / math.cos(lat) - n if abs(lat) < math.radians(80) else z / math.sin(lat) - n * (1 - E2_WGS84)
        lat_new = math.atan2(z, p * (1.0 - E2_WGS84 * n / (n + h)))
        if abs(lat_new - lat) < 1e-15:
            lat = lat_new
            break
        lat = lat_new
    _, n = radii(lat)
    h = p / math.cos(lat) - n if abs(lat) < math.radians(80) else z / math.sin(lat) - n * (1 - E2_WGS84)
    return lat, lon, h


def dcm_ecef_to_ned(lat: float, lon: float) -> Vec:
    """C_e^n: rotates ECEF vectors into the local NED frame at (lat, lon)."""
    sl, cl = math.sin(lat), math.cos(lat)
    so, co = math.sin(lon), math.cos(lon)
    return np.array([[-sl * co, -sl * so, cl], [-so, co, 0.0], [-cl * co, -cl * so, -sl]])


def ned_ref(lat0: float, lon0: float, h0: float) -> tuple[Vec, Vec]:
    """The reference (lat0, lon0 rad, h0 m) of :func:`ned_from_geodetic` computed once for many points: its ECEF
    position (m) and C_e^n."""
    return geodetic_to_ecef(lat0, lon0, h0), dcm_ecef_to_ned(lat0, lon0)


def ned_from_geodetic(lat: float, lon: float, h: float, lat0: float, lon0: float, h0: float,
                      ref: tuple[Vec, Vec] | None = None) -> Vec:  # fmt: skip
    """Exact NED offset (m) of point (lat, lon, h) from reference (lat0, lon0, h0); ``ref``: that reference's
    :func:`ned_ref`, when the caller holds it (many points from one origin: the same numbers)."""
    r0, c_en = ned_ref(lat0, lon0, h0) if ref is None else ref
    return c_en @ (geodetic_to_ecef(lat, lon, h) - r0)


def ned_from_geodetic_many(llh: Vec, lat0: float, lon0: float, h0: float) -> Vec:
    """:func:`ned_from_geodetic` of many points at once: ``llh`` (N, 3) lat, lon (rad), h (m) → (N, 3) NED (m)
    from the reference (a replay's track: one call instead of N)."""
    llh = np.asarray(llh, dtype=np.float64).reshape(-1, 3)
    if not len(llh):
        return np.zeros((0, 3))
    xyz = np.column_stack(_ecef(llh[:, 0], llh[:, 1], llh[:, 2], np))  # ecef_xyz element-wise
    d = xyz - np.array(ecef_xyz(lat0, lon0, h0))
    c = dcm_ecef_to_ned(lat0, lon0)
    x, y, z = d[:, 0], d[:, 1], d[:, 2]
    return np.column_stack([c[0, 0] * x + c[0, 1] * y + c[0, 2] * z, c[1, 0] * x + c[1, 1] * y + c[1, 2] * z,
                            c[2, 0] * x + c[2, 1] * y + c[2, 2] * z])  # fmt: skip


def geodetic_from_ned(ned: Vec, lat0: float, lon0: float, h0: float) -> tuple[float, float, float]:
    """Geodetic point at NED offset (m) from a reference (inverse of ned_from_geodetic)."""
    r = geodetic_to_ecef(lat0, lon0, h0) + dcm_ecef_to_ned(lat0, lon0).T @ np.asarray(ned, dtype=np.float64)
    return ecef_to_geodetic(r)


def ned_delta_small(dlat: float, dlon: float, dh: float, lat: float, h: float) -> Vec:
    """Linearised NED displacement for small geodetic differences (seed 001 eqs. 6, 7)."""
    return np.array(ned_delta_small_xyz(dlat, dlon, dh, lat, h))


def ned_delta_small_xyz(dlat: float, dlon: float, dh: float, lat: float, h: float) -> tuple[float, float, float]:
    """:func:`ned_delta_small` as three Python floats (no array: the drift monitor's per-fix path)."""
    m, n = radii(lat)
    return (m + h) * dlat, (n + h) * math.cos(lat) * dlon, -dh


def pressure_from_altitude(h: float) -> float:
    """ISA static pressure (Pa) at geopotential-like altitude h (m), troposphere."""
    return 101325.0 * (1.0 - 2.25577e-5 * h) ** 5.25588


def altitude_from_pressure(p: float) -> float:
    """Inverse of :func:`pressure_from_altitude` (m): ISA troposphere altitude of a static pressure p (Pa)."""
    return (1.0 - (p / 101325.0) ** (1.0 / 5.25588)) / 2.25577e-5
