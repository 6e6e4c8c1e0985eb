"""Magnetometer hard-iron states (FilterConfig.mag_bias): the measurement's H and a yawing simulated flight."""

from __future__ import annotations

import math

import numpy as np
import pytest

from ins_hil.core import NavConfig, NavCore
from ins_hil.core_parts.config import MagConfig
from ins_hil.fusion import measurements as mm
from ins_hil.fusion.ekf import FilterConfig, StateIndex, skew
from ins_hil.nav.mechanization import StrapdownState
from ins_hil.nav.rotation import dcm_from_euler, euler_from_quat, quat_from_euler
from ins_hil.sim import sensors as se
from ins_hil.sim import trajectory as tr

LAT0, LON0, H0 = math.radians(45.0), 0.5, 100.0


def test_default_layout_has_no_mag_bias_states():
    assert StateIndex.build(FilterConfig()).mb is None
    idx = StateIndex.build(FilterConfig(mag_bias=True))
    assert (idx.mb, idx.n) == (15, 18)


def test_magnetometer_h_matches_finite_differences():
    """z(μ, δb) of the direction measurement with the bias, at a consistent point (z = 0, where the model is
    linearised): +H_μ for Ĉ → (I + [ε×]) Ĉ, −H_b for b̂ → b̂ + ε."""
    idx = StateIndex.build(FilterConfig(mag_bias=True))
    ref = se.earth_field_ned()
    C = dcm_from_euler(0.2, -0.1, 2.0)
    b_hat = np.array((0.3, -0.2, 0.1))
    field_b = C.T @ ref + b_hat * np.linalg.norm(ref)
    z0, H = mm.magnetometer(idx, C, field_b, ref, b_hat)
    np.testing.assert_allclose(z0, 0.0, atol=1e-12)
    e = 1e-6
    for k in range(3):
        d = np.zeros(3)
        d[k] = e
        za, _ = mm.magnetometer(idx, (np.eye(3) + skew(d)) @ C, field_b, ref, b_hat)
        np.testing.assert_allclose((za - z0) / e, H[:, idx.att + k], atol=1e-5)
        zb, _ = mm.magnetometer(idx, C, field_b, ref, b_hat + d)
        np.testing.assert_allclose(-(zb - z0) / e, H[:, idx.mb + k], atol=1e-5)


@pytest.fixture(scope="module")
def flight():
    """A yawing UAV (±90° sweeps, 40 s period) with GNSS and a magnetometer carrying 0.4 |m| of hard iron."""
    dt = 0.01
    truth = tr.generate(tr.uav_profile(t_takeoff=2.0, ramp=8.0, turn_period=40.0), 80.0, dt, LAT0, LON0, H0)
    rng = np.random.default_rng(5)
    imu = se.corrupt_imu(truth, se.mems_gyro(rng), se.mems_accel(rng), seed=3).samples()
    ref = se.earth_field_ned()
    hard = np.array((0.3, -0.25, 0.1)) * np.linalg.norm(ref)
    mag = se.mag_samples(truth, field_ned=ref, rate=10, std=0.3e-6, hard_iron=hard, seed=8)
    fixes = se.gnss_fixes(truth, se.GnssModel(rate=5, std_ne=0.5, std_d=1.0, std_vel=0.05), seed=4)
    return truth, imu, sorted([*fixes, *mag], key=lambda m: m.t), ref, hard


def _yaw_rms(flight, mag_bias: bool) -> tuple[float, NavCore]:
    truth, imu, meas, ref, _ = flight
    e = truth.euler[0]
    init = StrapdownState(quat_from_euler(e[0], e[1], e[2] + 0.02), truth.vel_ned[0].copy(), truth.lat[0],
                          truth.lon[0], truth.h[0], truth.t[0])  # fmt: skip
    core = NavCore(init, NavConfig(filter=FilterConfig(mag_bias=mag_bias), mag=MagConfig(ref_ned=ref, std=0.01)))
    j, err = 0, []
    for k, s in enumerate(imu):
        core.step(s)
        while j < len(meas) and meas[j].t <= s.t + 1e-9:
            core.fuse(meas[j])
            j += 1
        if s.t >= 50.0 and k % 10 == 0:
            d = euler_from_quat(core.state().q_nb)[2] - truth.euler[k + 1][2]
            err.append(math.remainder(d, 2 * math.pi))
    return math.degrees(math.sqrt(float(np.mean(np.square(err))))), core


def test_hard_iron_states_remove_the_yaw_error_of_a_yawing_flight(flight):
    """Last 30 s yaw RMS vs truth: the uncompensated hard iron turns the heading; the states estimate it."""
    rms_off, _ = _yaw_rms(flight, False)
    rms_on, core = _yaw_rms(flight, True)
    hard = flight[4] / np.linalg.norm(flight[3])
    assert rms_off > 10.0  # 16.6° measured
    assert rms_on < 0.5  # 0.15° measured
    np.testing.assert_allclose(core.mb, hard, atol=0.01)  # within 1e-3 measured


def test_c_core_refuses_the_hard_iron_states():
    from ins_hil.cref import CNavCore

    init = StrapdownState(np.array([1.0, 0, 0, 0]), np.zeros(3), LAT0, LON0, H0)
    with pytest.raises(ValueError, match=r"not supported by the C core: filter\.mag_bias"):
        CNavCore(init, NavConfig(filter=FilterConfig(mag_bias=True)))


def test_snapshot_restores_the_hard_iron_estimate():
    """Delayed fusion rolls back to a snapshot: the nominal b̂_m is part of it."""
    init = StrapdownState(np.array([1.0, 0, 0, 0]), np.zeros(3), LAT0, LON0, H0)
    core = NavCore(init, NavConfig(filter=FilterConfig(mag_bias=True)))
    snap = core.snapshot()
    x = np.zeros(core.idx.n)
    x[core.idx.mb : core.idx.mb + 3] = (0.1, -0.2, 0.3)
    core._feedback(x)
    np.testing.assert_array_equal(core.mb, (0.1, -0.2, 0.3))
    core.restore(snap)
    np.testing.assert_array_equal(core.mb, np.zeros(3))
