"""Book eq. 4.9 (Artese & Trecroci 2008): position-error growth against the project's strapdown.

A level IMU at rest (NED, 45° N, 100 Hz, Earth rate and transport rate off so that the Schuler loop
does not bend the curves over the 60 s) is run by :class:`ins_hil.nav.mechanization.StrapdownNED`
with one error at a time; the position error at 60 s is compared with the term of eq. 4.9 that
models it. Two printed terms lack a factor: the gyro-bias term δb_0g Δt³/6 needs g (a tilt
b_g t lets g·b_g t into the horizontal channel), and the accelerometer scale-factor term
SF_0a Δt²/2 needs the measured acceleration F the book defines but does not use (DIGEST_000
§10 item 36). The terms δH_0z (VΔt) and SF_0g (ΔH_z)(VΔt) are dead-reckoning terms (a heading
error does not move an INS at constant velocity) and are not rows.
"""

from __future__ import annotations

import math
from functools import lru_cache

import numpy as np

from ins_hil.nav import earth
from ins_hil.nav.mechanization import StrapdownNED, StrapdownState
from ins_hil.nav.rotation import quat_from_euler
from ins_hil.types import Vec

from . import Row

LAT, H0, DT, T = math.radians(45.0), 100.0, 0.01, 60.0
G = earth.normal_gravity(LAT, H0)


def free_run(
    dv0: float = 0.0, b_a: Vec | None = None, tilt: float = 0.0, b_g: Vec | None = None, sf_z: float = 0.0
) -> Vec:
    """NED position error (m) after T s at rest: initial north velocity error dv0 (m/s), accelerometer bias b_a
    (m/s², body), pitch error tilt (rad), gyro bias b_g (rad/s, body), z-accelerometer scale-factor error sf_z."""
    b_a = np.zeros(3) if b_a is None else np.asarray(b_a, dtype=float)
    b_g = np.zeros(3) if b_g is None else np.asarray(b_g, dtype=float)
    m, _ = earth.radii(LAT)
    q0 = quat_from_euler(0.0, tilt, 0.0)
    ins = StrapdownNED(StrapdownState(q0, np.array([dv0, 0.0, 0.0]), LAT, 0.0, H0), earth_rate=False)
    f_true = np.array([0.0, 0.0, -G])  # level at rest: the specific force is −g (body FRD = NED)
    f_m = f_true * np.array([1.0, 1.0, 1.0 + sf_z]) + b_a
    for _ in range(round(T / DT)):
        ins.step(b_g * DT, f_m * DT, DT)
    s = ins.state
    return np.array([(s.lat - LAT) * (m + H0), s.lon * earth.radii(LAT)[1] * math.cos(LAT), H0 - s.h])


@lru_cache(maxsize=1)
def rows() -> list[Row]:
    g = "Book eq. 4.9 position-error growth vs the strapdown (level, at rest, 45° N, 100 Hz, 60 s, no Earth rate)"
    dv0, ba, tilt, bg, sf = 0.1, 1e-3, 1e-3, 1e-5, 1e-3
    p_v = free_run(dv0=dv0)[0]
    p_a = free_run(b_a=np.array([ba, 0.0, 0.0]))[0]
    p_t = free_run(tilt=tilt)[0]
    p_g = free_run(b_g=np.array([0.0, bg, 0.0]))[0]
    p_s = free_run(sf_z=sf)[2]
    t2, t3 = T * T / 2.0, T**3 / 6.0
    out = [
        Row(g, "δv₀ = 0.1 m/s: δp_N / (δv₀ Δt)", None, p_v / (dv0 * T), 1e-4, "abs", 1.0),
        Row(g, "δb_a = 1e-3 m/s²: δp_N / (δb_0a Δt²/2)", None, p_a / (ba * t2), 1e-4, "abs", 1.0),
        Row(g, "δα = 1e-3 rad (pitch): |δp_N| / (δα₀ g Δt²/2)", None, abs(p_t) / (tilt * G * t2), 1e-4, "abs", 1.0),
        Row(g, "δb_g = 1e-5 rad/s (east): |δp_N| / (g δb_0g Δt³/6)", None, abs(p_g) / (G * bg * t3), 1e-4, "abs", 1.0,
            "the gyro term with the factor g it needs"),
        Row(g, "δb_g = 1e-5 rad/s: |δp_N| / (δb_0g Δt³/6) as printed", None, abs(p_g) / (bg * t3), 0.05, "abs", G,
            "the printed term lacks g: off by g = 9.81 (units rad·s², not m)", typo=True),
        Row(g, "SF_a = 1e-3 (z): |δp_D| / (SF_0a F Δt²/2), F = g", None, abs(p_s) / (sf * G * t2), 2e-3, "abs", 1.0,
            "with the measured acceleration F the book defines; +0.09 %: the free-air gradient as it sinks"),
        Row(g, "SF_a = 1e-3 (z): |δp_D| / (SF_0a Δt²/2) as printed", None, abs(p_s) / (sf * t2), 0.05, "abs", G,
            "the printed term lacks F (DIGEST_000 §10 item 36): off by F = g", typo=True),
    ]  # fmt: skip
    return out
