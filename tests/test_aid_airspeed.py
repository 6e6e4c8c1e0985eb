"""The airspeed aid (ins_hil/aids/airspeed.py): its linearisation against |v − w|, its config, validation and
record, and a simulated fixed-wing circling in wind whose wind states it recovers within their σ."""

from __future__ import annotations

import math

import numpy as np
import pytest

from ins_hil.aids.airspeed import AirspeedConfig, AirspeedSample, true_airspeed
from ins_hil.core import NavConfig, NavCore
from ins_hil.fusion.ekf import FilterConfig, StateIndex
from ins_hil.nav.mechanization import StrapdownState
from ins_hil.nav.rotation import quat_from_euler
from ins_hil.runtime.recorder import decode_record, encode_record
from ins_hil.sim import sensors as se
from ins_hil.sim import trajectory as tr
from ins_hil.validation import SampleValidator

LAT0, LON0, H0 = math.radians(47.0), math.radians(8.0), 600.0
WIND = np.array((5.0, -3.0))  # m/s north, east


def test_the_airspeed_jacobian_matches_the_nonlinear_model() -> None:
    idx = StateIndex.build(FilterConfig(wind_states=True))
    assert idx.wind is not None
    rng = np.random.default_rng(1)
    v_hat, w_hat = np.array((18.0, 6.0, -1.0)), np.array((4.0, -2.0))
    for _ in range(5):
        dx = np.zeros(idx.n)
        dx[3:6] = rng.normal(0.0, 0.1, 3)
        dx[idx.wind : idx.wind + 2] = rng.normal(0.0, 0.1, 2)
        v, w = v_hat + dx[3:6], w_hat + dx[idx.wind : idx.wind + 2]
        tas = math.sqrt((v[0] - w[0]) ** 2 + (v[1] - w[1]) ** 2 + v[2] ** 2)
        z, H = true_airspeed(idx, v_hat, w_hat, tas)
        assert abs(z[0]) > 1e-3
        # |u + d| − |u| − û·d ≤ |d|² / (2|u|): the first-order model leaves the second-order term only
        d = dx[3:6] - np.r_[dx[idx.wind : idx.wind + 2], 0.0]
        u = float(np.linalg.norm(v_hat - np.r_[w_hat, 0.0]))
        assert abs(z[0] - float(H[0] @ dx)) <= float(d @ d) / (2.0 * u) + 1e-12, (z, H @ dx)


def test_config_validation_and_record() -> None:
    with pytest.raises(ValueError, match=r"airspeed\.std"):
        AirspeedConfig(std=-1.0)
    init = StrapdownState(np.array([1.0, 0, 0, 0]), np.zeros(3), LAT0, LON0, H0)
    with pytest.raises(ValueError, match="wind_states"):
        NavCore(init, NavConfig(sources={"airspeed": AirspeedConfig(enabled=True)}))
    v = SampleValidator()
    assert v.check(AirspeedSample(1.0, 20.0)) is None
    assert v.check(AirspeedSample(1.0, -2.0)) == "airspeed_range"
    assert v.check(AirspeedSample(1.0, math.inf)) == "airspeed_nonfinite"
    s = AirspeedSample(3.0, 21.5, 0.4, 1, 99)
    f = encode_record(s)
    assert decode_record(f[2], f[4:-4]) == s


def fly(airspeed: bool, seconds: float = 150.0, seed: int = 1) -> NavCore:
    """A fixed-wing circling at 20 m/s ground speed (period 60 s) in a steady wind ``WIND``: MEMS IMU, GNSS
    position/velocity at 5 Hz, the true airspeed |v − w| at 10 Hz (σ 0.3 m/s)."""
    dt = 0.01
    truth = tr.generate(tr.circle_profile(period=60.0, speed=20.0, roll_amp=0.0), seconds, dt, LAT0, LON0, H0)
    rng = np.random.default_rng(seed)
    imu = se.corrupt_imu(truth, se.mems_gyro(rng), se.mems_accel(rng), seed=seed + 1).samples()
    fixes = se.gnss_fixes(truth, se.GnssModel(rate=5, std_ne=0.5, std_d=1.0, std_vel=0.1), seed=seed + 2)
    tas = []
    for i in range(10, len(truth.t), 10):
        u = truth.vel_ned[i] - np.array((WIND[0], WIND[1], 0.0))
        tas.append(AirspeedSample(float(truth.t[i]), float(np.linalg.norm(u)) + rng.normal(0.0, 0.3), 0.3))
    e = truth.euler[0]
    init = StrapdownState(quat_from_euler(e[0], e[1], e[2] + 0.02), truth.vel_ned[0].copy(), truth.lat[0],
                          truth.lon[0], truth.h[0], truth.t[0])  # fmt: skip
    filt = FilterConfig(wind_states=True, init_wind=5.0, wind_sigma_rw=0.01)
    core = NavCore(init, NavConfig(filter=filt, sources={"airspeed": AirspeedConfig(enabled=airspeed)}))
    meas = sorted([*fixes, *(tas if airspeed else [])], key=lambda m: m.t)
    j = 0
    for s in imu:
        core.step(s)
        while j < len(meas) and meas[j].t <= s.t + 1e-9:
            core.fuse(meas[j])
            j += 1
    return core


def test_a_fixed_wing_with_airspeed_estimates_the_wind_within_its_sigma() -> None:
    core = fly(airspeed=True)
    iw = core.idx.wind
    assert iw is not None
    sd = np.sqrt(core.kf.P.diagonal()[iw : iw + 2])
    err = core.wind - WIND
    assert core.stats["airspeed"].accepted > 1400 and core.stats["airspeed"].rejected == 0
    assert np.all(sd < 0.1), sd  # from 5 m/s: learnt, not the prior (measured 0.04)
    assert np.all(np.abs(err) < 2.0 * sd), (core.wind, sd)  # measured 0.48 σ and 0.08 σ (seeds 1–3: ≤ 0.97 σ)
    blind = fly(airspeed=False, seconds=20.0)
    assert "airspeed" not in blind.stats
    assert float(np.sqrt(blind.kf.P[iw, iw])) > 4.0  # without it nothing sees the wind
