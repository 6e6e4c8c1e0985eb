"""`ins-hil replay`: run the navigation core offline and report its accuracy.

SOURCE is one of
* a simulated scenario name (``static``, ``example32``, ``example32_gnss``, ``coning``, ``uav``;
  see :mod:`ins_hil.sim.scenarios`),
* ``drive`` or the directory of the real drive (``../shared/data/gnss_imu_drive_0708``):
  the README's outage protocol with and without ground-vehicle aids plus a run with GNSS
  all the time,
* a recorded gateway log (``*.ihlog``), handed to ``ins_hil.runtime.replay.replay_log``,
* ``sim``: the ``[sim]`` flight of ``--config`` (default ``configs/default.toml``) through its pipeline,
  offline, over ``--runs`` seeds: bias, RMS, NEES, 3σ coverage (``ins_hil.runtime.replay.sim_cli``).

Writes ``metrics.json`` and PNG plots to ``--out`` and prints a summary table. ``--docs``
runs the full report (real drive, Example 3.2, UAV mission, Monte-Carlo NEES/NIS, hot-path
timing) and regenerates ``docs/accuracy.md`` with its plots in ``docs/accuracy/``.
"""

from __future__ import annotations

import argparse
import dataclasses
import importlib
import json
import math
import os
import platform
import sys
import time
from pathlib import Path
from typing import Any

import numpy as np

from ins_hil.core import NavConfig, NavCore
from ins_hil.datasets import drive0708
from ins_hil.datasets.evaluate import Series, run_drive, run_truth
from ins_hil.fusion.ekf import FilterConfig
from ins_hil.machine import cpu_model, load_note
from ins_hil.sim import scenarios

NAME = "replay"
HELP = "run the core offline on a simulated scenario, the real drive or a gateway log; write metrics and plots"

REPO = Path(__file__).resolve().parents[2]
DEFAULT_DRIVE = REPO.parent / "shared" / "data" / "gnss_imu_drive_0708"
DEG = math.pi / 180.0
VALIDATION_SHIFTS = (17.5, 22.5, 27.5)  # s: validation outages inside the protocol's GNSS-present intervals


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("source", nargs="?", default="drive",
                   help="scenario name, 'drive', a drive directory, 'sim' or a *.ihlog")  # fmt: skip
    p.add_argument("--out", type=Path, default=Path("replay_out"), help="output directory (default ./replay_out)")
    p.add_argument("--seed", type=int, default=0, help="random seed of a simulated scenario")
    p.add_argument("--duration", type=float, default=None, help="scenario length in s (default: the scenario's)")
    p.add_argument("--runs", type=int, default=0, help="Monte-Carlo runs for the NEES/NIS check (simulations)")
    p.add_argument("--no-aids", action="store_true", help="real drive: skip the run with ZUPT/NHC")
    p.add_argument("--no-plots", action="store_true", help="do not write PNG plots")
    p.add_argument("--docs", action="store_true", help="full report: regenerate docs/accuracy.md and its plots")
    p.add_argument("--quiet", action="store_true", help="no progress output")
    p.add_argument(
        "--config", type=Path, default=None, help="source 'sim': the config whose [sim] flight is flown (default.toml)"
    )


# ---------------------------------------------------------------------------------------------- helpers
class _Progress:
    """A minimal progress line on stderr (long runs)."""

    def __init__(self, label: str, quiet: bool) -> None:
        self.label = label
        self.quiet = quiet
        self.t0 = time.perf_counter()
        self.last = -1

    def __call__(self, k: int, n: int) -> None:
        if self.quiet:
            return
        pct = int(100 * k / max(n, 1))
        if pct // 5 != self.last // 5 or k == n:
            self.last = pct
            bar = "#" * (pct // 5) + "." * (20 - pct // 5)
            el = time.perf_counter() - self.t0
            sys.stderr.write(f"\r{self.label:<28} [{bar}] {pct:3d}% {el:6.1f} s")
            if k == n:
                sys.stderr.write("\n")
            sys.stderr.flush()


def drive_config(aids: bool, cov_every: int = 1) -> NavConfig:
    """The NavConfig used on the real drive (car MEMS IMU; gyro noise chosen on held-out validation outages)."""
    f = FilterConfig(
        cov_every=cov_every,
        # sensor noise (session 6): the README's noise densities (gyro 0.0038 °/s/√Hz, accelerometer 70 µg/√Hz)
        # plus the vibration terms: the roof IMU's pitch gyro shakes by 3–10 °/s on rough road, and the angle
        # (velocity change) over a 10 ms interval is uncertain by about the rate (specific-force) change across
        # it. They replace the fixed 0.2 °/√s and 0.02 m/s²/√Hz that sessions 1–5 chose (30–50× the README).
        # Chosen on the held-out validation outages (drive0708.cv_outage_windows, shifts 17.5/22.5/27.5 s) and
        # the start-up outage, never the protocol's windows (docs/accuracy.md, session 6): gyro gain
        # 0.2 / 0.3 / 0.4 / 0.5 / 0.6 → validation 1.07 / 0.90 / 0.89 / 0.92 / 0.96 m (old VRW); accelerometer gain
        # 0.5 / 0.6 / 0.7 → 0.91/4.85, 0.90/4.58, 0.91/4.39 m (RMS / max; 0.88/5.29 without it)
        gyro_arw=0.0038 * DEG,
        gyro_vib_gain=0.4,
        accel_vrw=70e-6 * 9.80665,
        accel_vib_gain=0.6,
        # session 3: the 21-state model (gyro and accelerometer scale factors, FilterConfig defaults), screened on
        # the same validation windows: 1.11 / 5.80 → 1.08 / 5.64 m, better on each of the three shifts
        scale_factors=True,
        # session 4: a 1 % prior on the forward accelerometer scale factor (y/z keep 0.2 %): with 0.2 % the x scale
        # factor left its prior by 5 σ (≈ 1 % at the end of the drive, still rising); with 1 % it settles at
        # ≈ 3 % (σ 0.3 %). Validation windows: 1.08 / 5.64 → 1.02 / 5.48 m, RMS lower on each of the three shifts
        init_accel_sf=(0.01, 2e-3, 2e-3),
        gyro_bias_sigma=0.003,
        gyro_bias_tau=300.0,
        accel_bias_sigma=0.02,
        accel_bias_tau=300.0,
    )
    return NavConfig(
        filter=f,
        gnss_lever_arm_b=drive0708.LEVER_GNSS - drive0708.LEVER_IMU,
        gnss_min_std=(0.03, 0.06, 0.15),  # RTK σ floors; the RTK velocity is noisier than its reported σ
        gnss_vel_delay=0.13,  # the .pos velocity lags its position by 130–135 ms (docs/accuracy.md)
        gate_gnss=10.0,
        align="static",
        # session 5: level on the whole rest before the drive (37 s; at most 30 s), not its last 2 s: the gyro
        # bias from a 30 s mean (the idling engine shakes the pitch gyro by 1.4 °/s RMS); validation 1.02 → 0.97 m
        align_time=30.0,
        nhc=aids,
        zupt=aids,
    )


def _rms(a: np.ndarray, axis: int = 0) -> np.ndarray:
    return np.sqrt(np.mean(a**2, axis=axis))


def scenario_metrics(ser: Series, t_from: float) -> dict[str, Any]:
    a = ser.arrays()
    m = a["t"] >= t_from
    if not m.any():
        return {}
    att = np.degrees(a["att_err"][m])
    return {
        "steady_from_s": t_from,
        "att_rms_deg": _rms(att).round(4).tolist(),
        "att_max_deg": np.abs(att).max(0).round(4).tolist(),
        "vel_rms_mps": _rms(a["vel_err"][m]).round(4).tolist(),
        "vel_max_mps": np.abs(a["vel_err"][m]).max(0).round(4).tolist(),
        "pos_rms_m": _rms(a["pos_err"][m]).round(3).tolist(),
        "pos_max_m": np.abs(a["pos_err"][m]).max(0).round(3).tolist(),
        "nees_mean_9dof": float(np.mean(a["nees"][m])) if len(a["nees"]) else math.nan,
    }


def run_scenario(name: str, seed: int, duration: float | None, quiet: bool) -> tuple[dict[str, Any], Series, NavCore]:
    sc = scenarios.build(name, seed=seed, duration=duration)
    core = NavCore(sc.initial, sc.config)
    core.keep_nis = True
    t0 = time.perf_counter()
    ser = run_truth(core, sc.imu, sc.meas, sc.truth, record_every=10, progress=_Progress(f"{name} seed {seed}", quiet))
    el = time.perf_counter() - t0
    span = float(sc.truth.t[-1] - sc.truth.t[0])
    m = scenario_metrics(ser, min(float(sc.info.get("steady_from", 0.25 * span)), 0.5 * span))
    m.update(
        {
            "scenario": name,
            "seed": seed,
            "duration_s": span,
            "realtime_factor": span / el,
            "aligned": core.state().aligned,
            "counters": {k: {"accepted": v.accepted, "rejected": v.rejected} for k, v in core.stats.items()},
        }
    )
    nis = [(k, n, d) for (_, k, n, d) in core.nis_log]
    m["nis_mean_over_dof"] = {
        k: float(np.mean([n for kk, n, _ in nis if kk == k]) / next(d for kk, _, d in nis if kk == k))
        for k in sorted({k for k, _, _ in nis})
    }
    return m, ser, core


def monte_carlo(name: str, runs: int, duration: float | None, quiet: bool) -> dict[str, Any]:
    """Average NEES (9 dof) over ``runs`` seeds vs the two-sided 95 % χ² bounds; mean NIS/dof per sensor."""
    from scipy.stats import chi2

    nees = []
    nis: dict[str, list[float]] = {}
    yaw_e2: list[float] = []
    yaw_s2: list[float] = []
    t_from = 0.0
    for seed in range(runs):
        m, ser, core = run_scenario(name, 1000 + seed, duration, quiet)
        a = ser.arrays()
        t_from = m.get("steady_from_s", 0.0)
        sel = a["t"] >= t_from
        nees.append(a["nees"][sel])
        yaw_e2.append(float(np.mean(a["att_err"][sel, 2] ** 2)))  # yaw error vs the filter's own yaw σ
        yaw_s2.append(float(np.mean(a["std_att"][sel, 2] ** 2)))
        for _, k, n, d in core.nis_log:
            nis.setdefault(k, []).append(n / d)
    L = min(len(x) for x in nees)
    avg = np.mean([x[:L] for x in nees], axis=0)  # ANEES(t)
    lo, hi = chi2.ppf([0.025, 0.975], 9 * runs) / runs
    inside = float(np.mean((avg >= lo) & (avg <= hi)))
    return {
        "scenario": name,
        "runs": runs,
        "anees_mean": float(np.mean(avg)),
        "anees_bounds_95": [float(lo), float(hi)],
        "fraction_inside": inside,
        "nis_mean_over_dof": {k: float(np.mean(v)) for k, v in nis.items()},
        "from_s": t_from,
        "yaw_err_rms_deg": math.degrees(math.sqrt(float(np.mean(yaw_e2)))),
        "yaw_std_rms_deg": math.degrees(math.sqrt(float(np.mean(yaw_s2)))),
    }


def benchmark_hot_path(n: int = 20000) -> dict[str, float]:
    """µs per IMU step: mechanization alone, + 15-state predict (every step / every 5), full NavCore.step."""
    from ins_hil.nav.mechanization import StrapdownNED, StrapdownState
    from ins_hil.types import ImuSample

    st = StrapdownState(np.array([1.0, 0, 0, 0]), np.array([10.0, 0, 0]), 0.7, 0.5, 100.0)
    dth = np.array([1e-4, -2e-4, 3e-4])
    dv = np.array([0.01, 0.002, -0.0981])
    out: dict[str, float] = {}
    m = StrapdownNED(st.copy())
    t0 = time.perf_counter()
    for _ in range(n):
        m.step(dth, dv, 0.01)
    out["mechanization_us"] = (time.perf_counter() - t0) / n * 1e6
    for every in (1, 5):
        for label, cfg in (
            (
                f"core_step_cov_every_{every}_us",
                NavConfig(filter=FilterConfig(cov_every=every), delay_compensation=False),
            ),
            (f"core_step_cov_every_{every}_with_delay_history_us", NavConfig(filter=FilterConfig(cov_every=every))),
        ):
            core = NavCore(st.copy(), cfg)
            samples = [ImuSample(t=0.01 * (k + 1), dt=0.01, dtheta=dth, dvel=dv) for k in range(n)]
            t0 = time.perf_counter()
            for s in samples:
                core.step(s)
            out[label] = (time.perf_counter() - t0) / n * 1e6
    kf = NavCore(st.copy(), NavConfig()).kf
    C = np.eye(3)
    z3 = np.zeros(3)
    t0 = time.perf_counter()
    for _ in range(n):
        kf.predict(0.01, C, dv / 0.01, z3, z3, z3, z3, 0.7, 100.0)
    out["predict_15_alone_us"] = (time.perf_counter() - t0) / n * 1e6
    return out


# ---------------------------------------------------------------------------------------------- plots
def plot_series(
    ser: Series, title: str, path_prefix: Path, outages: list[tuple[float, float]] | None = None
) -> list[Path]:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    a = ser.arrays()
    if len(a["t"]) == 0:
        return []
    t = a["t"] - a["t"][0]
    t_off = a["t"][0]
    files = []
    # trajectory
    fig, ax = plt.subplots(figsize=(6, 5))
    ax.plot(a["ref_ned"][:, 1], a["ref_ned"][:, 0], "k-", lw=1, label="reference")
    ax.plot(a["ned"][:, 1], a["ned"][:, 0], "r-", lw=0.8, label="filter")
    ax.set_xlabel("East (m)")
    ax.set_ylabel("North (m)")
    ax.axis("equal")
    ax.legend()
    ax.set_title(f"{title}: trajectory")
    f = path_prefix.with_name(path_prefix.name + "_trajectory.png")
    fig.tight_layout()
    fig.savefig(f, dpi=90)
    plt.close(fig)
    files.append(f)
    # errors with 3σ
    fig, axs = plt.subplots(3, 1, figsize=(9, 8), sharex=True)
    for ax, key, sk, unit, scale in (
        (axs[0], "pos_err", "std_pos", "m", 1.0),
        (axs[1], "vel_err", "std_vel", "m/s", 1.0),
        (axs[2], "att_err", "std_att", "deg", 1 / DEG),
    ):
        for i, (c, lab) in enumerate(zip("rgb", "NED" if key != "att_err" else ("roll", "pitch", "yaw"))):
            ax.plot(t, a[key][:, i] * scale, c, lw=0.7, label=lab)
            ax.plot(t, 3 * a[sk][:, i] * scale, c + ":", lw=0.6)
            ax.plot(t, -3 * a[sk][:, i] * scale, c + ":", lw=0.6)
        if outages:
            for o0, o1 in outages:
                ax.axvspan(o0 - t_off, o1 - t_off, color="0.9")
        ax.set_ylabel(f"{key.split('_')[0]} error ({unit})")
        ax.legend(loc="upper right", fontsize=7, ncol=3)
    axs[-1].set_xlabel("time (s)")
    axs[0].set_title(f"{title}: errors and ±3σ (dotted)")
    f = path_prefix.with_name(path_prefix.name + "_errors.png")
    fig.tight_layout()
    fig.savefig(f, dpi=90)
    plt.close(fig)
    files.append(f)
    # biases and test ratios
    fig, axs = plt.subplots(3, 1, figsize=(9, 7), sharex=True)
    axs[0].plot(t, a["gyro_bias"] / DEG)
    axs[0].set_ylabel("gyro bias (°/s)")
    axs[1].plot(t, a["accel_bias"])
    axs[1].set_ylabel("accel bias (m/s²)")
    kinds = sorted({k for r in ser.ratios for k in r})
    for k in kinds:
        axs[2].semilogy(t, [max(r.get(k, np.nan), 1e-4) for r in ser.ratios], lw=0.7, label=k)
    axs[2].axhline(1.0, color="k", lw=0.8)
    axs[2].set_ylabel("test ratio")
    axs[2].legend(fontsize=7, ncol=3)
    axs[-1].set_xlabel("time (s)")
    axs[0].set_title(f"{title}: estimated biases and innovation test ratios (reject > 1)")
    f = path_prefix.with_name(path_prefix.name + "_biases_ratios.png")
    fig.tight_layout()
    fig.savefig(f, dpi=90)
    plt.close(fig)
    files.append(f)
    return files


# ---------------------------------------------------------------------------------------------- drive
def replay_drive(
    directory: Path, aids_variants: list[bool], quiet: bool, cov_every_trade: bool = False
) -> tuple[dict[str, Any], dict[str, Series]]:
    if not (directory / "imu_1934.csv").is_file():
        raise SystemExit(f"ins-hil replay: {directory} does not hold the drive (imu_1934.csv missing)")
    dr = drive0708.load_drive(directory)
    outages = drive0708.outage_windows(dr.pos.t)
    rtk = [f.fix_type == 6 for f in dr.gnss]
    fixed = {f.t for f, ok in zip(dr.gnss, rtk, strict=True) if ok}  # the scored (RTK-fixed) epochs
    duration = float(dr.imu[-1].t - dr.imu[0].t)
    res: dict[str, Any] = {"imu_samples": len(dr.imu), "gnss_epochs": len(dr.gnss), "outages": len(outages),
                           "csv_bad_lines": dr.imu_log.bad_lines, "duration_s": duration}  # fmt: skip
    series: dict[str, Series] = {}
    for aids in aids_variants:
        tag = "aids" if aids else "no_aids"
        for label, outs in ((f"outages_{tag}", outages), (f"gnss_{tag}", [])):
            t0 = time.perf_counter()
            m, ser, _ = run_drive(dr.imu, dr.gnss, rtk, drive_config(aids), outs, _Progress(f"drive {label}", quiet))
            m["realtime_factor"] = duration / (time.perf_counter() - t0)
            res[label] = m
            series[label] = ser
    if cov_every_trade:
        # cost/accuracy trade of propagating P every 5 IMU steps (with aids, outage protocol)
        t0 = time.perf_counter()
        m, _, _ = run_drive(dr.imu, dr.gnss, rtk, drive_config(True, cov_every=5), outages,
                            _Progress("drive outages cov_every=5", quiet))  # fmt: skip
        m["realtime_factor"] = duration / (time.perf_counter() - t0)
        res["outages_aids_cov5"] = m
    if cov_every_trade:
        # held-out validation: the protocol's outages shifted into its GNSS-present intervals (how settings are chosen)
        for aids in (True, False):
            sq = n = 0.0
            mx = 0.0
            for shift in VALIDATION_SHIFTS:
                outs_v = drive0708.cv_outage_windows(dr.pos.t, shift)
                m, _, _ = run_drive(dr.imu, dr.gnss, rtk, drive_config(aids), outs_v,
                                    _Progress(f"drive validation +{shift:g} s", quiet))  # fmt: skip
                sq += m["outage_h_rms_m"] ** 2 * m["outage_epochs"]
                n += m["outage_epochs"]
                mx = max(mx, m["outage_h_max_m"])
            res[f"validation_{'aids' if aids else 'no_aids'}"] = {
                "outage_h_rms_m": math.sqrt(sq / n),
                "outage_h_max_m": mx,
            }
        # held-out start-up outage (a fresh alignment, like the protocol's first outage; never its epochs)
        cfg = drive_config(True)
        imu_s, gnss_s, outs_s = drive0708.startup_validation(dr, yaw_speed=cfg.gnss_yaw_speed)
        m, _, _ = run_drive(imu_s, gnss_s, [f.fix_type == 6 for f in gnss_s], cfg, outs_s,
                            _Progress("drive start-up validation", quiet))  # fmt: skip
        res["startup_aids"] = {k: m[k] for k in ("outage_h_rms_m", "outage_h_max_m", "outage_epochs")}
        # the core must have entered navigation at the fix that opens the outage (0.25 s before it)
        res["startup_aids"]["t_aligned_s"] = m["t_aligned_s"] + gnss_s[0].t - dr.pos.t[0]
        res["startup_window_s"] = [outs_s[0][0] - dr.pos.t[0], outs_s[0][1] - dr.pos.t[0]]
        res["startup_restart_s"] = drive0708.STARTUP_RESTART
        # what-if (session 7): the protocol with a synthetic barometer made from the RTK height (uses the truth:
        # a sensor study, never a protocol figure), two noise levels × two seeds
        res["whatif_baro"] = []
        for name, white, drift in drive0708.WHATIF_BAROS:
            for seed in (0, 1):
                cfg = dataclasses.replace(drive_config(True), baro_std=white)
                aux = drive0708.synthetic_baro(dr.pos, white, drift, seed)
                m, ser, _ = run_drive(dr.imu, dr.gnss, rtk, cfg, outages,
                                      _Progress(f"drive what-if {name} baro seed {seed}", quiet), aux=aux)  # fmt: skip
                res["whatif_baro"].append({"baro": name, "white_m": white, "drift_m_sqrt_s": drift, "seed": seed,
                                           **{k: m[k] for k in ("outage_h_rms_m", "outage_h_max_m", "outage_v_rms_m")},
                                           "per_window": per_window(ser, outages, fixed)})  # fmt: skip
    res["outage_windows_s"] = [(a - dr.pos.t[0], b - dr.pos.t[0]) for a, b in outages]
    if "outages_aids" in series:
        res["per_window_aids"] = per_window(series["outages_aids"], outages, fixed)
    return res, series


def per_window(ser: Series, outages: list[tuple[float, float]], scored: set[float]) -> list[dict[str, float]]:
    """Horizontal RMS / max (m) of the antenna error inside each outage, over the epochs whose time is in
    ``scored`` (the RTK-fixed ones, as :func:`run_drive` scores them); NaN for an outage with none."""
    t = np.array(ser.t)
    e = np.array(ser.pos_err)
    ok = np.array([x in scored for x in ser.t], dtype=bool)
    rows = []
    for a, b in outages:
        i = (t >= a) & (t < b) & ok
        h = np.hypot(e[i, 0], e[i, 1])
        rows.append({"rms_m": float(np.sqrt(np.mean(h**2))) if len(h) else math.nan,
                     "max_m": float(h.max()) if len(h) else math.nan})  # fmt: skip
    return rows


SESSION6_ROWS = (
    (
        "base (session 5)",
        "0.97 / 5.47",
        "0.54/2.02, 1.04/4.83, 1.21/5.47",
        "1.90 / 3.55",
    ),
    (
        "gyro term on the deviation from a 0.2 s mean, ARW 0.2 °/√s kept, gain 0.2 / 0.4 / 0.8",
        "0.99/5.31, 1.05/5.54, 1.17/6.50",
        "",
        "1.87/3.49, 1.82/3.35, 1.72/3.13",
    ),
    (
        "same, ARW 0.1 °/√s, gain 0.3 / 0.4 / 0.5 / 0.8",
        "0.96/5.30, 0.96/5.38, 0.99/5.47, 1.08/5.91",
        "",
        "1.74/3.22, 1.71/3.14, 1.68/3.08, 1.62/2.97",
    ),
    (
        "ARW 0.1 °/√s alone",
        "1.23 / 6.37",
        "1.07/6.11, 1.15/5.96, 1.44/6.37",
        "1.80 / 3.36",
    ),
    (
        "same term, README ARW, gain 0.4 / 0.5",
        "0.93/5.33, 0.94/5.40",
        "0.74/2.74, 0.85/4.87, 1.16/5.33 (0.4)",
        "1.64/2.99, 1.61/2.95",
    ),
    (
        "**sample-to-sample change, README ARW, gain 0.2 / 0.3 / 0.4 / 0.5 / 0.6**",
        "1.07/5.69, 0.90/5.13, **0.89/5.20**, 0.92/5.27, 0.96/5.33",
        "0.61/2.83, 0.87/4.49, 1.12/5.20 (0.4)",
        "1.68/3.07, 1.65/3.00, **1.62/2.93**, 1.59/2.87, 1.56/2.82",
    ),
    (
        "gain 0.4, average over 3 s / 0.3 s instead of 1 s",
        "0.89/5.30, 0.92/5.10",
        "",
        "1.64/2.97, 1.60/2.89",
    ),
    (
        "**implemented (gyro 0.4), E[Δω²] in the snapshots**",
        "**0.88 / 5.29**",
        "0.61/2.87, 0.87/4.50, 1.10/5.29",
        "**1.63 / 2.95**",
    ),
    (
        "+ gyro-bias σ 1e-3 / 1.5e-3 / 6e-3 rad/s (instead of 3e-3)",
        "0.88/5.87, 0.88/5.41, 0.98/5.65",
        "",
        "1.61/2.90, 1.61/2.91, 1.63/2.99",
    ),
    (
        "+ accelerometer term on top of 0.02 m/s²/√Hz, gain 0.2 / 0.4 / 0.8 / 1.2 (gyro term on)",
        "0.89/5.24, 0.89/5.13, 0.98/4.78, 1.20/6.24",
        "",
        "1.62/2.93, 1.62/2.94, 1.64/3.00, 1.65/3.04",
    ),
    (
        "README accelerometer density, no accelerometer term (gyro term on)",
        "1.16 / 6.67",
        "0.98/4.71, 1.19/5.00, 1.29/6.67",
        "1.58 / 2.83",
    ),
    (
        "**README density + accelerometer term, gain 0.4 / 0.5 / 0.6 / 0.7 / 0.8 / 1.0**",
        "0.94/5.29, 0.91/4.85, **0.90/4.58**, 0.91/4.39, 0.94/4.36, 1.05/4.37",
        "0.70/2.70, 0.95/4.41, 1.02/4.58 (0.6)",
        "1.59/2.86, 1.59/2.87, **1.59/2.89**, 1.60/2.90, 1.60/2.92, 1.61/2.95",
    ),
    (
        "**implemented (gyro 0.4 + accelerometer 0.6, adopted)**",
        "**0.90 / 4.45**",
        "0.70/2.70, 0.95/4.41, 1.03/4.45",
        "**1.59 / 2.88**",
    ),
    (
        "gyro gain 0.3 / 0.5 with accelerometer 0.6",
        "0.96/4.65, 0.91/4.65",
        "",
        "1.62/2.95, 1.56/2.83",
    ),
    (
        "session-5 base, increments with the nominal 10 ms interval, the stamps kept",
        "1.03 / 6.29",
        "0.59/2.20, 1.06/4.97, 1.31/6.29",
        "1.91 / 3.62",
    ),
)

SESSION6_NOTE = """### Session 6: sensor noise from the measured vibration

**What the second outage is.** The protocol's 85–100 s outage (the worst, 9.9 m in session 5) was compared with a
run that keeps GNSS all the time. The outage run's pitch differs from the GNSS-aided one by 0.14° at 86 s, 0.29°
at 88 s and about 0.5° from 92 s on. Most of the difference appears in the first 3 s. In that time the GNSS-aided
run moves its own pitch by about 0.3°: the fixes after 85 s show that the pitch at 85 s was off. The pitch gyro
shakes hardest in those seconds (85.0–85.5 s: 10 °/s standard deviation, peaks of 28 °/s). On this drive it
shakes by 3–10 °/s on rough road and by 1 °/s at a stop. The rate is known only at 100 Hz samples, so the angle
over each 10 ms interval is uncertain by about the change of the rate across it. Sessions 1–5 covered that with a
fixed ARW of 0.2 °/√s, 50× the README's 0.0038 °/s/√Hz, the same on smooth and on rough road.

**The model** (`FilterConfig.gyro_vib_gain`, `accel_vib_gain`, `vib_tau`; default off): per body axis the
attitude (velocity) block gets (gain · dt)² · E[Δx²] per step, on top of the white noise, with Δx the
sample-to-sample change of the compensated rate (specific force), E[·] an exponential average over 1 s, turned to
NED (not isotropic). It is in the delayed-fusion snapshots (a rollback that fuses nothing leaves the core
bit-identical, tested), QR/Cholesky take the root of the full block (same estimates as Joseph, tested), UD and the
C core refuse it by name. Cost with both terms: the 21-state predict 18.3 → 26.5 µs (best of 15 × 2000 calls,
this machine). The drive uses the README's noise densities (gyro 0.0038 °/s/√Hz, accelerometer 70 µg/√Hz) plus
gyro gain 0.4 and accelerometer gain 0.6, instead of 0.2 °/√s and 0.02 m/s²/√Hz. The sample-to-sample
change also holds the sensor's white noise (for independent samples it adds 2 N²/dt to E[Δx²]: the white noise
once more, times 2·gain², 0.32× for the gyro, 0.72× for the accelerometer) and the small jumps of the estimated
biases at each feedback; the gains were chosen with both in.

Chosen on the validation windows and the start-up outage (temporary patch code for the screening, then the
implementation; per shift RMS / max in m):

{table}

The accelerometer term trades validation RMS (0.88 → 0.90 m) for the worst case (5.29 → 4.45 m; better on the
27.5 s shift in both, the other two shifts trade RMS for worst case) and improves the start-up outage: adopted,
because the worst case is the target that is missed. The protocol was run twice: once when the gyro term alone was
the choice (1.27 / 8.51 m), and once after the accelerometer term was added (the table at the top). The second is
worse on the protocol in both figures; the choice was not changed back, because that would choose on the protocol.

**Effect elsewhere** (the report's tables, same command): with GNSS present the error is 0.018 / 0.011 m prior /
post (was 0.017 / 0.009 m). Without ground-vehicle aids the protocol is unchanged (3.14 / 12.72 m, was
3.12 / 12.72 m), but the validation windows without aids got worse (4.65 / 31.29 m, was 4.25 / 26.87 m). The choice
was made with the aids, as in sessions 1–5. A UAV configuration should choose its own gains on its own data.
The per-outage figures above show where the protocol gained: outages 3–11 are 0.21–1.01 m RMS (0.36–0.90 m
before). The first is worse: 2.18 / 3.77 m, was 1.88 / 3.42 m.

**What is left.** The second outage stays the worst (9.19 m). The filter's own horizontal σ at its end is 6.1 m
(N and E combined), and the error there is 1.5 times that; at the ends of the other ten outages the error is
0.06–0.85 of the filter's σ. A non-causal diagnostic (`scripts/diagnostics/outage_oracle.py 2`; it uses the
outage's RTK truth) asks how large a change of the state at 85 s would have kept the outage within 6 m. It
corrects four things: the pitch, the gyro-y bias, the accelerometer-x bias and the forward velocity. The smallest
such change, measured in the filter's covariance at 85 s, is 1.83 σ: pitch −5.0 mrad (σ 4.3), gyro-y bias
+1.05 mrad/s (σ 0.98), accelerometer-x bias −0.8 cm/s² (σ 0.85), forward velocity +0.05 m/s (σ 0.04). For ≤ 3 m it
is 3.6 σ. The error depends almost on one combination of the four, so 1.83 σ is a one-sided tail of about 3 %:
the start state alone does not explain the outage, and the rest builds up inside it (the filter's in-outage noise,
with the vibration term, is part of its 6.1 m). For a worst case of 6 m over 11 outages the filter's σ at the end
of a 15-s outage would have to be about 3 m (6 m a 2-σ event); at this outage it is 6.1 m, because the pitch and
the gyro-y bias are weakly determined after 30 s of GNSS, and during the outage nothing measures either. With this
IMU that needs a measurement of pitch or forward speed (an odometer, wheel speeds). The vertical NHC ties the pitch
to the vertical velocity, which is free without a height reference: a barometer would help.
"""


SESSION5_NOTE = """### Session 5: the start-up (levelling on the rest, correlated tilt prior, yaw σ from the receiver)

**Where the protocol's error was.** Per outage (session-4 settings): 3.30/5.33, **4.08/10.31**, 1.10/3.54, then
0.35–1.03 m RMS and ≤ 2.2 m worst in the other eight. The first two outages come while the filter is still young:
the car stands for 37 s, starts at 37.5 s, the core takes its yaw from the GNSS course at 39.75 s, and the first
outage begins 0.25 s later. The validation windows (from 57.5 s on) never test that, so a **start-up outage**
was added to the selection set (held out from the protocol, not from the choice): the replay restarts during the
stop at 200.8–209.5 s and the outage runs from 0.25 s after the in-motion yaw alignment to 220 s (where the
protocol's next outage begins; its epochs are never scored). Its rest is only 8.5 s, so it cannot test a longer
levelling window (the 2.46 → 2.45 m row). Three things were weak at a fresh alignment:

* the levelling used only the last 2 s (`align_time`) of the 37 s rest; the idling engine shakes the pitch gyro
  by 1.4 °/s RMS (y; x 0.27, z 0.09 °/s), so a 2 s mean leaves a gyro-bias error of order 0.1 °/s. The drive now
  levels on up to 30 s of rest (`align_time = 30`);
* the tilt after levelling was given an independent 2° σ, but levelling makes the computed horizontal specific
  force zero: the tilt holds the horizontal accelerometer error (book §4.1.1). `ErrorStateEKF.level_tilt` sets
  μ_NE = A x + ε with A from δv̇ = [f×]μ − C δb_a − C diag(f) δs_a (`NavConfig.level_tilt_prior`, default on;
  tested against the tilt a biased static accelerometer really leaves, also after a pivot between the levelling
  and the course fix). Alone it changes the start-up outage little (RMS 2.46 → 2.44 m, worst 4.68 → 4.88 m);
  in the static simulation (levelling + magnetometer), where the magnetometer can then separate tilt from
  accelerometer bias, the attitude RMS fell from [0.87, 0.68, 2.43]° to [0.21, 0.15, 0.57]° (table below);
* the in-motion yaw σ used the fusion floor of the GNSS velocity σ (0.15 m/s, there for the velocity's lag)
  and added its terms: 3° + 2·0.15/1.16 = 18° at the drive's first fix at ≥ 1 m/s. The course accuracy is the
  receiver's (0.06 m/s; `gnss_yaw_vel_floor`, default 0), and the two independent 1-σ terms (course − heading,
  course noise) add in quadrature: √(3² + 2.96²) = 4.2°.

| variant (ZUPT + NHC) | validation h RMS / max (m) | per shift 17.5 / 22.5 / 27.5 s | start-up outage h RMS / max (m) |
|---|---|---|---|
| base (session 4) | 1.02 / 5.48 | 0.49/2.02, 1.13/4.80, 1.28/5.48 | 2.46 / 4.68 |
| tilt prior correlated with the accelerometer error | 1.02 / 5.47 | 0.49/2.02, 1.12/4.83, 1.28/5.47 | 2.44 / 4.88 |
| levelling on up to 30 s of rest | 0.97 / 5.47 | 0.54/2.02, 1.04/4.82, 1.21/5.47 | 2.45 / 4.68 |
| both | 0.97 / 5.47 | 0.54/2.02, 1.04/4.83, 1.21/5.47 | 2.39 / 4.75 |
| **both + yaw σ from the receiver σ_v** | **0.97 / 5.47** | 0.54/2.02, 1.04/4.83, 1.21/5.47 | **2.00 / 3.80** |
| **+ 1·σ_v/V in quadrature (adopted)** | **0.97 / 5.47** | 0.54/2.02, 1.04/4.83, 1.20/5.47 | **1.89 / 3.53** |
| both + receiver σ_v, base yaw σ 1° instead of 3° (a tuned constant: not adopted) | | | 1.95 / 3.67 |
| GNSS velocity fusion floor 0.06 m/s, not 0.15 (changes every fusion; session 2: worse) | | | 2.01 / 3.84 |
| yaw-axis gyro ARW 0.15 / 0.1 / 0.05 °/√s (temp. code) | 0.97/5.44, 0.98/5.41, 0.98/5.39 | 0.55/2.00, 1.05/5.03, … | |
| session-4 base with coning/sculling off; with end-of-interval increments | 1.02 / 5.49; 1.08 / 5.88 | | |
| IMU clock: constant dt from a line through the ticks (not causal) | 1.01 / 6.42 | 0.56/2.12, … | 2.02 / 3.72 |

The rows were measured with the tilt prior built on the attitude at the entry into navigation; the review then
kept the levelled attitude instead (turned with the yaw reset: the tilt is fixed in NED, the accelerometer errors
in the body), which is what the tables at the top of this report use: validation 0.97 / 5.47 m, start-up outage
1.90 / 3.55 m (1.89 / 3.53 m before).

Simulated check (an ad-hoc script, not in the repo; no real data): a car at rest 20 s with a MEMS IMU (20 mg
accelerometer, 0.2 °/s gyro turn-on biases), then driving off into a 15 s outage from 0.25 s after the yaw
alignment, 12 seeds: horizontal error at the end of the outage 4.65 → 4.45 m RMS with the correlated tilt prior, →
4.14 m with the yaw σ in quadrature.

The csv ticks are a perfect 10.000 ms clock (a line through all 54,860 ticks leaves −0.53 … +1.47 ms) plus a
stamp jitter (intervals of 8/9/10/11 ms): replacing the jittered intervals by the clock is worse on both
validation sets (table), so the samples seem to be taken at the stamped times; the intervals are kept.

**What is left: the second outage.** Its error is along-track and grows as t³ (velocity error −0.05, −0.17, −0.45,
−0.74, −1.06, −1.64 m/s at 0, 3, … 14.75 s): a pitch that drifts at ≈ 1.4 mrad/s, i.e. a pitch-gyro bias ≈ 0.08 °/s
off after only 30 s of GNSS with one turn. The gyro means at the four stops are stable (y: −67, −71, −47, −43 m°/s),
but the filter's in-motion y-bias estimate at the outage starts ranges from −17 to −147 m°/s: the loose bias
model (chosen on the validation windows; tighter is worse, sessions 1–4) lets it wander with the speed-dependent
vibration (pitch-gyro high-frequency content 1.0 °/s at rest, 2.6 °/s at 3–7 m/s, 4.9 °/s above 11 m/s). Only a
sensor that sees the forward speed (odometer) or pitch directly would hold it through the outage.
"""


SESSION4_NOTE = """### Session 4: NHC reference point, accelerometer scale factor, tilt (validation windows only)

Base: the session-3 settings with one bug fixed (below): validation 1.08 / 5.64 m (per shift 0.58/1.86,
1.14/5.42, 1.36/5.64: unchanged by the fix). Each variant alone, then combined (bold: adopted); per shift RMS / max (m).

| variant | validation h RMS / max (m) | per shift 17.5 / 22.5 / 27.5 s |
|---|---|---|
| base (session 3 + rollback fix) | 1.08 / 5.64 | 0.58/1.86, 1.14/5.42, 1.36/5.64 |
| NHC point 1 m behind the IMU, ω low-passed at 2 Hz (`nhc_omega_lp_hz`) | 4.16 / 25.79 | 3.12/11.73, 5.11/25.79, … |
| same, 0.25 / 0.5 / 1.5 m behind | 1.51 / 10.60, 2.31 / 15.74, 6.10 / 35.47 | 0.93/3.85, 1.77/10.60, 1.68/5.84 |
| same, 0.5 m ahead | 2.17 / 10.59 | 1.69/7.13, 2.45/10.59, 2.30/7.43 |
| lateral row 0.73 m below (roll centre), LP 2 Hz (temporary code) | 1.08 / 5.77 | 0.57/1.86, 1.16/4.82, 1.35/5.77 |
| vertical row 1.43 m ahead (mid-wheelbase), LP 2 Hz (temporary code) | 1.10 / 5.87 | 0.68/2.43, 1.11/5.87, 1.39/5.30 |
| both rows | 1.10 / 5.42 | 0.67/2.46, 1.13/5.27, 1.37/5.42 |
| accel. SF prior 1 % / 3 % on all axes (was 0.2 %) | 1.05 / 5.60, 1.09 / 5.78 | 0.51/2.15, 1.17/4.73, 1.30/5.60 |
| **accelerometer SF prior 1 % on x only (`init_accel_sf`)** | **1.02 / 5.48** | 0.49/2.02, 1.13/4.80, 1.28/5.48 |
| same, 2 % / 4 % on x only | 1.03 / 5.47, 1.04 / 5.46 | 0.50/2.05, 1.15/4.72, 1.27/5.47 (2 %) |
| accelerometer SF process noise σ 1 % (τ 3600 s, instead of 0.2 %) | 1.10 / 6.00 | 0.64/2.12, 1.20/4.86, 1.34/6.00 |
| gyro-y bias σ 1e-3 rad/s (x, z stay 3e-3) (temporary code) | 1.23 / 7.04 | 0.88/3.68, 1.29/6.51, 1.46/7.04 |
| gyro-y bias σ 6e-3 rad/s (temporary code) | 1.08 / 6.27 | 0.60/2.25, 1.16/6.00, 1.35/6.27 |
| boresight state, pitch only (random constant, 1°) (temporary code) | 1.13 / 5.83 | 0.63/2.08, 1.20/4.73, 1.40/5.83 |
| fixed NHC boresight pitch −5 / +5 mrad (temporary code) | 1.20 / 6.49, 1.22 / 7.92 | 0.77/2.56, 1.22/5.70, 1.49/6.49 |
| x SF prior 1 % + lateral row 0.73 m below | 1.03 / 5.61 | 0.48/1.85, 1.17/4.54, 1.27/5.61 |
| x SF prior 1 % + both rows | 1.03 / 5.20 | 0.57/2.56, 1.11/4.58, 1.27/5.20 |
| x SF 1 % + suspension pitch 0.002 / 0.004 rad per m/s² | 0.98 / 5.32, 0.97 / 5.79 | 0.51/2.20, 1.13/5.32, 1.18/4.85 |

**Bug (fixed, tested):** the delayed-fusion snapshots did not hold the ZUPT rest detector's averaged rate and
specific force (also used for the suspension-pitch a_x): every rollback (at every GNSS epoch, for the 0.13 s
velocity lag) fed the replayed IMU samples into the averages a second time. The snapshot now holds them; a
rollback that fuses nothing leaves the core bit-identical (`tests/test_fusion_aiding.py`). Effect on the drive:
none measurable (validation 1.08 / 5.64 m before and after).

**Where the NHC holds (a calibration on the GNSS-present run, no outage data).** A run with GNSS all the time and
no ground aids, body-frame IMU velocity regressed on the 2 Hz low-passed rates and the speed (speed > 3 m/s):
the lateral velocity does not depend on the yaw rate (coefficient 0.000 m: the IMU is above the rear axle, the
lateral constraint already holds at the IMU) but on the roll rate (0.73 m: the roll centre is 0.73 m below the
roof IMU); the vertical velocity follows the pitch rate with 1.43 m (the zero-vertical-velocity point is about
mid-wheelbase, 1.43 m ahead; correlation 0.45). This is why any single reference point behind or ahead made
things much worse, with the raw rate (session 3) and with the low-passed one: the lateral row wants the IMU's
own x. The per-row points (lateral 0.73 m below, vertical 1.43 m ahead) are physical, but on the validation
windows they trade shift 17.5 s against the other two (0.49/2.02 → 0.57/2.56 m with the SF prior): not adopted,
the code was removed; `nhc_omega_lp_hz` is kept (an NHC at another point must not use the vibrating rate;
tested). The same regression gives a body vertical velocity of −0.0049 × speed (a 4.9 mrad pitch between the body
x axis and the velocity), but as a fixed boresight it is worse with either sign: it is the GNSS-only filter's
pitch error, not a mounting error.

**The forward scale factor.** At the validation window starts (base) the x accelerometer scale factor rose
monotonically from 0.3e-3 to 10.9e-3 over the drive with σ 1.7–2.0e-3: 5 σ outside its 0.2 % prior, still
rising. With a 1 % prior on x only it settles at 29–30e-3 (σ 3.3e-3) from 330 s on (the parking lot), i.e. the
filter wants a ≈ 3 % forward scale factor (plausible for a MEMS accelerometer, or a forward specific-force
error proportional to a_x of that size); y/z stay < 2.5e-3, and loosening them as well is worse (1 % on all
axes: 1.05 / 5.60 m). The x prior lowers the validation RMS on each of the three shifts (0.58 → 0.49,
1.14 → 1.13, 1.36 → 1.28 m) and the worst case of two (5.42 → 4.80, 5.64 → 5.48 m; shift 17.5 s: 1.86 → 2.02 m):
adopted. It does not explain the +1 m/s along-track error while accelerating 6 → 12 m/s (a 15 % effect). With the
x prior, the session-3 suspension pitch again trades the shifts (0.002: the 27.5 s shift 1.28/5.48 → 1.18/4.85 m,
the other two worse in the worst case): not adopted.

**Tilt.** Pitch σ at the window starts is 3–5.4 mrad and the gyro-y bias σ 0.9–1.0e-3 rad/s (estimate −3.3 …
+0.3e-3): the pitch is weakly determined, and 4 mrad of pitch is the 0.04 m/s² forward error of session 3.
Tightening the gyro-y bias model (1e-3) or loosening it (6e-3) is worse: 3e-3 stays the optimum. The vertical NHC
is applied in the body frame, which is the vehicle frame after the fixed mounting rotation (as intended); the
screened variants of it are in the session-3 table.

Cost: `NavCore.step` unchanged within the noise (default config 101–115 µs on `main` and 103–115 µs on this
branch, `time.process_time`, 20 000 steps, best of 3, loaded machine); the drive run's CPU time is unchanged
(≈ 16–19 s per 549 s run). Protocol, run once after the choice (table at the top): 1.74 / 10.36 → 1.73 / 10.31 m
with ZUPT + NHC, 4.10 / 22.97 m without (unchanged): the protocol target (≤ 1.5 / ≤ 6 m) is still missed.
This report was generated under the idle scheduler (`chrt -i 0`, another job measured latency at the same
time): its wall-clock columns (replay speed, hot path) are upper bounds, e.g. the 4.9× of the no-aids row is
the time the job waited for the CPU, not its cost (the drive run's CPU time is ≈ 18 s, 30× real time).
"""


SESSION3_NOTE = """### Session 3: where the validation error comes from, and the modelling changes screened

**Where the error comes from** (validation windows only, shifts 17.5 / 22.5 / 27.5 s, 30 windows; the end-of-window
error split along / across the RTK track): the error is **along-track** in every large window (the six worst,
3–5.8 m, are 2.9–5.8 m along-track and ≤ 0.5 m across), in straight windows (turn < 11°) as much as in the 90–170°
turns, where the error stays below 1.6 m. Heading (yaw) is not what limits the drive: the NHC holds the
cross-track error; the along-track speed error grows at a constant 0.04–0.08 m/s² inside a window (velocity error
−0.56 m/s after 14 s at constant speed; +1.0 m/s while accelerating from 6 to 12 m/s), i.e. a forward specific-force
error (tilt ↔ accelerometer-bias split, suspension pitch, scale factor), not a gyro error.

Screened on the validation windows (ZUPT + NHC, session-2 settings as the base; per-shift RMS / max in m):

| variant | validation h RMS / max (m) | per shift 17.5 / 22.5 / 27.5 s |
|---|---|---|
| base (session 2) | 1.11 / 5.80 | 0.62/1.86, 1.16/5.80, 1.41/5.69 |
| **21 states: gyro + accelerometer scale factors (FilterConfig defaults), adopted** | **1.08 / 5.64** | 0.59/1.86, 1.14/5.41, 1.36/5.64 |
| boresight states (`mount_states`), random constant / random walk 1e-4 rad/√s | 1.17 / 5.87, 1.18 / 6.10 | 0.67/2.10, 1.21/5.24, 1.49/5.87 |
| NHC reference point 1 m behind / ahead of the IMU (`nhc_lever_b`) | 4.23 / 26.33, 4.00 / 18.39 | (the raw ω × l carries the vibration) |
| vertical NHC off / vertical NHC σ 0.3 m/s | 3.37 / 25.34, 1.10 / 6.32 | 4.00/21.55 …; 0.78/3.10, 1.21/6.32, 1.26/4.47 |
| gyro g-sensitivity, 9 states (`gyro_gsens`), +40 % CPU | 1.05 / 5.72 | 0.81/3.62, 1.02/5.48, 1.27/5.72 |
| same with the scale factors, +55 % CPU | 1.02 / 5.68 | 0.79/3.65, 1.01/5.19, 1.23/5.68 |
| accelerometer bias τ 30 s / τ 60 s σ 0.05 m/s² (instead of 300 s, 0.02) | 1.24 / 7.87, 1.57 / 12.21 | |
| causal first-order low-pass of the IMU rates, 10 Hz (temporary code, removed) | 1.16 / 5.73 | 0.66/1.90, 1.13/5.03, 1.52/5.73 |
| NHC off above 0.3 rad/s averaged rate (temporary code, removed) | 1.18 / 7.40 | 0.76/2.50, 1.29/7.40, 1.40/5.56 |
| suspension pitch `nhc_pitch_per_accel` +0.004 / +0.008 / −0.004 rad per m/s² | 1.00 / 6.20, 0.98 / 6.41, 1.31 / 7.53 | 0.56/2.39, 1.17/6.20, 1.15/4.50 (+0.004) |
| scale factors + suspension pitch 0.004 | 0.99 / 6.00 | 0.56/2.36, 1.16/6.00, 1.13/4.52 |
| scale factors + suspension pitch 0.002 | 1.02 / 5.73 | 0.56/2.00, 1.14/5.73, 1.24/4.84 |
| scale factors + vertical NHC σ 0.05 m/s (instead of 0.1) | 1.31 / 8.52 | 0.73/3.72, 1.45/6.44, 1.59/8.52 |
| scale factors + gyro ARW 0.15 °/√s (instead of 0.2) | 1.08 / 5.75 | 0.70/2.69, 1.10/5.63, 1.35/5.75 |

Reading: the only change that improves each of the three shifts (RMS and worst case) is the 21-state model, and
only by 3 %; it is adopted (physically motivated, issue bullet "optional scale-factor states"; cost: +16 % CPU,
15.8 → 18.4 s of `time.process_time` per 549 s drive run, 30× real time). The
suspension-pitch term (the body pitches nose-up by k·a_x on the suspension when the car accelerates, so the
velocity is not along the body x axis; the plain vertical NHC turns that into a pitch error and a gravity leak
along the track) has the physical sign (−0.004 is clearly worse, +0.004/+0.008 lower the RMS by 10 %, the 27.5 s
shift by 20–30 %), but it raises the worst case of the 22.5 s shift (the window at 467.5 s, 6 → 12 m/s
acceleration, gets worse, not better): not adopted — a vehicle-specific constant that helps some windows and
hurts the worst one is the overfitting the protocol warns about. The g-sensitivity states estimate a synthetic G
(tests) but on the drive they trade one shift against another at +40 % CPU: not adopted. A gyro ARW of 0.2 °/√s is
still the validation optimum with the scale factors (0.15 °/√s: 1.08 / 5.75 m). Negative result: the along-track
error mechanism is identified (forward specific-force error in straight windows), but no causal model screened
here removes it; an odometer (wheel speed) would observe it directly, this data set has none. Protocol, run once
after the choice (table at the top); before (session 2): 1.76 / 10.31 m with ZUPT + NHC, 4.10 / 22.97 m without;
after: 1.74 / 10.36 m and 4.10 / 22.97 m, i.e. unchanged: the protocol target (≤ 1.5 / ≤ 6 m) is still missed.

"""  # noqa: E501 (markdown table rows)

CHOICE_NOTE = """### Session 2: time alignment (a modelling error found, fixed everywhere)

The gyro error model ~26× looser than the README's noise density (session 1) pointed to a systematic error.
Cross-correlations against the RTK positions (not the outage errors) found three timing errors:

* **The upstream linear tick → GPST map is wrong by a drifting 0–130 ms.** It stretches the csv ticks onto
  [tag start, tag start + last tag tick], i.e. assumes the first csv line arrived at the tag start. The time
  tags give every line's arrival (tag record = tick, bytes of the logged stream reached; the stream had CRLF
  line ends, the csv has LF: the last offset exceeds the file size by exactly the 54,860 lines): the first line
  arrived 115 ms after the tag start and the IMU's ms clock runs at the tag clock's rate (13 ppm, 7 ms over
  the drive), so the linear map's error runs from −123 ms at the start to +10 ms at the end. Now
  (`drive0708.load_drive(time_map="tags")`, default) every csv tick is mapped with the tag clock offset taken
  causally from the first 10 s of lines (lower envelope of arrival − tick).
* **The IMU latency is 0.24 s, not 0.125 s, after that map**: gyro yaw rate integrated between GNSS epochs
  against the course of the RTK position chords (p[k+1] − p[k−1]) gives +240 / +242.5 ms in the two halves
  of the drive (with the linear map the best lag drifts over the drive; tests/test_dataset.py checks both).
* **The RTKLIB `.pos` velocity lags its own position by 130–135 ms** (every quarter of the drive; RMS of
  velocity − position-chord velocity 0.16 m/s at lag 0, 0.05 m/s at 130 ms). The cross-correlation of the
  gyro with the *velocity* course (+82 ms) and of the forward specific force with the velocity derivative
  (+140 ms) are biased by this lag, which is why they disagree with the position-based 240 ms.
  `NavConfig.gnss_vel_delay = 0.13` fuses the velocity separately at its own time of validity (delayed
  fusion, the same rollback as a delayed GNSS fix).

Validation (held-out shifted outages, `drive0708.cv_outage_windows`, shifts 17.5 / 22.5 / 27.5 s, ZUPT + NHC,
session-1 noise settings), horizontal RMS / max (m):

| change | validation h RMS / max (m) |
|---|---|
| session 1: linear map, offset −0.125 s | 1.68 / 10.91 |
| tag map, offset −0.125 / −0.10 / −0.075 s | 2.18 / 11.65, 2.48 / 13.51, 2.83 / 15.29 |
| tag map, offset −0.15 / −0.175 / −0.20 / −0.225 s | 1.89 / 9.89, 1.65 / 8.64, 1.45 / 7.57, 1.38 / 6.91 |
| **tag map, offset −0.24 s (the cross-correlation value)** | **1.37 / 7.49** |
| tag map, offset −0.25 s | 1.39 / 7.86 |
| tag map −0.24 s, **+ GNSS velocity at its own time (0.13 s earlier)**, adopted as a modelling fix | **1.39 / 7.17** |
| same + GNSS velocity σ floor 0.05 m/s (instead of 0.15), not adopted | 1.38 / 8.06 |
| tag map, gyro −0.085 s and accelerometer 55 ms later (velocity-based lags), not adopted | 2.72 / 12.79 |
| tag map −0.24 s, README-like gyro model (ARW 0.03 °/√s, bias σ 1e-3 rad/s), not adopted | 3.04 / 16.65 |
| tag map −0.24 s + velocity delay, gyro ARW 0.07 °/√s (instead of 0.1), not adopted | 1.60 / 9.50 |
| same, gyro-bias σ 1e-3 rad/s (instead of 3e-3), not adopted | 1.87 / 9.19 |
| same, gyro ARW 0.15 °/√s: **diverges** (GNSS-present prior error 7.6 m); the linear map diverges too | 25.40 / 162.3 |
| same, accelerometer VRW 0.05 m/s/√s: diverges on the 22.5 s shift | 10.01 / 72.2 |

**A ZUPT bug** (found while checking why a looser gyro model diverged): rest was detected on |f| − g, which a
car pulling away at 1 m/s² changes by only 0.05 m/s² (second order), so the ZUPT kept clamping the velocity for
up to ~1 s after a start; inside an outage that left metres of error and, with a looser gyro model, the GNSS was
then rejected after the outage (divergence: the 162 m row above). Rest is now tested on the NED specific force
(horizontal components included; `tests/test_fusion_aiding.py`). Validation after this fix (tag map −0.24 s,
velocity delay 0.13 s):

| gyro ARW (°/√s), gyro-bias σ 3e-3 rad/s, NHC σ 0.1 m/s | validation h RMS / max (m) |
|---|---|
| 0.07 | 1.58 / 9.52 |
| 0.1 (session 1's choice) | 1.29 / 7.07 |
| 0.15 | 1.12 / 6.05 |
| **0.2 (chosen)** | **1.11 / 5.80** |
| 0.3 | 1.23 / 6.20 |

The optimum of the latency sweep on the validation windows is the cross-correlation value, which supports the
fix being physical. The looser gyro model is still needed after the timing fix (a README-like gyro model
doubles the validation error) and, after the ZUPT fix, the validation optimum moved to an even looser ARW
(0.15–0.2 °/√s, flat): the remaining gyro error is not a timing artefact: vibration-induced
gyro errors of the car MEMS IMU (session 1's reading) remain the best explanation; not proven.

Honest reading (protocol run once, after the choice; table at the top): with ZUPT + NHC the protocol went from
2.13 / 10.99 m (session 1) to the figures above, without aids from 5.06 / 23.08 m; GNSS-present prior/post from
0.041 / 0.026 m. The validation windows meet the target (1.11 / 5.80 m), the protocol's RMS and worst case do
not: 11 outages are few and one or two windows dominate the worst case, so the gap between the two sets is
within what the windows' spread shows (per-shift validation RMS 0.62–1.41 m). Cost: the separate GNSS-velocity
update rolls the filter back 0.13 s at every epoch, ~40 % more CPU per drive run (≈ 17 s of CPU time for the
548 s drive, ≈ 32× real time, measured with `time.process_time`; the wall-clock factor in the table was taken
while other jobs shared the CPUs).

### Session 1: how the noise settings were chosen (without the protocol's outage truth)

Every drive setting was chosen on the held-out validation outages; the protocol was run once, after the
choice, to report. Session-1 figures (linear tick map):

| drive setting (ZUPT + NHC) | validation h RMS / max (m) |
|---|---|
| former: gyro ARW 0.03 °/√s, gyro-bias σ 2e-4 rad/s (τ 300 s), NHC σ 0.1 m/s | 4.46 / 28.5 |
| gyro-bias σ 1e-3 rad/s | 2.09 / 21.6 |
| gyro-bias σ 3e-3, ARW 0.1 °/√s, NHC σ 0.05 | 1.79 / 12.8 |
| **chosen: gyro-bias σ 3e-3 rad/s, ARW 0.1 °/√s, NHC σ 0.1 m/s** | **1.68 / 10.9** |

Screened in session 1 and not adopted: IMU → vehicle boresight states (`FilterConfig.mount_states`), the NHC
reference point 0.65 m below the IMU, the 21-state scale factors, faster accelerometer-bias models, ZUPT σ
0.05 m/s. Session-1 protocol result: 2.13 / 10.99 m with aids, 5.06 / 23.08 m without.
"""


EX32_NOTE = """**Example 3.2 yaw (session 2 check).** The steady-state yaw error of `example32_gnss`
(0.29° RMS on seed 0) misses the issue's < 0.1°.
The filter's own steady-state yaw σ with the book's sensors (gyro 3 arcmin/s and
accelerometer 1e-2 m/s² per 20 Hz sample, magnetometer σ_m = 0.0524 ≈ 3°) is the figure above, ≈ 0.18°: the
target is not reachable with these sensors, by the filter's own covariance. The error is consistent with that σ
over the Monte-Carlo runs (seed 0 is an unlucky draw; the ratio above is slightly > 1, the filter ≈ 15 %
optimistic in yaw, not a bug-sized inconsistency). Checked for a systematic cause: the mechanization on the
exact circle increments (20 Hz, roll oscillation) drifts < 2e-5° in 100 s, so the yaw error is estimation error,
not a mechanization/truth mismatch. Yaw observability here is the 1.26 m/s² centripetal acceleration seen
through the GNSS velocity, plus the 3° magnetometer (without it the
filter's yaw σ is 0.25°, measured on seed 0).
"""


# ---------------------------------------------------------------------------------------------- main
def _print_table(rows: list[tuple[str, str, str, str]]) -> None:
    w = [max(len(r[i]) for r in rows) for i in range(4)]
    for r in rows:
        print("  ".join(c.ljust(w[i]) for i, c in enumerate(r)))


def _fmt(x: Any, nd: int = 3) -> str:
    if isinstance(x, float):
        return f"{x:.{nd}f}"
    if isinstance(x, list):
        return "[" + ", ".join(_fmt(v, nd) for v in x) + "]"
    return str(x)


def _runtime_replay() -> Any:
    """The runtime helper's gateway-log replayer (``ins_hil.runtime.replay``), imported on demand."""
    return importlib.import_module("ins_hil.runtime.replay")


def run(args: argparse.Namespace) -> int:
    src = str(args.source)
    if src.endswith(".ihlog"):
        try:
            mod = _runtime_replay()
        except ImportError:
            print("ins-hil replay: gateway-log replay needs ins_hil.runtime.replay (not installed)", file=sys.stderr)
            return 2
        return int(mod.replay_log(Path(src), args) or 0)
    if src == "sim":  # the [sim] flight of a config through its pipeline, over --runs seeds from --seed
        return int(_runtime_replay().sim_cli(args))
    if args.docs:
        return full_report(args)
    args.out.mkdir(parents=True, exist_ok=True)
    if src in scenarios.NAMES:
        m, ser, _ = run_scenario(src, args.seed, args.duration, args.quiet)
        out: dict[str, Any] = {"scenario": m}
        if args.runs > 0:
            out["monte_carlo"] = monte_carlo(src, args.runs, args.duration, args.quiet)
        if not args.no_plots:
            out["plots"] = [str(p) for p in plot_series(ser, src, args.out / src)]
        rows = [("quantity", "N/roll", "E/pitch", "D/yaw")]
        for k in ("att_rms_deg", "att_max_deg", "vel_rms_mps", "pos_rms_m", "pos_max_m"):
            if k in m:
                rows.append((k, _fmt(m[k][0], 4), _fmt(m[k][1], 4), _fmt(m[k][2], 4)))
        _print_table(rows)
        print(f"realtime factor {m['realtime_factor']:.1f}x, NEES mean (9 dof) {m['nees_mean_9dof']:.2f}")
        if "monte_carlo" in out:
            mc = out["monte_carlo"]
            lo, hi = mc["anees_bounds_95"]
            print(f"Monte-Carlo {mc['runs']} runs: ANEES {mc['anees_mean']:.2f} (95 % bounds {lo:.2f}–{hi:.2f}), "
                  f"inside {mc['fraction_inside']:.0%}")  # fmt: skip
    else:
        directory = DEFAULT_DRIVE if src == "drive" else Path(src)
        if not directory.is_dir():
            print(f"ins-hil replay: unknown source {src!r} (scenarios: {', '.join(scenarios.NAMES)}, 'drive', "
                  "a drive directory or a *.ihlog)", file=sys.stderr)  # fmt: skip
            return 2
        res, series = replay_drive(directory, [False] if args.no_aids else [True, False], args.quiet)
        out = {"drive": res}
        if not args.no_plots:
            out["plots"] = []
            t0 = drive0708.read_pos(directory / "gnss_1934_sf.pos").t[0]
            outs = [(a + t0, b + t0) for a, b in res["outage_windows_s"]]
            for label, ser in series.items():
                out["plots"] += [str(p) for p in plot_series(ser, f"drive {label}", args.out / f"drive_{label}", outs)]
        _print_drive(res)
    (args.out / "metrics.json").write_text(json.dumps(out, indent=2, default=float))
    print(f"metrics: {args.out / 'metrics.json'}")
    return 0


def _print_drive(res: dict[str, Any]) -> None:
    rows = [("run", "outage h RMS / max (m)", "GNSS-present h RMS prior/post (m)", "speed (x real time)")]
    for tag in ("aids", "no_aids"):
        o, g = res.get(f"outages_{tag}"), res.get(f"gnss_{tag}")
        if o is None or g is None:
            continue
        rows.append(
            (tag, f"{o['outage_h_rms_m']:.2f} / {o['outage_h_max_m']:.2f}",
             f"{g['gnss_h_rms_prior_m']:.3f} / {g['gnss_h_rms_post_m']:.3f}",
             f"{o['realtime_factor']:.1f}")
        )  # fmt: skip
    _print_table(rows)


def full_report(args: argparse.Namespace) -> int:
    """Regenerate docs/accuracy.md and docs/accuracy/*.png."""
    docs = REPO / "docs"
    figdir = docs / "accuracy"
    figdir.mkdir(parents=True, exist_ok=True)
    quiet = args.quiet
    report: dict[str, Any] = {}
    t_start = time.perf_counter()
    report["hot_path"] = benchmark_hot_path()
    res, series = replay_drive(DEFAULT_DRIVE, [True, False], quiet, cov_every_trade=True)
    report["drive"] = res
    plots: dict[str, list[Path]] = {}
    t0 = drive0708.read_pos(DEFAULT_DRIVE / "gnss_1934_sf.pos").t[0]
    outs = [(a + t0, b + t0) for a, b in res["outage_windows_s"]]
    for label in ("outages_aids", "outages_no_aids", "gnss_aids"):
        plots[f"drive_{label}"] = plot_series(series[label], f"drive {label}", figdir / f"drive_{label}", outs)
    sims: dict[str, Any] = {}
    for name in ("example32_gnss", "example32", "uav", "coning", "static"):
        m, ser, _ = run_scenario(name, 0, None, quiet)
        sims[name] = m
        plots[name] = plot_series(ser, name, figdir / name)
    report["scenarios"] = sims
    report["monte_carlo"] = monte_carlo("example32_gnss", 10, None, quiet)
    report["monte_carlo_uav"] = monte_carlo("uav_modelled", 10, 140.0, quiet)
    report["elapsed_s"] = time.perf_counter() - t_start
    (figdir / "metrics.json").write_text(json.dumps(report, indent=2, default=float))
    (docs / "accuracy.md").write_text(render_markdown(report, plots, docs))
    print(f"wrote {docs / 'accuracy.md'} ({report['elapsed_s']:.0f} s)")
    return 0


def _machine() -> str:
    cpu = cpu_model()
    load = os.getloadavg() if hasattr(os, "getloadavg") else (math.nan,) * 3
    return (f"{os.cpu_count()} CPUs (`nproc`), {cpu}, Python {platform.python_version()}; "
            f"during the run: {load_note(load[0])}")  # fmt: skip


def _per_outage(pw: list[dict[str, float]]) -> str:
    """'RMS/max, …' (m) of each outage, as the report's tables give them."""
    return ", ".join(f"{x['rms_m']:.2f}/{x['max_m']:.2f}" for x in pw)


def _whatif_baro_md(
    wb: list[dict[str, Any]], pw: list[dict[str, float]], windows: list[list[float]], base: dict[str, Any]
) -> str:
    """The session-7 what-if section: the protocol with a synthetic barometer (rows from ``replay_drive``)."""
    rows = [("none (the protocol, table above)", "", f"{base['outage_h_rms_m']:.2f} / {base['outage_h_max_m']:.2f}",
             f"{base['outage_v_rms_m']:.2f}", _per_outage(pw))]  # fmt: skip
    for r in wb:
        rows.append((f"{r['baro']}: {r['white_m']:g} m white, {r['drift_m_sqrt_s']:g} m/√s drift", str(r["seed"]),
                     f"{r['outage_h_rms_m']:.2f} / {r['outage_h_max_m']:.2f}", f"{r['outage_v_rms_m']:.2f}",
                     _per_outage(r["per_window"])))  # fmt: skip
    w = max(range(len(pw)), key=lambda i: pw[i]["max_m"])
    with_b = [r["per_window"][w]["max_m"] for r in wb]
    meets = all(r["outage_h_rms_m"] <= 1.5 and r["outage_h_max_m"] <= 6.0 for r in wb)
    worst_b = [int(np.argmax([x["max_m"] for x in r["per_window"]])) for r in wb]
    head = ("synthetic barometer", "seed", "outage h RMS / max (m)", "outage v RMS (m)", "per outage h RMS / max (m)")
    return (
        "### Session 7: what a barometer would do (a what-if with a synthetic sensor, not a protocol figure)\n\n"
        "The drive has no barometer. Sessions 3–6 found that the worst outage is an along-track error from a pitch "
        "(gyro-y bias) that nothing measures during the outage: the vertical NHC ties the pitch to the vertical "
        "velocity, which is free without a height reference. To test that reading, `ins-hil replay --docs` also runs "
        "the protocol (drive settings, ZUPT + NHC) with a barometer made from the RTK height at the RTK-fixed "
        "epochs (4 Hz) plus white noise and a random-walk drift (`drive0708.synthetic_baro`, seeded), fused the whole "
        "time, outages included (`run_drive(aux=...)`), its datum learnt against GNSS as the gateway does "
        "(`baro_offset_tau`) and `baro_std` set to the white noise. It is built from the truth, so it is a study "
        "for choosing a sensor, never a protocol result.\n\n"
        + _md_table(head, tuple(rows))
        + f"\n\nThe worst protocol outage ({windows[w][0]:.0f} s, {pw[w]['max_m']:.2f} m) has a worst case of "
        + ", ".join(f"{x:.2f}" for x in with_b)
        + " m with the barometers. With a barometer the worst outage of each run is "
        + ", ".join(f"{windows[i][0]:.0f} s" for i in worst_b)
        + " (the first outage starts 0.25 s after the in-motion yaw alignment; the baro datum is learnt against "
        "GNSS during the rest before it). The spread between the two seeds of one barometer is as large as the "
        "difference between the barometers: two seeds show the size of the effect, not a ranking. "
        + ("Every" if meets else "Not every")
        + " barometer run meets both targets (≤ 1.5 m RMS, ≤ 6 m worst)"
        + "; the drive's own data hold no pitch or height reference.\n"
    )


def _md_table(head: tuple[str, ...], rows: tuple[tuple[str, ...], ...]) -> str:
    """A markdown table."""
    lines = ["| " + " | ".join(head) + " |", "|" + "---|" * len(head)]
    lines += ["| " + " | ".join(r) + " |" for r in rows]
    return "\n".join(lines)


def render_markdown(r: dict[str, Any], plots: dict[str, list[Path]], docs: Path) -> str:
    d = r["drive"]
    L: list[str] = []
    a = L.append
    a("# Accuracy report (generated by `ins-hil replay --docs`)\n")
    a(f"Machine: {_machine()}.\n")
    a("All processing is causal (no smoothing, no look-back); GNSS is fused at its time of validity.\n")
    a("## Real drive (`../shared/data/gnss_imu_drive_0708`)\n")
    a(f"{d['imu_samples']} IMU samples, {d['gnss_epochs']} GNSS epochs, {d['outages']} outages of 15 s "
      f"(README protocol), {d['csv_bad_lines']} unparseable csv lines skipped.\n")  # fmt: skip
    a("| run | outage h RMS (m) | outage h max (m) | outage v RMS (m) | GNSS-present h RMS prior / post (m) |"
      " replay speed (× real time) |")  # fmt: skip
    a("|---|---|---|---|---|---|")
    for tag, name in (("aids", "with ZUPT + NHC"), ("no_aids", "no ground-vehicle aids (UAV-like)")):
        o, g = d[f"outages_{tag}"], d[f"gnss_{tag}"]
        a(f"| {name} | {o['outage_h_rms_m']:.2f} | {o['outage_h_max_m']:.2f} | {o['outage_v_rms_m']:.2f} | "
          f"{g['gnss_h_rms_prior_m']:.3f} / {g['gnss_h_rms_post_m']:.3f} | {o['realtime_factor']:.1f} |")  # fmt: skip
    c5 = d.get("outages_aids_cov5")
    if c5:
        a(f"| with aids, P propagated every 5 IMU steps | {c5['outage_h_rms_m']:.2f} | {c5['outage_h_max_m']:.2f} | "
          f"{c5['outage_v_rms_m']:.2f} | | {c5['realtime_factor']:.1f} |")  # fmt: skip
    for tag, name in (("aids", "with ZUPT + NHC"), ("no_aids", "no aids")):
        v = d.get(f"validation_{tag}")
        if v:
            a(f"| held-out validation outages (3 × 11 shifted windows), {name} | {v['outage_h_rms_m']:.2f} | "
              f"{v['outage_h_max_m']:.2f} | | | |")  # fmt: skip
    su = d.get("startup_aids")
    if su:
        w = d["startup_window_s"]
        a(f"| start-up outage (restart {d['startup_restart_s']:.0f} s, outage {w[0]:.2f}–{w[1]:.2f} s), ZUPT + NHC | "
          f"{su['outage_h_rms_m']:.2f} | {su['outage_h_max_m']:.2f} | | | |")  # fmt: skip
    a("| target | ≤ 1.5 | ≤ 6 | (upstream 0.41) | ≤ 0.05 | ≥ 20 |")
    a("| upstream filter, causal | 3.09 | 12.8 | 0.41 | | |\n")
    a("GNSS-present RMS: every RTK-fixed epoch of a run with GNSS all the time, antenna position; 'prior' is the "
      "state propagated to the epoch before that epoch is fused (what a consumer sees between fixes), 'post' "
      "after the update.\n")  # fmt: skip
    pw = d.get("per_window_aids")
    if pw:
        a(
            "Per protocol outage, with ZUPT + NHC (h RMS / max, m): "
            + ", ".join(f"{w[0]:.0f} s {r['rms_m']:.2f}/{r['max_m']:.2f}" for w, r in zip(d["outage_windows_s"], pw))
            + ".\n"
        )
    wb = d.get("whatif_baro")
    if wb and pw:
        a(_whatif_baro_md(wb, pw, d["outage_windows_s"], d["outages_aids"]))
    a(SESSION6_NOTE.format(table=_md_table(
        ("variant (ZUPT + NHC)", "validation h RMS / max (m)", "per shift 17.5 / 22.5 / 27.5 s",
         "start-up outage h RMS / max (m)"), SESSION6_ROWS)))  # fmt: skip
    a(SESSION5_NOTE)
    a(SESSION4_NOTE)
    a(SESSION3_NOTE)
    a(CHOICE_NOTE)
    for k in ("drive_outages_aids", "drive_outages_no_aids", "drive_gnss_aids"):
        for p in plots.get(k, []):
            a(f"![{p.stem}]({p.relative_to(docs)})")
    a("")
    a("## Simulations\n")
    a("| scenario | attitude RMS (°, r/p/y) | attitude max (°) | velocity RMS (m/s) | position RMS (m) |"
      " position max (m) | mean NEES (9 dof) | × real time |")  # fmt: skip
    a("|---|---|---|---|---|---|---|---|")
    for name, m in r["scenarios"].items():
        if not m.get("att_rms_deg"):
            continue
        a(f"| {name} (from {m['steady_from_s']:.0f} s) | {_fmt(m['att_rms_deg'], 3)} | {_fmt(m['att_max_deg'], 3)} | "
          f"{_fmt(m['vel_rms_mps'], 3)} | {_fmt(m['pos_rms_m'], 2)} | {_fmt(m['pos_max_m'], 2)} | "
          f"{m['nees_mean_9dof']:.1f} | {m['realtime_factor']:.0f} |")  # fmt: skip
    a("\nTargets (Example 3.2 steady state): attitude < 0.1°, velocity < 0.1 m/s, position < 1 m "
      "(book: ~0.2 m/s, < 1 m). `example32` is the book's schedule and sensors (GNSS 50 m / 0.1 m/s every 2 s, "
      "magnetometer σ_m = 0.0524, altimeter 1 m; GNSS off in [180, 420] s); `example32_gnss` is the same "
      "motion and IMU with a 5 Hz GNSS (0.5 m, 0.02 m/s). Circle interpretation: DIGEST_000 §10 item 18, "
      "aircraft angles, level circle with the roll oscillation φ = 0.3 sin(10ψ) superposed.\n")  # fmt: skip
    for mc in (r["monte_carlo"], r["monte_carlo_uav"]):
        a(f"Monte-Carlo consistency, `{mc['scenario']}`, {mc['runs']} runs (from {mc['from_s']:.0f} s): "
          f"average NEES {mc['anees_mean']:.2f} for 9 dof, two-sided 95 % χ² bounds "
          f"[{mc['anees_bounds_95'][0]:.2f}, {mc['anees_bounds_95'][1]:.2f}], inside the bounds "
          f"{mc['fraction_inside']:.0%} of the time; mean NIS/dof "
          + ", ".join(f"{k} {v:.2f}" for k, v in mc["nis_mean_over_dof"].items())
          + " (1.0 = consistent); yaw error RMS over the runs "
          + f"{mc['yaw_err_rms_deg']:.3f}° against the filter's own yaw σ (RMS) "
          + f"{mc['yaw_std_rms_deg']:.3f}°.\n")  # fmt: skip
    a(EX32_NOTE)
    for name in r["scenarios"]:
        for p in plots.get(name, []):
            if p.stem.endswith("errors"):
                a(f"![{p.stem}]({p.relative_to(docs)})")
    a("")
    a("## Hot path (µs per IMU step, Python)\n")
    hp = r["hot_path"]
    scale = 21.0 / hp["mechanization_us"]
    a("| measurement | µs (measured, loaded machine) | µs scaled to a 21 µs mechanization (estimate) |")
    a("|---|---|---|")
    for k, v in hp.items():
        a(f"| {k} | {v:.1f} | {v * scale:.1f} |")
    a("\nTarget: mechanization + 15-state predict ≤ 150 µs (mechanization alone ~21 µs on an idle machine; the "
      "scaled column divides out the machine load measured on the mechanization itself). "
      "`with_delay_history` keeps the state snapshots for delayed GNSS fusion (rollback and forward "
      "propagation).\n")  # fmt: skip
    a(f"Report generated in {r['elapsed_s']:.0f} s.\n")
    return "\n".join(L)
