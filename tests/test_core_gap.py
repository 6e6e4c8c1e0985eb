"""Lost IMU data (a logging gap, a stalled link): NavCore coasts across it at constant velocity and attitude,
grows its covariance by the motion it could not see (FilterConfig.gap_accel_sigma, gap_rate_sigma), and the
next GNSS fix pulls the state back at once."""

from __future__ import annotations

import math

import numpy as np

from ins_hil.core import NavConfig, NavCore
from ins_hil.core_parts.config import DelayConfig
from ins_hil.fusion.ekf import FilterConfig
from ins_hil.nav import earth
from ins_hil.nav.mechanization import StrapdownState
from ins_hil.nav.rotation import quat_from_euler
from ins_hil.types import FaultMode, GnssFix, ImuSample

G = 9.80665
LAT, LON, H = math.radians(47.0), math.radians(8.0), 400.0
V_N = 10.0  # m/s north, level, yaw 0


def _imu(t: float) -> ImuSample:
    """Level, unaccelerated flight: the specific force holds the vehicle up (Earth and transport rates are
    below 1e-4 rad/s: over a few seconds they move the state by millimetres)."""
    g = earth.normal_gravity(LAT, H)
    return ImuSample(t=t, dt=0.01, dtheta=np.zeros(3), dvel=np.array((0.0, 0.0, -g * 0.01)))


def _core(t0: float = 0.0, delay: bool = False) -> NavCore:
    init = StrapdownState(quat_from_euler(0.0, 0.0, 0.0), np.array((V_N, 0.0, 0.0)), LAT, LON, H, t0)
    # a well-known start (σ 0.2 m, 0.05 m/s, 0.1°): without a gap the σ stays small over these few seconds
    filt = FilterConfig(init_pos=0.2, init_vel=0.05, init_att=math.radians(0.1), init_yaw=math.radians(0.5),
                        init_accel_bias=0.01, init_gyro_bias=math.radians(0.01))  # fmt: skip
    return NavCore(init, NavConfig(filter=filt, delay=DelayConfig(compensation=delay)))


def _north(core: NavCore) -> float:
    s = core.ins.state
    return float(earth.ned_from_geodetic(s.lat, s.lon, s.h, LAT, LON, H)[0])


def _run(core: NavCore, times: list[float]) -> None:
    for t in times:
        core.step(_imu(t))


def test_a_gap_is_coasted_at_constant_velocity() -> None:
    core = _core()
    _run(core, [0.01 * k for k in range(1, 101)])  # to t = 1.00 s
    n0, sd0 = _north(core), core.state()
    _run(core, [3.0 + 0.01 * k for k in range(1, 11)])  # 2.00 s lost, then 3.01..3.10 s
    assert core.imu_lost[0] == 1 and abs(core.imu_lost[1] - 2.0) < 1e-9
    (ev,) = [e for e in core.drain_events() if e.sensor == "imu"]  # the operator is told, once
    assert ev.mode == FaultMode.DROPOUT and abs(ev.magnitude - 2.0) < 1e-9 and abs(ev.t - 3.0) < 1e-9
    assert core.ins.state.t == 3.10
    assert abs(_north(core) - n0 - V_N * 2.10) < 0.02  # the lost 2 s advanced the position too
    sd = core.state()
    cfg = FilterConfig()
    # the unknown motion of 2 s: σ_v ≥ σ_a·2 s, σ_r ≥ σ_a·(2 s)²/2, σ_att ≥ σ_ω·2 s
    assert np.all(sd.std_vel[:2] >= cfg.gap_accel_sigma * 2.0 * 0.99)
    assert np.all(sd.std_pos[:2] >= 0.5 * cfg.gap_accel_sigma * 4.0 * 0.99)
    assert np.all(sd.std_att >= cfg.gap_rate_sigma * 2.0 * 0.99)
    assert np.all(sd0.std_vel < 0.2)  # before the gap: about the initial σ


def test_no_gap_no_coast_and_the_first_step_is_not_a_gap() -> None:
    core = _core(t0=0.0)
    _run(core, [1000.0 + 0.01 * k for k in range(1, 201)])  # the first sample is 1000 s after the initial state
    assert core.imu_lost == (0, 0.0)
    core2 = _core()
    _run(core2, [0.01 * k for k in range(1, 301)])
    assert core2.imu_lost == (0, 0.0)
    assert np.all(core2.state().std_vel < 0.2)


def test_the_fix_after_a_gap_is_taken_at_once() -> None:
    """A vehicle that turned during the gap is 5 m east of the coasted position at the first fix: the grown
    σ lets that fix through its gate and pulls the position most of the way."""
    for lost in (False, True):
        core = _core()
        times = [0.01 * k for k in range(1, 101)] + [(3.0 if lost else 1.0) + 0.01 * k for k in range(1, 11)]
        _run(core, times)
        s = core.ins.state
        ned = earth.ned_from_geodetic(s.lat, s.lon, s.h, LAT, LON, H) + np.array((0.0, 5.0, 0.0))
        lat, lon, h = earth.geodetic_from_ned(ned, LAT, LON, H)
        rej0 = core.stats["gnss_pos"].rejected
        core.fuse(GnssFix(t=s.t, lat=lat, lon=lon, h=h, vel_ned=(V_N, 0.0, 0.0), std_ne=0.5, std_d=1.0))
        east = float(earth.ned_from_geodetic(core.ins.state.lat, core.ins.state.lon, core.ins.state.h,
                                             LAT, LON, H)[1])  # fmt: skip
        if lost:
            assert core.stats["gnss_pos"].rejected == rej0
            assert east > 4.0
        else:  # without a gap the same fix is 5 m off a state the filter trusts to ~0.2 m: not taken whole
            assert east < 1.0


def test_a_rollback_after_a_gap_does_not_count_it_twice() -> None:
    core = _core(delay=True)
    _run(core, [0.01 * k for k in range(1, 101)] + [3.0 + 0.01 * k for k in range(1, 21)])
    s = core.ins.state
    core.fuse(GnssFix(t=s.t - 0.1, lat=s.lat, lon=s.lon, h=s.h, vel_ned=(V_N, 0.0, 0.0), std_ne=0.5, std_d=1.0))
    _run(core, [3.2 + 0.01 * k for k in range(1, 6)])
    assert core.imu_lost[0] == 1
    assert abs(core.ins.state.t - 3.25) < 1e-9


def test_the_live_pipeline_rides_through_an_imu_stall() -> None:
    """A stalled IMU link (2 s without samples, then the stream resumes) in the gateway's pipeline: no core
    restart, the operator gets one ``imu`` dropout event, and the states go on from the coasted state."""
    from ins_hil.runtime.pipeline import Pipeline, PipelineConfig

    p = Pipeline(PipelineConfig(init="config", init_lat_deg=47.0, init_lon_deg=8.0, init_h=400.0))
    times = [0.01 * k for k in range(1, 101)] + [3.0 + 0.01 * k for k in range(1, 101)]
    states = [p.imu(_imu(t)) for t in times]
    p.flush()
    assert all(st is not None for st in states)
    assert states[-1] is not None and abs(states[-1].t - 4.0) < 1e-9
    assert not any(k.startswith("core_") for k in p.counts), p.counts
    drop = [e for e in p.events if e.sensor == "imu" and e.mode == FaultMode.DROPOUT]
    assert len(drop) == 1 and abs(drop[0].magnitude - 2.0) < 1e-9


def test_a_sensor_time_far_ahead_is_coasted_for_ten_seconds_at_most() -> None:
    """A hostile or corrupt sample stamped a day ahead: the state's time follows it, but the position moves by
    at most GAP_MAX_S of the held velocity and the state stays finite."""
    from ins_hil.core import GAP_MAX_S

    core = _core()
    _run(core, [0.01 * k for k in range(1, 101)])
    n0 = _north(core)
    _run(core, [86400.0 + 0.01 * k for k in range(1, 3)])
    st = core.state()
    assert st.t == 86400.02 and np.all(np.isfinite(st.std_pos)) and np.all(np.isfinite(st.q_nb))
    assert abs(_north(core) - n0 - V_N * (GAP_MAX_S + 0.02)) < 0.05
    assert core.imu_lost[0] == 1 and core.imu_lost[1] > 86000.0
