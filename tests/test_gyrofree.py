"""Gyro-free INS of book §2.4 (DIGEST_000 §2.5; §8 cases 12–13, 32–34; sign typo §10 item 15)."""

from __future__ import annotations

import math

import numpy as np
import pytest

from ins_hil.nav import gyrofree as gf
from ins_hil.reproduce import gyrofree as rep

ROWS = rep.rows()


@pytest.mark.parametrize("row", ROWS, ids=[r.case for r in ROWS])
def test_published_value(row) -> None:
    assert row.status != "fail", f"ours {row.ours:.6g} vs reference {row.ref:.6g} ({row.tolerance_text}); {row.note}"


def test_accelerometer_identities_exact() -> None:
    """Case 32: (2.43)–(2.45) recover ε, ω_iω_j and ω_i² exactly from ideal 12-accelerometer readings."""
    rng = np.random.default_rng(11)
    for _ in range(20):
        w, e, w0 = rng.normal(size=(3, 3)) * [[3], [10], [9.81]]
        L = float(rng.uniform(0.02, 0.5))
        r = gf.accelerometer_readings(12, L, w, e, w0)
        eps, prod = gf.nine_accel_rates(r, L, 12)
        np.testing.assert_allclose(eps, e, atol=1e-11)
        np.testing.assert_allclose(prod, [w[1] * w[2], w[0] * w[2], w[0] * w[1]], atol=1e-11)
        np.testing.assert_allclose(gf.twelve_accel_squares(r, L), w**2, atol=1e-11)
        eps9, prod9 = gf.nine_accel_rates(gf.accelerometer_readings(9, L, w, e, w0), L, 9)
        np.testing.assert_allclose(eps9, e, atol=1e-11)
        np.testing.assert_allclose(prod9, prod, atol=1e-11)
        e6, w06 = gf.solve_six_accel(L, r[:6], w)
        np.testing.assert_allclose(e6, e, atol=1e-10)
        np.testing.assert_allclose(w06, w0, atol=1e-10)


def test_point_velocity_least_squares_and_the_sign_typo() -> None:
    """Case 33: corrected A_v recovers (ω, v0) exactly; the printed +β2 does not. det(6-acc) = −2L³."""
    rng = np.random.default_rng(12)
    w, v0 = rng.normal(size=3), rng.normal(size=3) * 10
    P = rng.normal(size=(3, 3))
    V = v0[:, None] + np.cross(w, P.T).T
    ww, vv = gf.solve_point_velocities(P, V)
    np.testing.assert_allclose(ww, w, atol=1e-12)
    np.testing.assert_allclose(vv, v0, atol=1e-12)
    A_printed = gf.point_matrix(P)
    A_printed[0:3, 2] *= -1  # the book's first block row [o, β3, β2, h, o, o]
    x, *_ = np.linalg.lstsq(A_printed, V.reshape(-1), rcond=None)
    assert np.linalg.norm(x[:3] - w) > 1e-3
    for L in (0.05, 0.1, 0.3):
        assert np.linalg.det(gf.six_accel_matrix(L)) == pytest.approx(-2 * L**3, rel=1e-12)
    # accelerations of m ≥ 3 points: (ε, w0) with the B_w − B_ω right-hand side
    e = rng.normal(size=3)
    Pw = rng.normal(size=(3, 5))
    U = v0[:, None] + np.cross(e, Pw.T).T + np.cross(w, np.cross(w, Pw.T)).T
    ee, uu = gf.solve_point_accelerations(Pw, U, w)
    np.testing.assert_allclose(ee, e, atol=1e-12)
    np.testing.assert_allclose(uu, v0, atol=1e-12)


@pytest.mark.parametrize("m", [3, 6])
def test_rate_correction_forms_agree(m: int) -> None:
    """Case 34: (2.53) with ρ = R-factor of [λI; H] equals (2.48) with M = μ²I, R = γ²I, λ = γ/μ."""
    rng = np.random.default_rng(13)
    w_prev, dw, z = rng.normal(size=3) * 3, rng.normal(size=3) * 0.01, rng.normal(size=m)
    mu, gam = 0.02, 0.5
    wls = gf.rate_correction_wls(w_prev, dw, z, mu**2 * np.eye(3), gam**2 * np.eye(m))
    np.testing.assert_allclose(gf.rate_correction_qr(w_prev, dw, z, gam / mu), wls, rtol=1e-10, atol=1e-14)
    np.testing.assert_allclose(gf.rate_correction_normal(w_prev, dw, z, gam / mu), wls, rtol=1e-10, atol=1e-14)


def _circle(layout: int, dt: float, duration: float, lam: float = 0.1):
    """Ex 2.4 circle (v̄ = 30 m/s, T = 60 s, z up, g = −9.81): noise-free gyro-free INS vs truth."""
    vbar, T = 30.0, 60.0
    wz = 2 * math.pi / T
    R0 = T * vbar / (2 * math.pi)
    g = np.array([0.0, 0.0, -9.81])
    w = np.array([0.0, 0.0, wz])
    w0 = np.array([0.0, -(vbar**2) / R0, 9.81])  # specific force at O, constant in body axes
    r = gf.accelerometer_readings(layout, 0.1, w, np.zeros(3), w0)
    ins = gf.GyroFreeINS(layout, 0.1, np.array([1.0, 0, 0, 0]), w.copy(), np.array([-vbar, 0, 0]),
                         np.array([0.0, R0, 0.0]), g, lam)  # fmt: skip
    n = round(duration / dt)
    for _ in range(n):
        ins.step(r, dt)
    psi = wz * n * dt
    r_true = R0 * np.array([-math.sin(psi), math.cos(psi), 0.0])
    return float(np.linalg.norm(ins.r - r_true)), ins


@pytest.mark.parametrize("layout", [6, 9, 12])
def test_gyro_free_ins_follows_the_ex24_circle(layout: int) -> None:
    """Noise-free Ex 2.4 circle: every layout stays on the circle; the error is first order in Δt (eq. 2.42)."""
    e1, ins = _circle(layout, 0.02, 15.0)
    e2, _ = _circle(layout, 0.01, 15.0)
    assert e1 < 1.0
    assert 1.6 < e1 / e2 < 2.5
    np.testing.assert_allclose(ins.omega, [0, 0, 2 * math.pi / 60], atol=1e-12)


def test_bad_layout_is_rejected() -> None:
    with pytest.raises(ValueError, match="layout"):
        gf.GyroFreeINS(7, 0.1, np.array([1.0, 0, 0, 0]), np.zeros(3), np.zeros(3), np.zeros(3))


def test_ex25_truth_is_consistent() -> None:
    """Case 31: integrating (2.10) with the (2.55) rates tracks (2.2) only with the corrected λ2 sign."""
    from ins_hil.nav.rotation import quat_from_rotvec, quat_mul

    lam, w, _ = rep.ex25_truth(np.linspace(0.0, 0.5, 5001))
    q = lam[0]
    dt = 0.5 / 5000
    for k in range(5000):
        q = quat_mul(q, quat_from_rotvec(0.5 * (w[k] + w[k + 1]) * dt))
    np.testing.assert_allclose(q, lam[-1], atol=1e-5)
    printed = lam[-1].copy()
    printed[2] = -printed[2]  # the book's sign of λ2 in (2.2)
    assert np.linalg.norm(q - printed) > 1e-2
