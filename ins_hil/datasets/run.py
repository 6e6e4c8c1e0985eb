"""Replay a :class:`~ins_hil.datasets.dataset.Dataset` causally through ``NavCore`` (pure: no I/O, no plots).

:func:`prepare` applies the dataset config (IMU → body mounting, time offsets, which aids) and resolves the
magnetic reference; :func:`run_dataset` steps the core sample by sample, fusing every measurement after the
IMU step that reaches its time, scores each GNSS fix before it is fused (the a-priori antenna error) and
after, removes GNSS inside the outage windows and scores the core there against the fixes it did not get,
with the two trivial predictors ("hold the last fix", "constant-velocity extrapolation") beside it. The
onboard-estimator comparison is :mod:`ins_hil.datasets.compare`.
"""

from __future__ import annotations

import dataclasses
import math
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from ins_hil.core import GAP_MAX_S, NavConfig, NavCore
from ins_hil.datasets.config import DatasetConfig
from ins_hil.datasets.dataset import Dataset, DatasetError, increasing
from ins_hil.datasets.evaluate import antenna_ned
from ins_hil.nav import alignment, earth
from ins_hil.nav.rotation import dcm_from_euler, dcm_from_quat
from ins_hil.types import BaroSample, FaultMode, GnssFix, ImuSample, MagSample, Vec
from ins_hil.validation import Limits, SampleValidator

Progress = Callable[[int, int], None]
#: the flight controllers' log formats: without a magnetometer their yaw comes from the GNSS-velocity yaw bank
FC_FORMATS = frozenset({"px4-ulog", "px4-csv", "ardupilot-bin", "ardupilot-log"})
#: WMM coefficient files shipped with pygeomag, by the first year of their epoch
WMM_EPOCHS = ((2025, "WMM_2025.COF"), (2020, "WMM_2020.COF"), (2015, "WMM_2015v2.COF"), (2010, "WMM_2010.COF"))


#: the validation boundary of a replay: the gateway's (:class:`ins_hil.validation.SampleValidator`, its default
#: ranges) with room for the intervals a reader bridges over a logging gap (PX4: up to 50 ms in one interval)
REPLAY_LIMITS = Limits(imu_dt_max_periods=20.0)
#: an IMU time gap (s) longer than the core coasts across (``ins_hil.core.GAP_MAX_S``) splits the log: its
#: longest part is replayed
SPLIT_GAP_S = GAP_MAX_S


class ReplayError(DatasetError):
    """A replay that cannot give figures: no valid IMU data, non-finite states, a numerical failure (one line
    naming the recording and where it happened)."""


@dataclass
class Screened:
    """The streams that pass the validation boundary, and what it dropped (notes)."""

    imu: list[ImuSample]
    gnss: list[GnssFix]
    aux: list[BaroSample | MagSample]
    notes: list[str]


def _counted(reasons: dict[str, int]) -> str:
    return ", ".join(f"{k} {n}" for k, n in sorted(reasons.items()))


def screen(
    imu: list[ImuSample], gnss: list[GnssFix], aux: list[BaroSample | MagSample], source: str,
    limits: Limits = REPLAY_LIMITS,
) -> Screened:  # fmt: skip
    """The replay's validation boundary, the gateway's own (:class:`ins_hil.validation.SampleValidator`): each
    sample finite and in range, the time strictly increasing per sensor (of the times out of order, the longest
    increasing run is kept: one stamp far off costs that sample only); an IMU gap longer than ``SPLIT_GAP_S``
    splits the log and its longest part is replayed (the aiding within it), a shorter one is coasted by the core.
    What is dropped is said in the notes. ReplayError when no IMU sample is left."""
    v = SampleValidator(limits)
    notes: list[str] = []
    why: dict[str, int] = {}

    def drop(reason: str) -> None:
        why[reason] = why.get(reason, 0) + 1

    order = increasing([s.t for s in imu])
    ok_imu: list[ImuSample] = []
    for s, keep in zip(imu, order, strict=True):
        r = v.imu(s) if keep else "imu_time"
        if r is None:
            ok_imu.append(s)
        else:
            drop(r)
    if why:
        notes.append(f"validation: {sum(why.values())} of {len(imu)} IMU samples dropped ({_counted(why)})")
    if not ok_imu:
        raise ReplayError(f"{source}: no IMU sample passes the validation boundary"
                          + (f" ({_counted(why)})" if why else ""))  # fmt: skip
    # split at the gaps the core would not coast across: the longest part (by samples) is replayed
    cuts = [0] + [k for k in range(1, len(ok_imu)) if ok_imu[k].t - ok_imu[k].dt - ok_imu[k - 1].t > SPLIT_GAP_S]
    if len(cuts) > 1:
        ends = [*cuts[1:], len(ok_imu)]
        a, b = max(zip(cuts, ends, strict=True), key=lambda ab: ab[1] - ab[0])
        notes.append(f"IMU time gaps over {SPLIT_GAP_S:g} s split the log in {len(cuts)} parts: the longest, "
                     f"{ok_imu[a].t:.2f}–{ok_imu[b - 1].t:.2f} s ({b - a} samples), is replayed")  # fmt: skip
        ok_imu = ok_imu[a:b]
        lo, hi = ok_imu[0].t - ok_imu[0].dt - SPLIT_GAP_S, ok_imu[-1].t
        gnss = [f for f in gnss if lo <= f.t <= hi]
        aux = [m for m in aux if lo <= m.t <= hi]
    gw: dict[str, int] = {}
    fixes = [f for f in gnss if math.isfinite(f.t)]
    gw["gnss_nonfinite"] = len(gnss) - len(fixes)
    fixes.sort(key=lambda f: f.t)
    order = increasing([f.t for f in fixes])
    ok_gnss = []
    for f, keep in zip(fixes, order, strict=True):
        r = v.gnss(f) if keep else "gnss_time"
        if r is None:
            ok_gnss.append(f)
        else:
            gw[r] = gw.get(r, 0) + 1
    gw = {k: n for k, n in gw.items() if n}
    if gw:
        notes.append(f"validation: {sum(gw.values())} of {len(gnss)} GNSS fixes dropped ({_counted(gw)})")
    aw: dict[str, int] = {}
    ok_aux = []
    for m in aux:
        r = v.check(m)
        if r is None:
            ok_aux.append(m)
        else:
            aw[r] = aw.get(r, 0) + 1
    if aw:
        notes.append(f"validation: {sum(aw.values())} of {len(aux)} baro / magnetometer samples dropped "
                     f"({_counted(aw)})")  # fmt: skip
    return Screened(ok_imu, ok_gnss, ok_aux, notes)


@dataclass
class Prepared:
    """The dataset after the config: streams to fuse, the NavConfig and notes."""

    imu: list[ImuSample]
    gnss: list[GnssFix]
    aux: list[BaroSample | MagSample]
    nav: NavConfig
    t0: float
    t1: float
    origin: tuple[float, float, float]
    notes: list[str] = field(default_factory=list)
    mag_ref_ned_T: Vec | None = None
    mag_ref_source: str = ""
    mag_heading_only: bool = True
    source: str = ""  # the recording, for the errors


def _decimal_year(unix_s: float) -> float:
    import datetime as _dt

    d = _dt.datetime.fromtimestamp(unix_s, _dt.UTC)
    y0 = _dt.datetime(d.year, 1, 1, tzinfo=_dt.UTC)
    y1 = _dt.datetime(d.year + 1, 1, 1, tzinfo=_dt.UTC)
    return d.year + (d - y0).total_seconds() / (y1 - y0).total_seconds()


def wmm_field(lat: float, lon: float, h: float, year: float) -> tuple[Vec, str]:
    """The World Magnetic Model field (NED, tesla) at lat/lon (rad), h (m), decimal ``year``, with pygeomag's
    coefficient file of that epoch (offline); ValueError outside the shipped epochs."""
    from pygeomag import GeoMag

    cof = next((f for y0, f in WMM_EPOCHS if y0 <= year < y0 + 5), None)
    if cof is None:
        raise ValueError(f"no WMM epoch for {year:.2f} (pygeomag ships 2010–2030)")
    r = GeoMag(coefficients_file=f"wmm/{cof}").calculate(
        glat=math.degrees(lat), glon=math.degrees(lon), alt=h / 1000.0, time=year
    )
    where = f"{math.degrees(lat):.4f}°, {math.degrees(lon):.4f}°, {year:.2f}"
    return np.array((r.x, r.y, r.z)) * 1e-9, f"WMM {cof[:-4]} at {where}"


def field_at_rest(imu: list[ImuSample], mag: list[MagSample], t_from: float, t_to: float, decl: float) -> Vec | None:
    """A magnetic reference (NED, the readings' unit) from the data at rest in [t_from, t_to] s: the mean field
    levelled with the mean specific force (book §4.1.1) gives the dip and the strength; its direction in the
    horizontal plane is set to the declination ``decl`` (rad)."""
    f = [s.dvel / s.dt for s in imu if t_from <= s.t <= t_to]
    m = [x.field_b for x in mag if t_from <= x.t <= t_to]
    if len(f) < 10 or not m:
        return None
    roll, pitch = alignment.coarse_level(np.mean(f, axis=0))
    mn = dcm_from_euler(roll, pitch, 0.0) @ np.mean(m, axis=0)
    hz = math.hypot(float(mn[0]), float(mn[1]))
    return np.array((hz * math.cos(decl), hz * math.sin(decl), float(mn[2])))


def prepare(ds: Dataset, cfg: DatasetConfig) -> Prepared:
    """Apply the dataset config to ``ds`` (causal streams for the core; nothing from the onboard estimate)."""
    notes: list[str] = list(ds.meta.get("notes", []))
    R = cfg.mounting_dcm()  # IMU axes → body FRD
    rot = cfg.rotated
    off = cfg.imu_time_offset
    applied = ds.meta.get("mounted")  # what the reader applied already (rtklib): only the difference is applied
    if applied:
        off -= float(applied["imu_time_offset_s"])
        same = np.array_equal(cfg.imu_to_body, applied["imu_to_body"])
        rot = not same
        if rot:
            was = dataclasses.replace(cfg, imu_to_body=np.asarray(applied["imu_to_body"]))
            R = R @ was.mounting_dcm().T
    t1 = ds.t1
    source = str(ds.meta.get("source", "the dataset"))
    if ds.imu and not ds.imu[0].t <= t1:
        raise ReplayError(f"{source}: the end of valid data ({t1:.2f} s) comes before the first IMU sample "
                          f"({ds.imu[0].t:.2f} s): nothing to replay")  # fmt: skip
    if applied and not rot and off == 0.0:
        imu = [s for s in ds.imu if s.t <= t1]
    else:
        imu = [dataclasses.replace(s, t=s.t + off, dtheta=R @ s.dtheta, dvel=R @ s.dvel) if rot else
               dataclasses.replace(s, t=s.t + off) for s in ds.imu if s.t <= t1]  # fmt: skip
    gnss = [dataclasses.replace(f, t=f.t + cfg.gnss_time_offset) for f in ds.gnss] if cfg.use_gnss else []
    mag = [dataclasses.replace(m, field_b=R @ m.field_b) if rot else m for m in ds.mag] if cfg.use_mag else []
    baro = list(ds.baro) if cfg.use_baro else []
    # the validation boundary (the gateway's): what the core is given is finite, in range and in time order
    sc = screen(imu, gnss, [*baro, *mag], source)
    notes += sc.notes
    imu, gnss = sc.imu, sc.gnss
    baro = [m for m in sc.aux if isinstance(m, BaroSample)]
    mag = [m for m in sc.aux if isinstance(m, MagSample)]
    nav = cfg.nav_config()
    if gnss:
        origin = (gnss[0].lat, gnss[0].lon, gnss[0].h)
    elif cfg.position is not None:
        origin = cfg.position
    else:
        origin = (0.0, 0.0, 0.0)
    p = Prepared(imu, gnss, [], nav, imu[0].t, imu[-1].t, origin, notes, source=source)
    if mag and "ref_ned" not in cfg.nav.get("mag", {}):
        ref: Vec | None = None
        if isinstance(cfg.mag_reference, np.ndarray):
            ref, p.mag_ref_source = cfg.mag_reference * 1e-6, "the dataset config"
        elif cfg.mag_reference == "wmm":
            utc = ds.meta.get("utc_start_s")
            have_pos = bool(gnss) or cfg.position is not None
            if utc is None or not have_pos:
                notes.append("magnetometer not used: the WMM needs the log's position and date "
                             f"({'no date' if utc is None else 'no position'}); set aiding.mag_reference")  # fmt: skip
            else:
                try:
                    ref, p.mag_ref_source = wmm_field(*origin, _decimal_year(float(utc)))
                except ValueError as e:
                    notes.append(f"magnetometer not used: {e}")
        else:
            t_to = ds.event("takeoff") or (p.t0 + 5.0)
            ref = field_at_rest(imu, mag, p.t0, min(t_to, p.t0 + 10.0) - 0.5, cfg.declination)
            p.mag_ref_source = (
                f"levelled field at rest before take-off, declination {math.degrees(cfg.declination):.2f}°"
            )
            if ref is None:
                notes.append("magnetometer not used: no rest before take-off to measure the field")
        if ref is not None:
            p.mag_ref_ned_T = ref
            nav = dataclasses.replace(nav, mag=dataclasses.replace(nav.mag, ref_ned=ref))
        else:
            mag = []
    if gnss and not mag and ds.meta.get("format") in FC_FORMATS and "yaw_gsf" not in cfg.nav.get("alignment", {}):
        # a flight log without a magnetometer: the yaw from GNSS velocity changes, as EKF2 does (its EKF-GSF),
        # not from the course, which a multicopter's heading does not follow
        nav = dataclasses.replace(nav, alignment=dataclasses.replace(nav.alignment, yaw_gsf=True))
        notes.append("no magnetometer: the yaw from the GNSS-velocity yaw bank (EKF2's EKF-GSF), not the course")
    p.nav = nav
    p.mag_heading_only = cfg.mag_heading_only
    p.aux = sorted([*baro, *mag], key=lambda m: m.t)
    if not gnss and cfg.no_gnss_hold:
        # no absolute aiding in the log: the core's own hold (core_parts/hold.py; EKF2's fake position) from the
        # start, at the start point, with the dataset's σ and rate
        lat, lon, h = origin
        al = p.nav.alignment
        p.nav = dataclasses.replace(
            p.nav,
            hold=dataclasses.replace(p.nav.hold, enabled=True, after=0.0, std=cfg.hold_std, vel_std=cfg.hold_vel_std,
                                     rate=cfg.hold_rate),
            alignment=al if al.position is not None else dataclasses.replace(
                al, position=(math.degrees(lat), math.degrees(lon), float(h))),
        )  # fmt: skip
        notes.append(
            f"no GNSS fix in the log: constant-position hold (σ {cfg.hold_std:g} m"
            + (f", zero velocity σ {cfg.hold_vel_std:g} m/s" if cfg.hold_vel_std > 0 else "")
            + f", {cfg.hold_rate:g} Hz) keeps the tilt observable (EKF2's no-aiding mode)"
        )
    return p


def heading_only(m: MagSample, q_nb: Vec, ref_ned: Vec | None) -> MagSample:
    """The magnetometer as a heading measurement only (EKF2's heading fusion): the reading is levelled with the
    current attitude estimate ``q_nb``, its magnetic heading taken, and replaced by the reference field turned by
    the heading difference, expressed in body axes with the same attitude. The core's field update then sees a
    pure rotation about down: a dip or field error of the magnetometer (motor currents, residual hard iron) no
    longer tilts the solution."""
    if ref_ned is None:
        return m
    C = dcm_from_quat(q_nb)  # body → NED
    mn = C @ m.field_b
    d = math.atan2(float(mn[1]), float(mn[0])) - math.atan2(float(ref_ned[1]), float(ref_ned[0]))
    cd, sd = math.cos(d), math.sin(d)
    Rz = np.array(((cd, -sd, 0.0), (sd, cd, 0.0), (0.0, 0.0, 1.0)))
    return dataclasses.replace(m, field_b=C.T @ (Rz @ np.asarray(ref_ned)))


@dataclass
class RunResult:
    """A replay's record: the state at every navigating IMU step and the GNSS scores."""

    label: str
    origin: tuple[float, float, float]
    t: Vec
    q_nb: Vec
    vel_ned: Vec
    ned: Vec  # IMU position, m from ``origin``
    std_pos: Vec
    std_att: Vec
    t_nav: float  # first navigating step (s), NaN if never
    gnss_t: Vec  # fixes scored (s)
    gnss_err: Vec  # a-priori antenna error vs the fix (NED m)
    gnss_post: Vec  # a-posteriori (fused fixes; NaN inside outages)
    gnss_inside: Vec  # bool: inside an outage
    gnss_std: Vec  # the core's σ (NED m) at the prior
    gnss_ref: Vec  # the fix (NED m)
    gnss_fix: Vec  # its FixType (int)
    outages: list[tuple[float, float]]
    stats: dict[str, dict[str, int]]
    elapsed_s: float
    notes: list[str] = field(default_factory=list)
    align_status: str = ""  # why the core had not navigated at the end ("" when it did)
    imu_lost: tuple[int, float] = (0, 0.0)  # IMU gaps the core coasted across while navigating (count, s)
    vel_innov: Vec = field(default_factory=lambda: np.zeros((0, 4)))  # GNSS velocity innovations: t s, z NED m/s
    imu_gaps: Vec = field(default_factory=lambda: np.zeros((0, 2)))  # each coasted gap: its end (s), lost (s)
    rate_bins: Vec = field(default_factory=lambda: np.zeros((0, 2)))  # |mean body rate| per RATE_BIN_S: t s, rad/s
    sf_corr: Vec = field(default_factory=lambda: np.zeros((0, 3)))  # per fused fix: t s, Δ horizontal f NED m/s²
    divergences: list[tuple[float, str]] = field(default_factory=list)  # the core's divergence resets: t s, why
    sensor_warnings: list[str] = field(default_factory=list)  # the core's start-up IMU check (mounting, noise)
    yaw_resets: list[tuple[float, str]] = field(default_factory=list)  # the core's emergency yaw resets: t s, why


def run_dataset(p: Prepared, outages: list[tuple[float, float]] = (), label: str = "",  # type: ignore[assignment]
                progress: Progress | None = None) -> RunResult:  # fmt: skip
    """Replay ``p`` causally; GNSS inside ``outages`` (s, absolute) is scored, never fused. ReplayError (one line
    naming the recording and the time) when the state becomes non-finite or the core fails numerically."""
    at = [math.nan]
    try:
        return _run_dataset(p, outages, label, progress, at)
    except ReplayError:
        raise
    except (ArithmeticError, ValueError, np.linalg.LinAlgError) as e:
        raise ReplayError(f"{p.source or label or 'replay'}: the replay failed at t = {at[0]:.3f} s "
                          f"({type(e).__name__}: {' '.join(str(e).split())[:120]})") from None  # fmt: skip


def _run_dataset(p: Prepared, outages: list[tuple[float, float]], label: str, progress: Progress | None,
                 at: list[float]) -> RunResult:  # fmt: skip
    """:func:`run_dataset`'s loop; ``at[0]``: the time of the IMU sample being processed (for an error)."""
    core = NavCore(None, p.nav)
    core.innov_kinds = frozenset({"gnss_vel"})  # the GNSS velocity innovations, for innovation_whiteness
    lever = p.nav.gnss.lever_arm_b
    origin = p.origin
    meas: list[tuple[float, int, Any]] = [(f.t, 0, f) for f in p.gnss]
    meas += [(m.t, 2, m) for m in p.aux]
    meas.sort(key=lambda x: (x[0], x[1]))
    T: list[float] = []
    Q: list[Vec] = []
    V: list[Vec] = []
    P: list[Vec] = []
    SP: list[Vec] = []
    SA: list[Vec] = []
    gt: list[float] = []
    ge: list[Vec] = []
    gp: list[Vec] = []
    gi: list[bool] = []
    gs: list[Vec] = []
    gr: list[Vec] = []
    gf: list[int] = []
    corr: list[tuple[float, float, float]] = []
    j = 0
    n = len(p.imu)
    t_nav = math.nan
    nan3 = np.full(3, math.nan)
    t_start = time.perf_counter()
    for k, s in enumerate(p.imu):
        at[0] = s.t
        core.step(s)
        while j < len(meas) and meas[j][0] <= s.t:
            _, kind, m = meas[j]
            j += 1
            if kind != 0:
                if p.mag_heading_only and isinstance(m, MagSample) and core.phase == "nav":
                    m = heading_only(m, core.ins.state.q_nb, p.nav.mag.ref_ned)
                core.fuse(m)
                continue
            inside = any(a <= m.t < b for a, b in outages)
            ref = earth.ned_from_geodetic(m.lat, m.lon, m.h, *origin)
            nav = core.phase == "nav"
            if nav:
                gt.append(m.t)
                ge.append(antenna_ned(core, lever, m.t, origin) - ref)
                gs.append(core.state().std_pos)
                gi.append(inside)
                gr.append(ref)
                gf.append(int(m.fix_type))
            if not inside:
                if nav:  # how far the fix's attitude and bias corrections move an unaccelerated vehicle's f (NED)
                    g_n = np.array((0.0, 0.0, -core.g_local))
                    f_raw = dcm_from_quat(core.ins.state.q_nb).T @ g_n + core.ba  # its accelerometer reading
                    core.fuse(m)
                    f1 = dcm_from_quat(core.ins.state.q_nb) @ (f_raw - core.ba)
                    corr.append((s.t, float(f1[0]), float(f1[1])))
                else:
                    core.fuse(m)
            if nav:
                gp.append(nan3 if inside else antenna_ned(core, lever, m.t, origin) - ref)
        if core.phase == "nav":
            st = core.ins.state
            if not math.isfinite(st.lat + st.lon + st.h + float(np.sum(st.vel_ned)) + float(np.sum(st.q_nb))):
                raise ReplayError(f"{p.source or label or 'replay'}: non-finite navigation states from t = {s.t:.3f} s "
                                  f"({s.t - p.t0:.2f} s into the data): no figures")  # fmt: skip
            if math.isnan(t_nav):
                t_nav = s.t
            T.append(s.t)
            Q.append(st.q_nb)
            V.append(st.vel_ned)
            P.append(earth.ned_from_geodetic(st.lat, st.lon, st.h, *origin))
            sd = core.state()
            SP.append(sd.std_pos)
            SA.append(sd.std_att)
        if progress is not None and (k % 2000 == 0 or k == n - 1):
            progress(k + 1, n)

    def arr(x: list[Any], w: int) -> Vec:
        return np.array(x, dtype=np.float64) if x else np.zeros((0, w) if w else 0)

    # the core's own record of each IMU gap it coasted across: its end (s) and the data lost (s)
    gaps = [(e.t, e.magnitude) for e in core.drain_events() if e.sensor == "imu" and e.mode == FaultMode.DROPOUT]

    return RunResult(
        label, origin, arr(T, 0), arr(Q, 4), arr(V, 3), arr(P, 3), arr(SP, 3), arr(SA, 3), t_nav, arr(gt, 0),
        arr(ge, 3), arr(gp, 3), np.array(gi, dtype=bool), arr(gs, 3), arr(gr, 3), np.array(gf, dtype=int),
        list(outages),
        {k: {"accepted": v.accepted, "rejected": v.rejected} for k, v in core.stats.items()},
        time.perf_counter() - t_start, list(p.notes), core.align_status(), core.imu_lost,
        np.array([(t, *z) for t, _, z in core.innov_log]).reshape(-1, 4), arr(gaps, 2), rate_bins(p.imu),
        arr(corr, 3), list(core.divergences), list(core.sensor_warnings), list(getattr(core, "yaw_resets", ())),
    )  # fmt: skip


#: the bin (s) of :func:`rate_bins`: a turn's rate, not the vibration's
RATE_BIN_S = 0.25
#: how far back (s) :func:`outage_scores` looks for what preceded each outage
LOOKBACK_S = 10.0
#: the span (s) over which :func:`preceded_by` sums the fixes' specific-force corrections
CORR_S = 5.0


def rate_bins(imu: list[ImuSample]) -> Vec:
    """(M, 2): the start of each ``RATE_BIN_S`` bin (s) and the norm of the mean body rate in it (rad/s):
    the vehicle's turns with its vibration averaged out."""
    if not imu:
        return np.zeros((0, 2))
    t = np.fromiter((s.t for s in imu), np.float64, len(imu))
    d = np.array([s.dtheta for s in imu])
    dt = np.fromiter((s.dt for s in imu), np.float64, len(imu))
    # the bins that hold samples only: the arrays are sized by the samples, never by the time span
    bins, k = np.unique((t - t[0]) // RATE_BIN_S, return_inverse=True)
    ang = np.zeros((len(bins), 3))
    tim = np.zeros(len(bins))
    np.add.at(ang, k, d)
    np.add.at(tim, k, dt)
    ok = tim > 0
    return np.column_stack([t[0] + RATE_BIN_S * bins[ok], np.linalg.norm(ang[ok], axis=1) / tim[ok]])


def preceded_by(r: RunResult, a: float, lookback: float = LOOKBACK_S) -> dict[str, float]:
    """What came in the ``lookback`` s before an outage opened at ``a`` s: IMU data lost (s, coasted) and the
    time since that loss ended (s; NaN without one), the peak turn rate (°/s, :func:`rate_bins`) and the time
    since it (s): an outage that opens soon after either starts from a state the filter is still re-learning."""
    g = r.imu_gaps[(r.imu_gaps[:, 0] > a - lookback) & (r.imu_gaps[:, 0] <= a)] if len(r.imu_gaps) else r.imu_gaps
    b = r.rate_bins[(r.rate_bins[:, 0] >= a - lookback) & (r.rate_bins[:, 0] + RATE_BIN_S <= a)]
    k = int(np.argmax(b[:, 1])) if len(b) else -1
    return {"imu_lost_s": float(g[:, 1].sum()) if len(g) else 0.0,
            "since_imu_lost_s": float(a - g[-1, 0]) if len(g) else math.nan,
            "peak_rate_dps": math.degrees(float(b[k, 1])) if k >= 0 else math.nan,
            "since_peak_rate_s": float(a - b[k, 0] - RATE_BIN_S) if k >= 0 else math.nan,
            "sf_corr_mps2": corrections(r, a - CORR_S, a)}  # fmt: skip


def corrections(r: RunResult, t0: float, t1: float) -> float:
    """The norm of the summed horizontal specific-force corrections (m/s², NED) of the fixes fused in [t0, t1) s:
    how far the GNSS was still moving the filter's tilt and accelerometer bias (a settled filter's corrections
    cancel out)."""
    c = r.sf_corr[(r.sf_corr[:, 0] >= t0) & (r.sf_corr[:, 0] < t1)] if len(r.sf_corr) else r.sf_corr
    return float(np.hypot(*c[:, 1:3].sum(axis=0))) if len(c) else 0.0


def typical_corrections(r: RunResult) -> float:
    """The median of :func:`corrections` over consecutive ``CORR_S`` spans of the replay that hold fused fixes
    (m/s²; NaN without any): what a settled filter's corrections add up to on this log."""
    if not len(r.sf_corr):
        return math.nan
    t = r.sf_corr[:, 0]
    edges = np.arange(t[0], t[-1], CORR_S)
    sums = [corrections(r, e, e + CORR_S) for e in edges if np.any((t >= e) & (t < e + CORR_S))]
    return float(np.median(sums)) if sums else math.nan


def hrms(e: Vec) -> float:
    """Horizontal RMS (m) of NED errors (N, 3); NaN for none."""
    return float(np.sqrt(np.mean(e[:, 0] ** 2 + e[:, 1] ** 2))) if len(e) else math.nan


def hmax(e: Vec) -> float:
    return float(np.max(np.hypot(e[:, 0], e[:, 1]))) if len(e) else math.nan


def gnss_scores(r: RunResult, fixes: list[GnssFix], min_fix: int = 0) -> dict[str, Any]:
    """GNSS-present scores: the a-priori and a-posteriori horizontal antenna error (m) outside outages, at the
    fixes of type ``min_fix`` or better."""
    out = ~r.gnss_inside & (r.gnss_fix >= min_fix)
    pr, po = r.gnss_err[out], r.gnss_post[out]
    return {
        "gnss_epochs": int(out.sum()),
        "gnss_h_rms_prior_m": hrms(pr),
        "gnss_h_max_prior_m": hmax(pr),
        "gnss_v_rms_prior_m": float(np.sqrt(np.mean(pr[:, 2] ** 2))) if len(pr) else math.nan,
        "gnss_h_rms_post_m": hrms(po),
    }


def autocorrelation(t: Vec, x: Vec, lags: int = 3, gap: float = 1.5) -> list[float]:
    """Sample autocorrelation of the series ``x`` (N,) at lags 1 … ``lags`` over pairs of samples that are
    that many steps apart in time too (their time difference within ``(lag + gap − 1)`` median intervals:
    no pair across an outage or a data gap); NaN where fewer than 10 pairs."""
    out = []
    if len(x) < 3:
        return [math.nan] * lags
    d = x - np.mean(x)
    var = float(np.mean(d * d))
    dt = float(np.median(np.diff(t)))
    for lag in range(1, lags + 1):
        ok = (t[lag:] - t[:-lag]) <= (lag + gap - 1.0) * dt
        n = int(ok.sum())
        out.append(float(np.mean(d[lag:][ok] * d[:-lag][ok]) / var) if n >= 10 and var > 0 else math.nan)
    return out


def innovation_whiteness(r: RunResult, settle_s: float = 30.0) -> dict[str, Any] | None:
    """The whiteness of the GNSS velocity innovations (GNSS velocity less the filter's prior, N and E) from
    ``settle_s`` s after the core starts navigating: their RMS and autocorrelation at lags 1–3 (fixes) and the
    95 % band of a white sequence, ±1.96/√n. A filter with the right noise has white innovations (Mehra 1970);
    a negative lag 1 is a filter that weights the GNSS too much for its process noise (each correction
    overshoots), a positive one GNSS errors correlated over the fixes or too little process noise. None
    without velocity innovations."""
    v = r.vel_innov
    if not len(v) or math.isnan(r.t_nav):
        return None
    v = v[v[:, 0] >= r.t_nav + settle_s]
    if len(v) < 20:
        return None
    acs = [autocorrelation(v[:, 0], v[:, 1 + ax]) for ax in range(2)]
    return {
        "n": len(v),
        "rms_mps": [float(np.sqrt(np.mean(v[:, 1 + ax] ** 2))) for ax in range(2)],
        "lag1": [a[0] for a in acs],
        "lag2": [a[1] for a in acs],
        "lag3": [a[2] for a in acs],
        "white_band": 1.96 / math.sqrt(len(v)),
    }


def preceded_text(b: dict[str, Any]) -> str:
    """One line of what preceded an outage (:func:`preceded_by`; as read back from JSON too, NaN as None)."""
    lost, rate = b.get("imu_lost_s") or 0.0, b.get("peak_rate_dps")
    text = (f"{b['since_imu_lost_s']:.1f} s after {lost:.2f} s of lost IMU data" if lost > 0
            else f"no lost IMU data in the {LOOKBACK_S:.0f} s before it")  # fmt: skip
    if rate is not None and math.isfinite(rate):
        text += f", {b['since_peak_rate_s']:.1f} s after a {rate:.0f} °/s turn"
    if b.get("sf_corr_mps2") is not None:  # horizontal specific force: the tilt and the accelerometer bias
        typ = b.get("sf_corr_typical_mps2")
        text += f", the last {CORR_S:.0f} s of fixes moved its tilt {b['sf_corr_mps2']:.2f} m/s²"
        text += f" (typical {typ:.2f})" if typ is not None and math.isfinite(typ) else ""
    return text


def error_growth(tau: Vec, e: Vec) -> tuple[Vec, Vec, float] | None:
    """What an outage's horizontal error is made of: the least-squares fit e(τ) ≈ e₀ + v₀ τ + a τ²/2 of the
    errors ``e`` (N, 2; m, north / east) at ``tau`` (N,) s after the outage began. (v₀ m/s, the velocity error
    it started with; a m/s², the constant specific-force error (tilt or accelerometer bias) that grows it;
    the fit's residual RMS m). None for fewer than 6 epochs."""
    if len(tau) < 6:
        return None
    A = np.column_stack([np.ones_like(tau), tau, 0.5 * tau**2])
    coef, *_ = np.linalg.lstsq(A, e, rcond=None)
    res = e - A @ coef
    return coef[1], coef[2], float(np.sqrt(np.mean(np.sum(res**2, axis=1))))


def tilt_deg(a: float) -> float:
    """The tilt (°) whose gravity component is a horizontal specific force of ``a`` m/s²."""
    return math.degrees(math.atan2(a, earth.G0))


def outage_scores(r: RunResult, fixes: list[GnssFix], min_fix: int = 0) -> dict[str, Any]:
    """Per outage window: the core's horizontal error at each fix (of type ``min_fix`` or better) it did not
    get, against the two trivial
    predictors built from the last fix before the window (hold it; extrapolate it with its velocity), the
    2-dof NEES of the horizontal error with the core's σ, and what the error is made of (:func:`error_growth`:
    the horizontal velocity error at the window's start, m/s, and the specific-force error, m/s², with its
    tilt equivalent, °) beside the filter's own horizontal tilt σ when the window opened (°, √(σ_N² + σ_E²)),
    and what preceded it (``before``: :func:`preceded_by`, with the replay's :func:`typical_corrections`). A window
    that opens before the core navigates is reported as not scored."""
    rows = []
    allf, allh, allc, alln = [], [], [], []
    v0s, sfs, tilt_sd = [], [], []
    ft = np.array([f.t for f in fixes])
    typical = typical_corrections(r)
    for a, b in r.outages:
        row: dict[str, Any] = {"window_s": [a, b]}
        i = np.nonzero(r.gnss_inside & (r.gnss_t >= a) & (r.gnss_t < b) & (r.gnss_fix >= min_fix))[0]
        kl = int(np.searchsorted(ft, a, "left")) - 1  # the last fix before the window
        if not len(i) or kl < 0 or not (r.t_nav <= a):
            row["scored"] = False
            rows.append(row)
            continue
        last = fixes[kl]
        p_last = earth.ned_from_geodetic(last.lat, last.lon, last.h, *r.origin)
        v_last = last.vel_ned if last.vel_ned is not None else np.zeros(3)
        e = r.gnss_err[i]
        eh = r.gnss_ref[i] - p_last
        ec = r.gnss_ref[i] - (p_last + np.outer(r.gnss_t[i] - last.t, v_last))
        sd = r.gnss_std[i]
        nees = (e[:, 0] / sd[:, 0]) ** 2 + (e[:, 1] / sd[:, 1]) ** 2
        row.update({"scored": True, "epochs": len(i), "h_rms_m": hrms(e), "h_max_m": hmax(e),
                    "hold_h_rms_m": hrms(eh), "hold_h_max_m": hmax(eh), "cv_h_rms_m": hrms(ec), "cv_h_max_m": hmax(ec),
                    "nees_2dof": float(np.mean(nees))})  # fmt: skip
        row["beats_both"] = row["h_rms_m"] < row["hold_h_rms_m"] and row["h_rms_m"] < row["cv_h_rms_m"]
        row["before"] = {**preceded_by(r, a), "sf_corr_typical_mps2": typical}
        k0 = int(np.searchsorted(r.t, a, "right")) - 1  # the filter's tilt σ when the window opened
        if k0 >= 0:
            row["start_tilt_std_deg"] = math.degrees(math.hypot(float(r.std_att[k0, 0]), float(r.std_att[k0, 1])))
            tilt_sd.append(row["start_tilt_std_deg"])
        g = error_growth(r.gnss_t[i] - a, e[:, :2])
        if g is not None:
            v0, acc, res = g
            row.update({"start_vel_err_mps": float(np.hypot(*v0)), "sf_err_mps2": float(np.hypot(*acc)),
                        "sf_err_tilt_deg": tilt_deg(float(np.hypot(*acc))),
                        "growth_fit_rms_m": res})  # fmt: skip
            v0s.append(row["start_vel_err_mps"])
            sfs.append(row["sf_err_mps2"])
        rows.append(row)
        allf.append(e)
        allh.append(eh)
        allc.append(ec)
        alln.append(nees)
    cat = lambda x: np.vstack(x) if x else np.zeros((0, 3))
    F, H, C = cat(allf), cat(allh), cat(allc)
    return {
        "windows": rows,
        "outages_scored": len(allf),
        "outage_h_rms_m": hrms(F),
        "outage_h_max_m": hmax(F),
        "hold_h_rms_m": hrms(H),
        "hold_h_max_m": hmax(H),
        "cv_h_rms_m": hrms(C),
        "cv_h_max_m": hmax(C),
        "nees_2dof_mean": float(np.mean(np.concatenate(alln))) if alln else math.nan,
        "beats_both_in_every_outage": bool(allf) and all(w.get("beats_both", True) for w in rows if w["scored"]),
        "start_vel_err_rms_mps": float(np.sqrt(np.mean(np.square(v0s)))) if v0s else math.nan,
        "start_vel_err_max_mps": max(v0s) if v0s else math.nan,
        "sf_err_rms_mps2": float(np.sqrt(np.mean(np.square(sfs)))) if sfs else math.nan,
        "sf_err_rms_tilt_deg": tilt_deg(float(np.sqrt(np.mean(np.square(sfs))))) if sfs else math.nan,
        "sf_err_max_mps2": max(sfs) if sfs else math.nan,
        "start_tilt_std_rms_deg": float(np.sqrt(np.mean(np.square(tilt_sd)))) if tilt_sd else math.nan,
        "start_tilt_std_max_deg": max(tilt_sd) if tilt_sd else math.nan,
    }


def rejection(r: RunResult) -> dict[str, Any]:
    """The innovation gates' rejection rate per kind (fraction of the measurements tested)."""
    out = {}
    for k, v in r.stats.items():
        n = v["accepted"] + v["rejected"]
        if n:
            out[k] = {"tested": n, "rejected": v["rejected"], "rate": v["rejected"] / n}
    return out


def euler_series(q: Vec) -> Vec:
    """(N, 3) roll, pitch, yaw (rad) of quaternions (N, 4), aerospace ZYX."""
    w, x, y, z = q[:, 0], q[:, 1], q[:, 2], q[:, 3]
    roll = np.arctan2(2 * (w * x + y * z), 1 - 2 * (x * x + y * y))
    pitch = np.arcsin(np.clip(2 * (w * y - z * x), -1.0, 1.0))
    yaw = np.arctan2(2 * (w * z + x * y), 1 - 2 * (y * y + z * z))
    return np.column_stack([roll, pitch, yaw])
