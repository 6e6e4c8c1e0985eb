"""Seed 004 (platform INS with precession-angle sensors): each formula against an independent form."""

from __future__ import annotations

import math

import numpy as np
import pytest

from ins_hil.platform_ins import model as pi
from ins_hil.platform_ins import testbed as tb
from ins_hil.platform_ins.adaptive import AdaptiveKF
from ins_hil.reproduce import seed004

LAT = math.radians(55.0)


def _c_phi(pe: float, pn: float, pu: float) -> np.ndarray:
    """C(Φ) = R_N(Φ_N) R_E(Φ_E) R_up(Φ_up), rows 1–2 as in DIGEST_001_004 §4.1 note (ii), row 3 completed."""
    sE, cE, sN, cN, sU, cU = math.sin(pe), math.cos(pe), math.sin(pn), math.cos(pn), math.sin(pu), math.cos(pu)
    return np.array(
        [
            [cN * cU - sE * sN * sU, cN * sU + sE * sN * cU, -cE * sN],
            [-cE * sU, cE * cU, sE],
            [sN * cU + sE * cN * sU, sN * sU - sE * cN * cU, cE * cN],
        ]
    )


def test_c_phi_is_a_rotation() -> None:
    C = _c_phi(0.1, -0.2, 0.7)
    np.testing.assert_allclose(C @ C.T, np.eye(3), atol=1e-14)


def test_zero_error_is_an_equilibrium_only_in_the_corrected_reading() -> None:
    """Moving vehicle, no errors, no drift: the rates vanish with −v_N/R in Φ̇_E, not with the printed −v_E/R."""
    v, f = (120.0, -80.0, 3.0), (0.4, -0.2, 9.81)
    r = pi.error_rates(np.zeros(5), f, v, LAT, (0.0, 0.0, 0.0))
    np.testing.assert_allclose(r, 0.0, atol=1e-15)
    rp = pi.error_rates(np.zeros(5), f, v, LAT, (0.0, 0.0, 0.0), reading="printed")
    assert rp[2] == pytest.approx((-v[0] + v[1]) / pi.R_EARTH, rel=1e-12)  # (v_N − v_E)/R ≠ 0


def test_specific_force_terms_are_rows_of_c_phi() -> None:
    """v = 0, u = 0: δv̇_(E,N) = (C(Φ) f − f)_(E,N) + μ f + B (eq. 1, note ii)."""
    phi = (0.02, -0.03, 0.9)
    f = np.array([0.7, -1.1, 9.8])
    bias, mu = (1e-3, -2e-3), (1e-4, 3e-4)
    r = pi.error_rates(np.array([0.0, 0.0, *phi]), f, (0.0, 0.0, 0.0), LAT, (0, 0, 0), bias, mu, u=0.0)
    expect = (_c_phi(*phi) @ f - f)[:2] + np.array(mu) * f[:2] + np.array(bias)
    np.testing.assert_allclose(r[:2], expect, rtol=0, atol=1e-15)


def test_stationary_part_is_eq_11() -> None:
    """v = 0 on the equator, Φ_up = 0: eq. (1) reduces to eq. (11) (with + B_E), Φ̇_N carries ω_N^dr."""
    x = np.array([0.3, -0.2, 2e-3, -1e-3, 0.0])
    drift, bias = (1e-6, 2e-6, 5e-6), (1e-3, -1e-3)
    g = 9.81
    r = pi.error_rates(x, (0.0, 0.0, g), (0.0, 0.0, 0.0), 0.0, drift, bias, u=0.0)
    dve, dvn, pe, pn = x[:4]
    R = pi.R_EARTH
    eq11 = [
        -g * math.cos(pe) * math.sin(pn) + bias[0],
        g * math.sin(pe) + bias[1],
        -(dvn / R) * math.cos(pn) + drift[0] * math.cos(pn) + drift[2] * math.sin(pn),
        dve / R
        - (dvn / R) * math.tan(pe) * math.sin(pn)
        + drift[1]
        + drift[0] * math.tan(pe) * math.sin(pn)
        - drift[2] * math.tan(pe) * math.cos(pn),
    ]
    np.testing.assert_allclose(r, eq11, rtol=1e-12, atol=1e-18)
    rp = pi.error_rates(x, (0.0, 0.0, g), (0.0, 0.0, 0.0), 0.0, drift, bias, u=0.0, reading="printed")
    assert rp[3] - r[3] == pytest.approx(drift[2] - drift[1], rel=1e-9)  # printed ω_up^dr in place of ω_N^dr


def test_bad_reading_raises() -> None:
    with pytest.raises(ValueError, match="reading"):
        pi.error_rates(np.zeros(5), (0, 0, 9.8), (0, 0, 0), 0.0, (0, 0, 0), reading="literal")


def test_reconstruction_orders() -> None:
    """004-B: eq. (4) residual ∝ Φ², eq. (5) residual ∝ Φ³ and ≥ 10× smaller (precession angles from eq. 2)."""
    r1a, r2a = seed004.reconstruction_residuals(2e-4)
    r1b, r2b = seed004.reconstruction_residuals(1e-4)
    assert r1a / r1b == pytest.approx(4.0, rel=0.15)
    assert r2a / r2b == pytest.approx(8.0, rel=0.15)
    assert r2a < 0.1 * r1a


def test_reconstruction_recovers_the_linear_part_exactly() -> None:
    """Eq. (4) is the exact integral of eq. (3): with the cross terms of (2) absent the angles come back."""
    dt, J, H, h = 1e-3, 2e-3, 1.0, 1e-2
    t = dt * np.arange(4001)
    phi = np.column_stack([1e-4 * np.sin(2 * t), -2e-4 * np.sin(t) ** 2, 3e-4 * (1 - np.cos(1.5 * t))])
    # δ solves Jδ̈ + hδ̇ = −HΦ̇1 with δ(0) = δ̇(0) = 0: build it by integrating δ̇ from the first-order law
    d = np.zeros_like(phi)
    sign = np.array([-1.0, 1.0, -1.0])
    for k in range(len(t) - 1):  # J δ̇ + h δ = ±H Φ  (eq. 4 integrated once), exact exponential step
        a = math.exp(-h / J * dt)
        target = sign * H * 0.5 * (phi[k] + phi[k + 1]) / h
        d[k + 1] = target + (d[k] - target) * a
    rec = pi.reconstruct_angles(d, dt, J, H, h, order=1)
    np.testing.assert_allclose(rec[5:-5], phi[5:-5], atol=2e-9)


def test_moving_average() -> None:
    x = np.arange(10.0)
    np.testing.assert_allclose(pi.moving_average(x, 3)[1:-1], x[1:-1])
    np.testing.assert_allclose(pi.moving_average(np.full((7, 3), 2.5), 4), 2.5)
    np.testing.assert_array_equal(pi.moving_average(x, 1), x)
    with pytest.raises(ValueError, match="window"):
        pi.moving_average(x, 0)


def test_level_flight_sign() -> None:
    """004-C: a^o = (0, 0, g) ⇒ a_x^p = −Φ2 g, a_y^p = +Φ1 g; the printed eq. (10) has −Φ1 g."""
    p1, p2 = 3e-4, -5e-4
    ap = pi.platform_accel((0.0, 0.0, 9.81), (p1, p2, 0.02))
    z = pi.level_flight_measurement(p1, p2, 9.81)
    assert z == pytest.approx((ap[0], ap[1]), rel=1e-15)
    assert z[1] == pytest.approx(p1 * 9.81)
    zp = pi.level_flight_measurement(p1, p2, 9.81, printed=True)
    assert zp[1] == pytest.approx(-z[1])
    # the small-angle matrix (6) is C(Φ) to first order
    phi = (1e-4, -2e-4, 3e-4)
    a = np.array([0.3, -0.4, 9.81])
    np.testing.assert_allclose(pi.platform_accel(a, phi), _c_phi(*phi) @ a, atol=1e-6)


def test_reduced_measurements_case_a() -> None:
    """004-A: the digest's z values, S⁻¹z* = x₁, eq. (20) = inv(S), cond(S) ≈ 4.2e10."""
    a = seed004.case_a()
    assert a["z2"] == pytest.approx(1.000843038769424e-04, rel=1e-12)
    assert a["z3"] == pytest.approx(1.001683537749176e-04, rel=1e-12)
    assert (a["dvn"], a["phie"], a["wdr"]) == pytest.approx((0.1, 1e-4, 1e-7), rel=1e-6)
    assert a["cond"] == pytest.approx(4.2e10, rel=0.05)
    for T, beta, c in ((1.0, 1e-3, 1.0), (30.0, 1 / 3600, 0.8), (5.0, 0.01, 0.95)):
        S = pi.observability_matrix(pi.north_channel_F(T, beta=beta, cos_phi_n=c))
        np.testing.assert_allclose(pi.s_inverse(T, beta=beta, cos_phi_n=c), np.linalg.inv(S), rtol=1e-6)
        assert np.linalg.det(S) == pytest.approx(-(T**3) * beta * c * c / pi.R_EARTH, rel=1e-6)
    with pytest.raises(ValueError, match="β > 0"):
        pi.s_inverse(1.0, beta=0.0)


def test_reduced_measurements_recover_a_sequence() -> None:
    T, beta = 20.0, 1 / 1800
    F = pi.north_channel_F(T, beta=beta)
    x = np.array([0.2, -3e-5, 2e-7])
    xs, zs = [], []
    for _ in range(8):
        xs.append(x.copy())
        zs.append(x[1])
        x = F @ x
    y = pi.reduced_measurements(np.array(zs), T, beta=beta)
    np.testing.assert_allclose(y, np.array(xs)[:-2], rtol=1e-6, atol=1e-12)


def _kf_run(r_true: float, r_nom: float, q_scale_true: float, adapt: bool, n: int = 3000) -> AdaptiveKF:
    rng = np.random.default_rng(1)
    F = np.array([[1.0, 1.0], [0.0, 1.0]])
    H = np.array([[1.0, 0.0]])
    q_nom = np.array([1e-4, 1e-6])
    kf = AdaptiveKF(F, H, q_nom, [r_nom], np.zeros(2), np.eye(2), adapt=adapt)
    x = np.zeros(2)
    for _ in range(n):
        x = F @ x + np.sqrt(q_scale_true * q_nom) * rng.standard_normal(2)
        kf.step(H @ x + math.sqrt(r_true) * rng.standard_normal(1))
    return kf


def test_adaptive_kf_learns_r_and_stays_bounded() -> None:
    kf = _kf_run(r_true=1.0, r_nom=0.01, q_scale_true=1.0, adapt=True)
    assert 30.0 < kf.r_scales[0] < 300.0  # the true R is 100 × R_nom
    assert _kf_run(1.0, 0.01, 1.0, adapt=False).r_scales[0] == 1.0
    kf2 = _kf_run(r_true=1e6, r_nom=1e-6, q_scale_true=1.0, adapt=True, n=300)
    assert kf2.r_scales[0] == kf2.s_max  # bounded


def test_adaptive_kf_learns_q() -> None:
    kf = _kf_run(r_true=0.01, r_nom=0.01, q_scale_true=50.0, adapt=True)
    assert kf.q_scales[0] > 10.0
    assert np.all(kf.q_scales <= kf.s_max)


def test_testbed_short_run() -> None:
    """45 min with manoeuvres: the reduced-measurement correction improves the deviation angle; the classical
    one fails in manoeuvres unless its level-flight measurement is skipped there."""
    res = tb.simulate(tb.TestbedConfig(duration=2700.0, pulses=((900.0, 40.0, 0.0, 1.0), (1800.0, 60.0, 1.5, 0.5))))
    imp = tb.improvements(res)
    assert imp["reduced adaptive"][1] > 80.0
    assert imp["classical"][1] > 50.0
    assert imp["classical, ungated"][1] < 0.0
    assert res.cond_S > 1e9
    assert np.all(np.isfinite(res.est["reduced adaptive"][1:-2]))
