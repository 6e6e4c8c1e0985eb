"""The GNSS/baro drift monitor in the LIVE gateway configuration, run offline.

configs/default.toml as the gateway uses it: 1 kHz Python core (late fixes fused at their time of
validity, and with ``[core.nav.delay] compensation = false`` as current), the simulator's UAV flight
(take-off ramp, sweeping turns at 20 m/s), MEMS IMU errors, GNSS 5 Hz delivered ``gnss_latency`` (50 ms) after its
time of validity, baro 25 Hz. The Pipeline is fed directly (no real time) in the order the
live loop would hand it the samples.
"""

from __future__ import annotations

import dataclasses
from typing import Any

import numpy as np
from runtime_helpers import sim_config_dict

from ins_hil.config import from_dict
from ins_hil.fdi.aiding import AidingConfig, AidingMonitor
from ins_hil.runtime.pipeline import Pipeline
from ins_hil.sim import faults as fl
from ins_hil.sim.devices import send_order
from ins_hil.types import BaroSample, FaultEvent, FaultMode, GnssFix, ImuSample, NavState


class _Shadow:
    """The pipeline's monitor plus a second one (never excluding) fed the same (measurement, state) pairs."""

    def __init__(self, real: AidingMonitor, shadow: AidingMonitor) -> None:
        self.real, self.shadow = real, shadow
        self.events = real.events

    def check(self, m: GnssFix | BaroSample, st: NavState) -> bool:
        self.shadow.check(m, st)
        out = self.real.check(m, st)
        self.events = self.real.events
        return out

    def drain_events(self) -> list[FaultEvent]:
        ev = self.real.drain_events()
        self.events = self.real.events
        return ev


def _fly(
    duration: float, fault: str = "", rate: float = 0.0, shadow: AidingConfig | None = None, as_current: bool = True
) -> Any:
    """Fly the default config's simulator for ``duration`` s through a default-config Pipeline.

    ``fault``: "" | "pull" (position only) | "spoof" (velocity-matched) GNSS pull of ``rate`` m/s
    (north-east) from t = 60 s. Returns (pipeline events, counts, shadow monitor or None)."""
    d = sim_config_dict()
    if as_current:
        d["core"]["nav"]["delay"] = {"compensation": False}  # late fixes fused as current (as the C core always does)
    cfg = from_dict(d)
    p, sim = cfg.pipeline, cfg.sim
    # the configuration this test is about (fails loudly if it changes)
    assert p.core == "python" and p.nav.delay.compensation is not as_current and p.aiding_fdi
    assert sim.imu_rate == 1000.0 and sim.gnss_latency == 0.05 and sim.profile == "uav"
    pipe = Pipeline(p)
    mon = pipe._aid_mon
    assert isinstance(mon, AidingMonitor) and mon.cfg.late_fix_as_current is as_current
    shadow_mon = None
    if shadow is not None:
        shadow_mon = AidingMonitor(shadow)
        pipe._aid_mon = _Shadow(mon, shadow_mon)
    d = rate * np.array((0.6, 0.8, 0.0))
    events: list[FaultEvent] = []

    def alter(fixes: list, baro: list) -> tuple[list, list]:
        return (fl.gnss_drift(fixes, 60.0, d, match_velocity=fault == "spoof") if fault else fixes), baro

    for s in send_order(sim, duration, alter):  # the devices' send order
        if isinstance(s, ImuSample):
            pipe.imu(s)
            events += pipe.drain_events()
        else:
            pipe.aid(s)
    return events, pipe.counts, shadow_mon


def _drift(events: list[FaultEvent]) -> list[FaultEvent]:
    return [e for e in events if e.mode == FaultMode.DRIFT and not e.cleared]


def test_live_config_no_false_alarm_and_the_old_comparison_has_one() -> None:
    """150 s of the default flight (take-off ramp 10–30 s, then turns): the default monitor raises
    no DRIFT and never excludes the GNSS or the baro. The old comparison (each late fix against
    the state moved to its time of validity, no lag dead zone), run on the same (fix, state)
    pairs, raises a false GNSS DRIFT: the core fused the late fixes as current, so its state lags
    the truth by ≈ the latency (≈ 1 m along track at 20 m/s) and the position CUSUM accumulates it."""
    old = dataclasses.replace(AidingConfig(), late_fix_as_current=False, lag_margin=0.0, exclude=False)
    events, counts, sh = _fly(150.0, shadow=old)
    assert _drift(events) == []
    assert counts.get("excluded_GnssFix", 0) == 0 and counts.get("excluded_BaroSample", 0) == 0
    assert counts["fused_GnssFix"] > 5 * 130
    assert sh is not None
    assert [e.sensor for e in _drift(sh.events)][:1] == ["gnss"]


def test_live_config_detects_gnss_pulls() -> None:
    """The default configuration (late fixes fused at their time of validity): a position-only pull of
    0.3 m/s and a velocity-matched (spoofing-like) pull of 0.5 m/s from t = 60 s are each reported as a
    GNSS DRIFT within 15 s, none before (GNSS σ 1 m / 0.1 m/s here, twice the bench's, so the slope tests
    need longer). A velocity-matched 0.3 m/s pull is not reported within 40 s in this configuration."""
    for fault, size in (("pull", 0.3), ("spoof", 0.5)):
        events, counts, _ = _fly(76.0, fault, size, as_current=False)
        drift = _drift(events)
        assert drift, fault
        assert drift[0].sensor == "gnss" and 60.0 <= drift[0].t <= 75.0, (fault, drift[0])
        assert counts.get("excluded_GnssFix", 0) > 0, fault
