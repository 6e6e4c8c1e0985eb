"""Sensor error models: the statistics that go in come out."""

from __future__ import annotations

import math

import numpy as np
import pytest

from ins_hil.nav import earth
from ins_hil.sim import sensors
from ins_hil.sim.trajectory import generate, static_profile, uav_profile


@pytest.fixture(scope="module")
def static_truth():
    return generate(static_profile(), 200.0, 0.01, math.radians(45), 0.1, 100.0)


def test_white_noise_density_and_bias(static_truth) -> None:
    g = sensors.ImuErrorModel(bias=np.array([1e-3, -2e-3, 0.5e-3]), noise_density=1e-3)
    a = sensors.ImuErrorModel(noise_density=5e-4)
    imu = sensors.corrupt_imu(static_truth, g, a, seed=5)
    err = imu.dtheta / imu.dt - static_truth.dtheta / static_truth.dt
    np.testing.assert_allclose(err.mean(axis=0), g.bias, atol=3 * 1e-3 / math.sqrt(0.01) / math.sqrt(len(err)))
    assert np.std(err[:, 0]) == pytest.approx(1e-3 / math.sqrt(0.01), rel=0.05)
    verr = imu.dvel / imu.dt - static_truth.dvel / static_truth.dt
    assert np.std(verr[:, 2]) == pytest.approx(5e-4 / math.sqrt(0.01), rel=0.05)


def test_deterministic_with_seed(static_truth) -> None:
    a = sensors.corrupt_imu(static_truth, sensors.mems_gyro(), sensors.mems_accel(), seed=7)
    b = sensors.corrupt_imu(static_truth, sensors.mems_gyro(), sensors.mems_accel(), seed=7)
    np.testing.assert_array_equal(a.dtheta, b.dtheta)


def test_scale_factor_and_saturation() -> None:
    truth = generate(uav_profile(), 60.0, 0.01, 0.8, 0.1, 100.0)
    g = sensors.ImuErrorModel(scale_factor=np.array([0.01, 0.0, 0.0]), saturation=0.05)
    imu = sensors.corrupt_imu(truth, g, sensors.ImuErrorModel(), seed=1)
    assert np.all(np.abs(imu.dtheta / imu.dt) <= 0.05 + 1e-12)
    assert imu.flags.any()


def test_quantization_keeps_the_sum(static_truth) -> None:
    g = sensors.ImuErrorModel(quantization=1e-4)
    imu = sensors.corrupt_imu(static_truth, g, sensors.ImuErrorModel(), seed=1)
    np.testing.assert_allclose(imu.dtheta.sum(axis=0), static_truth.dtheta.sum(axis=0), atol=1e-4)
    assert np.allclose(np.round(np.cumsum(imu.dtheta, axis=0) / 1e-4), np.cumsum(imu.dtheta, axis=0) / 1e-4)


def test_gnss_rate_outage_and_noise(static_truth) -> None:
    m = sensors.GnssModel(rate=5.0, std_ne=2.0, outages=[(50.0, 80.0)])
    fixes = sensors.gnss_fixes(static_truth, m, seed=3)
    assert all(not (50.0 <= f.t < 80.0) for f in fixes)
    assert len(fixes) == pytest.approx(5 * 170, abs=3)
    n_err = [(f.lat - static_truth.lat[0]) * 6.37e6 for f in fixes]
    assert np.std(n_err) == pytest.approx(2.0, rel=0.1)


def test_baro_and_mag(static_truth) -> None:
    b = sensors.baro_samples(static_truth, std=0.3, bias=2.0)
    alts = np.array([s.altitude for s in b])
    assert alts.mean() == pytest.approx(102.0, abs=0.1)
    assert earth.altitude_from_pressure(earth.pressure_from_altitude(123.4)) == pytest.approx(123.4, abs=1e-6)
    m = sensors.mag_samples(static_truth, std=0.0)
    f = sensors.earth_field_ned()
    np.testing.assert_allclose(m[0].field_b, f, atol=1e-12)  # level, yaw 0: body = NED
