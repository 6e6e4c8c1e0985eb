"""Our solution against the flight controller's own estimate (EKF2, EKF3) or a reference trajectory.

Each onboard sample is compared with our state at the last IMU step at or before its time (causal, no
interpolation of ours). Attitude: roll/pitch/yaw differences (ours − theirs, wrapped to ±180°); velocity
NED; position NED: about the estimator's origin when the log holds it, else after removing the mean
difference (the estimators start from different origins; stated in the result).

:func:`rotor_drag` checks a multirotor's velocity (ours or the onboard estimator's) against the accelerometers:
a rotor's drag makes the horizontal body specific force follow the body velocity, f_x,y ≈ c − μ v_x,y (the
momentum drag EKF2 fuses with ``EKF2_MCOEF``; Martin & Salaün 2010, docs/references.md), so a velocity the
specific force does not follow is not the vehicle's. :func:`mag_heading` holds a yaw against the magnetometer's
own heading.
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np

from ins_hil.datasets.dataset import Trajectory
from ins_hil.datasets.run import RunResult, euler_series
from ins_hil.geoid import ellipsoidal_height
from ins_hil.nav import earth
from ins_hil.nav.rotation import dcm_from_quat_many
from ins_hil.types import ImuSample, MagSample, Vec

#: 1/s: the smallest rotor-drag coefficient a multirotor is taken to have (the shipped quadrotors: 0.10–0.22 from
#: their GNSS-aided velocity; PX4's EKF2_MCOEF default 0.15)
ROTOR_DRAG_MIN = 0.1
#: m/s: the body-axis speed span (5–95 %) below which μ is not fitted
DRAG_SPAN_MIN = 1.0


def _wrap_deg(a: Vec) -> Vec:
    """Angles (°) wrapped to [−180, 180)."""
    return (a + 180.0) % 360.0 - 180.0


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


def datum_origin(tr: Trajectory) -> tuple[float, float, float] | None:
    """The trajectory's origin on our datum (WGS84 ellipsoidal height): an MSL origin height (``origin_datum``
    "msl") plus the EGM96 undulation there (:func:`ins_hil.geoid.ellipsoidal_height`)."""
    if tr.origin is None:
        return None
    lat, lon, h = tr.origin
    if tr.origin_datum == "msl":
        return (lat, lon, ellipsoidal_height(lat, lon, h))
    if tr.origin_datum != "wgs84":
        raise ValueError(f"{tr.name}: origin datum {tr.origin_datum!r}: expected 'wgs84' or 'msl'")
    return tr.origin


def valid_span(tr: Trajectory, t_from: float, t_to: float, takeoff: float | None = None,
               landing: float | None = None) -> tuple[float, float, str]:  # fmt: skip
    """The part of [t_from, t_to] (s) where an onboard estimate is compared: in the air (``takeoff`` to ``landing``
    when the log has them) and before its own status says it is invalid (``Trajectory.t_valid_end``); (from, to,
    why it was trimmed, "" when not)."""
    a, b, why = t_from, t_to, []
    if takeoff is not None and takeoff > a:
        a = takeoff
        why.append("from take-off")
    if landing is not None and landing < b:
        b = landing
        why.append("to landing")
    if tr.t_valid_end is not None and tr.t_valid_end < b:
        b = tr.t_valid_end
        why.append(f"until {tr.name}'s status says invalid")
    return a, b, ", ".join(why)


def compare(r: RunResult, tr: Trajectory, t_from: float, t_to: float) -> dict[str, Any]:
    """Differences ours − ``tr`` in [t_from, t_to] (s): attitude (deg), velocity (m/s), position (m) of the point
    ``tr.lever_b`` (body FRD from the IMU) on one datum (WGS84 heights: :func:`datum_origin`)."""
    out: dict[str, Any] = {"against": tr.name, "from_s": t_from, "to_s": t_to}
    series: dict[str, Vec] = {}
    if tr.q_nb is not None and tr.t_att is not None:
        m, i = _ours_at(r, tr.t_att, t_from, t_to)
        if np.any(m):
            theirs = euler_series(tr.q_nb[m])
            d = np.degrees(euler_series(r.q_nb[i]) - theirs)
            d = _wrap_deg(d)
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
            lever = np.asarray(tr.lever_b, dtype=np.float64)
            if np.any(lever != 0.0):  # the point the positions refer to: our IMU + C_nb lever
                ours = ours + np.matmul(dcm_from_quat_many(r.q_nb[i]), lever[:, None])[:, :, 0]
            origin = datum_origin(tr)
            if origin is not None:
                ours = ours + earth.ned_from_geodetic(*r.origin, *origin)
                how = "about the estimator's origin (WGS84 heights)"
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


def rotor_drag(imu: list[ImuSample], t_v: Vec, v_ned: Vec, t_q: Vec, q_nb: Vec, t_from: float, t_to: float,
               avg_s: float = 0.5) -> dict[str, Any] | None:  # fmt: skip
    """The rotor-drag fit of a velocity against the accelerometers over [t_from, t_to] (s).

    In bins of ``avg_s`` s: the mean body specific force f (m/s², from the IMU increments) and the mean body
    velocity v = Cᵀ v_ned (m/s, C the same estimate's attitude at or before each velocity sample); per body
    axis x, y the least-squares f = c − μ v. Returns per axis ``mu_per_s`` (NaN where the speed span is below
    :data:`DRAG_SPAN_MIN`), ``corr``, ``residual_mps2``, ``f_std_mps2`` (the specific force's spread over the
    bins), ``span_mps`` (5–95 % of v) and ``expected_mps2`` = :data:`ROTOR_DRAG_MIN` × span (what the smallest
    rotor drag would have moved f by); None when fewer than 20 bins have both. Velocity samples with a NaN are
    left out."""
    ok = np.all(np.isfinite(v_ned), axis=1) & (t_v >= t_from) & (t_v < t_to)
    if not np.any(ok) or len(t_q) == 0:
        return None
    tv, vn = t_v[ok], v_ned[ok]
    iq = np.clip(np.searchsorted(t_q, tv, "right") - 1, 0, len(t_q) - 1)
    # Cᵀ v per sample: the stacked product (numpy's matmul of each 3×3 with its vector, the per-sample numbers)
    vb = np.matmul(dcm_from_quat_many(q_nb[iq]).transpose(0, 2, 1), vn[:, :, None])[:, :, 0]
    ti = np.array([s.t for s in imu])
    m = (ti >= t_from) & (ti < t_to)
    inside = [s for s, k in zip(imu, m.tolist(), strict=True) if k]
    dv = np.array([s.dvel for s in inside]).reshape(-1, 3)
    dt = np.array([s.dt for s in inside])
    n_bins = int((t_to - t_from) // avg_s)
    bi = ((ti[m] - t_from) // avg_s).astype(int)
    bv = ((tv - t_from) // avg_s).astype(int)
    cnt_i = np.bincount(bi, minlength=n_bins)[:n_bins]
    cnt_v = np.bincount(bv, minlength=n_bins)[:n_bins]
    use = (cnt_i >= 3) & (cnt_v >= 1)
    if use.sum() < 20:
        return None
    sdt = np.bincount(bi, dt, n_bins)[:n_bins]
    out: dict[str, Any] = {"bins": int(use.sum()), "avg_s": avg_s}
    for a, ax in enumerate(("x", "y")):
        f = (np.bincount(bi, dv[:, a], n_bins)[:n_bins] / np.maximum(sdt, 1e-12))[use]
        v = (np.bincount(bv, vb[:, a], n_bins)[:n_bins] / np.maximum(cnt_v, 1))[use]
        A = np.column_stack([np.ones(len(v)), v])
        c, *_ = np.linalg.lstsq(A, f, rcond=None)
        span = float(np.percentile(v, 95) - np.percentile(v, 5))
        sv, sf = float(np.std(v)), float(np.std(f))
        out[ax] = {
            "mu_per_s": float(-c[1]) if span >= DRAG_SPAN_MIN else math.nan,
            "corr": float(np.corrcoef(v, f)[0, 1]) if sv > 0 and sf > 0 else math.nan,
            "residual_mps2": float(np.sqrt(np.mean((f - A @ c) ** 2))),
            "f_std_mps2": sf,
            "span_mps": span,
            "expected_mps2": ROTOR_DRAG_MIN * span,
        }
    return out


def drag_unsensed(fit: dict[str, Any] | None) -> str | None:
    """The body axis ("x" / "y") whose velocity the specific force does not follow, None if each does (or
    cannot tell): a span of at least 3 m/s, the smallest rotor drag's expected change above 5× the specific
    force's whole spread, and a fitted μ below a third of :data:`ROTOR_DRAG_MIN`."""
    if fit is None:
        return None
    for ax in ("x", "y"):
        d = fit[ax]
        small = abs(d["mu_per_s"]) < ROTOR_DRAG_MIN / 3
        if d["span_mps"] >= 3.0 and d["expected_mps2"] > 5.0 * d["f_std_mps2"] and small:
            return ax
    return None


def mag_heading(
    mag: list[MagSample], t_q: Vec, q_nb: Vec, ref_ned: Vec, t_from: float, t_to: float
) -> dict[str, Any] | None:
    """An estimate's yaw against the magnetometer's own heading over [t_from, t_to] (s): each reading levelled
    with the estimate's attitude at or before it, C m_b, whose horizontal direction less the reference field's
    (``ref_ned``, its declination) is the estimate's yaw less the magnetic heading (°, wrapped to ±180).
    RMS / max |·| / mean, and (``_t``, ``_heading_deg``) the magnetic heading itself for the plots; None for
    fewer than 10 readings."""
    t = np.array([m.t for m in mag])
    ok = (t >= t_from) & (t <= t_to) & (t >= t_q[0]) if len(t_q) else np.zeros(len(t), bool)
    if ok.sum() < 10:
        return None
    iq = np.searchsorted(t_q, t[ok], "right") - 1
    ref = math.atan2(float(ref_ned[1]), float(ref_ned[0]))
    fb = np.array([m.field_b for m, k in zip(mag, ok.tolist(), strict=True) if k], dtype=np.float64).reshape(-1, 3)
    mn = np.matmul(dcm_from_quat_many(q_nb[iq]), fb[:, :, None])[:, :, 0]  # C m_b per reading (matmul's numbers)
    d = [math.degrees(math.atan2(e, n) - ref) for n, e in zip(mn[:, 0].tolist(), mn[:, 1].tolist(), strict=True)]
    x = _wrap_deg(np.array(d))
    rms, mx = float(np.sqrt(np.mean(x**2))), float(np.max(np.abs(x)))
    yaw = np.degrees(euler_series(q_nb[iq])[:, 2])
    heading = _wrap_deg(yaw - x)  # the magnetic heading with this estimate's tilt (for the plots)
    return {"n": len(x), "rms": rms, "max": mx, "mean": float(np.mean(x)), "_t": t[ok], "_heading_deg": heading}
