"""The baro/GNSS height slope test with time-correlated baro errors (``fdi.aiding.baro_slope_var``): a baro whose
error is a first-order Gauss–Markov sequence (0.4 m RMS, lag-1 correlation 0.74 at 5 Hz, as the ArduCopter flight's
baro − GNSS residuals) is not flagged; a steady 0.1 m/s drift on the same noise still is, within 30 s (the 20-s
window and the correlated noise)."""

from __future__ import annotations

import math

import numpy as np

from ins_hil.fdi.aiding import AidingConfig, AidingMonitor
from ins_hil.types import BaroSample, FaultMode, GnssFix, NavState

LAT, LON, H = math.radians(47.0), math.radians(8.0), 500.0


def _fly(seed: int, drift: float, seconds: float = 600.0, t_fault: float = 300.0) -> list:
    """5-Hz fixes on the truth (σ 0.02 m) and a baro 0.1 s after each with the AR(1) error (+ ``drift`` m/s from
    ``t_fault``); the state on the truth. The monitor's events."""
    rng = np.random.default_rng(seed)
    rho, sd = 0.74, 0.4
    mon = AidingMonitor(AidingConfig(baro_std=0.3, gnss_rate=5.0, baro_rate=5.0))
    e = 0.0
    for k in range(int(seconds * 5)):
        t = 10.0 + 0.2 * k
        e = rho * e + sd * math.sqrt(1.0 - rho * rho) * rng.normal()
        alt = H + e + drift * max(0.0, t - 10.0 - t_fault)
        mon.check(BaroSample(t - 0.1, math.nan, alt), _state(t - 0.1))
        g = GnssFix(t, LAT, LON, H, np.zeros(3), std_ne=0.02, std_d=0.04, std_vel=0.02)
        mon.check(g, _state(t))
    return [ev for ev in mon.events if ev.sensor == "baro" and ev.mode == FaultMode.DRIFT and not ev.cleared]


def _state(t: float) -> NavState:
    return NavState(t, np.array((1.0, 0.0, 0.0, 0.0)), np.zeros(3), LAT, LON, H, std_pos=np.full(3, 0.05),
                    std_vel=np.full(3, 0.02), std_att=np.full(3, 0.01), accel_b=np.array((0.0, 0.0, -9.81)),
                    aligned=True)  # fmt: skip


def test_a_time_correlated_baro_is_not_a_drift() -> None:
    """10 min on each of 3 seeds: no baro flag (the white-noise slope variance flagged each of them)."""
    for seed in range(3):
        assert _fly(seed, 0.0) == [], seed


def test_a_steady_baro_drift_is_still_flagged() -> None:
    for seed in range(3):
        ev = _fly(seed, 0.1)
        assert ev and 310.0 <= ev[0].t <= 310.0 + 30.0, (seed, ev)
