"""The aiding monitor's handling of late GNSS fixes (pure, no core): the fix is compared with the
state the way the core fused it, and the dead zone of what the lag alone can cause."""

from __future__ import annotations

import math

import numpy as np
import pytest

from ins_hil.fdi.aiding import AidingConfig, AidingMonitor, _dead_zone
from ins_hil.nav import earth
from ins_hil.types import FaultMode, GnssFix, NavState

LAT0, LON0, H0 = math.radians(45.0), 0.5, 100.0
LAG = 0.05  # s, the live gateway's GNSS latency
G = earth.normal_gravity(LAT0, H0)


def _truth(t: float) -> tuple[float, float, float, np.ndarray, np.ndarray]:
    """Level flight north, 20 m/s, with a ±2 m/s² north acceleration (period 20 s): lat, lon, h, v, a."""
    w = 2 * math.pi / 20.0
    a_n = 2.0 * math.sin(w * t)
    v_n = 20.0 + 2.0 * (1 - math.cos(w * t)) / w
    p_n = 20.0 * t + 2.0 * (t - math.sin(w * t) / w) / w
    m, _ = earth.radii(LAT0)
    return LAT0 + p_n / (m + H0), LON0, H0, np.array((v_n, 0.0, 0.0)), np.array((a_n, 0.0, 0.0))


def _state(t: float, t_truth: float) -> NavState:
    """The state stamped ``t`` holding the truth of ``t_truth`` (level, nose north: f_b = a − g)."""
    lat, lon, h, v, a = _truth(t_truth)
    return NavState(
        t, np.array((1.0, 0.0, 0.0, 0.0)), v, lat, lon, h,
        std_pos=np.full(3, 0.1), std_vel=np.full(3, 0.01), accel_b=a - np.array((0.0, 0.0, G)), aligned=True,
    )  # fmt: skip


def _fly(cfg: AidingConfig, state_lags: bool, n: int = 600) -> list:
    """Noise-free fixes checked LAG s late against a state that is either exact at the check time
    (a delay-compensating core) or the truth of the fix time (a core that fused late fixes as current)."""
    mon = AidingMonitor(cfg)
    for k in range(1, n):
        tg = 0.2 * k
        lat, lon, h, v, _ = _truth(tg)
        fix = GnssFix(tg, lat, lon, h, v, std_ne=0.5, std_d=1.0, std_vel=0.05)
        mon.check(fix, _state(tg + LAG, tg if state_lags else tg + LAG))
    return [e for e in mon.drain_events() if e.mode == FaultMode.DRIFT and not e.cleared]


@pytest.mark.parametrize("late_as_current", [False, True])
def test_late_fix_compared_the_way_the_core_fused_it(late_as_current: bool) -> None:
    """Matching model (state at the fix time moved back; or a lagging state compared as is): no alarm in
    2 min. The other model sees the 20–24 m/s × 50 ms = 1 m along-track offset (2σ): false DRIFT."""
    cfg = AidingConfig(late_fix_as_current=late_as_current, lag_margin=0.0)
    assert _fly(cfg, state_lags=late_as_current) == []
    wrong = _fly(cfg, state_lags=not late_as_current)
    assert wrong and wrong[0].sensor == "gnss" and "pos.N" in wrong[0].detail


def test_dead_zone() -> None:
    x = np.array((-3.0, -0.5, 0.0, 0.2, 2.0))
    assert np.allclose(_dead_zone(x, np.full(5, 1.0)), (-2.0, 0.0, 0.0, 0.0, 1.0))
    assert np.allclose(_dead_zone(x, np.zeros(5)), x)


def test_lag_config_errors_name_the_field() -> None:
    for k in ("lag_margin", "max_lag", "ins_vel_floor"):
        with pytest.raises(ValueError, match=k):
            AidingConfig(**{k: -1.0})
    with pytest.raises(ValueError, match="lag_tau"):
        AidingConfig(lag_tau=0.0)


def test_ins_disturbed_holds_the_ins_cusum_and_readmits_the_gnss() -> None:
    """An INS 0.3 m/s off (e.g. after lost IMU frames) trips the INS-innovation CUSUM and the GNSS is
    excluded; ``ins_disturbed`` re-admits it and holds the CUSUM for ``clear_time`` s."""
    cfg = AidingConfig()
    mon = AidingMonitor(cfg)
    t_flag = None
    for k in range(1, 200):
        tg = 0.2 * k
        lat, lon, h, v, _ = _truth(tg)
        st = _state(tg, tg)
        st.vel_ned = st.vel_ned + np.array((0.3, 0.0, 0.0))
        excluded = mon.check(GnssFix(tg, lat, lon, h, v, std_ne=0.5, std_d=1.0, std_vel=0.05), st)
        if excluded and t_flag is None:
            t_flag = tg
            assert "CUSUM" in mon.drain_events()[0].detail
            mon.ins_disturbed(tg)
            ev = mon.drain_events()
            assert [(e.sensor, e.cleared) for e in ev] == [("gnss", True)] and "IMU" in ev[0].detail
            assert not mon.faulted("gnss")
        elif t_flag is not None and tg < t_flag + cfg.clear_time:
            assert not excluded and mon.stats["gnss_cusum"] == 0.0
    assert t_flag is not None and t_flag < 10.0
    assert mon.faulted("gnss")  # after the hold the persisting disagreement is flagged again
