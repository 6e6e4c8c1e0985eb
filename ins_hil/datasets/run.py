"""Replay a :class:`~ins_hil.datasets.dataset.Dataset` causally through the gateway's pipeline (pure: no I/O,
no plots).

:func:`replay` is the one offline loop (a dataset, the drive's study, a simulated scenario, a batch job): the
samples in time order through :class:`~ins_hil.runtime.pipeline.Pipeline` as the live gateway runs them
(validation boundary, the aiding drift monitor, delayed fusion in segments), the core aligning itself; the
scoring is done by observers (:class:`~ins_hil.runtime.pipeline.Observer`: :class:`Track`, :class:`GnssScore`,
``ins_hil.datasets.reference.ReferenceScore``, ``ins_hil.datasets.evaluate.TruthScore``).

:func:`prepare` applies the dataset config (IMU → body mounting, time offsets, which aids) and resolves the
magnetic reference; :func:`run_dataset` replays it, scores each GNSS fix before it is fused (the a-priori
antenna error) and after, withholds GNSS inside the outage windows and scores the core there against the fixes
it did not get, with the two trivial predictors ("hold the last fix", "constant-velocity extrapolation") beside
it. The onboard-estimator comparison is :mod:`ins_hil.datasets.compare`.
"""

from __future__ import annotations

import bisect
import dataclasses
import math
import operator
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from typing import Any, cast

import numpy as np

from ins_hil.core import GAP_MAX_S, NavConfig, imu_lost_v
from ins_hil.datasets.config import DatasetConfig
from ins_hil.datasets.dataset import Dataset, DatasetError, increasing
from ins_hil.nav import alignment, earth
from ins_hil.nav.mechanization import StrapdownState
from ins_hil.nav.rotation import dcm_from_euler, dcm_from_quat
from ins_hil.runtime.pipeline import Observer, Pipeline, PipelineConfig
from ins_hil.types import BaroSample, FaultEvent, FaultMode, GnssFix, ImuSample, MagSample, NavState, Vec
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
    imu_arrays: tuple[Vec, Vec, Vec] | None = None  # :func:`imu_arrays` of ``imu`` (when screen built them)


def _counted(reasons: dict[str, int]) -> str:
    return ", ".join(f"{k} {n}" for k, n in sorted(reasons.items()))


def screen(
    imu: list[ImuSample], gnss: list[GnssFix], aux: list[Any], source: str,
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

    arrays = _imu_arrays_or_none(imu)
    order = increasing([s.t for s in imu] if arrays is None else arrays[1])
    acc = np.zeros(len(imu), dtype=bool)  # passed
    start = 0
    if arrays is not None:
        # the samples checked one by one until the validator knows the IMU's period, the rest in one numpy pass
        # (SampleValidator.imu_in_range: the same comparisons); those that fail it one by one, for the reason
        inc, t, dt = arrays
        iid = imu[0].imu_id if imu else 0
        ok: Any = None
        while start < len(imu) and ok is None:
            s = imu[start]
            r = v.imu(s) if order[start] else v.imu_unordered(s)
            if r is None:
                acc[start] = True
            else:
                drop(r)
            start += 1
            ok = v.imu_in_range(iid, dt[start:], inc[start:])
        if ok is not None:
            t_last = v.imu_time(iid)
            ok &= order[start:] & (t[start:] < math.inf)
            if start < len(imu):  # the times of the kept samples increase: only the first is compared here
                ok[0] &= bool(t[start] > t_last)
            for k in np.nonzero(~ok)[0].tolist():  # (the validator's last time is older: its time check passes)
                i = start + k
                r = v.imu(imu[i]) if order[i] else v.imu_unordered(imu[i])
                if r is None:
                    ok[k] = True
                else:
                    drop(r)
            acc[start:] = ok
            if start < len(imu) and ok.any():
                v.imu_screened(iid, float(t[start + int(np.nonzero(ok)[0][-1])]))
            start = len(imu)
    for i in range(start, len(imu)):  # (per sample: more than one IMU, or increments that are not 3-vectors)
        r = v.imu(imu[i]) if order[i] else v.imu_unordered(imu[i])
        if r is None:
            acc[i] = True
        else:
            drop(r)
    idx = np.nonzero(acc)[0]
    ok_imu: list[ImuSample] = [imu[i] for i in idx.tolist()]
    ok_arrays = None if arrays is None else (arrays[0][idx], arrays[1][idx], arrays[2][idx])
    if why:
        notes.append(f"validation: {sum(why.values())} of {len(imu)} IMU samples dropped ({_counted(why)})")
    if not ok_imu:
        raise ReplayError(f"{source}: no IMU sample passes the validation boundary"
                          + (f" ({_counted(why)})" if why else ""))  # fmt: skip
    # split at the gaps the core would not coast across: the longest part (by samples) is replayed
    if ok_arrays is not None:
        _, ta, da = ok_arrays
        cuts = [0, *(np.nonzero(ta[1:] - da[1:] - ta[:-1] > SPLIT_GAP_S)[0] + 1).tolist()]
    else:
        cuts = [0] + [k for k in range(1, len(ok_imu))
                      if ok_imu[k].t - ok_imu[k].dt - ok_imu[k - 1].t > SPLIT_GAP_S]  # fmt: skip
    if len(cuts) > 1:
        ends = [*cuts[1:], len(ok_imu)]
        a, b = max(zip(cuts, ends, strict=True), key=lambda ab: ab[1] - ab[0])
        notes.append(f"IMU time gaps over {SPLIT_GAP_S:g} s split the log in {len(cuts)} parts: the longest, "
                     f"{ok_imu[a].t:.2f}–{ok_imu[b - 1].t:.2f} s ({b - a} samples), is replayed")  # fmt: skip
        ok_imu = ok_imu[a:b]
        if ok_arrays is not None:
            ok_arrays = (ok_arrays[0][a:b], ok_arrays[1][a:b], ok_arrays[2][a:b])
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
        notes.append(f"validation: {sum(aw.values())} of {len(aux)} baro / magnetometer / other aiding samples dropped "
                     f"({_counted(aw)})")  # fmt: skip
    return Screened(ok_imu, ok_gnss, ok_aux, notes, ok_arrays)


def _imu_arrays_or_none(imu: list[ImuSample]) -> tuple[Vec, Vec, Vec] | None:
    """:func:`imu_arrays` of ``imu`` when the samples are of one IMU with 3-vector increments (None otherwise:
    :func:`screen` checks them one by one)."""
    if not imu or any(s.imu_id != imu[0].imu_id for s in imu):
        return None
    try:
        a = imu_arrays(imu)
    except (TypeError, ValueError):
        return None
    return a if a[0].shape == (len(imu), 6) else None


@dataclass
class Prepared:
    """The dataset after the config: streams to fuse, the NavConfig and notes. ``imu`` is not edited in place
    after :func:`prepare` (its arrays for the C core are kept per list: :meth:`imu_arrays`); a changed copy is a
    new list (``dataclasses.replace``)."""

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
    aiding_fdi: bool = True  # the gateway's aiding drift monitor in the replay's pipeline ([fdi] aiding)
    # what every replay of these streams computes alike (the outage protocol's run after the GNSS-present one)
    _cache: dict[str, Any] = field(default_factory=dict, repr=False, compare=False)

    def _of_imu(self, name: str, fn: Any) -> Any:
        """``fn(imu)``, computed once for this ``imu`` list (``dataclasses.replace`` shares the cache: a copy
        with another list computes its own)."""
        key = (name, id(self.imu), len(self.imu))
        v = self._cache.get(name)
        if v is None or v[0] != key:
            v = self._cache[name] = (key, fn(self.imu))
        return v[1]

    def use_imu_arrays(self, a: tuple[Vec, Vec, Vec]) -> None:
        """Take ``a`` (the screen's :func:`imu_arrays` of these samples) as :meth:`imu_arrays`' (not when its
        length is not that of ``imu``)."""
        if len(a[1]) == len(self.imu):
            self._cache["imu_arrays"] = (("imu_arrays", id(self.imu), len(self.imu)), a)

    def imu_arrays(self) -> tuple[Vec, Vec, Vec]:
        """:func:`imu_arrays` of ``imu``, built once (read only)."""
        a = self._of_imu("imu_arrays", imu_arrays)
        for x in a:
            x.flags.writeable = False
        return cast(tuple[Vec, Vec, Vec], a)

    def rate_bins(self) -> Vec:
        """:func:`rate_bins` of ``imu``, computed once."""
        a = self.imu_arrays()  # (the screen's when it built them)
        return cast(Vec, self._of_imu("rate_bins", lambda _: _rate_bins(a[1], a[0][:, :3], a[2])).copy())


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


_IMU_FIELDS = operator.attrgetter(*(f.name for f in dataclasses.fields(ImuSample)))


def _shifted(imu: list[ImuSample], t1: float, off: float, R: Vec | None) -> list[ImuSample]:
    """The samples of ``imu`` up to ``t1`` s with their time moved by ``off`` s and, with ``R``, their increments
    turned by it (``dataclasses.replace`` of each, without its per-call cost: copied field by field)."""
    out = []
    for s in imu:
        if s.t <= t1:
            n = ImuSample(*_IMU_FIELDS(s))
            n.t = s.t + off
            if R is not None:
                n.dtheta = R @ s.dtheta
                n.dvel = R @ s.dvel
            out.append(n)
    return out


_GNSS_FIELDS = operator.attrgetter(*(f.name for f in dataclasses.fields(GnssFix)))


def _gnss_shifted(gnss: list[GnssFix], off: float) -> list[GnssFix]:
    """Copies of the fixes with their time moved by ``off`` s (``dataclasses.replace`` of each, without its
    per-call cost: copied field by field)."""
    out = []
    for f in gnss:
        if type(f) is GnssFix:
            n = GnssFix(*_GNSS_FIELDS(f))
            n.t = f.t + off
        else:
            n = dataclasses.replace(f, t=f.t + off)
        out.append(n)
    return out


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
        imu = _shifted(ds.imu, t1, off, R if rot else None)
    gnss = _gnss_shifted(ds.gnss, cfg.gnss_time_offset) if cfg.use_gnss else []
    mag = [dataclasses.replace(m, field_b=R @ m.field_b) if rot else m for m in ds.mag] if cfg.use_mag else []
    baro = list(ds.baro) if cfg.use_baro else []
    # the validation boundary (the gateway's): what the core is given is finite, in range and in time order
    sc = screen(imu, gnss, [*baro, *mag, *ds.aids], source)  # ds.aids: the aid modules' samples (odometer, ...)
    notes += sc.notes
    imu, gnss = sc.imu, sc.gnss
    baro = [m for m in sc.aux if m.kind == "baro"]
    mag = [m for m in sc.aux if m.kind == "mag"]
    other = [m for m in sc.aux if m.kind not in ("baro", "mag")]
    nav = cfg.nav_config()
    if gnss:
        origin = (gnss[0].lat, gnss[0].lon, gnss[0].h)
    elif cfg.position is not None:
        origin = cfg.position
    else:
        origin = (0.0, 0.0, 0.0)
    p = Prepared(imu, gnss, [], nav, imu[0].t, imu[-1].t, origin, notes, source=source)
    if sc.imu_arrays is not None:
        p.use_imu_arrays(sc.imu_arrays)
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
    p.aiding_fdi = cfg.aiding_fdi
    p.aux = sorted([*baro, *mag, *other], key=lambda m: m.t)
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
    llh: Vec = field(default_factory=lambda: np.zeros((0, 3)))  # lat, lon (rad), h (m, WGS84) at each step
    std_vel: Vec = field(default_factory=lambda: np.zeros((0, 3)))  # velocity σ NED (m/s)
    counts: dict[str, int] = field(default_factory=dict)  # the pipeline's counters (rejections, exclusions)
    events: list[FaultEvent] = field(default_factory=list)  # the pipeline's fault events
    yaw_resets: list[tuple[float, str]] = field(default_factory=list)  # the core's emergency yaw resets: t s, why


def antenna_ned(st: Any, lever: Vec, t: float, origin: tuple[float, float, float],
                ref: tuple[Vec, Vec] | None = None, c_bn: Vec | None = None) -> Vec:  # fmt: skip
    """The GNSS antenna position (NED m from ``origin`` = (lat rad, lon rad, h m)) of a navigation state ``st``
    (``NavState``: t, lat, lon, h, q_nb, vel_ned) at time ``t`` s: its position plus the body lever arm ``lever``
    (m), moved on with its velocity to ``t``. ``ref`` (``earth.ned_ref(*origin)``) and ``c_bn``
    (``dcm_from_quat(st.q_nb)``), when the caller holds them: the same numbers."""
    p = earth.ned_from_geodetic(st.lat, st.lon, st.h, *origin, ref=ref)
    return p + (dcm_from_quat(st.q_nb) if c_bn is None else c_bn) @ lever + st.vel_ned * (t - st.t)


#: the pipeline settings of an offline replay: the Python core aligning itself from the first IMU sample, the
#: gateway's drift monitor on the aiding, the replay's validation limits (``REPLAY_LIMITS``)
def offline_config(aiding_fdi: bool = True, core: str = "python") -> PipelineConfig:
    """The :class:`~ins_hil.runtime.pipeline.PipelineConfig` of an offline replay (``init = "core"``); ``core``
    "c": the C reference core (aligned by the Python core's alignment, then handed over)."""
    return PipelineConfig(core=core, init="core", aiding_fdi=aiding_fdi, limits=REPLAY_LIMITS)


def navigating(pipe: Pipeline) -> bool:
    """The pipeline's core has finished its alignment and navigates (its ``align_status`` is "")."""
    core = pipe.core
    return core is not None and core.align_status() == ""


def states_at(points: Sequence[float], k: int, states: Sequence[NavState]) -> tuple[list[int], int]:
    """An observer's :meth:`~ins_hil.runtime.pipeline.Observer.epochs` matching of points in time to the states of
    one call: for each of ``points`` (times s, ascending) from index ``k`` up to the last state's time, the index
    of the first of ``states`` (ascending times) at or after it; and the index of the first point not reached (the
    next call's ``k``)."""
    if k >= len(points) or not len(states):
        return [], k
    ts = cast(Any, states).times() if hasattr(states, "times") else [s.t for s in states]
    end = ts[-1]
    at: list[int] = []
    i = 0
    while k < len(points) and points[k] <= end:
        i = bisect.bisect_left(ts, points[k], i)
        at.append(i)
        k += 1
    return at, k


AidHook = Callable[[Pipeline, Any], Any]


def replay(
    imu: Sequence[ImuSample],
    aids: Sequence[Any],
    nav: NavConfig,
    observers: Sequence[Observer] = (),
    *,
    initial: StrapdownState | None = None,
    hand_at: Sequence[float] | None = None,
    on_aid: AidHook | None = None,
    pipeline: PipelineConfig | None = None,
    progress: Progress | None = None,
    source: str = "replay",
    setup: Callable[[Pipeline], None] | None = None,
    live_schedule: bool = False,
    screened: bool = False,
    on_aid_kinds: frozenset[str] | None = None,
    imu_arrays: tuple[Vec, Vec, Vec] | None = None,
) -> tuple[Pipeline, list[FaultEvent]]:
    """The one offline loop: ``imu`` and ``aids`` (sorted by their hand-over time) through the gateway's
    :class:`~ins_hil.runtime.pipeline.Pipeline` (validation, drift monitor, delayed fusion in segments) with
    the core ``nav``, in time order: each aiding measurement is handed over after the IMU sample that reaches
    its hand-over time (``hand_at``, default its ``t``; a simulation's arrival time), through ``on_aid`` first
    when given (e.g. the magnetometer as a heading). Scoring is the ``observers``' (:class:`Observer`).

    Offline, the measurements handed over after an IMU sample are fused completely before the next one
    (``Pipeline.flush``: the live loop with time to spare); ``live_schedule`` runs them instead one segment per
    gap between IMU epochs as the live loop under load does (the same updates, a step or two later, through the
    core's delayed fusion; slower: on px4_quad the GNSS-present prior error is 0.148 m either way, the outages'
    RMS / max 2.05 / 7.81 m offline and 2.06 / 7.65 m on the live schedule).

    ``screened``: ``imu`` and ``aids`` passed :func:`screen` with the pipeline's limits (a :class:`Prepared`'s):
    the pipeline does not check those samples a second time (``Pipeline.aid``; on the C core ``Pipeline.imu_run``).

    On the C core, a stretch of baro samples with nothing else between them runs in one C call with the IMU
    samples between them (``Pipeline.baro_runs``: the same figures) when ``imu`` and ``aids`` are screened and
    ``on_aid`` leaves baro samples alone (``on_aid_kinds``: the kinds it changes; None: any); ``imu_arrays``: the
    (n, 6) increments, times and steps of ``imu`` (:func:`imu_arrays`) when the caller has them.

    ``setup`` is called with the pipeline before the first sample. Returns the pipeline (after its ``flush``)
    and every fault event it raised. ReplayError (one line: the recording and the time) when the core fails
    (an exception inside it, or a non-finite or implausible state): a replay gives no figures from a core
    the gateway would have had to restart."""
    pipe = Pipeline(pipeline or offline_config(), observers, nav=nav, initial=initial)
    if setup is not None:
        setup(pipe)
    when = [m.t for m in aids] if hand_at is None else hand_at
    events: list[FaultEvent] = []
    j, na, n = 0, len(aids), len(imu)
    t = math.nan
    if pipe.cfg.core == "c" and not live_schedule and n:
        # the C core: the IMU samples up to the next hand-over in one call of the pipeline (Pipeline.imu_run:
        # the same epochs, one C call for the run once the core navigates)
        ts = [s.t for s in imu]
        arrays = imu_arrays if imu_arrays is not None and len(imu_arrays[1]) == n else None
        plan = None
        if screened and isinstance(imu, list) and (on_aid is None or (on_aid_kinds is not None
                                                                        and "baro" not in on_aid_kinds)):  # fmt: skip
            plan = _BaroPlan(imu, aids, when, arrays)
            arrays = plan.arrays
        ordered = plan is not None and plan.one_id  # screened, one IMU: its times increase (Pipeline.imu_run)
        k = 0
        while k < n:
            if plan is not None and j < plan.na and plan.ok[j]:
                # a stretch of baro samples (and the IMU samples up to each) in one C call
                end, ab = plan.stretch(k, j)
                k_end, j_end = pipe.baro_runs(cast(list[ImuSample], imu), plan.arrays, k, end, ab, aids, plan.bt,
                                              plan.alt)  # fmt: skip
                if k_end > k:
                    if progress is not None and ((k_end - 1) // 2000 > (k - 1) // 2000 or k_end == n):
                        progress(k_end, n)
                    k, j = k_end, j_end
                    t = ts[k - 1]
                    if j < na and when[j] <= t:  # the rest of the last group, as below
                        j = _hand_over(pipe, aids, when, j, t, on_aid, screened)
                        pipe.flush()
                    if pipe.events:
                        _take_events(pipe, events, source, t)
                    continue
            k_end = n if j >= na else min(n, max(k + 1, bisect.bisect_left(ts, when[j], k) + 1))
            pipe.imu_run(
                list(imu[k:k_end]) if not isinstance(imu, list) else imu[k:k_end],
                screened,
                None if arrays is None else (arrays[0][k:k_end], arrays[1][k:k_end], arrays[2][k:k_end]),
                ordered,
            )
            t = ts[k_end - 1]
            if j < na and when[j] <= t:
                j = _hand_over(pipe, aids, when, j, t, on_aid, screened)
                pipe.flush()
            if pipe.events:
                _take_events(pipe, events, source, t)
            if progress is not None and ((k_end - 1) // 2000 > (k - 1) // 2000 or k_end == n):
                progress(k_end, n)
            k = k_end
        pipe.flush()
        if pipe.events:
            _take_events(pipe, events, source, t)
        return pipe, events
    for k, s in enumerate(imu):
        t = s.t
        pipe.imu(s)
        if j < na and when[j] <= t:
            j = _hand_over(pipe, aids, when, j, t, on_aid, screened)
            if not live_schedule:
                pipe.flush()
        if pipe.events:
            _take_events(pipe, events, source, t)
        if progress is not None and (k % 2000 == 0 or k == n - 1):
            progress(k + 1, n)
    pipe.flush()
    if pipe.events:
        _take_events(pipe, events, source, t)
    return pipe, events


def _hand_over(pipe: Pipeline, aids: Sequence[Any], when: Sequence[float], j: int, t: float, on_aid: AidHook | None,
               screened: bool) -> int:  # fmt: skip
    """:func:`replay`'s hand-over: ``aids`` from index ``j`` whose hand-over time ``when`` is at or before ``t`` s
    to the pipeline (each through ``on_aid`` first when given; ``screened``: not checked again, unless ``on_aid``
    made a new sample). Returns the index of the first aid not handed over."""
    na = len(aids)
    while j < na and when[j] <= t:
        m = aids[j]
        j += 1
        a = m if on_aid is None else on_aid(pipe, m)
        pipe.aid(a, screened and a is m)
    return j


def imu_arrays(imu: Sequence[ImuSample]) -> tuple[Vec, Vec, Vec]:
    """The (n, 6) increments (dθ rad, dv m/s), the (n,) times and the (n,) steps (s) of ``imu``, C-contiguous
    float64: the C core's run arrays (``CNavCore.run_states``)."""
    n = len(imu)
    if not n:
        return np.zeros((0, 6)), np.zeros(0), np.zeros(0)
    inc = np.empty((n, 6))
    inc[:, :3] = np.array([s.dtheta for s in imu], dtype=np.float64)
    inc[:, 3:] = np.array([s.dvel for s in imu], dtype=np.float64)
    t = np.fromiter((s.t for s in imu), np.float64, n)
    dt = np.fromiter((s.dt for s in imu), np.float64, n)
    return inc, t, dt


#: baro groups in one ``Pipeline.baro_runs`` call at most (bounds the work of a stretch the pipeline declines,
#: e.g. during the alignment, whose samples are then handed over one by one and the stretch planned again)
STRETCH_GROUPS = 256


class _BaroPlan:
    """Where :func:`replay` may hand a stretch of baro samples and the IMU samples up to each to the C core in one
    call (``Pipeline.baro_runs``): per aid whether it is a baro sample with a finite altitude handed over after an
    IMU sample of the log (``ok``) and that sample's index (``h``); the IMU samples with data lost before them
    (``CNavCore.run_states``' record: a stretch does not hold one)."""

    def __init__(self, imu: list[ImuSample], aids: Sequence[Any], when: Sequence[float],
                 arrays: tuple[Vec, Vec, Vec] | None) -> None:  # fmt: skip
        self.arrays = arrays if arrays is not None else imu_arrays(imu)
        _, t, dt = self.arrays
        n = self.n = len(t)
        self.na = len(aids)
        lost = np.zeros(n + 1, dtype=np.int64)
        lost[2:] = np.cumsum(imu_lost_v(t[1:], dt[1:], t[:-1])[1])
        self.lost = lost.tolist()  # lost[k]: samples before index k with data lost before them
        self.h = np.searchsorted(t, np.asarray(when, dtype=np.float64), "left").tolist()
        one_id = self.one_id = len({s.imu_id for s in imu}) == 1
        self.bt = np.array([m.t for m in aids], dtype=np.float64)
        self.alt = np.array([m.altitude if type(m) is BaroSample else math.nan for m in aids], dtype=np.float64)
        fin = np.isfinite(self.alt).tolist()
        # (valid by the end of the IMU sample it is handed over after: fused at once, never held)
        tl, btl = t.tolist(), self.bt.tolist()
        self.ok = [one_id and f and h < n and b <= tl[h] for f, h, b in zip(fin, self.h, btl, strict=True)]

    def stretch(self, k: int, j: int) -> tuple[Vec, Vec]:
        """From IMU sample ``k`` and aid ``j``: the groups of baro samples handed over after the same IMU sample,
        as ``Pipeline.baro_runs`` takes them (each group's IMU end, exclusive; the aid bounds), up to the first
        aid that is not one or the first group whose IMU samples hold a loss of data."""
        ok, h, lost, na = self.ok, self.h, self.lost, self.na
        ends: list[int] = []
        ab = [j]
        prev = k
        while j < na and ok[j] and len(ends) < STRETCH_GROUPS:
            hj = h[j]
            if hj < prev or lost[hj + 1] != lost[prev]:
                break
            j += 1
            while j < na and ok[j] and h[j] == hj:
                j += 1
            ends.append(hj + 1)
            ab.append(j)
            prev = hj + 1
            if j < na and h[j] == hj:  # the group goes on with another kind: the whole group is the caller's
                ends.pop()  # (a core fault in one of its updates drops the other kind's samples with it, as
                ab.pop()  # Pipeline.flush does)
                break
        return np.array(ends, dtype=np.int64), np.array(ab, dtype=np.int64)


def _take_events(pipe: Pipeline, into: list[FaultEvent], source: str, t: float) -> None:
    """Drain the pipeline's events into ``into``; ReplayError at a core fault (or an error of the pipeline)."""
    for e in pipe.drain_events():
        into.append(e)
        if e.sensor == "core" and not e.cleared:
            what = e.detail.split(": ", 1)[-1]
            if "non-finite or implausible" in e.detail:
                raise ReplayError(f"{source}: non-finite navigation states from t = {e.t:.3f} s: no figures")
            raise ReplayError(f"{source}: the replay failed at t = {e.t:.3f} s ({' '.join(what.split())[:160]})")
    if pipe.counts.get("pipeline_error"):
        raise ReplayError(f"{source}: the replay failed at t = {t:.3f} s (a pipeline error)")


class Track(Observer):
    """The state at every navigating IMU epoch (as the pipeline published it): time, attitude, velocity,
    position (NED m from ``origin`` and geodetic), σ."""

    def __init__(self, origin: tuple[float, float, float]) -> None:
        self.origin = origin
        self.t_nav = math.nan
        # the states in order: lists of NavState (one per epoch) and the C core's runs as their state-record
        # rows (``RunStates.rows``: no NavState built)
        self._chunks: list[Any] = []
        self._nav = False

    @property
    def states(self) -> list[NavState]:
        """Every state kept, in order (the C core's runs built into ``NavState`` here)."""
        out: list[NavState] = []
        for c in self._chunks:
            out.extend(c)
        return out

    def epoch(self, pipe: Pipeline, st: NavState) -> None:
        if not self._nav:
            if not navigating(pipe):
                return
            self._nav = True
            self.t_nav = st.t
        ch = self._chunks
        if not ch or not isinstance(ch[-1], list):
            ch.append([])
        ch[-1].append(st)

    def epochs(self, pipe: Pipeline, states: Sequence[NavState]) -> None:
        if not states:
            return
        if not self._nav:
            if not navigating(pipe):  # the run's states share the core's alignment status
                return
            self._nav = True
            self.t_nav = states[0].t
        if hasattr(states, "rows"):
            self._chunks.append(states)
        else:
            for st in states:
                self.epoch(pipe, st)

    def arrays(self) -> dict[str, Vec]:
        """t (N,), q_nb (N, 4), vel_ned, ned, llh (lat rad, lon rad, h m), std_pos, std_vel, std_att (N, 3)."""
        if any(hasattr(c, "rows") for c in self._chunks):  # the C core's runs: their rows, the rest as NavStates
            parts = [c.rows[:, :26] if hasattr(c, "rows") else _record_rows(c) for c in self._chunks]
            rows = np.concatenate(parts) if len(parts) > 1 else parts[0]
            llh = np.ascontiguousarray(rows[:, 8:11])
            ned = earth.ned_from_geodetic_many(llh, *self.origin)
            return {"t": rows[:, 0].copy(), "q_nb": rows[:, 1:5].copy(), "vel_ned": rows[:, 5:8].copy(), "ned": ned,
                    "llh": llh, "std_pos": rows[:, 17:20].copy(), "std_vel": rows[:, 20:23].copy(),
                    "std_att": rows[:, 23:26].copy()}  # fmt: skip
        st = self.states
        if not st:
            z = np.zeros((0, 3))
            return {"t": np.zeros(0), "q_nb": np.zeros((0, 4)), "vel_ned": z, "ned": z, "llh": z, "std_pos": z,
                    "std_vel": z, "std_att": z}  # fmt: skip
        llh = np.array([(s.lat, s.lon, s.h) for s in st])
        lat0, lon0, h0 = self.origin
        ned = earth.ned_from_geodetic_many(llh, lat0, lon0, h0)
        return {"t": np.array([s.t for s in st]), "q_nb": np.array([s.q_nb for s in st]),
                "vel_ned": np.array([s.vel_ned for s in st]), "ned": ned, "llh": llh,
                "std_pos": np.array([s.std_pos for s in st]), "std_vel": np.array([s.std_vel for s in st]),
                "std_att": np.array([s.std_att for s in st])}  # fmt: skip


def _record_rows(states: Sequence[NavState]) -> Vec:
    """(n, 26) rows of the C state record (t, q[4], v[3], lat, lon, h, b_g[3], b_a[3], σ pos, vel, att) of
    ``states``."""
    out = np.empty((len(states), 26))
    for k, s in enumerate(states):
        out[k, 0] = s.t
        out[k, 1:5] = s.q_nb
        out[k, 5:8] = s.vel_ned
        out[k, 8:11] = (s.lat, s.lon, s.h)
        out[k, 11:14] = s.gyro_bias
        out[k, 14:17] = s.accel_bias
        out[k, 17:20] = s.std_pos
        out[k, 20:23] = s.std_vel
        out[k, 23:26] = s.std_att
    return out


@dataclass
class FixScore:
    """One GNSS fix scored: the a-priori antenna error (NED m, the state before it was fused, or at its time
    when withheld), the a-posteriori one (NaN: withheld or excluded), the state it was scored with."""

    fix: GnssFix
    inside: bool  # withheld (an outage)
    prior: Vec
    post: Vec
    ref: Vec  # the fix, NED m from the origin
    state: NavState
    fused: bool = False
    corr: tuple[float, float] | None = None  # Δ horizontal specific force (NED m/s²) of its attitude/bias update


class GnssScore(Observer):
    """Scores each GNSS fix: the fused ones before and after their update (:meth:`before_fuse` /
    :meth:`after_fuse`), the ``withheld`` ones (outages, never handed to the pipeline) at the first epoch at or
    after their time; only while the core navigates. Per fused fix also how far its update moved the specific
    force an unaccelerated vehicle would feel (its attitude and accelerometer-bias corrections, NED): from the
    state before its update to the state after it, summed over the spans its update ran in without an IMU epoch
    between (so the figure does not depend on how a core cuts an update into segments: the Python core's position
    and velocity parts, its roll-back's pauses, the C core's one piece)."""

    #: the aiding kinds its fusion hooks look at (``Pipeline.baro_runs``: the others pass it by)
    fuse_kinds = frozenset({"gnss"})

    def __init__(self, lever: Vec, origin: tuple[float, float, float], withheld: Sequence[GnssFix] = ()) -> None:
        self.lever = np.asarray(lever, dtype=np.float64)
        self.origin = origin
        self.withheld = sorted(withheld, key=lambda f: f.t)
        self._wt = [f.t for f in self.withheld]
        self._w = 0
        self.rows: list[FixScore] = []
        self._open: dict[int, FixScore] = {}
        self._f_raw: dict[int, Vec] = {}
        self._span: dict[int, tuple[int, Vec]] = {}  # per open fix: the epoch count and f at its last segment end
        self._epochs = 0
        self._o = earth.ned_ref(*origin)  # the origin's ECEF point and C_e^n, once
        self._dcm_of: tuple[Any, Any, Vec] | None = None  # (state, its q_nb, C_b^n): :meth:`_dcm`'s last

    def _ref(self, f: GnssFix) -> Vec:
        return earth.ned_from_geodetic(f.lat, f.lon, f.h, *self.origin, ref=self._o)

    def _dcm(self, st: Any) -> Vec:
        """``dcm_from_quat(st.q_nb)``, computed once per state: a core hands out the same ``NavState`` while it
        does not change (the C core), so a fix's prior is turned once for :meth:`before_fuse` and its segment's
        start, its posterior once for the segment's end and :meth:`after_fuse` (states are never mutated)."""
        c = self._dcm_of
        q = st.q_nb
        if c is not None and c[0] is st and c[1] is q:
            return c[2]
        C = dcm_from_quat(q)
        self._dcm_of = (st, q, C)
        return C

    def _antenna(self, st: Any, t: float) -> Vec:
        """:func:`antenna_ned` of ``st`` at ``t`` (this observer's lever arm and origin)."""
        return antenna_ned(st, self.lever, t, self.origin, self._o, self._dcm(st))

    def epoch(self, pipe: Pipeline, st: NavState) -> None:
        self._epochs += 1
        w = self.withheld
        while self._w < len(w) and w[self._w].t <= st.t:
            f = w[self._w]
            self._w += 1
            if navigating(pipe):
                ref = self._ref(f)
                self.rows.append(FixScore(f, True, self._antenna(st, f.t) - ref,
                                          np.full(3, math.nan), ref, st))  # fmt: skip

    def epochs(self, pipe: Pipeline, states: Sequence[NavState]) -> None:
        n = len(states)
        if not n:
            return
        self._epochs += n
        j = self._w
        at, self._w = states_at(self._wt, j, states)  # each at the first state at or after its time
        if at and navigating(pipe):
            for f, i in zip(self.withheld[j : self._w], at, strict=True):
                st = states[i]
                ref = self._ref(f)
                self.rows.append(FixScore(f, True, self._antenna(st, f.t) - ref,
                                          np.full(3, math.nan), ref, st))  # fmt: skip

    def before_fuse(self, pipe: Pipeline, m: Any) -> None:
        if m.kind != "gnss" or not navigating(pipe):
            return
        assert pipe.core is not None
        st = pipe.core.state()
        ref = self._ref(m)
        row = FixScore(m, False, self._antenna(st, m.t) - ref, np.full(3, math.nan), ref, st)
        self.rows.append(row)
        self._open[id(m)] = row

    def segment(self, pipe: Pipeline, m: Any, start: bool) -> None:
        row = self._open.get(id(m))
        if row is None or pipe.core is None:
            return
        st = pipe.core.state()
        k = id(m)
        if start:
            span = self._span.get(k)
            if span is not None and span[0] == self._epochs:
                return  # no IMU epoch since the last segment: the span goes on
            self._close(k, row)
            # the accelerometer reading of an unaccelerated vehicle at the attitude and bias before this span
            g_n = np.array((0.0, 0.0, -earth.normal_gravity(st.lat, st.h)))
            self._f_raw[k] = self._dcm(st).T @ g_n + st.accel_bias
            return
        f_raw = self._f_raw.get(k)
        if f_raw is not None:  # seen through the updated attitude and bias: the horizontal f the update moved
            self._span[k] = (self._epochs, self._dcm(st) @ (f_raw - st.accel_bias))

    def _close(self, k: int, row: FixScore) -> None:
        """Add the horizontal f of the span that ended at the last segment end to the fix's correction."""
        span = self._span.pop(k, None)
        self._f_raw.pop(k, None)
        if span is not None:
            f1 = span[1]
            c = row.corr or (0.0, 0.0)
            row.corr = (c[0] + float(f1[0]), c[1] + float(f1[1]))

    def after_fuse(self, pipe: Pipeline, m: Any, fused: bool) -> None:
        row = self._open.pop(id(m), None)
        if row is not None:
            self._close(id(m), row)
        if row is None or pipe.core is None:
            return
        row.fused = fused
        if fused:
            row.post = self._antenna(pipe.core.state(), m.t) - row.ref
            row.corr = row.corr or (0.0, 0.0)

    def sorted_rows(self) -> list[FixScore]:
        """The scored fixes in time order."""
        return sorted(self.rows, key=lambda r: r.fix.t)


def run_dataset(p: Prepared, outages: list[tuple[float, float]] = (), label: str = "",  # type: ignore[assignment]
                progress: Progress | None = None, observers: Sequence[Observer] = (),
                aiding_fdi: bool | None = None, core: str = "python") -> RunResult:  # fmt: skip
    """Replay ``p`` through the gateway's pipeline (:func:`replay`); GNSS inside ``outages`` (s, absolute) is
    scored, never fused. ``observers``: more scoring (e.g. a reference trajectory's). ReplayError (one line
    naming the recording and the time) when the state becomes non-finite or the core fails numerically.
    ``aiding_fdi``: the drift monitor on or off (None: the dataset config's ``[fdi] aiding``). ``core``: "python"
    or "c" (a setting the C core lacks: RuntimeError naming it)."""
    src = p.source or label or "replay"
    try:
        return _run_dataset(
            p, outages, label, progress, observers, p.aiding_fdi if aiding_fdi is None else aiding_fdi, core
        )
    except ReplayError:
        raise
    except (ArithmeticError, ValueError, np.linalg.LinAlgError) as e:
        raise ReplayError(f"{src}: the replay failed ({type(e).__name__}: {' '.join(str(e).split())[:120]})"
                          ) from None  # fmt: skip


def _inside(t: float, outages: Sequence[tuple[float, float]]) -> bool:
    return any(a <= t < b for a, b in outages)


def _run_dataset(p: Prepared, outages: Sequence[tuple[float, float]], label: str, progress: Progress | None,
                 observers: Sequence[Observer], aiding_fdi: bool, core_kind: str = "python") -> RunResult:  # fmt: skip
    """:func:`run_dataset` on the one loop: a :class:`Track` and a :class:`GnssScore` observe it."""
    origin = p.origin
    fused = [f for f in p.gnss if not _inside(f.t, outages)]
    withheld = [f for f in p.gnss if _inside(f.t, outages)]
    aids: list[Any] = sorted([*fused, *p.aux], key=lambda m: (m.t, 0 if m.kind == "gnss" else 2))
    track = Track(origin)
    score = GnssScore(p.nav.gnss.lever_arm_b, origin, withheld)
    ref_ned = p.nav.mag.ref_ned

    def heading(pipe: Pipeline, m: Any) -> Any:
        if m.kind != "mag":  # (the last state is built only for a magnetometer sample)
            return m
        st = pipe.last_state
        if st is not None and navigating(pipe):
            return heading_only(m, st.q_nb, ref_ned)
        return m

    def setup(pipe: Pipeline) -> None:
        if pipe.core is not None and hasattr(pipe.core, "innov_kinds"):
            pipe.core.innov_kinds = frozenset({"gnss_vel"})  # the GNSS velocity innovations: innovation_whiteness

    t_start = time.perf_counter()
    pipe, events = replay(p.imu, aids, p.nav, [track, score, *observers], on_aid=heading if p.mag_heading_only
                          else None, pipeline=offline_config(aiding_fdi, core_kind), progress=progress,
                          source=p.source or label or "replay", setup=setup, screened=True,
                          on_aid_kinds=frozenset({"mag"}),
                          imu_arrays=p.imu_arrays() if core_kind == "c" else None)  # fmt: skip
    core: Any = pipe.core
    tr = track.arrays()
    rows = score.sorted_rows()

    def arr(x: list[Any], w: int) -> Vec:
        return np.array(x, dtype=np.float64) if x else np.zeros((0, w) if w else 0)

    # the core's own record of each IMU gap it coasted across: its end (s) and the data lost (s)
    gaps = [(e.t, e.magnitude) for e in events if e.sensor == "imu" and e.mode == FaultMode.DROPOUT]
    corr = [(r.state.t, *r.corr) for r in rows if r.corr is not None]
    excluded = {k: v for k, v in pipe.counts.items() if k.startswith(("excluded_", "reject_"))}
    notes = list(p.notes)
    if excluded:
        notes.append("pipeline: " + ", ".join(f"{k} {v}" for k, v in sorted(excluded.items())))
    return RunResult(
        label, origin, tr["t"], tr["q_nb"], tr["vel_ned"], tr["ned"], tr["std_pos"], tr["std_att"], track.t_nav,
        arr([r.fix.t for r in rows], 0), arr([r.prior for r in rows], 3), arr([r.post for r in rows], 3),
        np.array([r.inside for r in rows], dtype=bool), arr([r.state.std_pos for r in rows], 3),
        arr([r.ref for r in rows], 3), np.array([int(r.fix.fix_type) for r in rows], dtype=int), list(outages),
        {k: {"accepted": v.accepted, "rejected": v.rejected} for k, v in core.stats.items()},
        time.perf_counter() - t_start, notes, core.align_status(), core.imu_lost,
        np.array([(t, *z) for t, _, z in core.innov_log]).reshape(-1, 4), arr(gaps, 2), p.rate_bins(),
        arr(corr, 3), list(core.divergences), list(core.sensor_warnings), tr["llh"], tr["std_vel"],
        dict(pipe.counts), events, list(getattr(core, "yaw_resets", ())),
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
    return _rate_bins(t, d, dt)


def _rate_bins(t: Vec, d: Vec, dt: Vec) -> Vec:
    """:func:`rate_bins` of the samples' times ``t`` (n,) s, angle increments ``d`` (n, 3) rad and steps ``dt``."""
    if not len(t):
        return np.zeros((0, 2))
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
    return median(sums) if sums else math.nan


def median(x: Sequence[float] | Vec) -> float:
    """``float(np.median(x))`` of a 1-D sequence, the same number (the mean of the middle value or of the two
    middle ones as numpy takes it, its sum from 0.0; NaN if any value is NaN), without numpy's median: its NaN
    check imports ``numpy.ma`` (~38 ms of CPU, a third of a C replay's imports)."""
    v = x.tolist() if isinstance(x, np.ndarray) else [float(a) for a in x]
    n = len(v)
    if not n or any(a != a for a in v):
        return math.nan
    v.sort()
    m = n // 2
    return 0.0 + v[m] if n % 2 else (0.0 + v[m - 1] + v[m]) / 2.0


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
    dt = median(np.diff(t))
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
