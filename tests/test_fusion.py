"""Error-state EKF: linear model vs the nonlinear mechanization, GNSS-aided convergence, models."""

from __future__ import annotations

import math

import numpy as np
import pytest
from runtime_helpers import with_due

from ins_hil.core import NavConfig, NavCore
from ins_hil.core_parts.config import AlignmentConfig
from ins_hil.fusion import measurements as mm
from ins_hil.fusion.ekf import ErrorStateEKF, FilterConfig
from ins_hil.nav import earth
from ins_hil.nav.mechanization import StrapdownState
from ins_hil.nav.rotation import dcm_from_quat, euler_from_quat, quat_from_euler, quat_from_rotvec, quat_mul
from ins_hil.sim import sensors as se
from ins_hil.sim import trajectory as tr

LAT0, LON0, H0 = math.radians(45.0), 0.5, 100.0


def _run(core: NavCore, imu, fixes, extra=()):
    """Feed IMU samples and measurements in time order; returns the list of states after each step."""
    meas = sorted([*fixes, *extra], key=lambda m: m.t)
    out = []
    for s, due in with_due(imu.samples(), meas):
        out.append(core.step(s))
        for m in due:
            core.fuse(m)
    return out


def _errors(states, truth):
    """(pos error m, vel error m/s, euler error rad) arrays over the run (state k ↔ truth k+1)."""
    pe, ve, ae = [], [], []
    for k, st in enumerate(states):
        j = k + 1
        dp = earth.ned_delta_small(st.lat - truth.lat[j], st.lon - truth.lon[j], st.h - truth.h[j], truth.lat[j],
                                   truth.h[j])  # fmt: skip
        pe.append(dp)
        ve.append(st.vel_ned - truth.vel_ned[j])
        d = euler_from_quat(st.q_nb) - truth.euler[j]
        ae.append((d + np.pi) % (2 * np.pi) - np.pi)
    return np.array(pe), np.array(ve), np.array(ae)


@pytest.fixture(scope="module")
def uav_run():
    dt = 0.01
    truth = tr.generate(tr.uav_profile(), 120.0, dt, LAT0, LON0, H0)
    rng = np.random.default_rng(5)
    imu = se.corrupt_imu(truth, se.mems_gyro(rng), se.mems_accel(rng), seed=3)
    fixes = se.gnss_fixes(truth, se.GnssModel(rate=5, std_ne=1.0, std_d=2.0, std_vel=0.1), seed=4)
    return truth, imu, fixes


def _init(truth, datt=(0.01, -0.01, 0.05)):
    e = truth.euler[0]
    return StrapdownState(quat_from_euler(e[0] + datt[0], e[1] + datt[1], e[2] + datt[2]), truth.vel_ned[0].copy(),
                          truth.lat[0], truth.lon[0], truth.h[0], truth.t[0])  # fmt: skip


@pytest.mark.slow
def test_gnss_aided_converges_and_estimates_biases(uav_run):
    truth, imu, fixes = uav_run
    core = NavCore(_init(truth), NavConfig())
    states = _run(core, imu, fixes)
    pe, ve, ae = _errors(states, truth)
    last = slice(-3000, None)  # last 30 s
    assert np.sqrt(np.mean(np.sum(pe[last] ** 2, axis=1))) < 1.0
    assert np.sqrt(np.mean(np.sum(ve[last] ** 2, axis=1))) < 0.1
    assert np.max(np.abs(ae[last, :2])) < math.radians(0.3)
    assert np.max(np.abs(ae[last, 2])) < math.radians(1.5)
    # the turn-on gyro bias (0.2 °/s class) is estimated to better than 0.01 °/s
    assert np.max(np.abs(core.bg - imu.gyro_bias[-1])) < math.radians(0.01)
    assert np.max(np.abs(core.ba - imu.accel_bias[-1])) < 0.03
    st = core.state()
    assert st.aligned and set(st.test_ratios) == {"gnss_pos", "gnss_vel"}
    # the free INS (no GNSS) is far worse: the filter does something
    free = _run(NavCore(_init(truth), NavConfig()), imu, [])
    pf, _, _ = _errors(free, truth)
    assert np.linalg.norm(pf[-1]) > 20 * np.linalg.norm(pe[-1])


def test_F_matches_nonlinear_error_propagation():
    """Propagate a small initial error through the mechanization and through Φ: same to 2nd order."""
    dt = 0.01
    truth = tr.generate(tr.uav_profile(t_takeoff=0.0), 2.0, dt, LAT0, LON0, H0)
    from ins_hil.nav.mechanization import StrapdownNED

    x0 = np.zeros(15)
    x0[0:3] = (3.0, -2.0, 1.0)
    x0[3:6] = (0.2, -0.1, 0.05)
    x0[6:9] = (2e-3, -1e-3, 4e-3)
    bg = np.array((1e-4, -2e-4, 3e-4))  # true bias, estimate 0 → δb = bias
    ba = np.array((0.02, -0.01, 0.03))
    x0[9:12] = bg
    x0[12:15] = ba

    def make(perturb: bool) -> StrapdownNED:
        q, v, lat, lon, h = truth.q_nb[0], truth.vel_ned[0], truth.lat[0], truth.lon[0], truth.h[0]
        if perturb:  # computed = true − δ (pos/vel), Ĉ = (I + [μ×]) C
            m, n = earth.radii(lat)
            lat, lon, h = lat - x0[0] / (m + h), lon - x0[1] / ((n + h) * math.cos(lat)), h + x0[2]
            v = v - x0[3:6]
            q = quat_mul(quat_from_rotvec(x0[6:9]), q)
        return StrapdownNED(StrapdownState(q.copy(), v.copy(), lat, lon, h))

    ref, pert = make(False), make(True)
    kf = ErrorStateEKF(FilterConfig())
    x = x0.copy()
    for k in range(len(truth.dtheta)):
        # the true IMU has biases; the reference integrates bias-free increments, the perturbed one the raw
        ref.step(truth.dtheta[k], truth.dvel[k], dt)
        pert.step(truth.dtheta[k] + bg * dt, truth.dvel[k] + ba * dt, dt)
        C = dcm_from_quat(ref.state.q_nb)
        F = kf.build_F(C, ref.f_ned, ref.omega_ie, ref.omega_en, np.zeros(3), np.zeros(3), ref.state.lat, ref.state.h)
        x = x + F @ x * dt
    r, p = ref.state, pert.state
    dp = earth.ned_delta_small(r.lat - p.lat, r.lon - p.lon, r.h - p.h, r.lat, r.h)
    dv = r.vel_ned - p.vel_ned
    from ins_hil.nav.rotation import quat_conj, rotvec_from_quat

    mu = rotvec_from_quat(quat_mul(p.q_nb, quat_conj(r.q_nb)))
    np.testing.assert_allclose(dp, x[0:3], atol=0.02)
    np.testing.assert_allclose(dv, x[3:6], atol=0.01)
    np.testing.assert_allclose(mu, x[6:9], atol=2e-5)


def test_measurement_models_zero_for_perfect_state_and_linear_in_errors():
    idx = ErrorStateEKF(FilterConfig()).idx
    q = quat_from_euler(0.1, -0.2, 1.0)
    C = dcm_from_quat(q)
    lever = np.array((0.5, -0.2, -0.3))
    w = np.array((0.1, -0.2, 0.3))
    v = np.array((10.0, -3.0, 0.5))
    lat, lon, h = LAT0, LON0, H0
    # antenna truth
    ant = C @ lever
    m, n = earth.radii(lat)
    alat, alon, ah = lat + ant[0] / (m + h), lon + ant[1] / ((n + h) * math.cos(lat)), h - ant[2]
    z, _ = mm.gnss_position(idx, C, lat, lon, h, alat, alon, ah, lever)
    np.testing.assert_allclose(z, 0.0, atol=1e-6)
    z, _ = mm.gnss_velocity(idx, C, v, w, v + C @ np.cross(w, lever), lever)
    np.testing.assert_allclose(z, 0.0, atol=1e-12)
    # attitude error μ: the H columns predict the residual to first order
    mu = np.array((1e-3, -2e-3, 1.5e-3))
    Chat = dcm_from_quat(quat_mul(quat_from_rotvec(mu), q))  # Ĉ = (I + [μ×]) C
    x = np.zeros(idx.n)
    x[6:9] = mu
    # second-order terms are ~|μ|²|l| ≈ 5e-6 m
    z, H = mm.gnss_position(idx, Chat, lat, lon, h, alat, alon, ah, lever)
    np.testing.assert_allclose(z, H @ x, atol=1e-5)
    assert np.linalg.norm(H @ x) > 1e-3
    z, H = mm.gnss_velocity(idx, Chat, v, w, v + C @ np.cross(w, lever), lever)
    np.testing.assert_allclose(z, H @ x, atol=1e-5)
    z, H = mm.nonholonomic(idx, Chat, C @ np.array((12.0, 0.0, 0.0)))
    np.testing.assert_allclose(z, H @ x, atol=1e-4)
    # baro: true height 2 m above the computed one → z = 2 = −δr_D
    z, H = mm.baro_height(idx, h, h + 2.0)
    x = np.zeros(idx.n)
    x[2] = -2.0
    np.testing.assert_allclose(z, H @ x)


def test_magnetometer_book_measurement():
    """Book eqs. 3.28–3.38: zero for a perfect attitude; z = rows 2–3 of τ μ; m = e1 gives [μ2, μ3]."""
    idx = ErrorStateEKF(FilterConfig()).idx
    q = quat_from_euler(0.2, 0.1, -0.7)
    C = dcm_from_quat(q)
    ref = se.earth_field_ned()
    mb = C.T @ ref
    z, H = mm.magnetometer(idx, C, mb, ref)
    np.testing.assert_allclose(z, 0.0, atol=1e-14)
    mu = np.array((2e-3, -1e-3, 3e-3))
    Chat = dcm_from_quat(quat_mul(quat_from_rotvec(mu), q))
    z, H = mm.magnetometer(idx, Chat, mb, ref)
    x = np.zeros(idx.n)
    x[6:9] = mu
    np.testing.assert_allclose(z, H @ x, atol=2e-5)
    z, H = mm.magnetometer(idx, Chat, C.T @ np.array((1.0, 0, 0)), np.array((1.0, 0, 0)))
    np.testing.assert_allclose(z, mu[1:], atol=2e-5)
    # the book's WMM example (3.31)–(3.33), case 15: τ from the 4-decimal m_τ
    mt = np.array((0.3886, 0.0508, 0.9200))
    tau = mm.tau_matrix(mt)
    book = np.array(((0.3886, 0.0508, 0.9200), (-0.0508, 0.9981, -0.0337), (-0.9200, -0.0337, 0.3905)))
    np.testing.assert_allclose(tau, book, atol=5e-5)
    he = np.array((19546.5, 2554.2, 46277.9))
    tau = mm.tau_matrix(he / np.linalg.norm(he))
    np.testing.assert_allclose(tau @ (he / np.linalg.norm(he)), (1, 0, 0), atol=1e-12)
    np.testing.assert_allclose(tau @ tau.T, np.eye(3), atol=1e-12)
    assert np.linalg.det(tau) == pytest.approx(1.0)


def test_config_errors_name_the_bad_key():
    with pytest.raises(ValueError, match="numerics"):
        FilterConfig(numerics="lu")
    with pytest.raises(ValueError, match=r"alignment\.mode=.magic."):
        NavConfig(alignment=AlignmentConfig(mode="magic"))
    with pytest.raises(ValueError, match="initial state"):
        NavCore(None, NavConfig())


def test_21_state_filter_estimates_gyro_scale_factors():
    """Optional scale-factor states: a gyro with 3000–5000 ppm scale errors on the UAV mission; the 21-state
    filter estimates them (±1500 ppm) and its attitude error is < 0.75 × the 15-state one's."""
    from ins_hil.nav.rotation import quat_angle_between

    dt = 0.01
    truth = tr.generate(tr.mission_profile(t_takeoff=1.0), 100.0, dt, LAT0, LON0, H0)
    g = se.ImuErrorModel(noise_density=0.15 * math.pi / 180 / 60, scale_factor=np.array([3e-3, -3e-3, 5e-3]))
    a = se.ImuErrorModel(noise_density=70e-6 * 9.8)
    imu = se.corrupt_imu(truth, g, a, seed=1).samples()
    fixes = se.gnss_fixes(truth, se.GnssModel(rate=5, std_ne=0.5, std_d=1, std_vel=0.05), seed=2)
    res = {}
    for sf in (False, True):
        init = StrapdownState(truth.q_nb[0].copy(), truth.vel_ned[0].copy(), truth.lat[0], truth.lon[0], truth.h[0])
        core = NavCore(init, NavConfig(filter=FilterConfig(scale_factors=sf, init_sf=5e-3)))
        assert core.kf.n == (21 if sf else 15)
        errs = []
        for k, (s, due) in enumerate(with_due(imu, fixes)):
            core.step(s)
            for f in due:
                core.fuse(f)
            if k > 7000 and k % 50 == 0:
                errs.append(quat_angle_between(core.state().q_nb, truth.q_nb[k + 1]))
        res[sf] = (float(np.sqrt(np.mean(np.square(errs)))), core.sg.copy())
    assert res[True][0] < 0.75 * res[False][0]
    np.testing.assert_allclose(res[True][1], (3e-3, -3e-3, 5e-3), atol=1.5e-3)


def test_sage_husa_scale_converges_to_the_true_noise_scale():
    """Innovations ν ~ N(0, HPHᵀ + s·R_nom) with HPHᵀ as large as R_nom: the bounded Sage–Husa estimate of s
    converges to s (DIGEST_001_004 §4.4 form: E[ν²] − HPHᵀ = s R_nom). With the sign of the HPHᵀ term
    flipped it would converge to s + 2·HPHᵀ/R_nom = s + 2 instead."""
    from ins_hil.fusion.innovation import SageHusa

    rng = np.random.default_rng(3)
    hph, r_nom = np.array([1.0, 1.0]), np.array([1.0, 1.0])
    for s_true in (0.5, 3.0):
        est = SageHusa(b=0.999)
        for _ in range(20000):
            nu = rng.normal(0.0, np.sqrt(hph + s_true * r_nom))
            est.update(nu, hph, r_nom)
        assert est.scale == pytest.approx(s_true, rel=0.1)
