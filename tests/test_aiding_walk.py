"""The GNSS drift monitor on a slow, turning walk with good RTK (closed loop NavCore + AidingMonitor).

Scenario: a pedestrian at 1.2 m/s with gait sway (0.1 m/s at 0.9 Hz) and bob (0.1 m/s at 1.8 Hz), a slow
heading meander and a 90° turn every 25 s; MEMS IMU at 100 Hz; RTK fixes (σ 1 cm NE, 2 cm D, 0.02 m/s) at the
antenna, 0.3 m ahead of and 0.3 m above the IMU, with the antenna velocity v + C(ω × l) as a receiver reports
it. The core fuses the lever arm. A monitor that compares the fix with the IMU point sees the lever arm turn
with the heading (up to 0.6 m against a 1-cm σ) and flags good RTK as DRIFT; with the lever arm it must not.
A real pull on the same walk is still found within the stated delays of tests/test_fdi_aiding.py.
"""

from __future__ import annotations

import dataclasses
import math

import numpy as np
import pytest
from runtime_helpers import with_due

from ins_hil.core import NavConfig, NavCore
from ins_hil.core_parts.config import GnssConfig
from ins_hil.fdi.aiding import AidingConfig, AidingMonitor
from ins_hil.fusion.ekf import FilterConfig
from ins_hil.nav.mechanization import StrapdownState
from ins_hil.nav.rotation import dcm_from_quat, quat_from_euler
from ins_hil.sim import faults as fl
from ins_hil.sim import sensors as se
from ins_hil.sim import trajectory as tr
from ins_hil.types import FaultEvent, FaultMode, GnssFix

LAT0, LON0, H0 = math.radians(45.0), 0.5, 100.0
LEVER = np.array((0.3, 0.0, -0.3))
T_END = 150.0


def walk_profile(speed: float = 1.2, sway: float = 0.1, bob: float = 0.1, f_step: float = 1.8) -> tr.Profile:
    """Level walk: starts at 2 s (3-s ramp), yaw 0.6 sin(2πt/37) plus a 90° turn (3-s C² ramp) every 25 s,
    lateral sway at half the step rate and vertical bob at the step rate (m/s, Hz)."""

    def base(t: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        t = np.asarray(t, dtype=np.float64)
        s, ds, _ = tr._smoothstep((t - 2.0) / 3.0)
        v, dv = speed * s, speed * ds / 3.0
        st, dst, _ = tr._smoothstep((t % 25.0) / 3.0)
        yaw = 0.6 * np.sin(2 * np.pi * t / 37.0) + (math.pi / 2) * (np.floor(t / 25.0) + st - 1.0)
        w = 0.6 * 2 * np.pi / 37.0 * np.cos(2 * np.pi * t / 37.0) + (math.pi / 2) * dst / 3.0
        om = 2 * np.pi * f_step
        vl, al = s * sway * np.sin(0.5 * om * t), s * sway * 0.5 * om * np.cos(0.5 * om * t)
        vd, ad = s * bob * np.sin(om * t), s * bob * om * np.cos(om * t)
        cy, sy = np.cos(yaw), np.sin(yaw)
        vel = np.stack([v * cy - vl * sy, v * sy + vl * cy, vd], axis=-1)
        acc = np.stack(
            [dv * cy - v * sy * w - al * sy - vl * cy * w, dv * sy + v * cy * w + al * cy - vl * sy * w, ad], axis=-1
        )
        z = np.zeros_like(t)
        return np.stack([z, z, yaw], axis=-1), vel, acc

    return tr._rates_by_difference(base)


def _walk(rate: float, seed: int) -> tuple[tr.TruthSeries, list, list[GnssFix]]:
    truth = tr.generate(walk_profile(), T_END, 0.01, LAT0, LON0, H0)
    rng = np.random.default_rng(seed)
    imu = se.corrupt_imu(truth, se.mems_gyro(rng), se.mems_accel(rng), seed=seed + 1).samples()
    model = se.GnssModel(rate=rate, std_ne=0.01, std_d=0.02, std_vel=0.02, lever_arm_b=LEVER)
    fixes = se.gnss_fixes(truth, model, seed=seed + 2)
    step = round(1.0 / (rate * truth.dt))
    for i, f in enumerate(fixes):  # the receiver's velocity is the antenna's: v + C_b^n (ω × l)
        k = i * step
        w = truth.dtheta[max(0, k - 1)] / truth.dt
        fixes[i] = dataclasses.replace(f, vel_ned=f.vel_ned + dcm_from_quat(truth.q_nb[k]) @ np.cross(w, LEVER))
    return truth, imu, fixes


def _run(
    truth: tr.TruthSeries, imu: list, fixes: list[GnssFix], rate: float, lever: bool = True
) -> tuple[list[FaultEvent], int]:
    """Closed loop, exclusion honoured; (events, fixes excluded)."""
    init = StrapdownState(
        quat_from_euler(*truth.euler[0]), truth.vel_ned[0].copy(), truth.lat[0], truth.lon[0], truth.h[0], 0.0
    )
    core = NavCore(init, NavConfig(filter=FilterConfig(cov_every=5), gnss=GnssConfig(lever_arm_b=LEVER)))
    mon = AidingMonitor(AidingConfig(gnss_rate=rate), LEVER if lever else None)
    ev, excl = [], 0
    for s, due in with_due(imu, fixes):
        core.step(s)
        for f in due:
            if mon.check(f, core.state()):
                excl += 1
            else:
                core.fuse(f)
        ev += mon.drain_events()
    return ev, excl


def _drift(ev: list[FaultEvent]) -> list[FaultEvent]:
    return [e for e in ev if e.mode == FaultMode.DRIFT and e.sensor == "gnss" and not e.cleared]


@pytest.fixture(scope="module", params=[1.0, 5.0], ids=["rtk_1Hz", "rtk_5Hz"])
def walk(request: pytest.FixtureRequest) -> tuple[float, tr.TruthSeries, list, list[GnssFix]]:
    return (request.param, *_walk(request.param, seed=3))


def test_good_rtk_on_a_slow_turning_walk_is_not_flagged(walk) -> None:
    rate, truth, imu, fixes = walk
    ev, excl = _run(truth, imu, fixes, rate)
    assert _drift(ev) == [] and excl == 0


def test_without_the_lever_arm_the_turns_look_like_drift(walk) -> None:
    """The cause: the antenna turns about the IMU point; compared with the IMU point the good RTK is flagged."""
    rate, truth, imu, fixes = walk
    ev, excl = _run(truth, imu, fixes, rate, lever=False)
    assert _drift(ev) and excl > len(fixes) // 4


@pytest.mark.parametrize(
    ("rate_ned", "match", "delay"),
    [
        ((0.3, 0.0, 0.0), False, {1.0: 4.0, 5.0: 1.0}),
        ((0.0, -0.3, 0.0), False, {1.0: 4.0, 5.0: 0.8}),
        ((0.7, 0.7, 0.0), True, {1.0: 3.0, 5.0: 0.6}),
    ],
    ids=["pull_0.3N", "pull_0.3W", "spoof_1.0_matched"],
)
def test_a_real_pull_on_the_walk_is_still_detected(walk, rate_ned, match, delay) -> None:
    """Detected within ``delay`` s (the delay the monitor had before it knew the lever arm, on the same
    walk with the antenna at the IMU: 4 / 4 / 3 s at 1 Hz, 1.0 / 0.8 / 0.6 s at 5 Hz)."""
    rate, truth, imu, fixes = walk
    t0 = 100.0
    ev, _ = _run(truth, imu, fl.gnss_drift(fixes, t0, rate_ned, match_velocity=match), rate)
    d = _drift(ev)
    assert d, ev
    assert t0 <= d[0].t <= t0 + delay[rate] + 1e-6


def test_lever_arm_config_error_names_the_field() -> None:
    with pytest.raises(ValueError, match="gnss_lever_arm_b"):
        AidingMonitor(None, np.array((0.1, 0.2)))
