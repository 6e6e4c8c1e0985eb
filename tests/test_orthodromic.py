"""Seed 003's orthodromic frame (ins_hil.nav.orthodromic): Table 1.1, the transport rate (eq. 1.5) and the
curvature (eq. 1.6) against the NED frame and against the frame's own rotation by finite differences."""

from __future__ import annotations

import math

import numpy as np
import pytest

from ins_hil.nav import earth
from ins_hil.nav import orthodromic as o
from ins_hil.reproduce.seed003 import _track


def test_table_1_1_is_the_ned_frame_turned_by_the_azimuth() -> None:
    rng = np.random.default_rng(5)
    for _ in range(20):
        lat, lon, eps = rng.uniform(-1.4, 1.4), rng.uniform(-3, 3), rng.uniform(-3, 3)
        C = o.dcm_ecef_to_orthodromic(lat, lon, eps)
        assert np.max(np.abs(C - o.dcm_ned_to_orthodromic(eps) @ earth.dcm_ecef_to_ned(lat, lon))) < 1e-15
        assert np.linalg.det(C) == pytest.approx(1.0, abs=1e-14)


def test_azimuth_zero_gives_the_enu_transport_rate() -> None:
    lat, h, vn, ve = 0.8, 2000.0, 40.0, -70.0
    w = o.transport_rate(lat, h, 0.0, ve, vn)  # ξ₀ = East, η₀ = North
    m, n = earth.radii(lat)
    assert w == pytest.approx([-vn / (m + h), ve / (n + h), 0.0], rel=1e-15, abs=1e-20)


def test_transport_rate_is_the_rotation_of_table_1_1_along_a_track() -> None:
    """ω⁰ from central differences of the DCM along a track whose ε follows the semi-free rate."""
    h, vel = 3000.0, (150.0, -220.0)
    for t in (0.0, 1000.0):
        y = _track(t, h, vel)
        C = o.dcm_ecef_to_orthodromic(*y)
        dC = o.dcm_ecef_to_orthodromic(*_track(t + 0.5, h, vel)) - o.dcm_ecef_to_orthodromic(*_track(t - 0.5, h, vel))
        W = -dC @ C.T
        w_fd = np.array([W[2, 1], W[0, 2], W[1, 0]])
        v_o = o.dcm_ned_to_orthodromic(y[2]) @ np.array([vel[0], vel[1], 0.0])
        w = o.transport_rate(y[0], h, y[2], v_o[0], v_o[1])
        assert np.linalg.norm(w_fd - w) < 1e-8 * np.linalg.norm(w)  # vertical: 0 (semi-free azimuth)


def test_series_curvature_is_first_order_in_e2_and_the_printed_half_is_not() -> None:
    e2 = earth.E2_WGS84
    lat, eps = 0.0, math.pi / 2  # ξ₀ north on the equator: 1/R_ξ is the meridian curvature 1/M = 1/(a(1 − e²))
    C = o.dcm_ecef_to_orthodromic(lat, 0.0, eps)
    k_xi, _, tau = o.curvature(lat, 0.0, eps)
    s_xi, _, s_tau = o.curvature_series(C[0, 2], C[1, 2], C[2, 2], 0.0)
    assert k_xi == pytest.approx(1.0 / (earth.A_WGS84 * (1.0 - e2)), rel=1e-15)
    assert abs(s_xi / k_xi - 1.0) < 2 * e2 * e2
    assert abs((1.0 + 0.5 * e2) / earth.A_WGS84 / k_xi - 1.0) > 0.4 * e2  # the printed ½e²
    lat, eps = 0.5, 0.6
    C = o.dcm_ecef_to_orthodromic(lat, 0.0, eps)
    _, _, tau = o.curvature(lat, 100.0, eps)
    _, _, s_tau = o.curvature_series(C[0, 2], C[1, 2], C[2, 2], 100.0)
    assert s_tau == pytest.approx(tau, rel=5 * e2)
