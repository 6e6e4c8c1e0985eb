"""Simulated scenarios against their truth and the hot-path timing (pure: no I/O, no plots).

The scenarios are built by the caller (``ins_hil.sim.scenarios.build``; the simulator is a sibling layer, never
imported here): :func:`run_scenario` replays one, :func:`monte_carlo` averages the NEES over seeds against its
χ² bounds, :func:`benchmark_hot_path` times the IMU step.
"""

from __future__ import annotations

import math
import time
from collections.abc import Callable
from typing import Any

import numpy as np

from ins_hil.core import NavConfig, NavCore
from ins_hil.core_parts.config import DelayConfig
from ins_hil.datasets.evaluate import Progress, Series, run_truth
from ins_hil.datasets.run import offline_config, replay
from ins_hil.fusion.ekf import FilterConfig
from ins_hil.nav import earth
from ins_hil.runtime.pipeline import Observer, Pipeline, nav_config
from ins_hil.types import ImuSample

ProgressFactory = Callable[[str], Progress | None]


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


def run_scenario(
    sc: Any, name: str, seed: int, progress: Progress | None = None
) -> tuple[dict[str, Any], Series, NavCore]:
    """Replay a built simulated scenario ``sc`` (``ins_hil.sim.scenarios.build(name, seed=...)``: ``initial``,
    ``config``, ``imu``, ``meas``, ``truth``, ``info``) against its truth; (metrics, series, core)."""

    def keep_nis(pipe: Any) -> None:
        pipe.core.keep_nis = True

    t0 = time.perf_counter()
    ser, core = run_truth(nav_config(sc.nav), sc.initial, sc.imu, sc.meas, sc.truth, record_every=10,
                          progress=progress, setup=keep_nis)  # fmt: skip
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


def monte_carlo(
    build: Callable[[int], Any], name: str, runs: int, progress: ProgressFactory | None = None
) -> dict[str, Any]:
    """Average NEES (9 dof) over ``runs`` seeds (1000, 1001, …; ``build(seed)`` returns the simulated scenario)
    vs the two-sided 95 % χ² bounds; mean NIS/dof per sensor."""
    prog = progress or (lambda label: None)
    from scipy.stats import chi2

    nees = []
    nis: dict[str, list[float]] = {}
    yaw_e2: list[float] = []
    yaw_s2: list[float] = []
    t_from = 0.0
    for seed in range(runs):
        m, ser, core = run_scenario(build(1000 + seed), name, 1000 + seed, prog(f"{name} seed {1000 + seed}"))
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
                NavConfig(filter=FilterConfig(cov_every=every), delay=DelayConfig(compensation=False)),
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


class _OutageError(Observer):
    """The horizontal position error (m) against ``truth`` at each whole second inside ``outage`` (and at its last
    step before the next fix)."""

    def __init__(self, truth: Any, outage: tuple[float, float]) -> None:
        self.truth, self.outage = truth, outage
        self.errs: list[float] = []
        self._last: float | None = None

    def epoch(self, pipe: Pipeline, st: Any) -> None:
        t0, t1 = self.outage
        if not t0 < st.t < t1:
            return
        tr = self.truth
        i = round((st.t - tr.t[0]) / tr.dt)
        d = earth.ned_delta_small(st.lat - tr.lat[i], st.lon - tr.lon[i], st.h - tr.h[i], tr.lat[i], tr.h[i])
        e = float(np.hypot(d[0], d[1]))
        if abs(st.t - round(st.t)) < 0.5 * tr.dt:
            self.errs.append(e)
        self._last = e

    def result(self) -> tuple[float, float]:
        """(RMS over the outage, the error at its end) (m)."""
        errs = [*self.errs, self._last] if self._last is not None else self.errs
        return float(np.sqrt(np.mean(np.square(errs)))), float(errs[-1])


def odometer_outages(
    build: Callable[[int], Any], seeds: tuple[int, ...] = (1, 2, 3, 4, 5),
    outages: tuple[tuple[float, float], ...] = ((30.0, 60.0), (60.0, 90.0)),
) -> dict[str, Any]:  # fmt: skip
    """The simulated car with and without its wheel odometer in GNSS outages, through the gateway's Pipeline (the
    one offline loop, :func:`ins_hil.datasets.run.replay`; NHC + ZUPT in both runs): ``build(seed)`` →
    ``ins_hil.sim.scenarios.CarRun``. Per seed and outage the horizontal error's RMS over the outage and at its end
    (m), their means and medians over the seed × outage runs, and the odometer scale factor learnt before the
    outages (its truth ``scale``)."""
    from ins_hil.aids.odometer import OdometerSample

    runs: dict[str, list[tuple[float, float]]] = {"with": [], "without": []}
    scale: list[float] = []
    truth_scale = math.nan
    for seed in seeds:
        car = build(seed)
        truth_scale = car.scale
        odo = [OdometerSample(t, v) for t, v in car.odometer]
        for out in outages:
            fixes = [f for f in car.fixes if not out[0] < f.t < out[1]]
            for tag, on in (("with", True), ("without", False)):
                nav = nav_config({"aids": {"nhc": True, "zupt": True}, "odometer": {"enabled": on}})
                obs = _OutageError(car.truth, out)
                aids = sorted([*fixes, *(odo if on else [])], key=lambda m: m.t)
                pipe, _ = replay(car.imu, aids, nav, [obs], initial=car.initial, pipeline=offline_config(False),
                                 source="odometer car")  # fmt: skip
                runs[tag].append(obs.result())
                if on and out == outages[0]:
                    scale.append(float(getattr(pipe.core.aid("odometer"), "scale", math.nan)))  # type: ignore[union-attr]

    def stats(tag: str) -> dict[str, float]:
        rms, end = (np.array([r[k] for r in runs[tag]]) for k in (0, 1))
        return {"rms_mean_m": float(rms.mean()), "rms_median_m": float(np.median(rms)),
                "end_mean_m": float(end.mean()), "end_median_m": float(np.median(end))}  # fmt: skip

    return {
        "seeds": list(seeds), "outages_s": [list(o) for o in outages], "runs": len(runs["with"]),
        "with": stats("with"), "without": stats("without"),
        "per_run": {k: [[round(a, 3), round(b, 3)] for a, b in v] for k, v in runs.items()},
        "scale_learnt": [round(s, 4) for s in scale], "scale_true": truth_scale,
    }  # fmt: skip
