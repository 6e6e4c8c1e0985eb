"""GNSS velocity valid ``gnss.vel_delay`` before its position (the receiver's own lag) on an accelerating mission
(``ins_hil.bench.replay_cost``'s: 20-Hz RTK-grade fixes, velocity 0.1 s old, up to ≈ 2 m/s²): the drift monitor
integrates each velocity at its own time in its position/velocity test and allows for the core's start (its first
velocities, older than its history, fused as current: 0.14 m/s behind for about a second): nothing flagged, nothing
excluded. Before: the INS-innovation CUSUM excluded the GNSS at 12.6 s (349 of 601 fixes in 30 s), and without that,
the consistency test read the delay × acceleration as a 0.2 m/s pull (20.3 s)."""

from __future__ import annotations

import dataclasses
import math

import numpy as np
import pytest

from ins_hil.datasets import config as dcfg
from ins_hil.datasets.dataset import Dataset
from ins_hil.datasets.run import prepare, run_dataset
from ins_hil.fdi.aiding import AidingMonitor
from ins_hil.nav import earth
from ins_hil.sim import sensors as se
from ins_hil.sim import trajectory as tr
from ins_hil.types import GnssFix, NavState

DELAY = 0.1


def _vel_at(truth: tr.TruthSeries, t: float) -> np.ndarray:
    return np.array([np.interp(t, truth.t, truth.vel_ned[:, k]) for k in range(3)])


@pytest.fixture(scope="module")
def mission() -> tuple[tr.TruthSeries, list, list[GnssFix]]:
    rng = np.random.default_rng(1)
    truth = tr.generate(tr.mission_profile(), 30.0, 1.0 / 200.0, math.radians(45.0), math.radians(7.0), 100.0)
    imu = se.corrupt_imu(truth, se.mems_gyro(rng), se.mems_accel(rng), seed=rng).samples()
    fixes = list(se.gnss_fixes(truth, se.GnssModel(rate=20, std_ne=0.02, std_d=0.04, std_vel=0.02), seed=1))
    return truth, imu, [dataclasses.replace(f, vel_ned=_vel_at(truth, f.t - DELAY)) for f in fixes]


def test_velocity_delayed_fixes_are_not_flagged(mission) -> None:
    _, imu, fixes = mission
    c = dcfg.from_dict({"dataset": {"name": "vel-delay"}, "nav": {"gnss": {"vel_delay": DELAY}}})
    c.use_mag = c.use_baro = False
    r = run_dataset(prepare(Dataset(imu, fixes), c))
    assert r.counts.get("excluded_GnssFix", 0) == 0, (r.counts, r.events)
    assert not [e for e in r.events if e.sensor == "gnss"], r.events
    assert r.counts["fused_GnssFix"] == len(fixes)
    h = np.hypot(r.gnss_err[:, 0], r.gnss_err[:, 1])
    assert float(np.sqrt(np.mean(h**2))) < 0.05


def test_the_consistency_test_integrates_each_velocity_at_its_time() -> None:
    """The monitor alone, a state on the truth: 20-Hz fixes on a 2 m/s² acceleration, exact positions, velocities
    0.1 s old. Integrated as if valid at their positions' time, Σ(Δp − v̄Δt) grows at a·d = 0.2 m/s (flagged)."""
    a, n = 2.0, 400
    mon = AidingMonitor(gnss_min_std=(0.02, 0.04, 0.02), gnss_vel_delay=DELAY)
    lat0 = math.radians(45.0)
    m, _ = earth.radii(lat0)
    for k in range(n):
        t = 10.0 + 0.05 * k
        tt = t - 10.0
        north, v = 0.5 * a * tt * tt, a * tt
        g = GnssFix(t, lat0 + north / (m + 100.0), math.radians(7.0), 100.0, np.array((a * (tt - DELAY), 0.0, 0.0)),
                    std_ne=0.02, std_d=0.04, std_vel=0.02)  # fmt: skip
        st = NavState(t, np.array((1.0, 0.0, 0.0, 0.0)), np.array((v, 0.0, 0.0)), g.lat, g.lon, g.h,
                      std_pos=np.full(3, 0.02), std_vel=np.full(3, 0.02), std_att=np.full(3, 0.01),
                      accel_b=np.array((a, 0.0, -float(earth.gravity_ned(g.lat, g.h)[2]))), aligned=True)  # fmt: skip
        assert not mon.check(g, st), (t, mon.events)
    assert mon.events == []
