"""Fault injection and redundant-set simulation (ins_hil.sim.faults, ins_hil.sim.redundant)."""

from __future__ import annotations

import math

import numpy as np
import pytest

from ins_hil.fdi.geometry import book_cone5, by_name, dual_imu, imus, skewed6, triple_imu
from ins_hil.sim.faults import FaultSpec, inject, inject_column, inject_imu
from ins_hil.sim.redundant import simulate
from ins_hil.sim.sensors import ImuErrorModel, corrupt_imu, mems_accel, mems_gyro
from ins_hil.sim.trajectory import generate, uav_profile
from ins_hil.types import FaultMode

DT = 0.01


@pytest.fixture(scope="module")
def truth():
    return generate(uav_profile(turn_period=20.0, t_takeoff=0.0, ramp=2.0), 4.0, DT, 0.8, 0.5, 100.0)


def test_inject_column_modes() -> None:
    t = DT * np.arange(1, 101)
    base = np.linspace(-0.02, 0.03, 100)
    on = t - DT >= 0.5 - 1e-12
    step = inject_column(base, t, DT, FaultSpec(FaultMode.STEP_BIAS, 0, 0.5, 2.0))
    assert np.allclose(step[~on], base[~on]) and np.allclose(step[on] - base[on], 2.0 * DT)
    ramp = inject_column(base, t, DT, FaultSpec(FaultMode.RAMP, 0, 0.5, 3.0))
    d = (ramp - base)[on] / DT
    assert np.allclose(np.diff(d), 3.0 * DT) and d[0] == pytest.approx(1.5 * DT)
    stuck = inject_column(base, t, DT, FaultSpec(FaultMode.STUCK, 0, 0.5))
    k0 = int(np.argmax(on))
    assert np.all(stuck[on] == base[k0 - 1])
    drop = inject_column(base, t, DT, FaultSpec(FaultMode.DROPOUT, 0, 0.5, duration=0.2))
    assert np.isnan(drop).sum() == 20 and np.isnan(drop[k0]) and not np.isnan(drop[k0 + 20])
    burst = inject_column(base, t, DT, FaultSpec(FaultMode.NOISE_BURST, 0, 0.0, 5.0), seed=1)
    assert np.std((burst - base) / DT) == pytest.approx(5.0, rel=0.2)
    sat = inject_column(base, t, DT, FaultSpec(FaultMode.SATURATION, 0, 0.0, 1.0))
    assert np.abs(sat).max() == pytest.approx(1.0 * DT) and np.allclose(sat[np.abs(base) < DT], base[np.abs(base) < DT])
    sf = inject_column(base, t, DT, FaultSpec(FaultMode.SCALE_FACTOR, 0, 0.5, 0.1))
    assert np.allclose(sf[on], 1.1 * base[on]) and np.allclose(sf[~on], base[~on])


def test_fault_spec_validation() -> None:
    with pytest.raises(ValueError, match="group"):
        FaultSpec(FaultMode.STEP_BIAS, 0, 0.0, 1.0, group="mag")
    with pytest.raises(ValueError, match="SATURATION"):
        FaultSpec(FaultMode.SATURATION, 0, 0.0, 0.0)
    with pytest.raises(ValueError, match="not an inertial"):
        FaultSpec(FaultMode.JUMP, 0, 0.0, 1.0)


@pytest.mark.parametrize("make", [book_cone5, skewed6, dual_imu, triple_imu])
def test_redundant_projection_and_noise(truth, make) -> None:
    geo = make()
    clean = simulate(truth, geo, ImuErrorModel(), ImuErrorModel(), seed=0)
    assert np.allclose(clean.gyro, truth.dtheta @ geo.gyro_axes.T, atol=1e-15)
    assert np.allclose(clean.accel, truth.dvel @ geo.accel_axes.T, atol=1e-15)
    # least squares over the set returns the body increments (book eq. 5.26)
    Z = np.linalg.pinv(geo.gyro_axes)
    assert np.allclose(clean.gyro @ Z.T, truth.dtheta, atol=1e-15)
    g = mems_gyro()
    noisy = simulate(truth, geo, g, mems_accel(), seed=1)
    sd = np.std((noisy.gyro - clean.gyro) / DT, axis=0)
    assert np.allclose(sd, g.noise_density / math.sqrt(DT), rtol=0.2)
    # independent sensors: different noise per row
    assert np.corrcoef((noisy.gyro - clean.gyro).T)[0, 1] < 0.3
    # epoch layout: one ImuSample per unit
    ep = noisy.epoch(5)
    assert len(ep) == geo.units and [s.imu_id for s in ep] == list(range(geo.units))
    if geo.kind == "array":
        assert ep[2].dtheta[0] == noisy.gyro[5, 2] and ep[2].dvel[0] == noisy.accel[5, 2]
    else:
        assert np.array_equal(ep[1].dtheta, noisy.gyro[5, 3:6])
        # IMU j in its own frame: C_b^s Δθ_b
        assert np.allclose(clean.gyro[5, 3:6], geo.mountings[1].T @ truth.dtheta[5], atol=1e-15)


def test_inject_into_series_and_triad(truth) -> None:
    geo = skewed6()
    s = simulate(truth, geo, seed=2)
    f = inject(s, FaultSpec(FaultMode.STEP_BIAS, 4, 1.0, 0.5, group="accel"))
    diff = f.accel - s.accel
    assert np.allclose(diff[:, [0, 1, 2, 3, 5]], 0) and np.allclose(diff[truth.t[1:] > 1.0 + DT, 4], 0.5 * DT)
    assert np.array_equal(f.gyro, s.gyro)
    with pytest.raises(ValueError, match="out of range"):
        inject(s, FaultSpec(FaultMode.STEP_BIAS, 6, 1.0, 0.5))
    tri = corrupt_imu(truth, mems_gyro(), mems_accel(), seed=0)
    tf = inject_imu(tri, FaultSpec(FaultMode.DROPOUT, 2, 2.0))
    assert np.isnan(tf.dtheta[:, 2]).any() and not np.isnan(tf.dtheta[:, :2]).any()


def test_geometry_validation() -> None:
    with pytest.raises(ValueError, match="unknown redundant configuration"):
        by_name("quad")
    with pytest.raises(ValueError, match="at least two"):
        imus([(0, 0, 0)])
    g = dual_imu()
    assert np.allclose(g.gyro_axes.T @ g.gyro_axes, 2 * np.eye(3))
    assert g.row_name("gyro", 4) == "imu1.gyro.y" and skewed6().row_name("accel", 3) == "accel[3]"
