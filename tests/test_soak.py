"""Soak measurement: latency join, memory trend, fault schedule and scoring, accuracy stability (no timing)."""

from __future__ import annotations

import math

import numpy as np
import pytest

from ins_hil.soak.analysis import accuracy_stability, end_to_end, fault_check, growth_per_hour, pct
from ins_hil.soak.faults import AUTO_GYRO_STEP, format_faults, geometry_for, parse_faults
from ins_hil.types import FaultMode


def test_end_to_end_joins_states_to_their_epoch_by_sensor_time() -> None:
    t_us = np.arange(1000, 101000, 1000, dtype=np.int64)  # 1 kHz epochs
    emitted = 5_000_000_000 + t_us * 1000 + np.arange(len(t_us)) % 7  # emission ns
    em = np.column_stack((t_us, emitted))[::-1]  # order must not matter
    # states received 300 µs + k µs after the emission of epochs 10, 30, 50 and one unknown epoch
    picks = [9, 29, 49]
    odo = np.array([[t_us[k], emitted[k] + 300_000 + 1000 * j] for j, k in enumerate(picks)] + [[123, 1]])
    t, lat, unmatched = end_to_end(em, odo)
    assert unmatched == 1
    np.testing.assert_array_equal(lat, [300_000, 301_000, 302_000])
    np.testing.assert_allclose(t, t_us[picks] * 1e-6)


def test_pct_reports_microseconds() -> None:
    s = pct(np.arange(1, 1001) * 1000)  # 1..1000 µs
    assert s["count"] == 1000
    assert s["p50_us"] == pytest.approx(500.5)
    assert s["p99_us"] == pytest.approx(990.01)
    assert s["max_us"] == 1000.0
    assert math.isnan(pct(np.zeros(0))["p99_us"])


def test_rss_growth_ignores_warmup_and_scales_to_hours() -> None:
    t = np.arange(0.0, 3600.0, 1.0)
    rss = np.where(t < 300, 50 + t * 0.01, 53 + (t - 300) * (0.5 / 3600))  # fast warm-up, then 0.5 MiB/h
    g, span = growth_per_hour(t, rss, 300.0)
    assert g == pytest.approx(0.5, rel=1e-6)
    assert span == pytest.approx(3299.0)
    g_all, _ = growth_per_hour(t, rss, 0.0)
    assert g_all > 1.0  # with the warm-up the trend would fail the target


def test_fault_schedule_parse_round_trip_and_errors() -> None:
    auto = parse_faults("auto", 100.0, 2)
    assert [(f.group, f.sensor, f.mode, f.t_start) for f in auto] == [
        ("gyro", 1, FaultMode.STEP_BIAS, 40.0),
        ("accel", 3, FaultMode.STEP_BIAS, 70.0),
    ]
    assert auto[0].size == AUTO_GYRO_STEP
    specs = parse_faults("10:gyro:4:ramp:0.01:5,20:accel:0:noise_burst:0.3", 60.0, 2)
    assert parse_faults(format_faults(specs), 60.0, 2) == specs
    assert parse_faults("none", 60.0, 1) == []
    with pytest.raises(ValueError, match="needs --imus 2"):
        parse_faults("auto", 60.0, 1)
    with pytest.raises(ValueError, match=r"row 6 outside 0\.\.5"):
        parse_faults("10:gyro:6:step_bias:0.1", 60.0, 2)
    with pytest.raises(ValueError, match="unknown mode 'wobble'"):
        parse_faults("10:gyro:1:wobble:0.1", 60.0, 2)
    with pytest.raises(ValueError, match="not inside the run"):
        parse_faults("70:gyro:1:step_bias:0.1", 60.0, 2)


def test_geometry_names_match_the_monitor_rows() -> None:
    g = geometry_for(2)
    assert g.n == 6 and g.row_name("gyro", 4) == "imu1.gyro.y"
    assert geometry_for(3).n == 9
    for n in (1, 4):
        with pytest.raises(ValueError, match="2 \\(dual_imu\\) or 3"):
            geometry_for(n)


def _ev(t: float, sensor: str, mode: str = "STEP_BIAS", isolated: bool = True, cleared: bool = False) -> dict:
    return {"t": t, "sensor": sensor, "mode": mode, "isolated": isolated, "cleared": cleared, "detail": ""}


def test_fault_check_scores_detection_false_alarms_and_dropouts() -> None:
    opt = {"faults": "auto", "duration": 100.0, "imus": 2}  # imu0.gyro.y at 40 s, imu1.accel.x at 70 s
    events = [
        _ev(40.02, "imu0.gyro.y"),
        _ev(41.0, "imu0.gyro.y", "STEP_BIAS"),  # classification follow-up: not a false alarm
        _ev(12.0, "imu1.gyro.z"),  # nothing injected there: false alarm
        _ev(5.0, "imu1.gyro", "DROPOUT"),  # frames that did not arrive: counted apart
        _ev(71.0, "imu1.accel.y"),  # wrong sensor for the accel fault: false alarm, fault missed
    ]
    fc = fault_check(opt, events)
    assert [r["detected"] for r in fc["injected"]] == [True, False]
    assert fc["injected"][0]["delay_s"] == pytest.approx(0.02)
    assert fc["all_isolated"] is False
    assert fc["false_alarms"] == 2
    assert fc["dropout_events"] == 1
    ok = fault_check(opt, [_ev(40.1, "imu0.gyro.y"), _ev(70.2, "imu1.accel.x"), _ev(80, "imu1.accel.x", cleared=True)])
    assert ok["all_isolated"] is True and ok["false_alarms"] == 0
    late = fault_check(opt, [_ev(55.0, "imu0.gyro.y")])  # outside the detection window
    assert late["injected"][0]["detected"] is False


def test_accuracy_stability_flags_growth_divergence_and_silence() -> None:
    t = np.arange(0.0, 600.0, 0.1)
    flat = 0.5 + 0.1 * np.sin(t)
    s = accuracy_stability(t, flat, 30.0, 600.0)
    assert s["stable"] is True and s["first_rms"] == pytest.approx(s["last_rms"], rel=0.1)
    growing = 0.5 + t * 0.02  # 12 m at the end
    assert accuracy_stability(t, growing, 30.0, 600.0)["stable"] is False
    nan = flat.copy()
    nan[4000:] = np.nan
    d = accuracy_stability(t, nan, 30.0, 600.0)
    assert d["stable"] is False and "diverged" in d["note"]
    big = accuracy_stability(t, flat + 80.0, 30.0, 600.0, limit=50.0)  # flat but far off: a diverged filter
    assert big["stable"] is False and "above 50" in big["note"]
    quiet = accuracy_stability(t[t < 300], flat[t < 300], 30.0, 600.0)
    assert quiet["stable"] is False and "stop" in quiet["note"]


def test_steal_summary_counts_slow_samples_in_seconds_with_host_steal() -> None:
    from ins_hil.soak.analysis import CLK_TCK, steal_summary
    from ins_hil.soak.orchestrate import steal_ticks

    # cumulative steal ticks of (sensor CPU, gateway CPU) sampled once a second; steal only in (2, 3]
    proc = [{"t": float(k), "steal": [0, 0] if k < 3 else [CLK_TCK // 100, 2 * CLK_TCK // 100]} for k in range(6)]
    t_e2e = np.array([0.5, 2.5, 2.6, 4.5])
    lat = np.array([3e6, 3e6, 1e6, 3e6])  # ns: three over 2 ms, one of them at 2.5 s
    s = steal_summary(proc, t_e2e, lat, 10.0)
    assert s["seconds_per_cpu"] == [0.01, 0.02]
    assert s["intervals_with_steal"] == 1 and s["intervals"] == 5
    assert s["e2e_over_2ms"] == 3 and s["e2e_over_2ms_in_steal_seconds"] == 1
    ns = s["e2e_in_intervals_without_steal"]  # the samples at 0.5 and 4.5 s (2.5, 2.6 s: steal)
    assert ns["n"] == 2 and ns["p50_us"] == 3000.0
    assert steal_summary(proc[:1], t_e2e, lat, 10.0) == {}
    live = steal_ticks((0,))  # this machine's /proc/stat
    assert len(live) == 1 and live[0] >= 0


def test_cyclictest_histogram_statistics() -> None:
    from ins_hil.soak.baseline import parse_histogram, section

    # 1 µs bins, two CPUs; 1000 wake-ups each; CPU 1 has 2 overflows beyond the last bin (max 5000 µs)
    lines = ["# comment"]
    for us in range(0, 100):
        c0 = 990 if us == 20 else (10 if us == 99 else 0)
        c1 = 985 if us == 30 else (13 if us == 50 else 0)
        lines.append(f"{us:06d} {c0:06d}\t{c1:06d}")
    lines += ["# Total: 000001000 000000998", "# Max Latencies: 00099 05000", "# Histogram Overflows: 00000 00002"]
    st = parse_histogram("\n".join(lines), [0, 1])
    assert st[0]["n"] == 1000 and st[0]["p50_us"] == 20 and st[0]["p99_us"] == 20 and st[0]["p999_us"] == 99
    assert st[0]["max_us"] == 99 and st[0]["over_1ms"] == 0
    assert st[1]["n"] == 1000 and st[1]["p50_us"] == 30 and st[1]["p99_us"] == 50 and st[1]["p999_us"] == 5000
    assert st[1]["over_1ms"] == 2 and st[1]["over_2ms"] == 2
    table = section({"available": True, "priority": 80, "interval_us": 1000, "duration_s": 1, "cpus": st})
    assert "| 1 | 1000 | 30 | 50 | 5000 |" in table
    assert "not measured: x" in section({"available": False, "why": "x"})


def test_soak_report_load_note_idle_busy_and_unknown() -> None:
    """The report's machine-load note: idle, busy, and (no load average from the OS: NaN) unknown."""
    from ins_hil.soak.suite import load_lines

    assert "Idle machine" in load_lines({"loadavg": (0.4, 0.5, 0.6), "nproc": 2})[0]
    busy = load_lines({"loadavg": (1.7, 0.5, 0.6), "nproc": 2})[0]
    assert "Busy machine" in busy and "1.70" in busy
    unknown = load_lines({"loadavg": (float("nan"),) * 3, "nproc": 2})[0]
    assert "unknown" in unknown and "nan" not in unknown
