"""Per-step cost of the Python core and the C reference core, side by side (``ins-hil bench-core``).

On one simulated UAV flight (MEMS IMU, 5 Hz GNSS): IMU step = mechanization + 15-state EKF predict, and
one GNSS position+velocity update, for the Python ``NavCore``, the C core through the cffi extension one
call per step (``CNavCore.step``/``fuse``, and the bare ``lib.cref_step`` call), and the C core running the
whole log in one call (``CNavCore.run``; GNSS updates batched in one call); the mechanization alone
(Python ``StrapdownNED.step``; C with the filter off); instructions per step / per update of the C core
from ``valgrind --tool=callgrind`` (``firmware_ref/build/double/ins_ref_bench``), stable on a noisy
machine. Timings are the minimum over ``repeat`` runs (the least disturbed by other processes) with the
median beside it.
"""

from __future__ import annotations

import datetime as _dt
import math
import re
import shutil
import statistics
import subprocess
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np

from ins_hil import machine
from ins_hil.machine import load_note

ROOT = Path(__file__).resolve().parents[2]


def _timeit(fn: Callable[[], tuple[float, int]], repeat: int) -> tuple[float, float]:
    """fn() -> (seconds, count); returns (min, median) seconds per count."""
    per = []
    for _ in range(repeat):
        sec, n = fn()
        per.append(sec / max(n, 1))
    return min(per), statistics.median(per)


def callgrind(steps: int, updates: int) -> dict[str, float] | str:
    """Instructions per call of the C functions, or a reason string if unavailable."""
    if shutil.which("valgrind") is None or shutil.which("callgrind_annotate") is None:
        return "valgrind/callgrind_annotate not installed (apt-get install valgrind)"
    fw = ROOT / "firmware_ref"
    r = subprocess.run(["make", "-s", "-C", str(fw), "build/double/ins_ref_bench"], capture_output=True, text=True)
    if r.returncode != 0:
        return f"make failed: {r.stderr.strip()[:300]}"
    out = fw / "build" / "callgrind.out"
    exe = fw / "build" / "double" / "ins_ref_bench"
    r = subprocess.run(
        ["valgrind", "--tool=callgrind", f"--callgrind-out-file={out}", str(exe), str(steps), str(updates)],
        capture_output=True,
        text=True,
    )
    if r.returncode != 0:
        return f"callgrind failed: {r.stderr.strip()[-300:]}"
    ann = subprocess.run(["callgrind_annotate", "--inclusive=yes", str(out)], capture_output=True, text=True).stdout
    res: dict[str, float] = {}
    for fn in ("ins_core_step", "ins_mech_step", "ins_ekf_predict_full", "ins_core_fuse_gnss"):
        m = re.search(r"^\s*([\d,]+)\s.*\b" + fn + r"\b", ann, re.MULTILINE)
        if m is None:
            return f"callgrind_annotate has no line for {fn}"
        ir = float(m.group(1).replace(",", ""))
        res[fn] = ir / (updates if fn == "ins_core_fuse_gnss" else steps)
    return res


def time_cores(
    duration: float, rate: float, repeat: int, log: Callable[[str], None]
) -> tuple[dict[str, tuple[float, float]], int, int]:
    """(rows, IMU steps, GNSS fixes): seconds per call (minimum, median over ``repeat`` runs) keyed
    ``<core>/step`` and ``<core>/gnss``; ``log`` receives one line per measured core."""
    from ins_hil import cref
    from ins_hil.core import NavCore
    from ins_hil.nav.mechanization import StrapdownNED, StrapdownState
    from ins_hil.sim.sensors import GnssModel, corrupt_imu, gnss_fixes, mems_accel, mems_gyro
    from ins_hil.sim.trajectory import generate, uav_profile

    dt = 1.0 / rate
    lat0, lon0, h0 = math.radians(50.45), math.radians(30.52), 180.0
    truth = generate(uav_profile(), duration, dt, lat0, lon0, h0)
    rng = np.random.default_rng(3)
    imu = corrupt_imu(truth, mems_gyro(rng), mems_accel(rng), seed=4)
    fixes = gnss_fixes(truth, GnssModel(rate=5.0), seed=5)
    samples = imu.samples()
    n = len(samples)
    init = StrapdownState(truth.q_nb[0].copy(), truth.vel_ned[0].copy(), lat0, lon0, h0, truth.t[0])
    # GNSS epochs as step indices (fixes valid at step ends)
    fix_at: dict[int, Any] = {}
    for f in fixes:
        k = round((f.t - truth.t[0]) / dt) - 1
        if 0 <= k < n:
            fix_at[k] = f
    rows: dict[str, tuple[float, float]] = {}

    def loop(core: Any) -> tuple[tuple[float, int], tuple[float, int]]:
        t_step = t_fuse = 0.0
        m = 0
        pc = time.perf_counter
        for k, s in enumerate(samples):
            t0 = pc()
            core.step(s)
            t1 = pc()
            t_step += t1 - t0
            f = fix_at.get(k)
            if f is not None:
                core.fuse(f)
                t_fuse += pc() - t1
                m += 1
        return (t_step, n), (t_fuse, m)

    def both(make: Callable[[], Any], name: str) -> None:
        st: list[float] = []
        fu: list[float] = []
        for _ in range(repeat):
            (a, na), (b, nb) = loop(make())
            st.append(a / na)
            fu.append(b / max(nb, 1))
        rows[f"{name}/step"] = (min(st), statistics.median(st))
        rows[f"{name}/gnss"] = (min(fu), statistics.median(fu))
        log(f"  {name:<28} step {1e6 * min(st):8.2f} µs   GNSS update {1e6 * min(fu):8.2f} µs")

    log(f"timing ({repeat} runs, minimum shown; {n} IMU steps, {len(fix_at)} GNSS fixes):")
    both(lambda: NavCore(init), "python")
    both(lambda: cref.CNavCore(init, dt=dt), "c_ext_step")

    # bare extension call per step (no NavState construction)
    c0 = cref.CNavCore(init, dt=dt)
    ffi, lib = c0._ffi, c0._lib_
    bufs = [(ffi.from_buffer("double[]", s.dtheta), ffi.from_buffer("double[]", s.dvel), s.t) for s in samples]

    def bare() -> tuple[float, int]:
        c = cref.CNavCore(init, dt=dt)
        core, step = c._core, lib.cref_step
        t0 = time.perf_counter()
        for a, b, t in bufs:
            step(core, a, b, t)
        return time.perf_counter() - t0, n

    rows["c_ext_bare/step"] = _timeit(bare, repeat)
    log(f"  {'c_ext_bare (lib.cref_step)':<28} step {1e6 * rows['c_ext_bare/step'][0]:8.2f} µs")

    def whole(filter_on: bool) -> Callable[[], tuple[float, int]]:
        def f() -> tuple[float, int]:
            c = cref.CNavCore(init, dt=dt, filter=filter_on)
            t0 = time.perf_counter()
            c.run(imu.dtheta, imu.dvel, imu.t, every=0)
            return time.perf_counter() - t0, n

        return f

    rows["c_one_call/step"] = _timeit(whole(True), repeat)
    rows["c_one_call_mech/step"] = _timeit(whole(False), repeat)
    ng = 2000

    def gnss_batch() -> tuple[float, int]:
        c = cref.CNavCore(init, dt=dt)
        c.run(imu.dtheta[:100], imu.dvel[:100], imu.t[:100], every=0)
        st = c.state()
        vel = np.ascontiguousarray(st.vel_ned)
        t0 = time.perf_counter()
        lib.cref_fuse_gnss_repeat(
            c._core, st.lat + 1e-7, st.lon, st.h + 0.3, ffi.from_buffer("double[]", vel), 1.0, 2.0, 0.1, ng
        )
        return time.perf_counter() - t0, ng

    rows["c_one_call/gnss"] = _timeit(gnss_batch, repeat)
    log(
        f"  {'c_one_call (CNavCore.run)':<28} step {1e6 * rows['c_one_call/step'][0]:8.2f} µs   "
        f"GNSS update {1e6 * rows['c_one_call/gnss'][0]:8.2f} µs   (mechanization only "
        f"{1e6 * rows['c_one_call_mech/step'][0]:.2f} µs)"
    )

    def py_mech() -> tuple[float, int]:
        ins = StrapdownNED(init.copy())
        t0 = time.perf_counter()
        for s in samples:
            ins.step(s.dtheta, s.dvel, s.dt)
        return time.perf_counter() - t0, n

    rows["python_mech/step"] = _timeit(py_mech, repeat)
    log(f"  {'python StrapdownNED.step':<28} step {1e6 * rows['python_mech/step'][0]:8.2f} µs")
    return rows, n, len(fix_at)


def accuracy(duration: float) -> list[str]:
    """Agreement of the C core with the Python (double) and of the float build with the double one."""
    from ins_hil import cref
    from ins_hil.core import NavCore
    from ins_hil.nav import earth
    from ins_hil.nav.mechanization import StrapdownNED, StrapdownState
    from ins_hil.nav.rotation import quat_angle_between
    from ins_hil.sim.sensors import GnssModel, baro_samples, corrupt_imu, gnss_fixes, mems_accel, mems_gyro
    from ins_hil.sim.trajectory import generate, uav_profile
    from ins_hil.types import BaroSample, GnssFix

    dt = 0.02
    lat0, lon0, h0 = math.radians(50.45), math.radians(30.52), 180.0
    truth = generate(uav_profile(), duration, dt, lat0, lon0, h0)
    rng = np.random.default_rng(3)
    imu = corrupt_imu(truth, mems_gyro(rng), mems_accel(rng), seed=4)
    samples = imu.samples()
    meas: list[GnssFix | BaroSample] = [
        *gnss_fixes(truth, GnssModel(rate=5.0), seed=5),
        *baro_samples(truth, rate=10.0, std=0.5, seed=6),
    ]
    meas.sort(key=lambda m: m.t)
    init = StrapdownState(truth.q_nb[0].copy(), truth.vel_ned[0].copy(), lat0, lon0, h0, truth.t[0])

    def rel(a: Any, b: Any) -> np.ndarray:
        return np.array(
            [
                float(np.max(np.abs(a.q_nb - b.q_nb))),
                float(np.max(np.abs(a.vel_ned - b.vel_ned)) / max(1.0, float(np.max(np.abs(a.vel_ned))))),
                max(
                    abs(a.lat - b.lat) / abs(a.lat),
                    abs(a.lon - b.lon) / abs(a.lon),
                    abs(a.h - b.h) / max(1.0, abs(a.h)),
                ),
            ]
        )

    def div(a: Any, b: Any) -> np.ndarray:
        dp = earth.ned_delta_small(b.lat - a.lat, b.lon - a.lon, b.h - a.h, a.lat, a.h)
        return np.array(
            [
                quat_angle_between(a.q_nb, b.q_nb),
                float(np.linalg.norm(a.vel_ned - b.vel_ned)),
                float(np.linalg.norm(dp)),
            ]
        )

    # free inertial: Python StrapdownNED vs C double vs C float
    ins = StrapdownNED(init.copy())
    cd = cref.CNavCore(init, dt=dt, filter=False)
    cf = cref.CNavCore(init, dt=dt, filter=False, precision="float")
    w_mech = np.zeros(3)
    w_free = np.zeros(3)
    for k, s in enumerate(samples):
        a = ins.step(s.dtheta, s.dvel, s.dt)
        b = cd.step(s)
        c = cf.step(s)
        if k % 25 == 24:
            w_mech = np.maximum(w_mech, rel(a, b))
            w_free = np.maximum(w_free, div(b, c))
    # with GNSS + baro: Python NavCore vs C double vs C float
    py = NavCore(init)
    cd = cref.CNavCore(init, dt=dt)
    cf = cref.CNavCore(init, dt=dt, precision="float")
    w_ekf = np.zeros(3)
    w_aid = np.zeros(3)
    j = 0
    for k, s in enumerate(samples):
        py.step(s)
        cd.step(s)
        cf.step(s)
        while j < len(meas) and meas[j].t <= s.t + 1e-9:
            for core in (py, cd, cf):
                core.fuse(meas[j])
            j += 1
        if k % 25 == 24:
            sa, sb, sc = py.state(), cd.state(), cf.state()
            w_ekf = np.maximum(w_ekf, rel(sa, sb))
            w_aid = np.maximum(w_aid, div(sb, sc))
    return [
        f"- mechanization, C double vs Python `StrapdownNED` (free inertial): max |Δq| {w_mech[0]:.1e}, "
        f"max relative velocity {w_mech[1]:.1e}, position {w_mech[2]:.1e}",
        f"- full core with GNSS + baro, C double vs Python `NavCore`: max |Δq| {w_ekf[0]:.1e}, "
        f"relative velocity {w_ekf[1]:.1e}, position {w_ekf[2]:.1e}",
        f"- float build vs double, free inertial: attitude {w_free[0]:.1e} rad, velocity {w_free[1]:.2g} m/s, "
        f"position {w_free[2]:.3g} m",
        f"- float build vs double, with GNSS + baro: attitude {w_aid[0]:.1e} rad, velocity {w_aid[1]:.1e} m/s, "
        f"position {w_aid[2]:.1e} m",
    ]


def accuracy_md(lines: list[str], duration: float) -> str:
    if not lines:
        return ""
    head = [
        "",
        "## Accuracy: the C core held against the Python",
        "",
        f"Same input stream ({duration:g} s UAV flight at 50 Hz, MEMS IMU errors, 5 Hz GNSS, 10 Hz baro; maxima"
        " over the run, sampled every 0.5 s). Relative = |Δ| / max(1, |value|) for velocity and height,"
        " |Δ| / |value| for latitude/longitude; |Δq| on the unit quaternion.",
        "",
    ]
    tail = [
        "",
        "The double build reproduces the Python mechanization bit for bit (same formulas in the same order,"
        " same libm, `-ffp-contract=off`); with the filter the differences are round-off of the covariance"
        " products (numpy's BLAS order vs the C's sparse products). The float build's free-inertial"
        " divergence grows with the uncompensated MEMS errors; with GNSS it stays at round-off of the"
        " measurement corrections. `tests/test_firmware.py` bounds all four.",
        "",
    ]
    return "\n".join(head + lines + tail)


def report(
    rows: dict[str, tuple[float, float]],
    cg: dict[str, float] | str,
    duration: float,
    rate: float,
    repeat: int,
    n: int,
    m: int,
) -> str:
    """The Markdown report (docs/ref_core.md) of :func:`time_cores` and :func:`callgrind`."""
    mach = machine.info()
    py_s, py_g = rows["python/step"][0], rows["python/gnss"][0]

    def us(x: float) -> str:
        return f"{1e6 * x:.2f}"

    def ratio(a: float, b: float) -> str:
        return f"{a / b:.0f}×" if b > 0 else "n/a"

    lines = [
        "# C reference core vs Python core: speed",
        "",
        "Generated by `ins-hil bench-core"
        + (f" --duration {duration:g}" if duration != 60.0 else "")
        + (f" --rate {rate:g}" if rate != 100.0 else "")
        + "` (do not edit by hand).",
        "",
        f"Machine: {mach['cpu']}, `nproc` = {mach['nproc']}, {mach['os']}, Python {mach['python']}, {mach['cc']}.",
        f"Load average at the end of the run: {mach['load']} ({load_note()}); each wall-clock figure is the"
        f" minimum of {repeat} runs (median in brackets). The callgrind instruction counts do not depend on load.",
        f"Date: {_dt.datetime.now(_dt.UTC).strftime('%Y-%m-%d %H:%M UTC')}.",
        "",
        f"Workload: simulated UAV flight, {duration:g} s at {rate:g} Hz ({n} IMU steps), MEMS IMU errors,"
        f" {m} GNSS fixes (position + velocity) fused at their step. IMU step = strapdown mechanization +"
        " 15-state EKF covariance predict (both cores: second-order Φ, the same model).",
        "",
        "| core | IMU step [µs] | Python / this | GNSS update [µs] | Python / this |",
        "|---|---:|---:|---:|---:|",
    ]

    def row(label: str, ks: str, kg: str | None) -> None:
        s, sm = rows[ks]
        cells = [label, f"{us(s)} ({us(sm)})", ratio(py_s, s)]
        if kg is not None:
            g, gm = rows[kg]
            cells += [f"{us(g)} ({us(gm)})", ratio(py_g, g)]
        else:
            cells += ["—", "—"]
        lines.append("| " + " | ".join(cells) + " |")

    row("Python `NavCore` (`step`, `fuse`)", "python/step", "python/gnss")
    row("C via extension, one call per step (`CNavCore.step`, `fuse`)", "c_ext_step/step", "c_ext_step/gnss")
    row("C via extension, bare `lib.cref_step` call", "c_ext_bare/step", None)
    row("C, whole log in one call (`CNavCore.run`; GNSS batch)", "c_one_call/step", "c_one_call/gnss")
    lines += [
        "",
        "Mechanization alone: Python `StrapdownNED.step` "
        f"{us(rows['python_mech/step'][0])} µs, C (filter off, one call) {us(rows['c_one_call_mech/step'][0])} µs"
        f" ({ratio(rows['python_mech/step'][0], rows['c_one_call_mech/step'][0])}).",
        "",
    ]
    if isinstance(cg, dict):
        lines += [
            "Instructions per call (valgrind --tool=callgrind, `firmware_ref/build/double/ins_ref_bench 2000 200`,"
            " -O3, double; on an x86-64 host with AVX2 the covariance products and the scalar update run their AVX2"
            " copies, chosen at load time (`INS_HOT`, firmware_ref/src/ins_internal.h): the counts depend on the"
            " host's CPU, the numbers do not):",
            "",
            "| function | instructions per call |",
            "|---|---:|",
            f"| `ins_core_step` (IMU step: bias correction + mechanization + predict) | {cg['ins_core_step']:.0f} |",
            f"| `ins_mech_step` (mechanization) | {cg['ins_mech_step']:.0f} |",
            f"| `ins_ekf_predict_full` (15-state covariance predict) | {cg['ins_ekf_predict_full']:.0f} |",
            f"| `ins_core_fuse_gnss` (6 gated scalar Joseph updates + 2 feedbacks) | {cg['ins_core_fuse_gnss']:.0f} |",
            "",
        ]
    else:
        lines += [f"Instruction counts: {cg}.", ""]
    c_step = rows["c_one_call/step"][0]
    c_ext = rows["c_ext_step/step"][0]
    lines += [
        "Targets (issue 7):",
        "",
        f"- C core ≤ 5 µs per IMU step: {us(c_step)} µs in one call — {'met' if c_step <= 5e-6 else 'NOT met'}.",
        f"- C ≥ 50× the Python per-step speed: {ratio(py_s, c_step)} (whole log in one call), "
        f"{ratio(py_s, c_ext)} (through the extension one step at a time) — "
        f"{'met' if py_s / c_step >= 50 else 'NOT met'} for the C core itself.",
        f"- Python ≤ 150 µs per step: {us(py_s)} µs — {'met' if py_s <= 150e-6 else 'NOT met'}.",
        "",
        "The per-step extension figure is dominated by the Python side of the call (argument conversion and"
        " building the `NavState`), not by the C work; running the log in one call removes it.",
        "",
    ]
    return "\n".join(lines)
