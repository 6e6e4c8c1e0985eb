"""Square-root / UD / Joseph / conventional equivalence (book §3.1.2–3.1.3, DIGEST_000 §8 cases 26, 35, 36)."""

from __future__ import annotations

import math

import numpy as np
import pytest
from runtime_helpers import with_due

from ins_hil.core import NavConfig, NavCore
from ins_hil.core_parts.config import DelayConfig
from ins_hil.fusion import book
from ins_hil.fusion import sqrt as sq
from ins_hil.fusion.ekf import ErrorStateEKF, FilterConfig
from ins_hil.nav.mechanization import StrapdownState
from ins_hil.nav.rotation import dcm_from_euler, quat_from_euler
from ins_hil.sim import sensors as se
from ins_hil.sim import trajectory as tr


def _random_problem(rng, n=9, m=6):
    A = rng.normal(size=(n, n))
    P = A @ A.T + n * np.eye(n)
    Phi = np.eye(n) + 0.05 * rng.normal(size=(n, n))
    qd = rng.uniform(0.01, 0.1, n)
    H = rng.normal(size=(m, n))
    r = rng.uniform(0.1, 1.0, m)
    return P, Phi, qd, H, r


def test_all_forms_agree_on_random_9_state_problem():
    """Case 36: QR (3.10)–(3.15), Cholesky-Joseph (3.20)–(3.22), UD, Joseph (3.16), conventional (3.6)–(3.8)."""
    rng = np.random.default_rng(7)
    P0, Phi, qd, H, r = _random_problem(rng)
    x0 = rng.normal(size=9)
    zs = [rng.normal(size=6) for _ in range(5)]
    R = np.diag(r)
    # reference: conventional
    x, P = x0.copy(), P0.copy()
    for z in zs:
        P = sq.predict_cov(P, Phi, np.diag(qd))
        x = Phi @ x
        x, P = sq.conventional_update(x, P, z, H, R)
    for kind in ("qr", "cholesky", "ud"):
        f = sq.factor_from_cov(kind, P0)
        xf = x0.copy()
        for z in zs:
            f = sq.factor_predict(f, Phi, qd)
            xf = Phi @ xf
            xf, f = sq.factor_update(f, xf, z, H, r)
        np.testing.assert_allclose(xf, x, rtol=1e-10, atol=1e-10, err_msg=kind)
        np.testing.assert_allclose(sq.factor_cov(f), P, rtol=1e-9, atol=1e-10, err_msg=kind)
    xj, Pj = sq.joseph_update(x0, P0, zs[0], H, R)
    xc, Pc = sq.conventional_update(x0, P0, zs[0], H, R)
    np.testing.assert_allclose(xj, xc, atol=1e-12)
    np.testing.assert_allclose(Pj, Pc, atol=1e-10)


def test_qr_gain_is_posterior_times_HtRinv():
    """Book eq. (3.54): K = P(+) H^T R^{-1}; and (3.53) P(+) = (P^{-1} + H^T R^{-1} H)^{-1}."""
    rng = np.random.default_rng(3)
    P0, _, _, H, r = _random_problem(rng)
    m = np.linalg.cholesky(P0)
    x0 = np.zeros(9)
    z = rng.normal(size=6)
    x, p = sq.qr_update(x0, m, z, H, np.diag(np.sqrt(r)))
    Pp = p @ p.T
    Rinv = np.diag(1 / r)
    np.testing.assert_allclose(Pp, np.linalg.inv(np.linalg.inv(P0) + H.T @ Rinv @ H), rtol=1e-9)
    np.testing.assert_allclose(x, Pp @ H.T @ Rinv @ z, rtol=1e-9)


def test_ud_decomposition_and_thornton():
    rng = np.random.default_rng(11)
    P0, Phi, qd, _, _ = _random_problem(rng, n=15)
    U, d = sq.ud_decompose(P0)
    assert np.allclose(np.tril(U, -1), 0) and np.allclose(np.diag(U), 1)
    np.testing.assert_allclose((U * d) @ U.T, P0, rtol=1e-12)
    U2, d2 = sq.thornton_predict(U, d, Phi, qd)
    np.testing.assert_allclose((U2 * d2) @ U2.T, Phi @ P0 @ Phi.T + np.diag(qd), rtol=1e-10)


def test_book_phi_is_truncated_exponential():
    """Case 35: Φ of (3.2) and (3.41) equal I + FΔt + F²Δt²/2."""
    a = np.array((0.3, -0.2, 9.81))
    A = dcm_from_euler(0.1, 0.2, 0.3).T
    dt = 0.05
    F9 = np.zeros((9, 9))
    F9[3:6, 0:3] = book.skew(a)
    F9[6:9, 3:6] = np.eye(3)
    np.testing.assert_allclose(book.phi_9(a, dt), np.eye(9) + F9 * dt + F9 @ F9 * dt * dt / 2, atol=1e-15)
    F12 = np.zeros((12, 12))
    F12[:9, :9] = F9
    F12[0:3, 9:12] = A.T
    np.testing.assert_allclose(book.phi_12(a, A, dt), np.eye(12) + F12 * dt + F12 @ F12 * dt * dt / 2, atol=1e-15)


def test_observability_ranks_case_26():
    """GPS only: rank 8 of 9, null direction μ ∥ ã; with (3.30) rank 9; 12 states: 10 and 12."""
    a = np.array((0.5, -0.3, 9.81))
    dt = 0.05
    Phi = book.phi_9(a, dt)
    assert sq.observability_rank(Phi, book.h_gps(9)) == 8
    ob = sq.observability_matrix(Phi, book.h_gps(9))
    null = np.linalg.svd(ob)[2][-1]
    mu = null[0:3] / np.linalg.norm(null[0:3])
    assert abs(abs(mu @ a) / np.linalg.norm(a) - 1) < 1e-6
    assert sq.observability_rank(Phi, book.h_gps_mag_baro(9)) == 9
    Phi12 = book.phi_12(a, np.eye(3), dt)
    assert sq.observability_rank(Phi12, book.h_gps(12)) == 10
    assert sq.observability_rank(Phi12, book.h_gps_mag_baro(12)) == 12
    # the navigation filter's own F in the book's 12-state configuration (gyro bias, no accel bias)
    kf = ErrorStateEKF(FilterConfig(accel_bias=False, earth_terms=False, second_order=True))
    z3 = np.zeros(3)
    F = kf.build_F(np.eye(3), np.array((0.5, -0.3, -9.81)), z3, z3, z3, z3, 0.7, 0.0)
    Phi_f = np.eye(12) + F * dt + F @ F * dt * dt / 2
    Hg = np.zeros((6, 12))
    Hg[0:3, 0:3] = np.eye(3)
    Hg[3:6, 3:6] = np.eye(3)
    assert sq.observability_rank(Phi_f, Hg) == 10
    Hm = np.zeros((3, 12))
    Hm[0:2, 7:9] = np.eye(2)  # magnetometer with m = e1: [μ2, μ3]
    Hm[2, 2] = -1.0  # baro
    assert sq.observability_rank(Phi_f, np.vstack([Hg, Hm])) == 12


@pytest.mark.parametrize(
    "numerics,vib", [("conventional", 0.0), ("qr", 0.0), ("cholesky", 0.0), ("ud", 0.0), ("qr", 0.4), ("cholesky", 0.4),
                     ("conventional", 0.4)]
)  # fmt: skip
def test_navcore_numerics_give_the_same_estimates(numerics, vib):
    """The same GNSS-aided run with each numerics option: same state as the Joseph default (also with the
    vibration noise, a full 3×3 attitude block of Q: the QR/Cholesky factors take its root)."""
    dt = 0.02
    truth = tr.generate(tr.uav_profile(t_takeoff=0.0, ramp=5.0), 8.0, dt, math.radians(45), 0.5, 100.0)
    rng = np.random.default_rng(2)
    imu = se.corrupt_imu(truth, se.mems_gyro(rng), se.mems_accel(rng), seed=1).samples()
    fixes = se.gnss_fixes(truth, se.GnssModel(rate=5), seed=2)
    e = truth.euler[0]

    def run(num: str):
        init = StrapdownState(quat_from_euler(e[0] + 0.01, e[1], e[2] + 0.03), truth.vel_ned[0].copy(),
                              truth.lat[0], truth.lon[0], truth.h[0], 0.0)  # fmt: skip
        core = NavCore(
            init,
            NavConfig(
                filter=FilterConfig(numerics=num, gyro_vib_gain=vib, accel_vib_gain=vib),
                delay=DelayConfig(compensation=False),
            ),
        )
        for s, due in with_due(imu, fixes):
            core.step(s)
            for f in due:
                core.fuse(f)
        return core

    ref, other = run("joseph"), run(numerics)
    np.testing.assert_allclose(other.ins.state.q_nb, ref.ins.state.q_nb, atol=1e-9)
    np.testing.assert_allclose(other.ins.state.vel_ned, ref.ins.state.vel_ned, atol=1e-8)
    np.testing.assert_allclose(other.bg, ref.bg, atol=1e-10)
    np.testing.assert_allclose(other.kf.P, ref.kf.P, rtol=1e-6, atol=1e-12)


@pytest.mark.parametrize("numerics", ["qr", "cholesky"])
def test_vibration_noise_root_with_a_rank_deficient_block(numerics):
    """Review finding (session 6): with no white noise on an axis block (gyro_arw = accel_vrw = 0) and the
    vibration on one body axis only, the attitude/velocity noise blocks are rank 1; their root must not need a
    Cholesky factor (that raised 'not positive definite'). The factor filter matches the Joseph covariance."""
    cfg = dict(gyro_arw=0.0, accel_vrw=0.0, gyro_vib_gain=0.4, accel_vib_gain=0.6)
    kj = ErrorStateEKF(FilterConfig(**cfg))
    kq = ErrorStateEKF(FilterConfig(numerics=numerics, **cfg))
    C = dcm_from_euler(0.1, -0.2, 1.0)
    z3 = np.zeros(3)
    f_ned = np.array((0.0, 0.0, -9.8))
    H = np.zeros((3, kj.n))
    H[:, 0:3] = np.eye(3)
    for n in range(40):
        w = np.array((0.0, 0.05 if n % 2 else -0.05, 0.0))
        fb = C.T @ f_ned + np.array((0.3 if n % 3 else -0.3, 0.0, 0.0))
        for kf in (kj, kq):
            kf.predict(0.01, C, f_ned, z3, z3, fb, w, 0.7, 0.0)
            if n % 10 == 9:
                kf.update(np.array((0.1, -0.2, 0.05)), H, np.full(3, 0.25))
    np.testing.assert_allclose(kq.P, kj.P, rtol=1e-7, atol=1e-14)
    np.testing.assert_allclose(kq.x, kj.x, rtol=1e-7, atol=1e-12)
