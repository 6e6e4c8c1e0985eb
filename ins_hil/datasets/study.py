"""The protocol study of a data set with a reference-grade GNSS (the car drive: ``configs/datasets/drive0708.toml``).

What ``ins-hil replay drive`` and ``ins-hil replay --docs`` run on it, everything from the dataset config: the
outage protocol (``[outages]``) with and without the ground-vehicle aids (ZUPT, NHC) and a run with GNSS all the
time, scored at the fixes of ``score.min_fix_type`` or better (:func:`ins_hil.datasets.evaluate.run_drive`);
with ``full``, the checks used to choose settings without the protocol's truth (``[study]``): held-out
validation outages (the protocol shifted into its GNSS-present intervals), a start-up outage after a restart,
the cost/accuracy trade of propagating P every 5 IMU steps, and what-if synthetic barometers made from the
GNSS height (a sensor study, never a protocol figure).
"""

from __future__ import annotations

import dataclasses
import functools
import math
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np

from ins_hil.core import NavConfig
from ins_hil.datasets.config import DatasetConfig
from ins_hil.datasets.dataset import Dataset, DatasetError, read_dataset
from ins_hil.datasets.evaluate import Series, run_drive
from ins_hil.datasets.report import protocol_windows
from ins_hil.datasets.run import Prepared, prepare
from ins_hil.types import BaroSample, GnssFix, ImuSample

ProgressFactory = Callable[[str], Callable[[int, int], None] | None]
Windows = list[tuple[float, float]]


def load(cfg: DatasetConfig, path: Path | None = None) -> tuple[Dataset, Prepared, list[tuple[float, float]]]:
    """Read the recording (``path``, else the config's ``dataset.path``) and apply the config: (dataset,
    prepared streams, the protocol's outage windows in absolute s)."""
    src = path if path is not None else cfg.path
    if src is None:
        raise DatasetError(f"{cfg.source or cfg.name}: no dataset.path and no recording given")
    ds = read_dataset(Path(src), cfg.format, cfg)
    p = prepare(ds, cfg)
    if not p.gnss or cfg.outages is None:
        raise DatasetError(f"{cfg.source or cfg.name}: the protocol study needs GNSS fixes and an [outages] table")
    wins = protocol_windows(ds, p, cfg)
    if wins is None:
        raise DatasetError(f"{cfg.source or cfg.name}: no take-off event for the outage protocol")
    return ds, p, wins


def without_aids(nav: NavConfig) -> NavConfig:
    """The NavConfig without the ground-vehicle aids (ZUPT, NHC): how the filter runs on a UAV."""
    return dataclasses.replace(nav, aids=dataclasses.replace(nav.aids, nhc=False, zupt=False))


def shifted_windows(cfg: DatasetConfig, p: Prepared, shift: float) -> list[tuple[float, float]]:
    """Held-out validation outages: the protocol's windows shifted by ``shift`` s (``on_s`` .. ``off_s``), so
    each lies inside a GNSS-present interval of the protocol and never overlaps a protocol outage."""
    o = cfg.outages
    assert o is not None
    if not o.on_s <= shift <= o.off_s:
        raise ValueError(f"shifted_windows: shift={shift} s would overlap the protocol's outages "
                         f"(need {o.on_s:g}..{o.off_s:g})")  # fmt: skip
    moved = dataclasses.replace(o, start_s=o.start_s + shift)
    return moved.windows(p.gnss[0].t, p.gnss[-1].t)


def startup_validation(
    imu: list[ImuSample], gnss: list[GnssFix], restart: float, score_until: float, yaw_speed: float
) -> tuple[list[ImuSample], list[GnssFix], list[tuple[float, float]]]:
    """A held-out start-up outage (a fresh alignment): the replay restarts ``restart`` s after the first fix
    (during a stop), and the outage runs from 0.25 s after the first fix at ≥ ``yaw_speed`` m/s (when the core
    enters navigation) to ``score_until`` s after the first fix. Returns (IMU samples, fixes, [outage])."""
    t0 = gnss[0].t
    a = t0 + restart
    imu_s = [s for s in imu if s.t >= a]
    gnss_s = [f for f in gnss if f.t >= a]
    moving = [f.t for f in gnss_s if f.vel_ned is not None and math.hypot(*map(float, f.vel_ned[:2])) >= yaw_speed]
    if not moving or moving[0] + 0.25 >= t0 + score_until:
        raise ValueError(f"startup_validation: no departure between {restart} s and {score_until} s")
    return imu_s, gnss_s, [(moving[0] + 0.25, t0 + score_until)]


def synthetic_baro(
    gnss: list[GnssFix], white: float, drift: float, seed: int, datum: float, min_fix: int = 6
) -> list[BaroSample]:
    """A barometer the data set does not have, made from the truth for a what-if study (never a protocol
    figure): at every fix of type ``min_fix`` or better, its ellipsoidal height minus ``datum`` (m) plus white
    noise σ ``white`` (m) and a random-walk drift ``drift`` (m/√s); deterministic for a ``seed``."""
    if white < 0 or drift < 0:
        raise ValueError(f"synthetic_baro: white={white} m and drift={drift} m/√s must be ≥ 0")
    rng = np.random.default_rng(seed)
    ok = [f for f in gnss if f.fix_type >= min_fix]
    t = np.array([f.t for f in ok])
    h = np.array([f.h for f in ok])
    walk = np.cumsum(rng.normal(0.0, 1.0, len(t)) * drift * np.sqrt(np.diff(t, prepend=t[:1])))
    alt = h - datum + walk + rng.normal(0.0, 1.0, len(t)) * white
    return [BaroSample(float(ti), math.nan, altitude=float(a)) for ti, a in zip(t, alt, strict=True)]


def per_window(ser: Series, outages: list[tuple[float, float]], scored: set[float]) -> list[dict[str, float]]:
    """Horizontal RMS / max (m) of the antenna error inside each outage, over the epochs whose time is in
    ``scored`` (as :func:`run_drive` scores them); NaN for an outage with none."""
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


def _windows_from_first(wins: list[tuple[float, float]], t0: float) -> list[tuple[float, float]]:
    return [(a - t0, b - t0) for a, b in wins]


def study(
    cfg: DatasetConfig,
    path: Path | None = None,
    aids_variants: tuple[bool, ...] = (True, False),
    progress: ProgressFactory | None = None,
    full: bool = False,
) -> tuple[dict[str, Any], dict[str, Series]]:
    """Run the study (module docstring); (metrics, series by run label). Labels ``outages_aids``,
    ``gnss_aids``, ``outages_no_aids``, ``gnss_no_aids``; times in the metrics are s from the first fix."""
    prog = progress or (lambda label: None)
    drive = functools.partial(run_drive, aiding_fdi=cfg.aiding_fdi)  # the drift monitor as configured
    ds, p, outages = load(cfg, path)
    imu, gnss = p.imu, p.gnss
    t_first = gnss[0].t
    scored = [f.fix_type >= cfg.min_fix_type for f in gnss]
    scored_t = {f.t for f, ok in zip(gnss, scored, strict=True) if ok}
    duration = float(imu[-1].t - imu[0].t)
    res: dict[str, Any] = {"dataset": cfg.name, "source": ds.meta.get("source"), "imu_samples": len(imu),
                           "gnss_epochs": len(gnss), "outages": len(outages),
                           "csv_bad_lines": ds.meta.get("csv_bad_lines", 0), "duration_s": duration}  # fmt: skip
    series: dict[str, Series] = {}

    def nav(aids: bool) -> NavConfig:
        return p.nav if aids else without_aids(p.nav)

    def timed(
        label: str, imu: list[ImuSample], gnss: list[GnssFix], scored: list[bool], nav: NavConfig, outs: Windows
    ) -> tuple[dict[str, Any], Series]:
        t0 = time.perf_counter()
        m, ser, _ = drive(imu, gnss, scored, nav, outs, prog(label))
        m["realtime_factor"] = duration / (time.perf_counter() - t0)
        return m, ser

    for aids in aids_variants:
        tag = "aids" if aids else "no_aids"
        for label, outs in ((f"outages_{tag}", outages), (f"gnss_{tag}", [])):
            res[label], series[label] = timed(f"{cfg.name} {label}", imu, gnss, scored, nav(aids), outs)
    if full:
        st = cfg.study
        # cost/accuracy trade of propagating P every 5 IMU steps (with aids, outage protocol)
        cov5 = dataclasses.replace(p.nav, filter=dataclasses.replace(p.nav.filter, cov_every=5))
        res["outages_aids_cov5"], _ = timed(f"{cfg.name} outages cov_every=5", imu, gnss, scored, cov5, outages)
        # held-out validation: the protocol's outages shifted into its GNSS-present intervals
        for aids in (True, False):
            sq = n = 0.0
            mx = 0.0
            for shift in st.get("validation_shifts_s", []):
                m, _, _ = drive(imu, gnss, scored, nav(aids), shifted_windows(cfg, p, float(shift)),
                                    prog(f"{cfg.name} validation +{shift:g} s"))  # fmt: skip
                sq += m["outage_h_rms_m"] ** 2 * m["outage_epochs"]
                n += m["outage_epochs"]
                mx = max(mx, m["outage_h_max_m"])
            if n:
                res[f"validation_{'aids' if aids else 'no_aids'}"] = {"outage_h_rms_m": math.sqrt(sq / n),
                                                                       "outage_h_max_m": mx}  # fmt: skip
        if "startup_restart_s" in st:
            # held-out start-up outage (a fresh alignment, like the protocol's first outage; never its epochs)
            restart = float(st["startup_restart_s"])
            imu_s, gnss_s, outs_s = startup_validation(imu, gnss, restart, float(st["startup_score_until_s"]),
                                                       p.nav.alignment.gnss_yaw_speed)  # fmt: skip
            m, _, _ = drive(imu_s, gnss_s, [f.fix_type >= cfg.min_fix_type for f in gnss_s], p.nav, outs_s,
                                prog(f"{cfg.name} start-up validation"))  # fmt: skip
            res["startup_aids"] = {k: m[k] for k in ("outage_h_rms_m", "outage_h_max_m", "outage_epochs")}
            # the core must have entered navigation at the fix that opens the outage (0.25 s before it)
            res["startup_aids"]["t_aligned_s"] = m["t_aligned_s"] + gnss_s[0].t - t_first
            res["startup_window_s"] = _windows_from_first(outs_s, t_first)[0]
            res["startup_restart_s"] = restart
        res["whatif_baro"] = []
        for name, white, drift in st.get("whatif_baro", []):
            for seed in (0, 1):
                cfg_b = dataclasses.replace(p.nav, baro=dataclasses.replace(p.nav.baro, std=white))
                aux = synthetic_baro(gnss, white, drift, seed, float(st.get("whatif_baro_datum_m", 0.0)),
                                     max(cfg.min_fix_type, 1))  # fmt: skip
                m, ser, _ = drive(imu, gnss, scored, cfg_b, outages,
                                      prog(f"{cfg.name} what-if {name} baro seed {seed}"), aux=aux)  # fmt: skip
                res["whatif_baro"].append({"baro": name, "white_m": white, "drift_m_sqrt_s": drift, "seed": seed,
                                           **{k: m[k] for k in ("outage_h_rms_m", "outage_h_max_m", "outage_v_rms_m")},
                                           "per_window": per_window(ser, outages, scored_t)})  # fmt: skip
    res["outage_windows_s"] = _windows_from_first(outages, t_first)
    res["outage_on_s"] = cfg.outages.on_s if cfg.outages is not None else None
    for k in ("targets", "upstream"):  # the report's target and reference rows
        if k in cfg.study:
            res[k] = dict(cfg.study[k])
    res["t_first_fix_s"] = t_first
    if "outages_aids" in series:
        res["per_window_aids"] = per_window(series["outages_aids"], outages, scored_t)
    return res, series


def absolute_windows(res: dict[str, Any]) -> list[tuple[float, float]]:
    """The study's outage windows in absolute s (for plots)."""
    t0 = float(res["t_first_fix_s"])
    return [(a + t0, b + t0) for a, b in res["outage_windows_s"]]
