"""Our solution against the flight controller's own estimate (EKF2, EKF3) or a reference trajectory.

Each onboard sample is compared with our state at the last IMU step at or before its time (causal, no
interpolation of ours). Attitude: roll/pitch/yaw differences (ours − theirs, wrapped to ±180°); velocity
NED; position NED: about the estimator's origin when the log holds it, else after removing the mean
difference (the estimators start from different origins; stated in the result).
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np

from ins_hil.datasets.dataset import Trajectory
from ins_hil.datasets.run import RunResult, euler_series
from ins_hil.nav import earth
from ins_hil.types import Vec


def _ours_at(r: RunResult, t: Vec, t_from: float, t_to: float) -> tuple[Vec, Vec]:
    """(mask into t, index into r.t) of the onboard times inside [t_from, t_to] where we navigate."""
    i = np.searchsorted(r.t, t, "right") - 1
    m = (i >= 0) & (t >= t_from) & (t <= t_to)
    return m, i[m]


def _stats(d: Vec, names: tuple[str, ...]) -> dict[str, Any]:
    """RMS / max |·| / mean of each column over its finite samples (an axis with none is left out)."""
    out: dict[str, Any] = {"samples": int(np.sum(np.any(np.isfinite(d), axis=1)))}
    for k, n in enumerate(names):
        x = d[np.isfinite(d[:, k]), k]
        if len(x):
            out[n] = {"rms": float(np.sqrt(np.mean(x**2))), "max": float(np.max(np.abs(x))), "mean": float(np.mean(x))}
    return out


def compare(r: RunResult, tr: Trajectory, t_from: float, t_to: float) -> dict[str, Any]:
    """Differences ours − ``tr`` in [t_from, t_to] (s): attitude (deg), velocity (m/s), position (m)."""
    out: dict[str, Any] = {"against": tr.name, "from_s": t_from, "to_s": t_to}
    series: dict[str, Vec] = {}
    if tr.q_nb is not None and tr.t_att is not None:
        m, i = _ours_at(r, tr.t_att, t_from, t_to)
        if np.any(m):
            theirs = euler_series(tr.q_nb[m])
            d = np.degrees(euler_series(r.q_nb[i]) - theirs)
            d = (d + 180.0) % 360.0 - 180.0
            out["attitude_deg"] = _stats(d, ("roll", "pitch", "yaw"))
            series["att_t"], series["att_theirs_deg"], series["att_diff_deg"] = tr.t_att[m], np.degrees(theirs), d
    if tr.vel_ned is not None and tr.t_vel is not None:
        m, i = _ours_at(r, tr.t_vel, t_from, t_to)
        if np.any(m):
            d = r.vel_ned[i] - tr.vel_ned[m]
            st = _stats(d, ("north", "east", "down"))
            h = np.hypot(d[:, 0], d[:, 1])
            h = h[np.isfinite(h)]
            if len(h):
                st["horizontal"] = {"rms": float(np.sqrt(np.mean(h**2))), "max": float(h.max())}
            else:
                st["note"] = "the log's horizontal velocity is not valid: vertical only"
            out["velocity_mps"] = st
            series["vel_t"], series["vel_theirs"] = tr.t_vel[m], tr.vel_ned[m]
    if tr.pos_ned is not None and tr.t_pos is not None:
        m, i = _ours_at(r, tr.t_pos, t_from, t_to)
        if np.any(m):
            ours = r.ned[i]
            if tr.origin is not None:
                ours = ours + earth.ned_from_geodetic(*r.origin, *tr.origin)
                how = "about the estimator's origin"
            else:
                how = ""
            d = ours - tr.pos_ned[m]
            h_ok = bool(np.any(np.isfinite(d[:, 0])))
            if tr.origin is None:
                how = "after removing the mean difference (the log does not hold the estimator's origin)"
                for k in range(3):
                    ok = np.isfinite(d[:, k])
                    if np.any(ok):
                        d[:, k] -= float(np.mean(d[ok, k]))
            if h_ok:
                st = _stats(d, ("north", "east", "down"))
                ok = np.isfinite(d[:, 0])
                h = np.hypot(d[ok, 0], d[ok, 1])
                st["horizontal"] = {"rms": float(np.sqrt(np.mean(h**2))), "max": float(h.max())}
            else:  # horizontal invalid in the log (no absolute aiding): height only
                st = _stats(d[:, 2:3], ("down",))
                how += "; the log's horizontal position is not valid: height only"
            st["how"] = how
            out["position_m"] = st
            series["pos_t"], series["pos_theirs"] = tr.t_pos[m], tr.pos_ned[m] + (ours - tr.pos_ned[m] - d)
    out["_series"] = series
    return out


def summary_rows(c: dict[str, Any]) -> list[tuple[str, str, str]]:
    """(quantity, RMS, max) rows of a comparison for the summary table."""
    rows: list[tuple[str, str, str]] = []

    def f(x: float, nd: int) -> str:
        return "n/a" if x is None or not math.isfinite(x) else f"{x:.{nd}f}"

    for key, unit, nd in (("attitude_deg", "°", 2), ("velocity_mps", "m/s", 3), ("position_m", "m", 2)):
        st = c.get(key)
        if not st:
            continue
        for ax, v in st.items():
            if isinstance(v, dict):
                rows.append((f"{key.split('_')[0]} {ax} ({unit})", f(v["rms"], nd), f(v["max"], nd)))
    return rows
