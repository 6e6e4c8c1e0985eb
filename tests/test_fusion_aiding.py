"""Gating, adaptive R, delayed GNSS fusion, baro, magnetometer and ground-vehicle aids on simulated runs."""

from __future__ import annotations

import math
from dataclasses import replace

import numpy as np
import pytest
from runtime_helpers import with_due

from ins_hil.core import NavConfig, NavCore
from ins_hil.core_parts.config import AidsConfig, DelayConfig, GnssConfig, MagConfig
from ins_hil.fusion.ekf import ErrorStateEKF, FilterConfig
from ins_hil.nav import earth
from ins_hil.nav.mechanization import StrapdownState
from ins_hil.nav.rotation import euler_from_quat, quat_from_euler
from ins_hil.sim import sensors as se
from ins_hil.sim import trajectory as tr
from ins_hil.types import FaultMode, ImuSample

LAT0, LON0, H0 = math.radians(45.0), 0.5, 100.0


@pytest.fixture(scope="module")
def scen():
    dt = 0.01
    truth = tr.generate(tr.uav_profile(t_takeoff=2.0, ramp=8.0, turn_period=40.0), 60.0, dt, LAT0, LON0, H0)
    rng = np.random.default_rng(5)
    imu = se.corrupt_imu(truth, se.mems_gyro(rng), se.mems_accel(rng), seed=3).samples()
    return truth, imu


def _init(truth):
    e = truth.euler[0]
    return StrapdownState(quat_from_euler(e[0] + 0.005, e[1] - 0.005, e[2] + 0.02), truth.vel_ned[0].copy(),
                          truth.lat[0], truth.lon[0], truth.h[0], truth.t[0])  # fmt: skip


def _run(truth, imu, meas, cfg, delay=0.0, t_from=0.0):
    """Run; measurements delivered ``delay`` s after their validity. Returns (core, pos errors, vel errors)
    after t_from."""
    core = NavCore(_init(truth), cfg)
    core.keep_nis = True  # the accepted innovations' NIS, for the consistency checks
    meas = sorted(meas, key=lambda m: m.t)
    pe, ve = [], []
    for k, (s, due) in enumerate(with_due(imu, meas, delay)):
        core.step(s)
        for m in due:
            core.fuse(m)
        if s.t >= t_from and k % 10 == 0:
            st = core.state()
            i = k + 1
            pe.append(earth.ned_delta_small(st.lat - truth.lat[i], st.lon - truth.lon[i], st.h - truth.h[i],
                                            truth.lat[i], truth.h[i]))  # fmt: skip
            ve.append(st.vel_ned - truth.vel_ned[i])
    return core, np.array(pe), np.array(ve)


def _rms(a):
    return float(np.sqrt(np.mean(np.sum(a**2, axis=1))))


def test_delayed_gnss_compensated_matches_undelayed(scen):
    """200 ms GNSS latency: compensated (rollback + forward propagation) is as accurate as undelayed
    within 10 % (RMS position and velocity after 10 s); uncompensated is > 2x worse."""
    truth, imu = scen
    fixes = se.gnss_fixes(truth, se.GnssModel(rate=5, std_ne=0.5, std_d=1.0, std_vel=0.05), seed=4)
    cfg = NavConfig()
    _, p0, v0 = _run(truth, imu, fixes, cfg, 0.0, 10.0)
    core, p1, v1 = _run(truth, imu, fixes, cfg, 0.2, 10.0)
    _, p2, v2 = _run(truth, imu, fixes, replace(cfg, delay=replace(cfg.delay, compensation=False)), 0.2, 10.0)
    assert _rms(p1) < 1.1 * _rms(p0) + 0.02
    assert _rms(v1) < 1.1 * _rms(v0) + 0.005
    assert _rms(p2) > 2.0 * _rms(p0)
    assert _rms(v2) > 2.0 * _rms(v0)
    delivered = [f for f in fixes if f.t + 0.2 <= imu[-1].t + 1e-9]
    assert core.stats["gnss_pos"].accepted == len(delivered)


def test_gating_rejects_multipath_outliers_and_reports_events(scen):
    truth, imu = scen
    model = se.GnssModel(rate=5, std_ne=0.5, std_d=1.0, std_vel=0.05, outlier_prob=0.08, outlier_size=15.0)
    fixes = se.gnss_fixes(truth, model, seed=9)
    core, p_gate, _ = _run(truth, imu, fixes, NavConfig(), 0.0, 10.0)
    _, p_open, _ = _run(truth, imu, fixes, NavConfig(gnss=GnssConfig(gate=1e6)), 0.0, 10.0)
    st = core.stats["gnss_pos"]
    assert st.rejected >= 10
    assert st.accepted > 0.8 * len(fixes)
    assert _rms(p_gate) < 0.5 * _rms(p_open)
    ev = core.drain_events()
    assert ev and all(e.sensor == "gnss" and e.mode == FaultMode.JUMP for e in ev)
    assert any(not e.cleared for e in ev) and any(e.cleared for e in ev)
    assert core.drain_events() == []
    ratios = core.state().test_ratios
    assert set(ratios) >= {"gnss_pos", "gnss_vel"}
    # the accepted position innovations are consistent: NIS/dof near 1 (the outliers are gated away, so it is
    # not inflated by them), and most of them far inside the gate
    nis = np.array([n / d for _, k, n, d in core.nis_log if k == "gnss_pos"])
    assert len(nis) == st.accepted
    assert 0.6 <= float(np.mean(nis)) <= 1.5, float(np.mean(nis))


def test_adaptive_r_tracks_a_gnss_noise_change(scen):
    """GNSS noise jumps from 0.3 m to 2.4 m at t = 25 s while the receiver keeps reporting 0.3 m.
    Sage–Husa scale → ≈ (2.4/0.3)² = 64; the position RMS after the change is better than with fixed R."""
    truth, imu = scen
    a = se.gnss_fixes(truth, se.GnssModel(rate=5, std_ne=0.3, std_d=0.6, std_vel=0.05), seed=4)
    b = se.gnss_fixes(truth, se.GnssModel(rate=5, std_ne=2.4, std_d=4.8, std_vel=0.05), seed=5)
    fixes = [f for f in a if f.t < 25.0] + [replace(f, std_ne=0.3, std_d=0.6) for f in b if f.t >= 25.0]
    cfg = NavConfig(gnss=GnssConfig(gate=1e6))
    core_a, pa, _ = _run(truth, imu, fixes, replace(cfg, adaptive=True), 0.0, 40.0)
    _, pf, _ = _run(truth, imu, fixes, cfg, 0.0, 40.0)
    scale = core_a.adapt["gnss_pos"].scale
    assert 20.0 < scale < 200.0
    assert _rms(pa) < 0.8 * _rms(pf)
    # before the change the scale stays near 1
    core_b, _, _ = _run(truth, imu, [f for f in fixes if f.t < 25.0], replace(cfg, adaptive=True), 0.0, 60.0)
    assert 0.3 < core_b.adapt["gnss_pos"].scale < 3.0


def test_baro_holds_height_without_gnss(scen):
    truth, imu = scen
    fixes = se.gnss_fixes(truth, se.GnssModel(rate=5, std_ne=0.5, std_d=1.0, std_vel=0.05, outages=[(30.0, 61.0)]),
                          seed=4)  # fmt: skip
    baro = se.baro_samples(truth, rate=25, std=0.3, seed=6)
    core, p_b, _ = _run(truth, imu, [*fixes, *baro], NavConfig(), 0.0, 45.0)
    _, p_n, _ = _run(truth, imu, fixes, NavConfig(), 0.0, 45.0)
    assert np.sqrt(np.mean(p_b[:, 2] ** 2)) < 1.5
    assert np.sqrt(np.mean(p_b[:, 2] ** 2)) < 0.3 * np.sqrt(np.mean(p_n[:, 2] ** 2))
    assert core.stats["baro"].accepted > 1000


def test_magnetometer_bounds_heading_without_gnss(scen):
    """Book §3.2: with the magnetometer (real field, τ rotation) the heading stays bounded in a GNSS outage."""
    truth, imu = scen
    ref = se.earth_field_ned()
    fixes = se.gnss_fixes(truth, se.GnssModel(rate=5, std_ne=0.5, std_d=1.0, std_vel=0.05, outages=[(20.0, 61.0)]),
                          seed=4)  # fmt: skip
    mag = se.mag_samples(truth, field_ned=ref, rate=10, std=0.3e-6, seed=8)
    cfg = NavConfig(mag=MagConfig(ref_ned=ref, std=0.01))
    core = NavCore(_init(truth), cfg)
    meas = sorted([*fixes, *mag], key=lambda m: m.t)
    for s, due in with_due(imu, meas):
        core.step(s)
        for m in due:
            core.fuse(m)
    from ins_hil.nav.rotation import quat_angle_between

    assert math.degrees(quat_angle_between(core.state().q_nb, truth.q_nb[-1])) < 1.0
    assert core.state().std_att[2] < math.radians(1.0)
    assert core.stats["mag"].accepted > 400


def test_nhc_and_zupt_bound_a_ground_vehicle_outage():
    """A car (level, turning, stopping): NHC + ZUPT reduce the 20 s outage drift."""
    dt = 0.01

    truth = tr.generate(tr.car_profile(), 50.0, dt, LAT0, LON0, H0)
    rng = np.random.default_rng(1)
    imu = se.corrupt_imu(truth, se.mems_gyro(rng), se.mems_accel(rng), seed=2).samples()
    fixes = se.gnss_fixes(truth, se.GnssModel(rate=5, std_ne=0.5, std_d=1.0, std_vel=0.05, outages=[(25.0, 50.0)]),
                          seed=3)  # fmt: skip
    _, p_aid, _ = _run(truth, imu, fixes, NavConfig(aids=AidsConfig(nhc=True, zupt=True)), 0.0, 49.9)
    _, p_raw, _ = _run(truth, imu, fixes, NavConfig(), 0.0, 49.9)
    assert np.linalg.norm(p_aid[-1, :2]) < 0.5 * np.linalg.norm(p_raw[-1, :2])


def test_cov_every_n_is_close_to_every_step(scen):
    truth, imu = scen
    fixes = se.gnss_fixes(truth, se.GnssModel(rate=5, std_ne=0.5, std_d=1.0, std_vel=0.05), seed=4)
    _, p1, v1 = _run(truth, imu, fixes, NavConfig(), 0.0, 10.0)
    _, p5, v5 = _run(truth, imu, fixes, NavConfig(filter=FilterConfig(cov_every=5)), 0.0, 10.0)
    assert _rms(p5) < 1.2 * _rms(p1) + 0.02
    assert _rms(v5) < 1.2 * _rms(v1) + 0.005


def test_nhc_mounted_jacobian_matches_finite_differences():
    """H of the NHC with boresight states and a reference-point lever arm against a numerical Jacobian
    of the true constraint u_{y,z} = [R_true (C_true^T v_true + (ω̂ − δb_g) × l)]_{y,z}."""
    from ins_hil.fusion import measurements as mm
    from ins_hil.fusion.ekf import ErrorStateEKF, skew
    from ins_hil.nav.rotation import dcm_from_quat

    idx = ErrorStateEKF(FilterConfig(mount_states=True)).idx
    assert idx.mnt == 15 and idx.n == 18
    C = dcm_from_quat(quat_from_euler(0.1, -0.05, 1.2))
    R = dcm_from_quat(quat_from_euler(0.01, 0.02, -0.03))
    v, w, lev = np.array((8.0, 5.0, -0.4)), np.array((0.05, -0.02, 0.3)), np.array((0.3, -0.1, 0.65))
    z0, H, u = mm.nonholonomic_mounted(idx, C, v, R, w, lev)
    assert np.allclose(z0, -u[1:3])

    def u_true(x):
        Ct = (np.eye(3) - skew(x[6:9])) @ C  # Ĉ = (I + [μ×]) C
        Rt = (np.eye(3) - skew(x[idx.mnt : idx.mnt + 3])) @ R
        return (Rt @ (Ct.T @ (v + x[3:6]) + np.cross(w - x[idx.bg : idx.bg + 3], lev)))[1:3]

    J = np.zeros((2, idx.n))
    eps = 1e-6
    for k in range(idx.n):
        e = np.zeros(idx.n)
        e[k] = eps
        J[:, k] = (u_true(e) - u_true(-e)) / (2 * eps)
    assert np.allclose(H, J, atol=1e-6)  # z = 0 − û ≈ H x  ⇔  u_true ≈ û + H x


def test_mount_states_need_nhc():
    with pytest.raises(ValueError, match="mount_states"):
        NavConfig(filter=FilterConfig(mount_states=True))
    cfg = NavConfig(filter=FilterConfig(mount_states=True), aids=AidsConfig(nhc=True))
    core = NavCore(StrapdownState(np.array([1.0, 0, 0, 0]), np.array((5.0, 0, 0)), LAT0, LON0, H0), cfg)
    x = np.zeros(core.idx.n)
    x[core.idx.mnt + 2] = 0.01
    core._feedback(x)  # R̂ ← (I − [δε×]) R̂: a 0.01 rad boresight correction about z
    from ins_hil.nav.rotation import dcm_from_quat

    assert np.allclose(
        dcm_from_quat(core.q_mount), np.eye(3) - np.array(((0, -0.01, 0), (0.01, 0, 0), (0, 0, 0))), atol=1e-4
    )


def test_gnss_velocity_lag_is_fused_at_its_own_time(scen):
    """A receiver whose velocity lags its position by 0.13 s (the drive's RTKLIB .pos, docs/accuracy.md):
    with ``gnss.vel_delay`` the velocity is fused at its time of validity and the velocity error during
    the manoeuvres drops; fused at the position's time it biases the velocity along the acceleration."""
    truth, imu = scen
    lag = 0.13
    fixes = se.gnss_fixes(truth, se.GnssModel(rate=5, std_ne=0.3, std_d=0.5, std_vel=0.03), seed=4)

    def v_true(t: float) -> np.ndarray:
        return np.array([np.interp(t, truth.t, truth.vel_ned[:, i]) for i in range(3)])

    # the receiver's velocity noise kept, its time of validity moved 0.13 s before the position's
    lagged = [replace(f, vel_ned=np.asarray(f.vel_ned) - v_true(f.t) + v_true(f.t - lag)) for f in fixes]
    cfg = NavConfig(gnss=GnssConfig(min_std=(0.3, 0.5, 0.03)))
    _, _, v_naive = _run(truth, imu, lagged, cfg, 0.0, 15.0)
    core, _, v_comp = _run(truth, imu, lagged, replace(cfg, gnss=replace(cfg.gnss, vel_delay=lag)), 0.0, 15.0)
    assert core.stats["gnss_vel"].accepted > 200
    assert _rms(v_comp) < 0.6 * _rms(v_naive)
    with pytest.raises(ValueError, match=r"gnss\.vel_delay"):
        NavConfig(gnss=GnssConfig(vel_delay=0.5), delay=DelayConfig(max_delay=0.3))


def test_zupt_releases_when_a_car_starts_from_rest():
    """Bug fixed in session 2: rest was detected on |f| − g, which a horizontal start (1 m/s²) changes by only
    0.05 m/s², so the ZUPT kept clamping the velocity of a car pulling away. Rest is now tested on the NED
    specific force (horizontal components included): the velocity follows the acceleration."""
    lat, h, dt, a_x = LAT0, H0, 0.01, 1.0
    g = earth.normal_gravity(lat, h)
    core = NavCore(StrapdownState(np.array([1.0, 0, 0, 0]), np.zeros(3), lat, LON0, h),
                   NavConfig(aids=AidsConfig(zupt=True, zupt_time=0.5)))  # fmt: skip
    n_rest, n_go = 300, 300
    st = core.stats["zupt"]
    for k in range(n_rest + n_go):
        acc = a_x if k >= n_rest else 0.0
        core.step(ImuSample(t=(k + 1) * dt, dt=dt, dtheta=np.zeros(3), dvel=np.array((acc, 0.0, -g)) * dt))
        if k == n_rest - 1:
            at_rest = st.accepted + st.rejected
            assert st.accepted > 10  # the stop was detected
    # at most one ZUPT/ZARU epoch (2 updates) after the start (before: 9 epochs, 0.9 s, at 1 m/s²)
    assert st.accepted + st.rejected - at_rest <= 2
    v = core.state().vel_ned
    assert v[0] == pytest.approx(a_x * n_go * dt, abs=0.02)  # 3 m/s after 3 s (before: 2.946)


def test_nhc_suspension_pitch_keeps_the_pitch_of_an_accelerating_car():
    """``nhc_pitch_per_accel`` (session 3): a car at 10 m/s on a level road starts to accelerate at 1.5 m/s²
    (ramp 0.5 s) and its body pitches nose-up on the suspension by k a = 0.6° (velocity below the body x axis,
    v_b,z = v θ). No GNSS. The plain vertical NHC reads the squat as an attitude/velocity error and rotates
    the pitch toward the velocity: gravity leaks into the along-track acceleration. With the suspension pitch
    modelled, the pitch and the speed stay close to the truth."""
    lat, h, dt, a_x, k = LAT0, H0, 0.01, 1.5, 0.007
    g = earth.normal_gravity(lat, h)
    th = k * a_x

    def f_body(p: float, a: float) -> np.ndarray:
        C = np.array(((math.cos(p), 0.0, math.sin(p)), (0.0, 1.0, 0.0), (-math.sin(p), 0.0, math.cos(p))))
        return C.T @ np.array((a, 0.0, -g))  # C = C_b^n of a pure pitch p

    err = {}
    for kk in (0.0, k):
        core = NavCore(StrapdownState(quat_from_euler(0.0, 0.0, 0.0), np.array((10.0, 0.0, 0.0)), lat, LON0, h),
                       NavConfig(aids=AidsConfig(nhc=True, nhc_pitch_per_accel=kk)))  # fmt: skip
        v = 10.0
        p = 0.0
        for n in range(600):
            a, w = (0.0, 0.0) if n < 200 else (a_x * (n - 199) / 50, th / 0.5) if n < 250 else (a_x, 0.0)
            p_new = p + w * dt
            core.step(ImuSample(t=(n + 1) * dt, dt=dt, dtheta=np.array((0.0, w * dt, 0.0)),
                                dvel=f_body(0.5 * (p + p_new), a) * dt))  # fmt: skip
            p, v = p_new, v + a * dt
        st = core.state()
        assert core.stats["nhc"].accepted > 40
        err[kk] = (abs(euler_from_quat(st.q_nb)[1] - p), abs(st.vel_ned[0] - v))
    # measured: pitch 0.023 → 0.004 rad, speed 2.1 → 0.36 m/s
    assert err[k][0] < 0.3 * err[0.0][0]
    assert err[k][1] < 0.3 * err[0.0][1]


def test_gyro_g_sensitivity_states_estimate_g_and_hold_the_yaw():
    """``FilterConfig.gyro_gsens`` (session 3): a car (accelerating, weaving, braking) whose yaw gyro reads
    G f^b in addition (G_zx = −2e-3, G_zy = 3e-3 rad/s per m/s²), GNSS 5 Hz then a 15 s outage. The 9 g-sensitivity
    states recover G's yaw row and the yaw error at the end is several times smaller than without them."""
    dt = 0.01
    truth = tr.generate(tr.car_profile(), 50.0, dt, LAT0, LON0, H0)
    G = np.zeros((3, 3))
    G[2, 0], G[2, 1] = -2e-3, 3e-3
    imu = [ImuSample(t=float(truth.t[k + 1]), dt=dt, dtheta=truth.dtheta[k] + G @ truth.dvel[k], dvel=truth.dvel[k])
           for k in range(len(truth.dtheta))]  # fmt: skip
    fixes = se.gnss_fixes(truth, se.GnssModel(rate=5, std_ne=0.1, std_d=0.2, std_vel=0.02, outages=[(35.0, 50.0)]),
                          seed=3)  # fmt: skip
    yaw_err = {}
    for gs in (False, True):
        core, _, _ = _run(truth, imu, fixes, NavConfig(filter=FilterConfig(gyro_gsens=gs, init_gsens=3e-3)))
        yaw_err[gs] = abs(euler_from_quat(core.state().q_nb)[2] - truth.euler[-1][2])
        if gs:
            # measured: (−1.8e-3, 3.5e-3)
            assert core.G[2, 0] == pytest.approx(G[2, 0], abs=1e-3)
            assert core.G[2, 1] == pytest.approx(G[2, 1], abs=1e-3)
    assert yaw_err[True] < 0.3 * yaw_err[False]  # measured 0.0075 vs 0.063 rad


def test_c_core_refuses_the_gyro_g_sensitivity_states():
    """The C reference core has no g-sensitivity states: it refuses the option by name (like gnss.vel_delay)."""
    from ins_hil.cref import CNavCore

    init = StrapdownState(np.array([1.0, 0, 0, 0]), np.zeros(3), LAT0, LON0, H0)
    with pytest.raises(ValueError, match=r"not supported by the C core: filter\.gyro_gsens"):
        CNavCore(init, NavConfig(filter=FilterConfig(gyro_gsens=True)))


@pytest.mark.parametrize("cov_every", [1, 5])
def test_delayed_fusion_rollback_restores_the_ground_aid_averages(cov_every):
    """Bug fixed in session 4: the snapshots for delayed fusion did not hold the exponentially averaged rate
    and specific force of the ZUPT rest detector (also the suspension-pitch a_x), so every rollback fed the
    replayed IMU samples into the averages a second time. A rollback for a measurement that changes nothing
    (a velocity-only GNSS record without a velocity, 0.2 s late) must leave the core exactly as it was:
    also the vibration noise's averages and, with P propagated every 5 steps, its partial block sum."""
    from ins_hil.types import GnssFix

    dt = 0.01
    truth = tr.generate(tr.car_profile(t_start=1.0, ramp=3.0), 8.0, dt, LAT0, LON0, H0)
    rng = np.random.default_rng(1)
    imu = se.corrupt_imu(truth, se.mems_gyro(rng), se.mems_accel(rng), seed=2).samples()
    f = FilterConfig(gyro_vib_gain=0.4, accel_vib_gain=0.6, cov_every=cov_every)
    core = NavCore(
        _init(truth), NavConfig(filter=f, aids=AidsConfig(nhc=True, zupt=True), delay=DelayConfig(max_delay=0.3))
    )
    n_end = len(imu) - 2 if cov_every > 1 else len(imu)  # end inside a covariance block (3 of 5 steps)
    for s in imu[:n_end]:
        core.step(s)
    kf = core.kf
    if cov_every > 1:
        assert kf.snapshot().acc_n == 3 and kf.snapshot().acc_qv is not None
    acc_qv = kf.snapshot().acc_qv  # the partial block sum of the process noise (cov_every)
    before = (core.aids.ema_f.copy(), core.aids.ema_w.copy(), core.state().vel_ned.copy(), kf.vib_var, kf.vib_prev,
              kf.P.copy(), None if acc_qv is None else acc_qv.copy())  # fmt: skip
    assert np.all(np.array(kf.vib_var) > 0.0)
    assert core.stats["zupt"].accepted > 10 and core.stats["nhc"].accepted > 10
    core.fuse(GnssFix(t=imu[n_end - 1].t - 0.2, lat=math.nan, lon=math.nan, h=math.nan))  # rollback + replay
    assert np.array_equal(core.aids.ema_f, before[0])  # before the fix: differed by ~1e-3 m/s²
    assert np.array_equal(core.aids.ema_w, before[1])
    assert np.array_equal(core.state().vel_ned, before[2])
    assert kf.vib_var == before[3] and kf.vib_prev == before[4]
    assert np.array_equal(kf.P, before[5])
    if cov_every > 1:
        assert np.array_equal(kf.snapshot().acc_qv, before[6])


def test_nhc_lever_arm_uses_a_low_passed_rate():
    """``nhc_omega_lp_hz`` (session 4): the NHC at a point 1.5 m behind the IMU adds ω × l to the IMU velocity.
    A car at 10 m/s on a straight level road whose gyro also reads a 12 Hz mount vibration (0.2 rad/s about y,
    zero mean; not a motion of the car), aligned (small initial σ), no GNSS: with the raw rate, ω × l carries
    0.3 m/s of vertical 'velocity' that the 10 Hz NHC aliases into the pitch and the vertical velocity; the
    low-passed rate (1 Hz) mostly removes it."""
    lat, h, dt = LAT0, H0, 0.005
    g = earth.normal_gravity(lat, h)
    wv, fv = 0.2, 12.0
    err = {}
    for hz in (0.0, 1.0):
        f = FilterConfig(init_gyro_bias=0.01, init_att=0.01, init_yaw=0.01, init_vel=0.1)
        cfg = NavConfig(filter=f, aids=AidsConfig(nhc=True, nhc_lever_b=np.array((-1.5, 0.0, 0.0)), nhc_omega_lp_hz=hz))
        core = NavCore(StrapdownState(np.array([1.0, 0, 0, 0]), np.array((10.0, 0.0, 0.0)), lat, LON0, h), cfg)
        pitch = []
        for n in range(2000):
            t0, t1 = n * dt, (n + 1) * dt
            dth_y = wv / (2 * math.pi * fv) * (math.sin(2 * math.pi * fv * t1) - math.sin(2 * math.pi * fv * t0))
            core.step(ImuSample(t=t1, dt=dt, dtheta=np.array((0.0, dth_y, 0.0)), dvel=np.array((0.0, 0.0, -g)) * dt))
            pitch.append(euler_from_quat(core.state().q_nb)[1])
        assert core.stats["nhc"].accepted > 90  # 10 Hz for 10 s
        v = core.state().vel_ned
        err[hz] = (float(np.sqrt(np.mean(np.square(pitch[1000:])))), abs(float(v[2])))
    # measured: pitch RMS 0.0146 → 0.0070 rad, vertical velocity 0.21 → 0.05 m/s
    assert err[1.0][0] < 0.7 * err[0.0][0]
    assert err[1.0][1] < 0.5 * err[0.0][1]
    with pytest.raises(ValueError, match="nhc_omega_lp_hz"):
        NavConfig(aids=AidsConfig(nhc_omega_lp_hz=-1.0))


def test_per_axis_accelerometer_scale_factor_prior_learns_a_forward_scale_factor():
    """``FilterConfig.init_accel_sf`` (session 4): a car whose forward accelerometer reads 2 % high (a MEMS
    scale-factor error) accelerates to 10 m/s with GNSS, then brakes to rest in a 10 s GNSS outage. With the
    default 0.2 % prior the x scale factor is barely learnt; with a 3 % prior on x only it is, and the speed error
    after the braking (0.02 × 10 m/s if not compensated) is smaller."""
    dt = 0.01
    truth = tr.generate(tr.car_profile(speed=10.0, t_start=2.0, t_stop=30.0, ramp=5.0), 40.0, dt, LAT0, LON0, H0)
    sf = np.array((1.02, 1.0, 1.0))
    imu = [ImuSample(t=float(truth.t[k + 1]), dt=dt, dtheta=truth.dtheta[k], dvel=sf * truth.dvel[k])
           for k in range(len(truth.dtheta))]  # fmt: skip
    fixes = se.gnss_fixes(truth, se.GnssModel(rate=5, std_ne=0.1, std_d=0.2, std_vel=0.02, outages=[(28.0, 40.0)]),
                          seed=3)  # fmt: skip
    res = {}
    for prior in (None, (0.03, 0.002, 0.002)):
        f = FilterConfig(scale_factors=True, init_accel_sf=prior)
        core, _, _ = _run(truth, imu, fixes, NavConfig(filter=f, gnss=GnssConfig(min_std=(0.1, 0.2, 0.02))))
        res[prior is not None] = (float(core.sa[0]), float(np.linalg.norm(core.state().vel_ned - truth.vel_ned[-1])))
        if prior is not None:
            assert core.kf.P[core.idx.sa, core.idx.sa] < 0.03**2  # the x prior was used and then reduced
            assert core.kf.P[core.idx.sa + 1, core.idx.sa + 1] <= 0.002**2 + 1e-12
    assert res[True][0] == pytest.approx(0.02, abs=0.006)
    assert abs(res[False][0] - 0.02) > 2 * abs(res[True][0] - 0.02)
    assert res[True][1] < 0.7 * res[False][1]  # measured 0.011 vs 0.018 m/s


def test_vibration_noise_follows_the_sample_to_sample_change():
    """``gyro_vib_gain`` / ``accel_vib_gain`` (session 6): per step the attitude (velocity) block gets
    C diag((gain·dt)² E[Δx²]) C^T on top of the ARW (VRW), E[Δx²] the exponential average (τ = vib_tau) of the
    squared change of the compensated body rate (specific force) between samples. A pitch rate alternating ±A
    and a forward specific force alternating ±B change by 2A, 2B every step: E = (2A)²(1 − (1 − b)^k) after k
    changes, b = dt/τ; from a zero covariance one predict adds exactly that noise, turned to NED."""
    from ins_hil.nav.rotation import dcm_from_euler

    dt, A, B, gw, gf, tau = 0.01, 0.05, 0.3, 0.4, 0.6, 1.0
    cfg = FilterConfig(gyro_vib_gain=gw, accel_vib_gain=gf, vib_tau=tau)
    kf = ErrorStateEKF(cfg)
    C = dcm_from_euler(0.1, 0.2, 0.5)
    z3 = np.zeros(3)
    f_ned = np.array((0.0, 0.0, -9.8))

    def inputs(n):
        sgn = 1.0 if n % 2 else -1.0
        return np.array((0.0, sgn * A, 0.0)), C.T @ f_ned + np.array((sgn * B, 0.0, 0.0))

    k = 300
    for n in range(k + 1):  # k + 1 samples: k changes
        w, fb = inputs(n)
        kf.predict(dt, C, f_ned, z3, z3, fb, w, LAT0, H0)
    b = dt / tau
    grow = 1 - (1 - b) ** k
    vw, vf = (2 * A) ** 2 * grow, (2 * B) ** 2 * grow
    np.testing.assert_allclose(kf.vib_var, (0.0, vw, 0.0, vf, 0.0, 0.0), rtol=1e-9, atol=1e-15)
    # one more step from P = 0: the attitude/velocity blocks are exactly ARW/VRW + this step's vibration term
    kf._reset_P(np.zeros((kf.n, kf.n)))
    w, fb = inputs(k + 1)
    kf.predict(dt, C, f_ned, z3, z3, fb, w, LAT0, H0)
    vw, vf = vw + b * ((2 * A) ** 2 - vw), vf + b * ((2 * B) ** 2 - vf)
    att = np.eye(3) * cfg.gyro_arw**2 * dt + (gw * dt) ** 2 * vw * np.outer(C[:, 1], C[:, 1])
    vel = np.eye(3) * cfg.accel_vrw**2 * dt + (gf * dt) ** 2 * vf * np.outer(C[:, 0], C[:, 0])
    np.testing.assert_allclose(kf.P[6:9, 6:9], att, rtol=1e-9, atol=1e-24)
    np.testing.assert_allclose(kf.P[3:6, 3:6], vel, rtol=1e-9, atol=1e-24)
    assert np.abs(att - np.diag(np.diag(att))).max() > 1e-12  # not isotropic: off-diagonal terms in NED
    # a steady rate and specific force (a turn, a bias, gravity) add nothing
    kf2 = ErrorStateEKF(cfg)
    for _ in range(50):
        kf2.predict(dt, C, f_ned, z3, z3, np.array((0.5, 0.1, -9.7)), np.array((0.1, -0.2, 0.3)), LAT0, H0)
    assert kf2.vib_var == (0.0,) * 6
    # P every 5 steps (cov_every): the five steps' vibration terms are summed into the block's noise
    kf5 = ErrorStateEKF(replace(cfg, cov_every=5))
    for n in range(300):  # 60 whole blocks
        w, fb = inputs(n)
        kf5.predict(dt, C, f_ned, z3, z3, fb, w, LAT0, H0)
    kf5._reset_P(np.zeros((kf5.n, kf5.n)))
    qsum = np.zeros(3)
    for n in range(300, 305):
        w, fb = inputs(n)
        kf5.predict(dt, C, f_ned, z3, z3, fb, w, LAT0, H0)
        qsum += np.array(kf5.vib_var[:3])
    att5 = np.eye(3) * cfg.gyro_arw**2 * 5 * dt + (gw * dt) ** 2 * qsum[1] * np.outer(C[:, 1], C[:, 1])
    np.testing.assert_allclose(kf5.P[6:9, 6:9], att5, rtol=1e-9, atol=1e-24)


def test_vibration_noise_config_errors():
    for kw in ({"gyro_vib_gain": -0.1}, {"accel_vib_gain": math.nan}, {"vib_tau": 0.0}):
        with pytest.raises(ValueError, match="vib"):
            FilterConfig(**kw)
    with pytest.raises(ValueError, match="numerics='ud'"):
        FilterConfig(accel_vib_gain=0.4, numerics="ud")


def test_c_core_takes_the_vibration_noise():
    # the C core runs it (held against NavCore in tests/test_cref_parity.py)
    from ins_hil.cref import CNavCore

    init = StrapdownState(np.array([1.0, 0, 0, 0]), np.zeros(3), LAT0, LON0, H0)
    c = CNavCore(init, NavConfig(filter=FilterConfig(gyro_vib_gain=0.4, accel_vib_gain=0.6)))
    assert c._cfg.gyro_vib_gain == pytest.approx(0.4) and c._cfg.accel_vib_gain == pytest.approx(0.6)
