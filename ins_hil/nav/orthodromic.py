"""The orthodromic (semi-free azimuth) frame of seed 003 §1 (lines 264–316; DIGEST_001_004 §3.2).

Axes ξ₀, η₀, ζ₀: ζ₀ up (the ellipsoid normal), ξ₀ = sin ε·N + cos ε·E, η₀ = cos ε·N − sin ε·E (ε = 0: the
geographic East–North–Up trihedron), right-handed. Its direction cosines against the Greenwich (ECEF) axes are
Table 1.1 (:func:`dcm_ecef_to_orthodromic`, with the digest's corrections of c₁₂, c₂₁, c₃₁), b_ij its entries.

Relative to the Earth it turns about its horizontal axes only (ω⁰_ζ = 0: the azimuth is "semi-free"; ε then
follows :func:`azimuth_rate`), at (eq. 1.5)

    ω⁰_ξ = −v_η/R_η − τ v_ξ,    ω⁰_η = +v_ξ/R_ξ + τ v_η,

with the normal curvatures 1/R_ξ, 1/R_η of the ellipsoid in the planes ξ₀ζ₀, η₀ζ₀ and the geodesic torsion τ
(Euler's theorem on the meridian and prime-vertical radii M, N: :func:`curvature`). The thesis prints the first-order
series (eq. 1.6) 1/R_ξ = (1 − ½e²b₃₃² + ½e²b₁₃² − h/a)/a, 1/R_η likewise with b₂₃, and τ = e²b₁₃b₂₃/a; expanding
sin²ε/M + cos²ε/N to first order in e² gives e²b₁₃² (not ½e²b₁₃²; at the equator the meridian curvature is
(1 + e²)/a), the form used by :func:`curvature_series`. Eq. 1.5 prints ω⁰_η = −V_ξ/R_ξ − (v_η/a)e²b₁₃b₂₃, the
sign of the whole component reversed (the digest's "second suspicious"; for ε = 0 it must reduce to the ENU
transport rate ω_N = +v_E/(N + h)).

Analysis tools (the navigation core runs the NED frame); tests/test_orthodromic.py holds them against the NED
transport rate and against finite differences of Table 1.1 along a track.
"""

from __future__ import annotations

import math

import numpy as np

from ins_hil.types import Vec

from . import earth

__all__ = [
    "azimuth_rate",
    "curvature",
    "curvature_series",
    "dcm_ecef_to_orthodromic",
    "dcm_ned_to_orthodromic",
    "transport_rate",
]


def dcm_ecef_to_orthodromic(lat: float, lon: float, eps: float) -> Vec:
    """C^{ge} of Table 1.1 (corrected): rows ξ₀, η₀, ζ₀ in ECEF components at geodetic (lat, lon) and azimuth ε
    (rad); maps ECEF vectors to the orthodromic frame."""
    sf, cf, sl, cl = math.sin(lat), math.cos(lat), math.sin(lon), math.cos(lon)
    se, ce = math.sin(eps), math.cos(eps)
    return np.array(
        [
            [-sf * cl * se - sl * ce, -sf * sl * se + cl * ce, cf * se],
            [-sf * cl * ce + sl * se, -sf * sl * ce - cl * se, cf * ce],
            [cf * cl, cf * sl, sf],
        ]
    )


def dcm_ned_to_orthodromic(eps: float) -> Vec:
    """Maps NED vectors to the orthodromic frame (ξ₀ = sin ε·N + cos ε·E, η₀ = cos ε·N − sin ε·E, ζ₀ = −D)."""
    se, ce = math.sin(eps), math.cos(eps)
    return np.array([[se, ce, 0.0], [ce, -se, 0.0], [0.0, 0.0, -1.0]])


def curvature(lat: float, h: float, eps: float) -> tuple[float, float, float]:
    """(1/R_ξ, 1/R_η, τ) in 1/m at geodetic latitude lat (rad), height h (m), azimuth ε (rad): the normal
    curvatures along ξ₀ and η₀ and the geodesic torsion, sin²ε/(M+h) + cos²ε/(N+h), cos²ε/(M+h) + sin²ε/(N+h),
    sin ε cos ε (1/(M+h) − 1/(N+h))."""
    m, n = earth.radii(lat)
    km, kn = 1.0 / (m + h), 1.0 / (n + h)
    se, ce = math.sin(eps), math.cos(eps)
    return se * se * km + ce * ce * kn, ce * ce * km + se * se * kn, se * ce * (km - kn)


def curvature_series(b13: float, b23: float, b33: float, h: float) -> tuple[float, float, float]:
    """Seed 003 eq. 1.6 to first order in e² (coefficient of b₁₃², b₂₃² corrected to e²) and the torsion of eq. 1.5:
    (1/R_ξ, 1/R_η, τ) in 1/m from the Table 1.1 entries b₁₃ = cos φ sin ε, b₂₃ = cos φ cos ε, b₃₃ = sin φ."""
    a, e2 = earth.A_WGS84, earth.E2_WGS84
    base = 1.0 - 0.5 * e2 * b33 * b33 - h / a
    return (base + e2 * b13 * b13) / a, (base + e2 * b23 * b23) / a, e2 * b13 * b23 / a


def transport_rate(lat: float, h: float, eps: float, v_xi: float, v_eta: float) -> Vec:
    """ω⁰ (rad/s, orthodromic axes) of the frame relative to the Earth for the ground velocity (v_ξ, v_η) (m/s):
    seed 003 eq. 1.5 (corrected), (−v_η/R_η − τ v_ξ, v_ξ/R_ξ + τ v_η, 0)."""
    k_xi, k_eta, tau = curvature(lat, h, eps)
    return np.array([-v_eta * k_eta - tau * v_xi, v_xi * k_xi + tau * v_eta, 0.0])


def azimuth_rate(lat: float, h: float, v_east: float) -> float:
    """ε̇ (rad/s) that keeps ω⁰_ζ = 0: the geographic trihedron turns about the vertical at v_E tan φ/(N + h)
    relative to the Earth, and the semi-free frame does not, so ε̇ = −v_E tan φ/(N + h)."""
    _, n = earth.radii(lat)
    return -v_east * math.tan(lat) / (n + h)
