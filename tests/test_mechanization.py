"""NED strapdown mechanization against exact simulated truth (seed 001 §3, DIGEST_001_004 §1.5)."""

from __future__ import annotations

import math

import numpy as np

from ins_hil.nav import earth
from ins_hil.nav.mechanization import StrapdownNED, StrapdownState
from ins_hil.nav.rotation import quat_angle_between
from ins_hil.sim.trajectory import generate, static_profile, uav_profile


def _run(truth, **kw) -> StrapdownNED:
    s = StrapdownState(truth.q_nb[0].copy(), truth.vel_ned[0].copy(), truth.lat[0], truth.lon[0], truth.h[0])
    ins = StrapdownNED(s, **kw)
    for k in range(len(truth.dtheta)):
        ins.step(truth.dtheta[k], truth.dvel[k], truth.dt)
    return ins


def test_stationary_perfect_sensors_stays_put() -> None:
    """seed 001: a stationary INS with perfect sensors stays where it is."""
    lat0, lon0 = math.radians(45.0), math.radians(10.0)
    truth = generate(static_profile(0.05, -0.02, 1.0), 600.0, 0.01, lat0, lon0, 300.0)
    ins = _run(truth)
    s = ins.state
    d = earth.ned_from_geodetic(s.lat, s.lon, s.h, lat0, lon0, 300.0)
    assert np.linalg.norm(d) < 1e-3
    assert np.linalg.norm(s.vel_ned) < 1e-6
    assert quat_angle_between(s.q_nb, truth.q_nb[-1]) < 1e-9


def test_flight_with_perfect_sensors_follows_truth() -> None:
    truth = generate(uav_profile(), 120.0, 0.005, math.radians(50.45), math.radians(30.52), 180.0)
    ins = _run(truth)
    s = ins.state
    d = earth.ned_from_geodetic(s.lat, s.lon, s.h, truth.lat[-1], truth.lon[-1], truth.h[-1])
    assert np.linalg.norm(d) < 0.01
    assert np.linalg.norm(s.vel_ned - truth.vel_ned[-1]) < 1e-4
    assert quat_angle_between(s.q_nb, truth.q_nb[-1]) < 1e-7


def test_coning_sculling_corrections_reduce_error() -> None:
    """Without the two-sample corrections the same flight drifts more."""
    truth = generate(uav_profile(turn_period=30.0), 60.0, 0.01, math.radians(50.0), 0.5, 100.0)
    err = []
    for flag in (True, False):
        s = _run(truth, coning=flag, sculling=flag).state
        err.append(
            np.linalg.norm(earth.ned_from_geodetic(s.lat, s.lon, s.h, truth.lat[-1], truth.lon[-1], truth.h[-1]))
        )
    assert err[0] < err[1]


def test_earth_rate_matters() -> None:
    """Switching Earth rate off on a static run gives the Earth-rate drift it should."""
    truth = generate(static_profile(), 60.0, 0.01, math.radians(45.0), 0.0, 0.0)
    s = _run(truth, earth_rate=False).state
    # gyros sense Earth rate, which the flat mechanization takes as body rotation
    assert quat_angle_between(s.q_nb, truth.q_nb[-1]) > 0.5 * earth.OMEGA_E * 60


def test_sculling_correction_alone_reduces_velocity_error() -> None:
    """The sculling term by itself (coning kept on): in a turning, accelerating flight with exact increments
    the velocity error after 60 s is at least 25 % smaller with it (measured: 7.2e-5 vs 1.1e-4 m/s)."""
    truth = generate(uav_profile(turn_period=30.0), 60.0, 0.01, math.radians(50.0), 0.5, 100.0)
    err = [np.linalg.norm(_run(truth, sculling=flag).state.vel_ned - truth.vel_ned[-1]) for flag in (True, False)]
    assert err[0] < 0.75 * err[1], err
