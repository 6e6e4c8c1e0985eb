"""GNSS/baro drift and slow-pull detection (ins_hil.fdi.aiding) on simulated flights with NavCore.

Scenario: UAV profile (20 m/s sweeping turns), MEMS IMU at 100 Hz, GNSS 5 Hz (σ 0.5 m NE, 1 m D,
0.05 m/s), baro 25 Hz (σ 0.3 m); faults start at t = 40 s. Stated detection times (from t_start):
position-only pull 0.3 m/s ≤ 10 s, 1 m/s ≤ 5 s; consistent (velocity-matched) pull 1 m/s ≤ 2 s;
baro drift 0.3 m/s ≤ 15 s. Nominal: no DRIFT event over the 80 s closed-loop flight nor over one
simulated hour of fixes against a truth-referenced state.
"""

from __future__ import annotations

import math

import numpy as np
import pytest
from runtime_helpers import with_due

from ins_hil.core import NavConfig, NavCore
from ins_hil.fdi.aiding import AidingConfig, AidingMonitor, cusum_arl0, cusum_threshold
from ins_hil.fusion.ekf import FilterConfig
from ins_hil.nav import earth
from ins_hil.nav.mechanization import StrapdownState
from ins_hil.nav.rotation import quat_from_euler
from ins_hil.sim import faults as fl
from ins_hil.sim import sensors as se
from ins_hil.sim import trajectory as tr
from ins_hil.types import FaultMode, NavState

LAT0, LON0, H0 = math.radians(45.0), 0.5, 100.0
T_FAULT = 40.0
GNSS = se.GnssModel(rate=5, std_ne=0.5, std_d=1.0, std_vel=0.05)
CFG = AidingConfig(baro_std=0.3)


@pytest.fixture(scope="module")
def scen():
    truth = tr.generate(tr.uav_profile(t_takeoff=2.0, ramp=8.0, turn_period=40.0), 80.0, 0.01, LAT0, LON0, H0)
    rng = np.random.default_rng(5)
    imu = se.corrupt_imu(truth, se.mems_gyro(rng), se.mems_accel(rng), seed=6).samples()
    fixes = se.gnss_fixes(truth, GNSS, seed=15)
    baro = se.baro_samples(truth, rate=25, std=0.3, seed=25)
    return truth, imu, fixes, baro


def _run(truth, imu, fixes, baro, monitor: bool = True):
    """Closed loop NavCore + AidingMonitor (exclusion honoured). Returns (events, horizontal errors per 1 s)."""
    e = truth.euler[0]
    init = StrapdownState(quat_from_euler(*e), truth.vel_ned[0].copy(), truth.lat[0], truth.lon[0], truth.h[0], 0.0)
    core = NavCore(init, NavConfig(filter=FilterConfig(cov_every=5)))
    mon = AidingMonitor(CFG) if monitor else None
    meas = sorted([*fixes, *baro], key=lambda m: m.t)
    ev, err = [], []
    for k, (s, due) in enumerate(with_due(imu, meas)):
        core.step(s)
        for m in due:
            if mon is not None and mon.check(m, core.state()):
                continue
            core.fuse(m)
        if mon is not None:
            ev += mon.drain_events()
        ev += core.drain_events()
        if k % 100 == 99:
            st, i = core.state(), k + 1
            d = earth.ned_delta_small(st.lat - truth.lat[i], st.lon - truth.lon[i], 0.0, truth.lat[i], truth.h[i])
            err.append((s.t, float(np.hypot(d[0], d[1]))))
    return ev, np.array(err)


def _drift(ev, sensor):
    return [e for e in ev if e.mode == FaultMode.DRIFT and e.sensor == sensor and not e.cleared]


def test_cusum_threshold_matches_its_arl():
    h = cusum_threshold(1e8, 0.5)
    assert cusum_arl0(h, 0.5) == pytest.approx(1e8, rel=1e-6)
    assert cusum_threshold(1e9, 0.5) > h  # rarer false alarms → higher threshold
    mon = AidingMonitor(AidingConfig(p_fa_hour=1e-6))
    assert mon.h_cusum > AidingMonitor(AidingConfig()).h_cusum
    assert mon.thr_gnss > AidingMonitor(AidingConfig()).thr_gnss


def test_config_errors_name_the_field():
    with pytest.raises(ValueError, match="p_fa_hour"):
        AidingConfig(p_fa_hour=2.0)
    with pytest.raises(ValueError, match="min_span"):
        AidingConfig(window=5.0, min_span=8.0)


def test_nominal_flight_has_no_drift_alarm(scen):
    truth, imu, fixes, baro = scen
    ev, _ = _run(truth, imu, fixes, baro)
    assert [e for e in ev if e.mode == FaultMode.DRIFT] == []


@pytest.mark.slow
def test_nominal_hour_truth_referenced_has_no_false_alarm():
    """One simulated hour of GNSS (5 Hz) + baro against a truth state with a 0.3 m / 0.03 m/s σ
    (the INS error stated in the state and injected as white noise): no DRIFT event."""
    truth = tr.generate(tr.uav_profile(t_takeoff=2.0, ramp=8.0, turn_period=40.0), 3600.0, 0.05, LAT0, LON0, H0)
    fixes = se.gnss_fixes(truth, GNSS, seed=7)
    baro = {round(b.t, 3): b for b in se.baro_samples(truth, rate=20, std=0.3, seed=8)}
    rng = np.random.default_rng(9)
    mon = AidingMonitor(CFG)
    sp, sv = 0.3, 0.03
    m, n = earth.radii(LAT0)
    for f in fixes:
        k = round(f.t / 0.05)
        b = baro.get(round(f.t, 3))
        if b is not None:
            mon.check(b, _truth_state(truth, k, sp, sv, rng, m, n))
        mon.check(f, _truth_state(truth, k, sp, sv, rng, m, n))
    assert mon.drain_events() == []
    assert mon.stats["gnss_consistency"] > 0 and mon.stats["baro_slope"] > 0  # the tests ran


def _truth_state(truth, k, sp, sv, rng, m, n) -> NavState:
    dp = rng.normal(0, sp, 3)
    h = float(truth.h[k])
    return NavState(
        float(truth.t[k]), truth.q_nb[k], truth.vel_ned[k] + rng.normal(0, sv, 3),
        float(truth.lat[k]) + dp[0] / (m + h), float(truth.lon[k]) + dp[1] / ((n + h) * math.cos(LAT0)), h - dp[2],
        std_pos=np.full(3, sp), std_vel=np.full(3, sv), aligned=True,
    )  # fmt: skip


@pytest.mark.parametrize(
    ("rate", "match", "within"),
    [((0.3, 0.0, 0.0), False, 10.0), ((0.0, -0.3, 0.0), False, 10.0), ((0.7, 0.7, 0.0), True, 2.0)],
    ids=["pull_0.3N", "pull_0.3W", "spoof_1.0_matched"],
)
def test_gnss_pull_detected(scen, rate, match, within):
    truth, imu, fixes, baro = scen
    ev, _ = _run(truth, imu, fl.gnss_drift(fixes, T_FAULT, rate, match_velocity=match), baro)
    d = _drift(ev, "gnss")
    assert d, ev
    assert T_FAULT <= d[0].t <= T_FAULT + within
    assert d[0].magnitude > 0.02  # an estimated rate (m/s), not zero
    assert not _drift(ev, "baro")


def test_pull_exclusion_beats_fusing(scen):
    """1 m/s position-only pull: detected within 5 s; with the GNSS excluded the horizontal error over the
    last 20 s is less than half of fusing it (the filter follows the pull)."""
    truth, imu, fixes, baro = scen
    bad = fl.gnss_drift(fixes, T_FAULT, (0.7, 0.7, 0.0))
    ev, e_mon = _run(truth, imu, bad, baro)
    _, e_fuse = _run(truth, imu, bad, baro, monitor=False)
    d = _drift(ev, "gnss")
    assert d and d[0].t <= T_FAULT + 5.0
    assert 0.5 < d[0].magnitude < 2.0  # ≈ 1 m/s
    last = e_mon[:, 0] >= 60.0
    assert np.sqrt(np.mean(e_mon[last, 1] ** 2)) < 0.5 * np.sqrt(np.mean(e_fuse[last, 1] ** 2))


def test_jump_reported_as_jump_first(scen):
    """A persisting 10 m jump is reported by the filter's gate as JUMP at once (a DRIFT may follow for the
    persisting offset); a single-epoch 10 m outlier gives JUMP only."""
    truth, imu, fixes, baro = scen
    ev, _ = _run(truth, imu, fl.gnss_jump(fixes, T_FAULT, (10.0, 0.0, 0.0)), baro)
    faults = [e for e in ev if not e.cleared]
    assert faults and faults[0].mode == FaultMode.JUMP and faults[0].sensor == "gnss"
    assert abs(faults[0].t - T_FAULT) < 0.01
    ev, _ = _run(truth, imu, fl.gnss_jump(fixes, T_FAULT, (10.0, 0.0, 0.0), duration=0.1), baro)
    assert [e.mode for e in ev if not e.cleared] == [FaultMode.JUMP]


def test_baro_drift_detected_and_blamed_on_baro(scen):
    truth, imu, fixes, baro = scen
    ev, _ = _run(truth, imu, fixes, fl.baro_drift(baro, T_FAULT, -0.3))
    d = _drift(ev, "baro")
    assert d and T_FAULT <= d[0].t <= T_FAULT + 15.0
    assert not _drift(ev, "gnss")
