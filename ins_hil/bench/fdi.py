"""Monte-Carlo benchmark of inertial-sensor FDI (``ins-hil bench-fdi``, docs/fdi.md).

Per configuration (book's 5-gyro cone, 6-sensor skewed array, dual and triple IMU), failure mode and
size: detection probability, isolation correctness, median and 95th-percentile time to isolate, mode
classification; false alarms over simulated nominal flight; navigation error after isolation against the
same run with the failed sensor simply absent, free inertial (mechanization only) and GNSS-aided
(NavCore); µs per ``FdiMonitor.process`` call; the book's ch. 5 reproductions; the GNSS/baro drift
monitor (:mod:`ins_hil.fdi.aiding`) closed loop and in the live gateway configuration. Each ``bench_*``
appends its Markdown section to ``lines`` and returns its figures; progress goes to ``FdiBench.log``.
"""

from __future__ import annotations

import math
import os
import platform
import time
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from ins_hil.fdi.bias import bias_isolation, ls_matrix, run_example_5_3
from ins_hil.fdi.geometry import SensorGeometry, by_name
from ins_hil.fdi.monitor import FdiConfig, FdiMonitor
from ins_hil.fdi.parity import BOOK_CONE_A, determinant_isolation, determinant_scores, parity_basis, svd_isolation
from ins_hil.fdi.recursive import BOOK_TABLE_5_2, cyclic_decision, cyclic_isolation
from ins_hil.fdi.thresholds import fast_threshold, slow_threshold
from ins_hil.machine import cpu_model, load_note
from ins_hil.nav import earth
from ins_hil.nav.mechanization import StrapdownNED, StrapdownState
from ins_hil.nav.rotation import quat_angle_between
from ins_hil.sim.faults import FaultSpec, inject
from ins_hil.sim.redundant import RedundantSeries, simulate
from ins_hil.sim.sensors import GnssModel, gnss_fixes, mems_accel, mems_gyro
from ins_hil.sim.trajectory import TruthSeries, generate, uav_profile
from ins_hil.types import BaroSample, FaultMode, GnssFix, ImuSample


@dataclass
class FdiBench:
    """Settings of one benchmark run (the ``ins-hil bench-fdi`` options)."""

    rate: float = 200.0  # IMU rate (Hz)
    trials: int = 10  # Monte-Carlo runs per mode and size
    nominal_hours: float = 1.0  # nominal flight per configuration (h)
    p_fa: float = 1e-3  # false-alarm probability per hour and test
    seed: int = 1  # base random seed
    aiding_trials: int = 5  # closed-loop runs per GNSS/baro fault
    aiding_live_trials: int = 3  # flights per row of the live-configuration table (0 = skip)
    log: Callable[[str], None] = print  # progress lines


DEG = math.pi / 180
LAT0, LON0, H0 = math.radians(50.45), math.radians(30.52), 180.0


def _profile():
    return uav_profile(turn_period=20.0, t_takeoff=0.0, ramp=2.0)


def _config(geo: SensorGeometry, dt: float, p_fa: float) -> FdiConfig:
    g, a = mems_gyro(), mems_accel()
    return FdiConfig(geo, dt, g.noise_density, a.noise_density, g.bias_instability, a.bias_instability, p_fa)


@dataclass
class Case:
    group: str
    mode: FaultMode
    size: float
    label: str
    window: float  # s after the fault that the run covers


def _cases(dt: float) -> list[Case]:
    sg = mems_gyro().noise_density / math.sqrt(dt)
    sa = mems_accel().noise_density / math.sqrt(dt)
    F = FaultMode
    return [
        Case("gyro", F.STEP_BIAS, 5 * sg, "5σ", 4.0),
        Case("gyro", F.STEP_BIAS, 10 * sg, "10σ", 4.0),
        Case("gyro", F.RAMP, 1 * DEG / 60, "1 °/s per min", 15.0),
        Case("gyro", F.RAMP, 5 * DEG / 60, "5 °/s per min", 8.0),
        Case("gyro", F.STUCK, 0.0, "frozen", 4.0),
        Case("gyro", F.DROPOUT, 0.0, "no output", 3.0),
        Case("gyro", F.NOISE_BURST, 5 * sg, "5σ", 4.0),
        Case("gyro", F.NOISE_BURST, 10 * sg, "10σ", 4.0),
        Case("gyro", F.SATURATION, 0.5, "clip at ½ reading", 6.0),
        Case("gyro", F.SCALE_FACTOR, 0.02, "+2 %", 6.0),
        Case("gyro", F.SCALE_FACTOR, 0.05, "+5 %", 6.0),
        Case("accel", F.STEP_BIAS, 10 * sa, "10σ", 4.0),
        Case("accel", F.RAMP, 0.01, "0.01 m/s² per s", 15.0),
        Case("accel", F.STUCK, 0.0, "frozen", 4.0),
        Case("accel", F.DROPOUT, 0.0, "no output", 3.0),
        Case("accel", F.NOISE_BURST, 10 * sa, "10σ", 4.0),
        Case("accel", F.SATURATION, 0.5, "clip at ½ reading", 6.0),
        Case("accel", F.SCALE_FACTOR, 0.02, "+2 %", 6.0),
    ]


def _run_until(mon: FdiMonitor, s: RedundantSeries, k0: int, k1: int, stop_after_event: float) -> None:
    t_stop = math.inf
    for k in range(k0, k1):
        _, _, ev = mon.process_arrays(s.t[k], s.dt, s.gyro[k], s.accel[k])
        if ev and math.isinf(t_stop):
            t_stop = s.t[k] + stop_after_event
        if s.t[k] >= t_stop:
            break


def _pct(x: list[float], q: float) -> str:
    return f"{np.percentile(x, q):.3f}" if x else "–"


def bench_faults(names: list[str], truth: TruthSeries, cfg: FdiBench, lines: list[str]) -> dict:
    dt = truth.dt
    rng = np.random.default_rng(cfg.seed)
    summary: dict = {}
    lines += [
        "## Failure modes",
        "",
        f"{cfg.trials} runs per row; the fault starts at a random time in 5–8 s of a manoeuvring flight "
        "(turns of period 20 s, rates up to ~28 °/s, bank up to 45°) and hits each sensor in turn. "
        "Detection = any event after the onset; isolation = the first event names the faulty sensor; "
        "times are onset → exclusion (the event itself is emitted after the classification time); "
        "mode = classified failure mode equals the injected one. σ = per-sample noise of one sensor "
        f"({mems_gyro().noise_density / math.sqrt(dt) / DEG:.4f} °/s gyro, "
        f"{mems_accel().noise_density / math.sqrt(dt):.4f} m/s² accelerometer at {1 / dt:.0f} Hz).",
        "",
    ]
    for name in names:
        geo = by_name(name)
        lines += [
            f"### {name} ({geo.n} gyros + {geo.n} accelerometers, {geo.kind})",
            "",
            "| group | mode | size | detected | isolated correctly | median t [s] | p95 t [s] | max t [s] "
            "| mode ok | early alarms |",
            "|---|---|---|---|---|---|---|---|---|---|",
        ]
        for case in _cases(dt):
            det = iso = mode_ok = early = 0
            times: list[float] = []
            for trial in range(cfg.trials):
                sensor = trial % geo.n
                t_f = float(rng.uniform(5.0, 8.0))
                base = simulate(truth, geo, seed=int(rng.integers(1 << 30)))
                arr = base.gyro if case.group == "gyro" else base.accel
                size = case.size
                if case.mode == FaultMode.SATURATION:
                    size = case.size * float(np.median(np.abs(arr[int(t_f / dt) :, sensor]))) / dt
                spec = FaultSpec(case.mode, sensor, t_f, size, group=case.group)
                s = inject(base, spec, seed=int(rng.integers(1 << 30)))
                mon = FdiMonitor(_config(geo, dt, cfg.p_fa))
                k1 = min(len(s.t), int((t_f + case.window) / dt))
                k0 = max(0, int((t_f - 3.0) / dt))  # 3 s of nominal data before the onset
                _run_until(mon, s, k0, k1, mon.cfg.classify_time + 0.05)
                evs = [e for e in mon.events if not e.cleared]
                if evs and evs[0].t < t_f:
                    early += 1
                    evs = [e for e in evs if e.t >= t_f]
                if not evs:
                    continue
                det += 1
                e = evs[0]
                if e.isolated and e.sensor == geo.row_name(case.group, sensor):
                    iso += 1
                    times.append(e.t - t_f)
                    mode_ok += e.mode == case.mode
            n = cfg.trials
            lines.append(
                f"| {case.group} | {case.mode.name} | {case.label} | {det / n:.2f} | {iso / n:.2f} | "
                f"{_pct(times, 50)} | {_pct(times, 95)} | {max(times) if times else math.nan:.3f} | "
                f"{mode_ok}/{iso} | {early} |"
            )
            summary[(name, case.group, case.mode, case.label)] = (det / n, iso / n, times)
            cfg.log(f"  {name:10s} {case.group:5s} {case.mode.name:12s} {case.label:18s} det {det}/{n} iso {iso}/{n}")
        lines.append("")
    return summary


def bench_nominal(names: list[str], cfg: FdiBench, lines: list[str]) -> dict:
    dt = 1.0 / cfg.rate
    chunk = 600.0
    total = cfg.nominal_hours * 3600.0
    out: dict = {}
    lines += [
        "## False alarms on nominal data",
        "",
        f"Simulated flight of {total / 3600:.2f} h per configuration ({total / dt:.0f} epochs at {cfg.rate:.0f} Hz, "
        f"in {chunk:.0f} s chunks with fresh noise), white noise + bias instability on every sensor; "
        f"false-alarm probability {cfg.p_fa:g} per hour and test.",
        "",
        "| configuration | hours | epochs | events (false alarms) | fast / slow χ² thresholds (m) "
        "| µs per epoch (arrays) |",
        "|---|---|---|---|---|---|",
    ]
    for name in names:
        geo = by_name(name)
        mon = FdiMonitor(_config(geo, dt, cfg.p_fa))
        lat, lon, h, t0 = LAT0, LON0, H0, 0.0
        epochs = 0
        busy = 0.0
        while t0 < total - 1e-9:
            dur = min(chunk, total - t0)
            tr = generate(_profile(), dur, dt, lat, lon, h, t0=t0)
            s = simulate(tr, geo, seed=cfg.seed * 1000 + int(t0))
            c0 = time.perf_counter()
            for k in range(len(s.t)):
                mon.process_arrays(s.t[k], dt, s.gyro[k], s.accel[k])
            busy += time.perf_counter() - c0
            epochs += len(s.t)
            lat, lon, h, t0 = float(tr.lat[-1]), float(tr.lon[-1]), float(tr.h[-1]), t0 + dur
            cfg.log(f"  nominal {name}: {t0:.0f}/{total:.0f} s, events {len(mon.events)}")
        m = geo.n - 3
        thf = fast_threshold(cfg.p_fa, dt, mon.cfg.persistence, m)
        ths = slow_threshold(cfg.p_fa, mon.cfg.slow_tau, m)
        thr = f"{thf:.1f} / {ths:.1f} ({m})"
        lines.append(
            f"| {name} | {total / 3600:.2f} | {epochs} | {len(mon.events)} | {thr} | {1e6 * busy / epochs:.1f} |"
        )
        out[name] = (len(mon.events), epochs, total / 3600)
    lines.append("")
    return out


def _faults(sg: float) -> list[tuple[str, FaultMode, float]]:
    """The gyro-0 faults of the navigation tables: a 10σ step (``sg``: per-sample gyro σ, rad/s), a 1 °/s/min ramp."""
    return [("step 10σ", FaultMode.STEP_BIAS, 10 * sg), ("ramp 1 °/s per min", FaultMode.RAMP, DEG / 60)]


def _three_ways(geo: SensorGeometry) -> Callable[[np.ndarray, np.ndarray], list[tuple[np.ndarray, np.ndarray]]]:
    """Least-squares body increments (gyro rad, accel m/s) of one epoch's sensor outputs, without sensor 0 ('absent')
    and over all sensors ('no FDI'), as ``[absent, no FDI]`` of (dθ, Δv)."""
    zg_abs, za_abs = np.linalg.pinv(geo.gyro_axes[1:]), np.linalg.pinv(geo.accel_axes[1:])
    zg, za = np.linalg.pinv(geo.gyro_axes), np.linalg.pinv(geo.accel_axes)
    return lambda gyro, accel: [(zg_abs @ gyro[1:], za_abs @ accel[1:]), (zg @ gyro, za @ accel)]


def _ratio_head(what: str) -> list[str]:
    """A blank line and the head of a monitor / absent / no FDI table of ``what`` ("err", "RMS") with ratios."""
    return [
        "",
        f"| configuration | fault | att. {what} monitor / absent / no FDI [deg] "
        f"| pos. {what} monitor / absent / no FDI [m] | ratio att | ratio pos |",
        "|---|---|---|---|---|---|",
    ]


def _ratio_row(
    kind: str, name: str, label: str, e: np.ndarray, pos_dp: int, cfg: FdiBench, lines: list[str], out: dict
) -> None:
    """Append the table row of errors ``e`` (rows monitor / absent / no FDI; columns att. deg, pos. m) with the
    monitor/absent ratios, record the ratios in ``out[(name, label)]`` and log them."""
    ra, rp = e[0, 0] / e[1, 0], e[0, 1] / e[1, 1]
    lines.append(
        f"| {name} | {label} | {e[0, 0]:.4f} / {e[1, 0]:.4f} / {e[2, 0]:.4f} | "
        f"{e[0, 1]:.{pos_dp}f} / {e[1, 1]:.{pos_dp}f} / {e[2, 1]:.{pos_dp}f} | {ra:.2f} | {rp:.2f} |"
    )
    out[(name, label)] = (ra, rp)
    cfg.log(f"  {kind} {name} {label}: ratio att {ra:.2f} pos {rp:.2f}")


def bench_nav(names: list[str], cfg: FdiBench, lines: list[str]) -> dict:
    """Free-inertial navigation (mechanization only) on the monitor's output vs the failed sensor absent."""
    dt = 1.0 / cfg.rate
    dur, t_f = 60.0, 10.0
    truth = generate(_profile(), dur, dt, LAT0, LON0, H0)
    sg = mems_gyro().noise_density / math.sqrt(dt)
    out: dict = {}
    lines += [
        "## Navigation error after isolation",
        "",
        f"Free inertial (mechanization only, no aiding: the worst case for what leaks in before the exclusion), "
        f"{dur:.0f} s manoeuvring "
        f"flight, fault at {t_f:.0f} s on gyro 0; errors at the end, mean over {cfg.trials} seeds. "
        "'monitor' = navigation on the FdiMonitor output; 'absent' = least squares without the failed sensor "
        "for the whole run; 'no FDI' = least squares over all sensors. Target: monitor ≤ 1.5 × absent.",
        *_ratio_head("err"),
    ]
    for name in names:
        geo = by_name(name)
        others = _three_ways(geo)
        for label, mode, size in _faults(sg):
            errs = np.zeros((3, 2))
            for trial in range(cfg.trials):
                s = inject(simulate(truth, geo, seed=7000 + trial), FaultSpec(mode, 0, t_f, size))
                mon = FdiMonitor(_config(geo, dt, cfg.p_fa))
                navs = [
                    StrapdownNED(
                        StrapdownState(truth.q_nb[0].copy(), truth.vel_ned[0].copy(), LAT0, LON0, H0, truth.t[0])
                    )
                    for _ in range(3)
                ]
                for k in range(len(s.t)):
                    dth, dv, _ = mon.process_arrays(s.t[k], dt, s.gyro[k], s.accel[k])
                    for nv, (a, b) in zip(navs, [(dth, dv), *others(s.gyro[k], s.accel[k])]):
                        nv.step(a, b, dt)
                for i, nv in enumerate(navs):
                    st = nv.state
                    errs[i, 0] += math.degrees(quat_angle_between(st.q_nb, truth.q_nb[-1])) / cfg.trials
                    d = earth.ned_from_geodetic(st.lat, st.lon, st.h, truth.lat[-1], truth.lon[-1], truth.h[-1])
                    errs[i, 1] += float(np.linalg.norm(d)) / cfg.trials
            _ratio_row("nav", name, label, errs, 1, cfg, lines, out)
    lines.append("")
    return out


def bench_aided(names: list[str], cfg: FdiBench, lines: list[str]) -> dict:
    """GNSS-aided closed loop: NavCore (EKF, merged from the fusion branch) on the monitor's output."""
    from ins_hil.core import NavCore  # the fusion branch's NavCore (EKF); mechanization-only on main

    dt = 1.0 / cfg.rate
    dur, t_f, t_eval = 60.0, 10.0, 20.0
    truth = generate(_profile(), dur, dt, LAT0, LON0, H0)
    fixes = gnss_fixes(truth, GnssModel(rate=5.0), seed=cfg.seed)
    sg = mems_gyro().noise_density / math.sqrt(dt)
    out: dict = {}
    lines += [
        "## GNSS-aided closed loop (NavCore with the fusion EKF)",
        "",
        f"`ins_hil.core.NavCore` (error-state EKF from the fusion branch, merged) fed by the monitor's output, "
        f"GNSS at 5 Hz (1 m / 0.1 m/s), {dur:.0f} s manoeuvring flight, fault at {t_f:.0f} s on gyro 0; "
        f"RMS errors over {t_eval:.0f}–{dur:.0f} s, one seed. Columns as above.",
        *_ratio_head("RMS"),
    ]
    for name in names:
        geo = by_name(name)
        others = _three_ways(geo)
        for label, mode, size in _faults(sg):
            s = inject(simulate(truth, geo, seed=9000), FaultSpec(mode, 0, t_f, size))
            mon = FdiMonitor(_config(geo, dt, cfg.p_fa))
            init = StrapdownState(truth.q_nb[0].copy(), truth.vel_ned[0].copy(), LAT0, LON0, H0, truth.t[0])
            cores = [NavCore(init) for _ in range(3)]
            acc = np.zeros((3, 2))
            cnt = 0
            fi = 0
            for k in range(len(s.t)):
                tk = float(s.t[k])
                dth, dv, _ = mon.process_arrays(tk, dt, s.gyro[k], s.accel[k])
                for c, (a, b) in zip(cores, [(dth, dv), *others(s.gyro[k], s.accel[k])]):
                    c.step(ImuSample(tk, dt, a, b))
                while fi < len(fixes) and fixes[fi].t <= tk + 1e-9:
                    for c in cores:
                        c.fuse(fixes[fi])
                    fi += 1
                if tk >= t_eval:
                    cnt += 1
                    for i, c in enumerate(cores):
                        st = c.state()
                        acc[i, 0] += quat_angle_between(st.q_nb, truth.q_nb[k + 1]) ** 2
                        d = earth.ned_from_geodetic(
                            st.lat, st.lon, st.h, truth.lat[k + 1], truth.lon[k + 1], truth.h[k + 1]
                        )
                        acc[i, 1] += float(d @ d)
            rms = np.sqrt(acc / cnt)
            rms[:, 0] = np.degrees(rms[:, 0])
            _ratio_row("aided", name, label, rms, 2, cfg, lines, out)
    lines.append("")
    return out


def bench_timing(names: list[str], cfg: FdiBench, lines: list[str]) -> None:
    dt = 1.0 / cfg.rate
    truth = generate(_profile(), 20.0, dt, LAT0, LON0, H0)
    lines += [
        "## Cost per call",
        "",
        "`FdiMonitor.process(samples)` with ImuSample objects as the runtime calls it (nominal data, "
        "no fault; the rare isolation/classification path is not included). Median of 5 repetitions.",
        "",
        "| configuration | units per epoch | µs per call (median) | µs per call (best) |",
        "|---|---|---|---|",
    ]
    for name in names:
        geo = by_name(name)
        s = simulate(truth, geo, seed=3)
        epochs = [s.epoch(k) for k in range(len(s.t))]
        reps = []
        for _ in range(5):
            mon = FdiMonitor(_config(geo, dt, cfg.p_fa))
            c0 = time.perf_counter()
            for ep in epochs:
                mon.process(ep)
            reps.append(1e6 * (time.perf_counter() - c0) / len(epochs))
        lines.append(f"| {name} | {geo.units} | {np.median(reps):.1f} | {min(reps):.1f} |")
        cfg.log(f"  timing {name}: {np.median(reps):.1f} µs/call")
    lines.append("")


def book_section(lines: list[str]) -> None:
    A = BOOK_CONE_A
    w = np.array([1.0, 2.0, 3.0])
    U2 = parity_basis(A)
    J = np.array([svd_isolation(A @ w + np.eye(5)[i], U2).scores for i in range(5)])
    wn = np.array([0.0801, 0.0425, -0.0112, 0.0607, 0.0870])
    D = np.array([determinant_scores(A @ w + np.eye(5)[i] + wn, A) for i in range(5)])
    fmt = lambda M: ["| " + " | ".join(f"{abs(x) if abs(x) < 5e-5 else x:.4f}" for x in row) + " |" for row in M]
    rng = np.random.default_rng(2019)
    h = 0.1 * math.sqrt(3)
    hits = np.zeros(3)
    N = 2000
    for tr in range(N):
        i = tr % 5
        y = A @ w + np.eye(5)[i] + rng.uniform(-h, h, 5)
        hits += [cyclic_isolation(y, A, 0.1).index == i, svd_isolation(y, U2).index == i,
                 determinant_isolation(y, A).index == i]  # fmt: skip
    ex = run_example_5_3()
    iso = bias_isolation(0.1 * ls_matrix(A)[:, 0], ls_matrix(A))
    lines += [
        "## Book ch. 5 reproductions (DIGEST_000 §5, cases 21–25)",
        "",
        "Table 5.1 (J(k), corrected eq. 5.17; rows = failed sensor, columns = candidate), exact:",
        "",
        "| | k=1 | 2 | 3 | 4 | 5 |",
        "|---|---|---|---|---|---|",
        *[f"| J(k{i + 1}) " + r for i, r in enumerate(fmt(J))],
        "",
        "Table 5.3 (d_j, determinant method 5.32) recomputed from the digest's recovered noise "
        "w = [0.0801, 0.0425, −0.0112, 0.0607, 0.0870]; max deviation from the printed table "
        "is in tests/test_fdi_book.py (≤ 3e-4):",
        "",
        "| i \\ j | 1 | 2 | 3 | 4 | 5 |",
        "|---|---|---|---|---|---|",
        *[f"| {i + 1} " + r for i, r in enumerate(fmt(D))],
        "",
        f"Table 5.2 decisions from the printed μ*: i = {[cyclic_decision(r) + 1 for r in BOOK_TABLE_5_2]} "
        "(book: 1..5). Monte-Carlo correct isolation at σ = 0.1 (uniform noise, ρ = 1, "
        f"{N} draws): recursive LS + cyclic transposition {hits[0] / N:.3f}, SVD/parity {hits[1] / N:.3f}, "
        f"determinant {hits[2] / N:.3f}.",
        "",
        f"Example 5.3: δĉ = 0.1 z₁ gives i = {iso.index + 1}, â = {iso.size:.4f}. Closed-loop 20 s run "
        f"(12-state filter of book 3.3, corrections every 2 s): indicator i = {[int(i) + 1 for i in ex.index]}, "
        f"â = {[round(float(a), 3) for a in ex.a_hat]}.",
        "",
    ]


AID_BEGIN, AID_END = "<!-- aiding:begin -->", "<!-- aiding:end -->"
AID_T_FAULT, AID_T_END = 40.0, 80.0


def _aid_run(seed: int, fault: str, size: float) -> tuple[list, float]:
    """One closed-loop NavCore + AidingMonitor flight (80 s, fault at 40 s); (events, flight seconds aligned)."""
    from ins_hil.core import NavConfig, NavCore
    from ins_hil.fdi.aiding import AidingConfig, AidingMonitor
    from ins_hil.fusion.ekf import FilterConfig
    from ins_hil.nav.rotation import quat_from_euler
    from ins_hil.sim import faults as fl
    from ins_hil.sim.sensors import baro_samples, corrupt_imu

    truth = generate(uav_profile(t_takeoff=2.0, ramp=8.0, turn_period=40.0), AID_T_END, 0.01, LAT0, LON0, H0)
    rng = np.random.default_rng(seed)
    imu = corrupt_imu(truth, mems_gyro(rng), mems_accel(rng), seed=seed + 1).samples()
    fixes = gnss_fixes(truth, GnssModel(rate=5, std_ne=0.5, std_d=1.0, std_vel=0.05), seed=seed + 2)
    baro = baro_samples(truth, rate=25, std=0.3, seed=seed + 3)
    d = size * np.array((math.cos(0.3 * seed), math.sin(0.3 * seed), 0.0))  # horizontal direction varies
    if fault == "pull":
        fixes = fl.gnss_drift(fixes, AID_T_FAULT, d)
    elif fault == "spoof":
        fixes = fl.gnss_drift(fixes, AID_T_FAULT, d, match_velocity=True)
    elif fault == "jump":
        fixes = fl.gnss_jump(fixes, AID_T_FAULT, d)
    elif fault == "baro":
        baro = fl.baro_drift(baro, AID_T_FAULT, size)
    e = truth.euler[0]
    core = NavCore(
        StrapdownState(quat_from_euler(*e), truth.vel_ned[0].copy(), truth.lat[0], truth.lon[0], truth.h[0], 0.0),
        NavConfig(filter=FilterConfig(cov_every=5)),
    )
    mon = AidingMonitor(AidingConfig(baro_std=0.3))
    meas: list[GnssFix | BaroSample] = sorted([*fixes, *baro], key=lambda m: m.t)
    j, ev = 0, []
    for s in imu:
        core.step(s)
        while j < len(meas) and meas[j].t <= s.t + 1e-9:
            m = meas[j]
            j += 1
            if not mon.check(m, core.state()):
                core.fuse(m)
        ev += mon.drain_events() + core.drain_events()
    return ev, AID_T_END


AID_LIVE_T_FAULT, AID_LIVE_T_END = 60.0, 90.0


def _aid_live_run(seed: int, fault: str, size: float) -> tuple[list, dict[str, int]]:
    """One flight of the LIVE configuration offline: configs/default.toml's Pipeline (1 kHz Python core,
    ``[core.nav.delay] compensation = false``, monitor on) fed the default simulator (UAV flight, GNSS 50 ms late)
    in arrival order; fault at 60 s, end at 90 s. Returns (events, pipeline counts)."""
    import tomllib

    from ins_hil.config import default_path, from_dict
    from ins_hil.runtime.pipeline import Pipeline
    from ins_hil.sim import faults as fl
    from ins_hil.sim.devices import send_order

    cfg = from_dict(tomllib.loads(Path(default_path()).read_text()), "bench")
    sim = cfg.sim
    sim.seed = seed
    pipe = Pipeline(cfg.pipeline)
    d = size * np.array((math.cos(0.3 * seed), math.sin(0.3 * seed), 0.0))
    ev: list = []

    def alter(fixes: list, baro: list) -> tuple[list, list]:
        if fault in ("pull", "spoof"):
            fixes = fl.gnss_drift(fixes, AID_LIVE_T_FAULT, d, match_velocity=fault == "spoof")
        elif fault == "baro":
            baro = fl.baro_drift(baro, AID_LIVE_T_FAULT, size)
        return fixes, baro

    for s in send_order(sim, AID_LIVE_T_END, alter):
        if s.kind == "imu":
            pipe.imu(s)
            ev += pipe.drain_events()
        else:
            pipe.aid(s)
    return ev, pipe.counts


AID_KINDS = {  # fault kind -> (table label, sensor that should be flagged, expected mode)
    "none": ("none (nominal)", "", FaultMode.DRIFT),
    "pull": ("GNSS position pull", "gnss", FaultMode.DRIFT),
    "spoof": ("GNSS pull, matching velocity", "gnss", FaultMode.DRIFT),
    "jump": ("GNSS jump (m)", "gnss", FaultMode.JUMP),
    "baro": ("baro drift", "baro", FaultMode.DRIFT),
}


def _aid_cases(*rows: tuple) -> list[tuple[str, str, float, str, FaultMode]]:
    """Table rows (label, kind, size, sensor, mode) from ``(kind, size, size, ...)`` groups; sizes in m/s (m for
    the jump)."""
    return [(AID_KINDS[r[0]][0], r[0], size, *AID_KINDS[r[0]][1:]) for r in rows for size in r[1:]]


def bench_aiding_live(cfg: FdiBench, lines: list[str]) -> None:
    """GNSS/baro drift rows in the live gateway configuration (configs/default.toml, offline)."""
    cases = _aid_cases(("none", 0.0), ("pull", 0.3, 1.0), ("spoof", 0.1, 0.3, 1.0), ("baro", 0.3))
    n = cfg.aiding_live_trials
    lines += [
        "",
        "### In the live gateway configuration",
        "",
        "configs/default.toml run offline (no real time): Pipeline with the 1 kHz Python core, "
        "`[core.nav.delay] compensation = false` (late fixes fused as current), monitor on by default; the default "
        "simulator (UAV: take-off ramp 10–30 s, sweeping turns at 20 m/s, MEMS IMU), GNSS 5 Hz delivered "
        "50 ms after its time of validity (σ 1 m NE / 2 m D / 0.1 m/s), baro 25 Hz (σ 0.5 m); fault at "
        f"t = {AID_LIVE_T_FAULT:.0f} s, flight {AID_LIVE_T_END:.0f} s; {n} simulator seeds per row "
        f"(`ins-hil bench-fdi --aiding-only --aiding-live-trials {n}`).",
        "",
        "| fault | size (m/s) | detected | median / max time to detect (s) | wrong sensor | false alarms |",
        "|---|---|---|---|---|---|",
    ]
    fa_events, fa_time = 0, 0.0
    for label, kind, size, sensor, mode in cases:
        times, wrong, fa = [], 0, 0
        for k in range(n):
            ev, _counts = _aid_live_run(cfg.seed + k, kind, size)
            drift = [e for e in ev if e.mode == FaultMode.DRIFT and not e.cleared]
            t_on = AID_LIVE_T_END if kind == "none" else AID_LIVE_T_FAULT
            fa += sum(1 for e in drift if e.t < t_on)
            fa_time += t_on
            if kind == "none":
                continue
            hit = [e for e in drift if e.sensor == sensor and e.mode == mode and e.t >= t_on]
            wrong += any(e.sensor != sensor and e.t >= t_on for e in drift)
            if hit:
                times.append(hit[0].t - t_on)
        fa_events += fa
        med = f"{np.median(times):.1f} / {max(times):.1f}" if times else "–"
        det = "–" if kind == "none" else f"{len(times)}/{n}"
        lines.append(f"| {label} | {size:g} | {det} | {med if kind != 'none' else '–'} | {wrong} | {fa} |")
        cfg.log(lines[-1])
    lines += [
        "",
        f"False alarms (DRIFT before the onset; the whole flight for the nominal row): {fa_events} in "
        f"{fa_time / 3600:.2f} h of live-configuration flight (tests/test_aiding_live.py runs 150 s of it and "
        "asserts none). A late fix is compared with the state the way the core fuses it (here as current: the "
        "old comparison at the time of validity saw the state's ≈ 1 m along-track lag and raised false DRIFTs), "
        "with dead zones for what the 50 ms lag alone can cause in manoeuvres, and the INS velocity σ in the "
        "CUSUM floored at the fix's velocity σ (0.1 m/s here: the 1 kHz filter's velocity error is ≈ its σ of "
        "0.03 m/s in RMS but has episodes of 0.10 m/s lasting seconds in turns, with or without delay "
        "compensation). Detection is slower than in the table above because the live GNSS is twice as noisy. "
        "A velocity-matched pull is seen only while the filter has not absorbed it (≈ 14 fixes at this velocity "
        "gain): 0.1 m/s gives an SNR ≈ 0.1·√14/0.14 ≈ 2.7 against the ≈ 5.5σ that 1e-3 false alarms per hour "
        "need, so it is not observable here; 0.3 m/s is at the edge.",
    ]


def bench_aiding(cfg: FdiBench, lines: list[str]) -> None:
    """GNSS/baro drift table (ins_hil.fdi.aiding) on closed-loop simulated flights."""
    cases = _aid_cases(("pull", 0.1, 0.3, 1.0), ("spoof", 0.1, 0.3, 1.0), ("jump", 10.0), ("baro", 0.1, 0.3, 1.0))
    n = cfg.aiding_trials
    lines += [
        "## GNSS / baro drift (ins_hil.fdi.aiding)",
        "",
        AID_BEGIN,
        f"Closed-loop NavCore + AidingMonitor (defaults, P_fa = 1e-3 /h, 20 s window), UAV flight {AID_T_END:.0f} s, "
        f"MEMS IMU 100 Hz, GNSS 5 Hz (σ 0.5 m NE / 1 m D / 0.05 m/s), baro 25 Hz (σ 0.3 m); fault at "
        f"t = {AID_T_FAULT:.0f} s; {n} seeds per row (`ins-hil bench-fdi --aiding-only --aiding-trials {n}`). "
        "Detected = first event of the expected sensor and mode (DRIFT; JUMP for the jump) after the onset; "
        "wrong = a DRIFT on the other sensor.",
        "",
        "| fault | size (m/s; m for jump) | detected | median / max time to detect (s) | wrong sensor |",
        "|---|---|---|---|---|",
    ]
    fa_events, fa_time = 0, 0.0
    for label, kind, size, sensor, mode in cases:
        times, wrong = [], 0
        for k in range(n):
            ev, _ = _aid_run(cfg.seed + 100 * k, kind, size)
            hit = [e for e in ev if e.sensor == sensor and e.mode == mode and not e.cleared and e.t >= AID_T_FAULT]
            other = "baro" if sensor == "gnss" else "gnss"
            wrong += any(e.sensor == other and e.mode == FaultMode.DRIFT and not e.cleared for e in ev)
            fa_events += sum(1 for e in ev if e.mode == FaultMode.DRIFT and not e.cleared and e.t < AID_T_FAULT)
            fa_time += AID_T_FAULT
            if hit:
                times.append(hit[0].t - AID_T_FAULT)
        med = f"{np.median(times):.1f} / {max(times):.1f}" if times else "–"
        lines.append(f"| {label} | {size:g} | {len(times)}/{n} | {med} | {wrong} |")
        cfg.log(lines[-1])
    lines += [
        "",
        f"False alarms (DRIFT before the onset, the first {AID_T_FAULT:.0f} s of every run): "
        f"{fa_events} in {fa_time / 3600:.2f} h of closed-loop flight. The test suite also runs one simulated "
        "hour of fixes against a truth-referenced state with zero DRIFT events (tests/test_fdi_aiding.py).",
        "",
        "Tests: GNSS position vs GNSS velocity (LS slope of Σ(Δp − v̄Δt) over the window, χ²₃), two-sided "
        "CUSUM of the horizontal INS innovations (threshold from Siegmund's ARL₀), baro − GNSS height slope "
        "(χ²₁); thresholds from P_fa per hour. Limits: a velocity-matched pull as small as the GNSS velocity "
        "noise (0.1 m/s = 2σ here) is absorbed by the filter and not detected; a pull ramped in through "
        "acceleration only is not benchmarked; a fast baro drift (1 m/s) drags the filter height so the "
        'GNSS is sometimes flagged as well ("wrong sensor"); the GNSS lever arm is ignored.',
    ]
    if cfg.aiding_live_trials > 0:
        bench_aiding_live(cfg, lines)
    lines += [
        AID_END,
        "",
    ]


def header(cfg: FdiBench) -> list[str]:
    """The report's title, machine and command lines."""
    return [
        "# FDI benchmark (generated by `ins-hil bench-fdi`)",
        "",
        f"Machine: {os.cpu_count()} CPUs ({cpu_model()}), Python {platform.python_version()}; {load_note()} (the"
        " detection times are in simulated time and do not depend on load).",
        f"Command: `ins-hil bench-fdi --rate {cfg.rate:g} --trials {cfg.trials} "
        f"--nominal-hours {cfg.nominal_hours:g} --p-fa {cfg.p_fa:g}`.",
        "",
    ]


def flight(duration: float, dt: float) -> TruthSeries:
    """The manoeuvring UAV flight (turns of period 20 s) of the failure-mode trials, ``duration`` s at ``dt``."""
    return generate(_profile(), duration, dt, LAT0, LON0, H0)


def targets(names: list[str], summ: dict, nom: dict, nav: dict, aided: dict, dt: float) -> list[str]:
    """The "Targets" table from the figures of bench_faults, bench_nominal, bench_nav and bench_aided."""
    tg = ["## Targets", "", "| target | result | met |", "|---|---|---|"]
    for name in names:
        st = summ.get((name, "gyro", FaultMode.STEP_BIAS, "10σ"))
        if st:
            ok = st[1] == 1.0 and max(st[2], default=math.inf) <= 20 * dt + 1e-9
            tg.append(
                f"| {name}: 10σ gyro step isolated within 20 samples | isolated {st[1]:.2f}, worst "
                f"{max(st[2], default=math.nan) / dt:.0f} samples | {'yes' if ok else 'NO'} |"
            )
        rp = summ.get((name, "gyro", FaultMode.RAMP, "1 °/s per min"))
        if rp:
            ok = rp[1] == 1.0 and max(rp[2], default=math.inf) <= 10.0
            tg.append(
                f"| {name}: 1 °/s per min gyro ramp isolated within 10 s | isolated {rp[1]:.2f}, worst "
                f"{max(rp[2], default=math.nan):.2f} s | {'yes' if ok else 'NO'} |"
            )
        fa = nom[name]
        tg.append(
            f"| {name}: zero false alarms in the nominal {fa[2]:.2f} h | {fa[0]} events "
            f"| {'yes' if fa[0] == 0 else 'NO'} |"
        )
        for kind, res in (("free inertial", nav), ("GNSS-aided", aided)):
            for (cn, label), (ra, rp2) in res.items():
                if cn == name:
                    ok = ra <= 1.5 and rp2 <= 1.5
                    tg.append(
                        f"| {name}: {kind} nav error after isolation ≤ 1.5× sensor absent ({label}) "
                        f"| attitude {ra:.2f}×, position {rp2:.2f}× | {'yes' if ok else 'NO'} |"
                    )
    tg.append("")
    return tg


def splice_aiding(text: str, section: str) -> str:
    """``text`` (a report) with its GNSS/baro section (between AID_BEGIN and AID_END) replaced by ``section``,
    or ``section`` appended when it has none."""
    if AID_BEGIN in text and AID_END in text:
        head = text[: text.index("## GNSS / baro drift")] if "## GNSS / baro drift" in text else text
        tail = text[text.index(AID_END) + len(AID_END) :].lstrip("\n")
        return head + section + "\n" + tail
    return text.rstrip("\n") + "\n\n" + section + "\n"
