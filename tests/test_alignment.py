"""Initial alignment: book §4.1 coarse levelling, Example 4.1 refined alignment, NavCore alignment phases."""

from __future__ import annotations

import math

import numpy as np
import pytest

from ins_hil.core import NavConfig, NavCore
from ins_hil.core_parts.config import AidsConfig, AlignmentConfig, GnssConfig
from ins_hil.nav import alignment, earth
from ins_hil.nav.rotation import (
    book_A,
    dcm_from_euler,
    dcm_from_quat,
    euler_from_quat,
    quat_angle_between,
    quat_from_euler,
)
from ins_hil.runtime.pipeline import nav_config
from ins_hil.sim import scenarios
from ins_hil.sim import sensors as se
from ins_hil.sim import trajectory as tr
from ins_hil.types import ImuSample

A_BOOK = np.array(((0.1464, 0.8536, 0.5000), (-0.8536, -0.1464, 0.5000), (0.5000, -0.5000, 0.7071)))
A_TILDE_BOOK = np.array(((0.1410, 0.8516, 0.5048), (-0.8549, -0.1523, 0.4959), (0.4992, -0.5015, 0.7066)))


def test_example_4_1_deterministic_parts():
    """DIGEST_000 §8 case 17 (a)–(c)."""
    A = alignment.book_A_classic(math.pi / 4, math.pi / 4, math.pi / 4)
    np.testing.assert_allclose(A, A_BOOK, atol=5e-5)  # (a)
    a, m = np.array((0.0, 0.0, 1.0)), np.array((1.0, 1.0, 1.0))
    np.testing.assert_allclose(np.cross(a, m), (-1, 1, 0))
    A_raw = alignment.refined_alignment(np.vstack([a, m]), np.vstack([A @ a, A @ m]), orthogonalize=False)
    np.testing.assert_allclose(A_raw, A, atol=1e-12)  # (b) noise-free A = Z1 Z^-1
    # (c) the printed Ã: spectral norm of A − Ã is 0.0075 (the book's "‖A − Ã‖"), Ã orthogonal to 2e-4
    assert np.linalg.norm(A_BOOK - A_TILDE_BOOK, 2) == pytest.approx(0.0075, abs=1e-4)
    np.testing.assert_allclose(A_TILDE_BOOK @ A_TILDE_BOOK.T, np.eye(3), atol=2e-4)
    # the quaternion from Ã (eq. 2.7 on A^T) reproduces Ã
    q = alignment.quat_from_book_A(A)
    np.testing.assert_allclose(book_A(q), A, atol=1e-12)


def test_example_4_1_noisy_property():
    """Case 17 (d): noise of amplitude ~1e-2 in Z1 → singular values within a few % of 1, ‖A − Ã‖₂ ~ 1e-2,
    and the SVD orthogonalisation (4.7)–(4.8) is closer to A than the raw Z1 Z^-1."""
    A = alignment.book_A_classic(math.pi / 4, math.pi / 4, math.pi / 4)
    a, m = np.array((0.0, 0.0, 1.0)), np.array((1.0, 1.0, 1.0))
    Z = np.column_stack([a, m, np.cross(a, m)])
    rng = np.random.default_rng(41)
    errs = []
    for _ in range(50):
        Z1 = A @ Z + rng.uniform(-1e-2, 1e-2, (3, 3))
        A1 = Z1 @ np.linalg.inv(Z)  # eqs. 4.5–4.6
        s = alignment.singular_values(A1)
        assert np.all(np.abs(s - 1) < 0.05)
        At = alignment.orthogonalize_dcm(A1)
        np.testing.assert_allclose(At @ At.T, np.eye(3), atol=1e-12)
        assert np.linalg.det(At) == pytest.approx(1.0)
        errs.append((np.linalg.norm(A - At, 2), np.linalg.norm(A - A1, 2)))
    e = np.array(errs)
    assert 1e-3 < np.mean(e[:, 0]) < 3e-2
    assert np.mean(e[:, 0]) < np.mean(e[:, 1])


def test_orthogonalize_guards_reflection():
    R = dcm_from_euler(0.1, 0.2, 0.3)
    F = R @ np.diag((1.0, 1.0, -1.0))  # det −1
    At = alignment.orthogonalize_dcm(F)
    assert np.linalg.det(At) == pytest.approx(1.0)


@pytest.mark.parametrize("roll,pitch", [(0.0, 0.0), (0.2, -0.1), (-0.5, 0.4)])
def test_coarse_levelling(roll, pitch):
    """Book eq. 4.1 (in FRD: pitch from f_x, roll from f_y, f_z; DIGEST_000 §10 item 31)."""
    g = 9.80665
    f = dcm_from_euler(roll, pitch, 1.0).T @ np.array((0.0, 0.0, -g))
    r, p = alignment.coarse_level(f)
    assert r == pytest.approx(roll, abs=1e-12) and p == pytest.approx(pitch, abs=1e-12)
    # accelerometer bias δφ ≈ b/g (eq. 4.1): 0.01 m/s² on y → ~1 mrad of roll
    r2, _ = alignment.coarse_level(f + np.array((0.0, 0.01, 0.0)))
    assert abs(r2 - r) == pytest.approx(0.01 / g, rel=0.3)


def test_gyrocompass_yaw():
    """Book eq. 4.2 with an Earth-rate-grade (noise-free) levelled gyro triad."""
    lat, yaw = math.radians(50.0), 0.7
    w = dcm_from_euler(0.0, 0.0, yaw).T @ earth.earth_rate_ned(lat)
    assert alignment.gyrocompass_yaw(w) == pytest.approx(-yaw, abs=1e-9) or alignment.gyrocompass_yaw(
        w
    ) == pytest.approx(yaw, abs=1e-9)


def test_navcore_static_alignment_with_magnetometer():
    """Static scenario: not aligned before ``alignment.time``; then levelling + refined alignment (gravity +
    magnetometer) gives the attitude to better than 1° and the flag turns True."""
    sc = scenarios.build("static", seed=1, duration=10.0)
    core = NavCore(None, nav_config(sc.nav))
    meas = sorted(sc.meas, key=lambda m: m.t)
    j = 0
    flags = []
    for s in sc.imu:
        st = core.step(s)
        flags.append(st.aligned)
        while j < len(meas) and meas[j].t <= s.t + 1e-9:
            core.fuse(meas[j])
            j += 1
    assert not any(flags[:150])  # 1.5 s < alignment.time = 2 s
    assert flags[-1]
    # at rest the tilt error is set by the accelerometer bias, δφ ≈ b/g (book eq. 4.1), and with a steep
    # field (inclination 66°) the magnetometer ties yaw to roll: the filter must report that honestly
    err = quat_angle_between(core.state().q_nb, sc.truth.q_nb[-1])
    assert math.degrees(err) < 2.5
    e = euler_from_quat(core.state().q_nb) - sc.truth.euler[-1]
    assert np.all(np.abs(e) < 3 * core.state().std_att + 1e-3)


def test_navcore_in_motion_yaw_from_gnss_course():
    """Car at rest, then driving: levelling at rest, yaw from the GNSS course above 1 m/s, aligned afterwards."""
    dt = 0.01
    truth = tr.generate(tr.car_profile(t_start=5.0), 25.0, dt, math.radians(40.0), -1.8, 1600.0)
    rng = np.random.default_rng(4)
    imu = se.corrupt_imu(truth, se.mems_gyro(rng), se.mems_accel(rng), seed=5).samples()
    fixes = se.gnss_fixes(truth, se.GnssModel(rate=5, std_ne=0.05, std_d=0.1, std_vel=0.03), seed=6)
    core = NavCore(None, NavConfig(alignment=AlignmentConfig(mode="static"), aids=AidsConfig(nhc=True)))
    j = 0
    phases = []
    for s in imu:
        st = core.step(s)
        phases.append((s.t, core.phase, st.aligned))
        while j < len(fixes) and fixes[j].t <= s.t + 1e-9:
            core.fuse(fixes[j])
            j += 1
    assert [p for t, p, _ in phases if t < 4.0][-1] == "level"
    t_nav = next(t for t, p, _ in phases if p == "nav")
    assert 5.0 < t_nav < 8.0
    assert phases[-1][2]
    e = euler_from_quat(core.state().q_nb) - truth.euler[-1]
    e = (e + np.pi) % (2 * np.pi) - np.pi
    assert np.max(np.abs(np.degrees(e))) < 1.0


def test_quat_from_euler_roundtrip_used_by_alignment():
    q = quat_from_euler(0.1, -0.2, 2.0)
    np.testing.assert_allclose(euler_from_quat(q), (0.1, -0.2, 2.0), atol=1e-12)


@pytest.mark.parametrize("scale_factors", [False, True])
def test_level_tilt_prior_predicts_the_tilt_a_biased_accelerometer_leaves(scale_factors: bool):
    """Levelling a biased accelerometer at rest leaves a tilt μ_NE that makes the computed horizontal
    specific force zero (book §4.1.1). After ``ErrorStateEKF.level_tilt`` the covariance's regression of μ_NE
    on the accelerometer bias error must give that tilt (sign and size), and the filter's horizontal
    specific-force error σ must be the small levelling residual, not g·σ_tilt."""
    from ins_hil.fusion.ekf import ErrorStateEKF, FilterConfig

    g = 9.80665
    roll, pitch, yaw = 0.05, -0.12, 2.2
    C = dcm_from_euler(roll, pitch, yaw)  # true C_b^n
    f_true = C.T @ np.array((0.0, 0.0, -g))
    b = np.array((0.12, -0.07, 0.03))  # accelerometer bias (m/s²); the filter's estimate is 0, so δb_a = b
    sf = np.array((0.02, -0.015, 0.01)) if scale_factors else np.zeros(3)  # f̃ = (1 + s) f + b; δs_a = s
    f_meas = (1.0 + sf) * f_true + b
    r, p = alignment.coarse_level(f_meas)
    C_hat = dcm_from_quat(quat_from_euler(r, p, yaw))
    mu_x = C_hat @ C.T - np.eye(3)  # Ĉ = (I + [μ×]) C
    mu = np.array((mu_x[2, 1], mu_x[0, 2], mu_x[1, 0]))
    kf = ErrorStateEKF(FilterConfig(scale_factors=scale_factors))
    kf.level_tilt(C_hat, f_meas, 1e-4)
    i = kf.idx
    P = kf.P
    X = np.r_[i.ba : i.ba + 3, i.sa : i.sa + 3] if scale_factors else np.r_[i.ba : i.ba + 3]
    A = P[6:8][:, X] @ np.linalg.inv(P[np.ix_(X, X)])  # the prior's regression of μ_NE on the accelerometer errors
    x = np.r_[b, sf] if scale_factors else b
    np.testing.assert_allclose(A @ x, mu[:2], atol=2e-4)  # |μ| ≈ 0.014 rad: linearization error only
    # the horizontal specific-force error δf_h = [f×]μ − C δb_a − C diag(f) δs_a has σ ≈ g·1e-4
    F = kf.build_F(C_hat, C_hat @ f_meas, np.zeros(3), np.zeros(3), f_meas, np.zeros(3), 0.7, 0.0)
    S = F[3:5] @ P @ F[3:5].T
    assert np.sqrt(np.diag(S)).max() < 2 * g * 1e-4
    assert np.sqrt(P[6, 6]) > 0.01  # the tilt itself is as uncertain as the bias allows (0.3 m/s² / g)


def test_in_motion_yaw_sigma_uses_the_receiver_velocity_sigma():
    """The course of a velocity with σ_v at speed V has σ ≈ σ_v/V: the in-motion yaw σ uses the receiver's σ_v,
    not the fusion floor ``gnss.min_std[2]`` (that floor covers the velocity's lag), unless
    ``gnss_yaw_vel_floor`` asks for one; it adds to ``gnss_yaw_std`` (course ≠ heading) in quadrature."""
    dt = 0.01
    truth = tr.generate(tr.car_profile(t_start=5.0), 12.0, dt, math.radians(40.0), -1.8, 1600.0)
    imu = se.corrupt_imu(truth, se.mems_gyro(), se.mems_accel(), seed=5).samples()
    fixes = se.gnss_fixes(truth, se.GnssModel(rate=5, std_ne=0.02, std_d=0.04, std_vel=0.03), seed=6)
    yaw_sd = {}
    for floor in (0.0, 0.10):
        cfg = NavConfig(
            alignment=AlignmentConfig(mode="static", gnss_yaw_vel_floor=floor),
            aids=AidsConfig(nhc=True),
            gnss=GnssConfig(min_std=(0.03, 0.06, 0.15)),
        )
        core = NavCore(None, cfg)
        j = 0
        for s in imu:
            core.step(s)
            while j < len(fixes) and fixes[j].t <= s.t + 1e-9:
                was = core.phase
                core.fuse(fixes[j])
                if was != "nav" and core.phase == "nav":
                    v = fixes[j].vel_ned
                    speed = math.hypot(v[0], v[1])
                    yaw_sd[floor] = (math.sqrt(core.kf.P[8, 8]), speed)
                j += 1
            if floor in yaw_sd:
                break
    sd0, v0 = yaw_sd[0.0]
    assert sd0 == pytest.approx(math.hypot(math.radians(3.0), 0.03 / v0), rel=1e-9)  # 1-σ terms add in quadrature
    sd1, v1 = yaw_sd[0.10]  # the floor asked for, not the fusion floor gnss.min_std[2] = 0.15
    assert sd1 == pytest.approx(math.hypot(math.radians(3.0), 0.10 / v1), rel=1e-9)


def test_level_tilt_prior_without_accelerometer_states_keeps_the_tilt_prior():
    """A 9- or 12-state filter has no accelerometer error to correlate: the tilt keeps its prior variance
    (not the tiny levelling residual, which would make the filter overconfident by b/g)."""
    from ins_hil.fusion.ekf import ErrorStateEKF, FilterConfig

    kf = ErrorStateEKF(FilterConfig(accel_bias=False))
    before = kf.P.copy()
    kf.level_tilt(np.eye(3), np.array((0.0, 0.0, -9.8)), 1e-4)
    np.testing.assert_array_equal(kf.P, before)


def test_level_tilt_prior_follows_a_turn_between_levelling_and_the_course_fix():
    """NavCore end to end: a car levels at rest with a biased accelerometer (heading 0.5 rad, computed yaw 0),
    pivots by 90° on the spot, then drives off; the yaw is reset to the GNSS course above 1 m/s. The tilt is
    fixed in NED while the bias turns with the body, and the reset rotates the computed frame: at the entry
    into navigation the prior's regression of μ_NE on the accelerometer errors must give the tilt the
    levelling really left (with the attitude at entry instead, the prediction would be 90° off)."""
    dt = 0.01
    truth = tr.generate(tr.pivot_profile(yaw0=0.5, turn=math.pi / 2), 12.0, dt, math.radians(40.0), -1.8, 1600.0)
    b = np.array((0.15, -0.1, 0.05))
    imu = [ImuSample(t=float(truth.t[k + 1]), dt=dt, dtheta=truth.dtheta[k], dvel=truth.dvel[k] + b * dt)
           for k in range(len(truth.dtheta))]  # fmt: skip
    fixes = se.gnss_fixes(truth, se.GnssModel(rate=5, std_ne=0.01, std_d=0.02, std_vel=0.02), seed=1)
    for f in fixes:  # exact fixes: the course is the heading
        k = round((f.t - truth.t[0]) / dt)
        f.vel_ned = truth.vel_ned[k].copy()
    core = NavCore(
        None, NavConfig(alignment=AlignmentConfig(mode="static", level_only=True), aids=AidsConfig(nhc=False))
    )
    j = 0
    k_nav = None
    for k, s in enumerate(imu):
        core.step(s)
        while j < len(fixes) and fixes[j].t <= s.t + 1e-9:
            core.fuse(fixes[j])
            j += 1
            if core.phase == "nav":
                k_nav = k + 1
                break
        if k_nav is not None:
            break
    assert k_nav is not None and truth.t[k_nav] > 8.0  # navigation starts after the pivot, once driving
    C_true = dcm_from_quat(truth.q_nb[k_nav])
    C_hat = dcm_from_quat(core.ins.state.q_nb)
    mu_x = C_hat @ C_true.T - np.eye(3)
    mu = np.array((mu_x[2, 1], mu_x[0, 2], mu_x[1, 0]))
    assert abs(mu[2]) < 2e-3  # the course reset left no yaw error to speak of
    i = core.idx
    P = core.kf.P
    X = np.r_[i.ba : i.ba + 3]
    A = P[6:8][:, X] @ np.linalg.inv(P[np.ix_(X, X)])
    pred = A @ (b - core.ba)
    assert np.linalg.norm(mu[:2]) > 0.01  # ≈ |b_h| / g
    np.testing.assert_allclose(pred, mu[:2], atol=1.5e-3)  # the horizontal Earth rate leaks ~5e-4 rad in 8 s
