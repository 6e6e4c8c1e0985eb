"""Simulator: trajectories (Example 3.2 circle, coning, UAV mission, car), sensor models, scenarios."""

from __future__ import annotations

import math

import numpy as np
import pytest

from ins_hil.nav import earth
from ins_hil.nav.mechanization import StrapdownNED, StrapdownState
from ins_hil.nav.rotation import quat_angle_between
from ins_hil.sim import scenarios
from ins_hil.sim import sensors as se
from ins_hil.sim import trajectory as tr

LAT0, LON0, H0 = math.radians(45.0), 0.5, 100.0


def _mech_error(truth: tr.TruthSeries) -> tuple[float, float]:
    """Max attitude (rad) and velocity (m/s) error of the strapdown run on the ideal increments."""
    m = StrapdownNED(StrapdownState(truth.q_nb[0].copy(), truth.vel_ned[0].copy(), truth.lat[0], truth.lon[0],
                                    truth.h[0]))  # fmt: skip
    ea = ev = 0.0
    for k in range(len(truth.dtheta)):
        m.step(truth.dtheta[k], truth.dvel[k], truth.dt)
        ea = max(ea, quat_angle_between(m.state.q_nb, truth.q_nb[k + 1]))
        ev = max(ev, float(np.linalg.norm(m.state.vel_ned - truth.vel_ned[k + 1])))
    return ea, ev


def test_example_3_2_circle_geometry_and_consistency():
    """Level circle, T = 300 s, V = 60 m/s: radius VT/2π = 2864.79 m (case 14), roll 0.3 sin(10ψ)."""
    truth = tr.generate(tr.circle_profile(), 75.0, 0.05, LAT0, LON0, H0)
    ned = np.array([earth.ned_from_geodetic(la, lo, h, LAT0, LON0, H0)
                    for la, lo, h in zip(truth.lat, truth.lon, truth.h)])  # fmt: skip
    R = 60.0 * 300.0 / (2 * math.pi)
    assert R == pytest.approx(2864.79, abs=0.01)
    centre = np.array((0.0, R, 0.0))  # starts north-bound, turning right (east)
    r = np.linalg.norm(ned[:, :2] - centre[:2], axis=1)
    np.testing.assert_allclose(r, R, atol=1.0)  # tangent-plane projection of the ellipsoidal path: < 1 m
    np.testing.assert_allclose(np.linalg.norm(truth.vel_ned, axis=1), 60.0, atol=1e-9)
    psi = 2 * math.pi * truth.t / 300.0
    np.testing.assert_allclose(truth.euler[:, 0], 0.3 * np.sin(10 * psi), atol=1e-12)
    ea, ev = _mech_error(truth)
    assert ea < 1e-5 and ev < 1e-3  # the ideal increments reproduce the motion through the INS


def test_coning_profile_is_coning_at_rest():
    truth = tr.generate(tr.coning_profile(), 5.0, 0.005, LAT0, LON0, H0)
    assert np.allclose(truth.vel_ned, 0.0)
    assert np.max(np.abs(truth.euler[:, :2])) == pytest.approx(0.05, abs=1e-4)
    # coning: the body x and y rates are 90° out of phase, so ω_b keeps a constant magnitude direction sweep
    ea, ev = _mech_error(truth)
    assert ea < 1e-5 and ev < 1e-4


def test_mission_profile_phases():
    truth = tr.generate(tr.mission_profile(), 240.0, 0.02, LAT0, LON0, H0)
    t = truth.t
    speed = np.linalg.norm(truth.vel_ned[:, :2], axis=1)
    assert np.all(speed[t < 10.0] < 1e-9)  # at rest before take-off
    assert np.max(truth.h) - H0 == pytest.approx(3.0 * 32.0, abs=0.5)  # climb 96 m
    assert np.max(speed) == pytest.approx(20.0, abs=1e-6)  # cruise
    assert np.all(speed[t > 216.0] < 1e-6)  # back at rest
    yaw_span = np.max(truth.euler[:, 2]) - np.min(truth.euler[:, 2])
    assert yaw_span == pytest.approx(math.pi, abs=1e-6)  # right 90°, left 180°, right 90°: 0 → 90° → −90° → 0
    assert np.max(np.abs(truth.euler[:, 0])) > math.radians(5)  # coordinated bank in the turns
    assert truth.h[-1] == pytest.approx(H0 + 96.0 - 60.0, abs=0.5)  # descended 60 m
    short = tr.generate(tr.mission_profile(t_takeoff=1.0), 70.0, 0.02, LAT0, LON0, H0)
    ea, ev = _mech_error(short)
    assert ea < 1e-5 and ev < 1e-3


def test_legacy_profiles_still_work():
    for prof in (tr.static_profile(0.1, 0.0, 1.0), tr.uav_profile()):
        truth = tr.generate(prof, 2.0, 0.01, LAT0, LON0, H0)
        assert truth.dtheta.shape == (200, 3)


def test_sensor_models_deterministic_and_with_errors():
    truth = tr.generate(tr.static_profile(), 20.0, 0.01, LAT0, LON0, H0)
    g1 = se.corrupt_imu(truth, se.mems_gyro(np.random.default_rng(1)), se.mems_accel(np.random.default_rng(2)), 3)
    g2 = se.corrupt_imu(truth, se.mems_gyro(np.random.default_rng(1)), se.mems_accel(np.random.default_rng(2)), 3)
    np.testing.assert_array_equal(g1.dtheta, g2.dtheta)
    q = se.ImuErrorModel(quantization=1e-4, saturation=1.0)
    fast = tr.generate(tr.coning_profile(amplitude=0.3, freq=2.0), 2.0, 0.005, LAT0, LON0, H0)
    s = se.corrupt_imu(fast, q, se.ImuErrorModel(), 0)
    assert np.all(np.abs(np.round(np.cumsum(s.dtheta, 0) / 1e-4) * 1e-4 - np.cumsum(s.dtheta, 0)) < 1e-9)
    assert s.flags.any()  # the 3.8 rad/s coning rate saturates a 1 rad/s gyro
    gm = se.GnssModel(rate=5, outages=[(5.0, 10.0)], outlier_prob=0.5, outlier_size=30.0)
    fixes = se.gnss_fixes(truth, gm, seed=4)
    assert not any(5.0 <= f.t < 10.0 for f in fixes) and len(fixes) == 76
    dn = [earth.ned_from_geodetic(f.lat, f.lon, f.h, LAT0, LON0, H0) for f in fixes]
    assert max(np.linalg.norm(d) for d in dn) > 15.0  # multipath-like outliers present


@pytest.mark.parametrize("name", scenarios.NAMES)
def test_scenarios_build_deterministically(name):
    a = scenarios.build(name, seed=3, duration=8.0)
    b = scenarios.build(name, seed=3, duration=8.0)
    assert len(a.imu) == len(b.imu) > 0
    np.testing.assert_array_equal(a.imu[5].dtheta, b.imu[5].dtheta)
    assert [m.t for m in a.meas] == [m.t for m in b.meas]
    c = scenarios.build(name, seed=4, duration=8.0)
    assert not np.array_equal(a.imu[5].dtheta, c.imu[5].dtheta)
    if name == "uav":  # 200 ms latency: delivery time recorded in t_arrival_ns
        g = [m for m in a.meas if hasattr(m, "vel_ned")]
        assert all(m.t_arrival_ns == round((m.t + 0.2) * 1e9) for m in g)
    with pytest.raises(ValueError, match="unknown scenario"):
        scenarios.build("nope")
