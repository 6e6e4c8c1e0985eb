"""PX4 readers: a ULog file (``*.ulg``, with pyulog) and a ``ulog2csv`` folder (one CSV per topic).

Topics (instance 0; conventions in ``../shared/data/uav/README.md``):

* ``sensor_combined``: ``gyro_rad`` mean rate (rad/s) over ``gyro_integral_dt``, ``accelerometer_m_s2``
  mean specific force (m/s²) over ``accelerometer_integral_dt``; dt in µs (float s in PX4 ≤ 1.7 logs,
  told apart by size); increments = mean × dt, stamped at ``timestamp`` (the last gyro sample);
* else ``vehicle_imu`` (a log without ``sensor_combined``): ``delta_angle`` / ``delta_velocity`` over
  ``delta_angle_dt`` / ``delta_velocity_dt`` (µs), ending at ``timestamp_sample``: the instance of
  ``sensor_selection``'s accelerometer (else instance 0). It must be logged at its full rate: PX4's default
  logging keeps one interval in about a hundred, which is refused;
* ``vehicle_gps_position`` (or ``sensor_gps``): fixes with fix type ≥ 3, stamped at ``timestamp_sample``
  where logged; σ: ``eph`` (per horizontal axis, as EKF2 uses it), ``epv``, ``s_variance_m_s``;
* ``vehicle_air_data.baro_alt_meter``; ``vehicle_magnetometer.magnetometer_ga`` (gauss → tesla);
* EKF2's output as the onboard estimate: ``vehicle_attitude.q``, ``vehicle_local_position``
  (NED about ``ref_lat``/``ref_lon``/``ref_alt``; x/y only where ``xy_valid``, vx/vy where
  ``v_xy_valid``), else ``estimator_states``;
* ``vehicle_land_detected``: take-off / landing events; ``vehicle_status``: the vehicle type;
* what the comparison with EKF2 needs to be read (:func:`onboard_notes`): the IMU ``sensor_combined`` carries
  (``sensor_selection``) against EKF2's primary one (``estimator_selector_status``), EKF2's accelerometer bias
  at the start (``estimator_sensor_bias``), EKF2's unaided horizontal velocity (``vehicle_local_position``).

``sensor_combined`` and ``vehicle_magnetometer`` are PX4's corrected data, the ones EKF2 fuses: the
accelerometer with ``CAL_ACCn`` offsets and scales and the board rotation (``SENS_BOARD_ROT`` and
``SENS_BOARD_X/Y/Z_OFF``) applied, the field with ``CAL_MAGn`` offsets and scale matrix and the pre-flight
``magnetometer_bias_estimate`` removed; the reader applies none of them again (raw ``sensor_accel`` /
``sensor_mag`` are not read).

In a ``ulog2csv`` folder a topic's file is found by the topic name inside the file name
(``log_376_..._sensor_combined_0.csv`` or ``sensor_combined_0.csv``).
"""

from __future__ import annotations

import csv
import io
import math
import re
from pathlib import Path

import numpy as np

from ins_hil import aids
from ins_hil.datasets.dataset import (
    Dataset,
    DatasetError,
    Reader,
    Trajectory,
    count_of,
    fix_type_of,
    increasing,
)
from ins_hil.geoid import ellipsoidal_height
from ins_hil.types import BaroSample, FixType, GnssFix, ImuFlags, ImuSample, MagSample, Vec

Topic = dict[str, Vec]
ULOG_MAGIC = b"ULog\x01\x12\x35"
#: logging gaps in sensor_combined up to this long (s) are bridged with the next sample's mean rate
MAX_BRIDGE = 0.05
TOPICS = ("sensor_combined", "vehicle_imu", "vehicle_gps_position", "sensor_gps", "vehicle_air_data",
          "vehicle_magnetometer", "vehicle_attitude", "vehicle_local_position", "vehicle_global_position",
          "estimator_states", "vehicle_land_detected", "sensor_selection", "estimator_selector_status",
          "estimator_sensor_bias", "vehicle_status")  # fmt: skip
#: m/s: EKF2's unaided horizontal velocity above which the notes say it dead-reckons
DEAD_RECKONING_SPEED = 1.0
#: the share of its time span that ``vehicle_imu``'s intervals must cover to be read as the IMU
MIN_IMU_COVER = 0.9


def all_topics() -> tuple[str, ...]:
    """The topics the reader loads: its own (:data:`TOPICS`) and the aid sources' (:func:`ins_hil.aids.ulog_topics`)."""
    return (*TOPICS, *(t for t in aids.ulog_topics() if t not in TOPICS))


def _col(t: Topic, *names: str) -> Vec | None:
    for n in names:
        if n in t:
            return np.asarray(t[n], dtype=np.float64)
    return None


def _time(t: Topic) -> Vec:
    """Time of validity (s): ``timestamp_sample`` where logged, else ``timestamp`` (µs since boot)."""
    ts = _col(t, "timestamp_sample")
    if ts is None or not np.all(np.isfinite(ts)) or np.all(ts == 0):
        ts = _col(t, "timestamp")
    if ts is None:
        raise DatasetError("a topic without a timestamp column (expected timestamp or timestamp_sample)")
    return ts * 1e-6


def _dt_seconds(dt: Vec) -> Vec:
    """An integral dt column in s: integer µs in current logs, float s in old ones (told apart by size)."""
    return dt * 1e-6 if float(np.nanmedian(dt)) > 1.0 else dt


def imu_from_sensor_combined(t: Topic, gaps: list[float] | None = None) -> list[ImuSample]:
    """Increments (rad, m/s, body FRD) stamped at the interval end; samples with a non-positive dt skipped.
    Where the logger dropped messages (a timestamp step > 1.5 × the integral dt, up to ``MAX_BRIDGE``) the
    sample spans the whole gap; the missing time (s) of every gap is appended to ``gaps``."""
    if gaps is None:
        gaps = []
    ts = _col(t, "timestamp")
    if ts is None or "gyro_rad[0]" not in t or "accelerometer_m_s2[0]" not in t:
        raise DatasetError("sensor_combined: expected timestamp, gyro_rad[0..2], accelerometer_m_s2[0..2]")
    if any(f"{q}[{i}]" not in t for q in ("gyro_rad", "accelerometer_m_s2") for i in range(3)):
        raise DatasetError("sensor_combined: expected timestamp, gyro_rad[0..2], accelerometer_m_s2[0..2]")
    g = np.column_stack([t[f"gyro_rad[{i}]"] for i in range(3)]).astype(np.float64)
    a = np.column_stack([t[f"accelerometer_m_s2[{i}]"] for i in range(3)]).astype(np.float64)
    dtg = _col(t, "gyro_integral_dt")
    dta = _col(t, "accelerometer_integral_dt")
    tt = ts * 1e-6
    if len(tt) < 2:
        return []
    if dtg is None:
        dtg = np.diff(tt, prepend=tt[0] - float(np.median(np.diff(tt))))
    else:
        dtg = _dt_seconds(dtg)
    dta = dtg if dta is None else _dt_seconds(dta)
    clip_a = _col(t, "accelerometer_clipping")
    clip_g = _col(t, "gyro_clipping")
    out: list[ImuSample] = []
    last = -math.inf
    usable = np.isfinite(g).all(axis=1) & np.isfinite(a).all(axis=1) & (dtg > 0) & (dta > 0)
    # the longest increasing run of times: a stamp far ahead costs that sample, not every sample after it
    keep = increasing(np.where(usable, tt, math.nan))
    flags = np.zeros(len(tt), dtype=np.int64)
    if clip_a is not None:
        flags[clip_a != 0] |= int(ImuFlags.ACCEL_SATURATED)
    if clip_g is not None:
        flags[clip_g != 0] |= int(ImuFlags.GYRO_SATURATED)
    with np.errstate(all="ignore"):
        dth, dv = g * dtg[:, None], a * dta[:, None]  # the same products as row by row
    fl_l, tt_l, dtg_l = flags.tolist(), tt.tolist(), dtg.tolist()
    dth_r, dv_r = list(dth), list(dv)  # the rows as views, taken at C speed (an index of the array costs ~0.2 µs)
    for k in np.flatnonzero(keep).tolist():
        t_k, dt_k = tt_l[k], dtg_l[k]
        gap = t_k - last
        if out and gap > 1.5 * dt_k:
            gaps.append(gap - dt_k)
        if out and 1.5 * dt_k < gap <= MAX_BRIDGE:
            # messages the logger dropped: the interval since the previous logged sample is integrated with this
            # sample's mean rate and specific force (else the attitude would miss the rotation of the gap); a longer
            # gap is lost data: the sample keeps its own interval and the core's time jumps (reported)
            out.append(ImuSample(t_k, gap, g[k] * gap, a[k] * gap, seq=k, flags=fl_l[k]))
        else:
            out.append(ImuSample(t_k, dt_k, dth_r[k], dv_r[k], seq=k, flags=fl_l[k]))
        last = t_k
    return out


def sensor_combined_from_vehicle_imu(t: Topic, source: str = "vehicle_imu", min_cover: float = MIN_IMU_COVER) -> Topic:
    """``vehicle_imu``'s deltas as ``sensor_combined``'s columns: the mean rate (rad/s) and specific force (m/s²)
    over each interval, stamped at ``timestamp_sample`` (PX4's sensor_combined is the selected vehicle_imu
    divided by its dt: the hover log's agree to 1e-9 rad/s). DatasetError when the intervals cover less than
    ``min_cover`` of the time (the default logging profile samples the topic at about 2 Hz)."""
    need = ("timestamp", "delta_angle_dt", "delta_velocity_dt", *(f"delta_{q}[{i}]" for q in ("angle", "velocity")
                                                                   for i in range(3)))  # fmt: skip
    if any(n not in t for n in need):
        raise DatasetError(f"{source}: vehicle_imu: expected timestamp(_sample), delta_angle[0..2], "
                           "delta_velocity[0..2], delta_angle_dt, delta_velocity_dt")  # fmt: skip
    ts = _time(t) * 1e6
    dtg = np.asarray(t["delta_angle_dt"], dtype=np.float64)
    dta = np.asarray(t["delta_velocity_dt"], dtype=np.float64)
    span = float(ts[-1] - ts[0]) if len(ts) > 1 else 0.0
    span = span if math.isfinite(span) else 0.0
    cover = float(np.sum(dtg[1:])) / span if span > 0 else 0.0
    if not cover >= min_cover:  # NaN too
        raise DatasetError(
            f"{source}: no sensor_combined, and vehicle_imu's intervals cover {cover:.0%} of its {span * 1e-6:.0f} s "
            f"({len(ts) / max(span * 1e-6, 1e-9):.1f} messages/s): not a continuous IMU (log sensor_combined, or "
            "vehicle_imu at its full rate)"
        )
    with np.errstate(divide="ignore", invalid="ignore"):
        out: Topic = {"timestamp": ts, "gyro_integral_dt": dtg, "accelerometer_integral_dt": dta}
        for i in range(3):
            out[f"gyro_rad[{i}]"] = np.asarray(t[f"delta_angle[{i}]"], dtype=np.float64) / (dtg * 1e-6)
            out[f"accelerometer_m_s2[{i}]"] = np.asarray(t[f"delta_velocity[{i}]"], dtype=np.float64) / (dta * 1e-6)
    for a, b in (("delta_angle_clipping", "gyro_clipping"), ("delta_velocity_clipping", "accelerometer_clipping")):
        if a in t:
            out[b] = np.asarray(t[a], dtype=np.float64)
    return out


def gnss_from_gps(t: Topic) -> list[GnssFix]:
    """Fixes with fix type ≥ 3 (3-D): lat/lon (1e-7 deg or ``latitude_deg``), ellipsoidal height (mm or m)."""
    ts = _time(t)
    lat = _col(t, "latitude_deg")
    lon = _col(t, "longitude_deg")
    h = _col(t, "altitude_ellipsoid_m")
    if lat is None:
        la, lo = _col(t, "lat"), _col(t, "lon")
        if la is None or lo is None:
            raise DatasetError("vehicle_gps_position: expected lat/lon or latitude_deg/longitude_deg")
        lat, lon = la * 1e-7, lo * 1e-7
    if lon is None:
        raise DatasetError("vehicle_gps_position: expected longitude_deg with latitude_deg")
    if h is None:
        he, msl = _col(t, "alt_ellipsoid"), _col(t, "alt")
        if he is not None:
            h = he * 1e-3
        elif msl is not None:  # MSL (mm): + the EGM96 undulation = the WGS84 height
            h = np.array([ellipsoidal_height(math.radians(float(a)), math.radians(float(b)), float(m) * 1e-3)
                          for a, b, m in zip(lat, lon, msl, strict=True)])  # fmt: skip
        else:
            h = np.zeros_like(lat)
    fix = _col(t, "fix_type")
    eph, epv, sv = _col(t, "eph"), _col(t, "epv"), _col(t, "s_variance_m_s")
    vn, ve, vd = _col(t, "vel_n_m_s"), _col(t, "vel_e_m_s"), _col(t, "vel_d_m_s")
    vok = _col(t, "vel_ned_valid")
    sats = _col(t, "satellites_used")
    out: list[GnssFix] = []
    for k in range(len(ts)):
        where = f"vehicle_gps_position record {k} (t={float(ts[k]):.3f} s)"
        ft = fix_type_of(fix[k], where) if fix is not None else FixType.FIX_3D
        no_pos = not (math.isfinite(lat[k]) and math.isfinite(lon[k])) or (lat[k] == 0 and lon[k] == 0)
        if ft is None or ft < FixType.FIX_3D or no_pos:
            continue
        vel = None
        if vn is not None and ve is not None and vd is not None and (vok is None or vok[k] != 0):
            vel = np.array((vn[k], ve[k], vd[k]))
        out.append(GnssFix(
            float(ts[k]), math.radians(lat[k]), math.radians(lon[k]), float(h[k]), vel,
            std_ne=float(eph[k]) if eph is not None else 2.5, std_d=float(epv[k]) if epv is not None else 5.0,
            std_vel=float(sv[k]) if sv is not None else 0.3, fix_type=ft,
            num_sats=count_of(sats[k], f"{where}: satellites_used") if sats is not None else 0,
        ))  # fmt: skip
    return out


def baro_from_air_data(t: Topic) -> list[BaroSample]:
    ts = _time(t)
    alt = _col(t, "baro_alt_meter")
    p = _col(t, "baro_pressure_pa")
    if alt is None:
        raise DatasetError("vehicle_air_data: expected baro_alt_meter")
    return [BaroSample(float(ts[k]), float(p[k]) if p is not None else math.nan, float(alt[k]))
            for k in range(len(ts)) if math.isfinite(alt[k])]  # fmt: skip


def mag_from_magnetometer(t: Topic) -> list[MagSample]:
    ts = _time(t)
    if "magnetometer_ga[0]" not in t:
        raise DatasetError("vehicle_magnetometer: expected magnetometer_ga[0..2]")
    m = np.column_stack([t[f"magnetometer_ga[{i}]"] for i in range(3)]).astype(np.float64) * 1e-4  # G → T
    return [MagSample(float(ts[k]), m[k]) for k in range(len(ts)) if np.all(np.isfinite(m[k]))]


def status_end(t: Vec, flags: list[Vec | None]) -> float | None:
    """The time (s) of the first sample of the estimator's last run of samples with one of its validity ``flags``
    (columns at ``t``, None: not logged) false, after a sample with all of them true; None when the log ends valid.
    A flag never true is left out (EKF2 without GNSS keeps ``xy_valid`` false throughout: the rest still counts)."""
    cols = [np.asarray(f) != 0 for f in flags if f is not None and len(f) == len(t)]
    cols = [c for c in cols if np.any(c)]
    if not cols or not len(t):
        return None
    ok = np.logical_and.reduce(cols)
    if not np.any(ok) or ok[-1]:
        return None
    return float(t[int(np.nonzero(ok)[0][-1]) + 1])


def onboard_from_ekf2(topics: dict[str, Topic]) -> Trajectory | None:
    """EKF2's output: attitude (``vehicle_attitude`` or ``estimator_states``), velocity and position."""
    tr = Trajectory("EKF2")
    att = topics.get("vehicle_attitude")
    es = topics.get("estimator_states")
    if att is not None and all(f"q[{i}]" in att for i in range(4)):
        tr.t_att = _time(att)
        tr.q_nb = np.column_stack([att[f"q[{i}]"] for i in range(4)]).astype(np.float64)
    elif es is not None and all(f"states[{i}]" in es for i in range(4)):
        tr.t_att = _time(es)
        tr.q_nb = np.column_stack([es[f"states[{i}]"] for i in range(4)]).astype(np.float64)
    lp = topics.get("vehicle_local_position")
    if lp is not None and all(c in lp for c in ("vx", "vy", "vz", "x", "y", "z")):
        t = _time(lp)
        tr.t_vel = tr.t_pos = t
        tr.vel_ned = np.column_stack([lp["vx"], lp["vy"], lp["vz"]]).astype(np.float64)
        vxy = _col(lp, "v_xy_valid")
        if vxy is not None and np.any(vxy == 0):
            tr.vel_ned_unaided = np.where((vxy == 0)[:, None], tr.vel_ned, math.nan)
            tr.vel_ned[vxy == 0, :2] = math.nan  # EKF2 dead-reckoning without aiding: not a valid velocity
        pos = np.column_stack([lp["x"], lp["y"], lp["z"]]).astype(np.float64)
        xy = _col(lp, "xy_valid")
        if xy is not None:
            pos[xy == 0, :2] = math.nan
        tr.pos_ned = pos
        tr.t_valid_end = status_end(t, [_col(lp, c) for c in ("xy_valid", "v_xy_valid", "z_valid", "v_z_valid")])
        glob = _col(lp, "xy_global")
        rl, rlo, ra = _col(lp, "ref_lat"), _col(lp, "ref_lon"), _col(lp, "ref_alt")
        if rl is not None and rlo is not None and ra is not None and (glob is None or glob[-1] != 0):
            if xy is not None and np.any(xy != 0) and abs(float(rl[-1])) > 1e-9:
                olat, olon = math.radians(float(rl[-1])), math.radians(float(rlo[-1]))
                tr.origin = (olat, olon, ellipsoidal_height(olat, olon, float(ra[-1])))  # ref_alt is MSL
    elif es is not None and all(f"states[{i}]" in es for i in range(4, 10)):
        t = _time(es)
        tr.t_vel = tr.t_pos = t
        tr.vel_ned = np.column_stack([es[f"states[{i}]"] for i in (4, 5, 6)]).astype(np.float64)
        tr.pos_ned = np.column_stack([es[f"states[{i}]"] for i in (7, 8, 9)]).astype(np.float64)
    if tr.q_nb is None and tr.vel_ned is None:
        return None
    return tr


def _first(t: Topic | None, name: str) -> float | None:
    c = _col(t, name) if t is not None else None
    return float(c[0]) if c is not None and len(c) else None


def onboard_notes(topics: dict[str, Topic], g: float = 9.80665) -> tuple[list[str], dict[str, object]]:
    """Notes (and their figures for ``meta["onboard_check"]``) that say what EKF2's output is as a reference.

    * The accelerometer of ``sensor_combined`` (``sensor_selection.accel_device_id``) against the one of EKF2's
      primary instance (``estimator_selector_status``): two IMUs differ in tilt by their relative alignment.
    * EKF2's accelerometer bias estimate at the first ``estimator_sensor_bias`` sample (m/s², body FRD), learned
      before the log when it is not zero: EKF2's tilt at rest is the levelled specific force less it, i.e.
      Δroll = b_y / g, Δpitch = −b_x / g (rad, small angles of φ = atan2(−f_y, −f_z), θ = atan2(f_x, |f_yz|)).
    * Where ``vehicle_local_position`` has no valid horizontal velocity (``v_xy_valid`` false) EKF2 dead-reckons:
      the largest unaided speed V reached T s after the first invalid sample is a mean horizontal
      specific-force error V / T (m/s²), ≈ atan(V / (g T)) of tilt, that its attitude carried."""
    notes: list[str] = []
    chk: dict[str, object] = {}
    sel, ess, bias = (
        topics.get("sensor_selection"),
        topics.get("estimator_selector_status"),
        topics.get("estimator_sensor_bias"),
    )
    acc_sc, acc_ekf = _first(sel, "accel_device_id"), _first(ess, "accel_device_id")
    if acc_sc is not None and acc_ekf is not None:
        chk["accel_device_id"] = {"sensor_combined": int(acc_sc), "ekf2_primary": int(acc_ekf)}
        if acc_sc != acc_ekf:
            notes.append(
                f"sensor_combined carries accelerometer {int(acc_sc)}, EKF2's primary instance fuses "
                f"{int(acc_ekf)}: their tilts differ by the two IMUs' relative alignment and biases"
            )
    b = [_first(bias, f"accel_bias[{i}]") for i in range(3)]
    bias_dev = _first(bias, "accel_device_id")
    if all(x is not None for x in b) and (acc_ekf is None or bias_dev is None or bias_dev == acc_ekf):
        ba = np.array(b, dtype=np.float64)
        chk["ekf2_accel_bias_start_mps2"] = ba.round(4).tolist()
        if np.any(ba[:2] != 0.0):
            d_roll, d_pitch = math.degrees(ba[1] / g), math.degrees(-ba[0] / g)
            notes.append(
                f"EKF2 starts with an accelerometer bias estimate of ({ba[0]:+.3f}, {ba[1]:+.3f}, {ba[2]:+.3f}) m/s² "
                f"(learned before the log): its tilt at rest is the levelled specific force less it, "
                f"roll {d_roll:+.2f}°, pitch {d_pitch:+.2f}°"
            )
    lp = topics.get("vehicle_local_position")
    vxy = _col(lp, "v_xy_valid") if lp is not None else None
    if lp is not None and vxy is not None and "vx" in lp and "vy" in lp and np.any(vxy == 0):
        t = _time(lp)
        bad = vxy == 0
        sp = np.where(
            bad, np.hypot(np.asarray(lp["vx"], dtype=np.float64), np.asarray(lp["vy"], dtype=np.float64)), 0.0
        )
        k = int(np.argmax(sp))
        span = float(t[k] - t[np.argmax(bad)])
        if sp[k] > DEAD_RECKONING_SPEED and span > 0.0:
            err = float(sp[k]) / span
            chk["ekf2_unaided_speed_mps"] = round(float(sp[k]), 2)
            chk["ekf2_unaided_accel_error_mps2"] = round(err, 3)
            notes.append(
                f"EKF2 dead-reckons without horizontal aiding (v_xy_valid false): its velocity reached "
                f"{sp[k]:.1f} m/s in {span:.0f} s, a mean horizontal specific-force error of {err:.2f} m/s² "
                f"(≈ {math.degrees(math.atan(err / g)):.1f}° of tilt) that its attitude and accelerometer bias carry"
            )
    return notes, chk


def land_events(t: Topic | None) -> list[tuple[float, str]]:
    """Take-off (landed 1 → 0) and landing (0 → 1) from ``vehicle_land_detected``."""
    if t is None or "landed" not in t:
        return []
    ts = _col(t, "timestamp")
    if ts is None:
        return []
    landed = np.asarray(t["landed"]) != 0
    ev: list[tuple[float, str]] = []
    for k in range(1, len(landed)):
        if landed[k - 1] and not landed[k]:
            ev.append((float(ts[k]) * 1e-6, "takeoff"))
        elif not landed[k - 1] and landed[k]:
            ev.append((float(ts[k]) * 1e-6, "landing"))
    return ev


def dataset_from_topics(topics: dict[str, Topic], source: str, fmt: str) -> Dataset:
    """A Dataset from PX4 topics (name → column → array)."""
    sc = topics.get("sensor_combined")
    imu_topic = "sensor_combined"
    notes: list[str] = []
    if sc is None and "vehicle_imu" in topics:
        sc, imu_topic = sensor_combined_from_vehicle_imu(topics["vehicle_imu"], source), "vehicle_imu"
        dev = _col(topics["vehicle_imu"], "accel_device_id")
        notes.append("IMU from vehicle_imu (no sensor_combined)" + (f", accelerometer {int(dev[0])}" if dev is not None
                                                                    and len(dev) else ""))  # fmt: skip
    if sc is None:
        raise DatasetError(f"{source}: no sensor_combined or vehicle_imu topic (the PX4 readers need the IMU)")
    gaps: list[float] = []
    ds = Dataset(imu_from_sensor_combined(sc, gaps))
    gps = topics.get("vehicle_gps_position", topics.get("sensor_gps"))
    if gaps:
        long = [g for g in gaps if g > MAX_BRIDGE]
        notes.append(
            f"{imu_topic}: {len(gaps)} logging gaps ({sum(gaps):.2f} s); {len(gaps) - len(long)} up to "
            f"{MAX_BRIDGE * 1e3:.0f} ms bridged with the next sample's mean"
            + (
                f"; {len(long)} longer (up to {max(long):.2f} s): IMU data lost: the INS "
                "coasts across them at constant velocity with its σ grown"
                if long
                else ""
            )
        )
    utc_start = None
    if gps is not None:
        ds.gnss = gnss_from_gps(gps)
        utc = _col(gps, "time_utc_usec")
        if utc is not None and np.any(utc > 1e15):
            utc_start = float(utc[utc > 1e15][0]) * 1e-6  # UNIX s
        if not ds.gnss:
            notes.append(f"GNSS receiver logged ({len(_time(gps))} messages) but never had a 3-D fix")
    if "vehicle_air_data" in topics:
        ds.baro = baro_from_air_data(topics["vehicle_air_data"])
    if "vehicle_magnetometer" in topics:
        ds.mag = mag_from_magnetometer(topics["vehicle_magnetometer"])
    ds.aids, more = aids.from_ulog(topics, _time)  # the aid sources' own topics (ins_hil.aids: airspeed, ...)
    notes += more
    ds.onboard = onboard_from_ekf2(topics)
    check: dict[str, object] = {}
    if ds.onboard is not None:
        more, check = onboard_notes(topics)
        notes += more
    ds.events = land_events(topics.get("vehicle_land_detected"))
    rw = vehicle_rotary_wing(topics.get("vehicle_status"))
    ds.meta = {
        "source": source,
        "format": fmt,
        "vehicle": "PX4",
        "topics": sorted(topics),
        "notes": notes,
        "utc_start_s": utc_start,
        "onboard_check": check,
    }
    if rw is not None:
        ds.meta["rotary_wing"] = rw
    return ds


def vehicle_rotary_wing(t: Topic | None) -> bool | None:
    """Whether ``vehicle_status`` says rotary-wing at any time (a VTOL is while it hovers): ``vehicle_type``
    VEHICLE_TYPE_ROTARY_WING (1) since PX4 v1.14, ``is_rotary_wing`` before; None when neither is logged."""
    if t is None:
        return None
    vt, rw = _col(t, "vehicle_type"), _col(t, "is_rotary_wing")
    if vt is not None and len(vt):
        return bool(np.any(vt == 1))
    if rw is not None and len(rw):
        return bool(np.any(rw > 0))
    return None


# ---------------------------------------------------------------------------------------------- ULog
def _is_ulog(path: Path) -> bool:
    if not path.is_file():
        return False
    with path.open("rb") as f:
        return f.read(7) == ULOG_MAGIC


class _Stuck(RuntimeError):
    """pyulog read a damaged file far longer than its size allows (its resync can seek back for ever)."""


class _Bounded(io.BufferedReader):
    """The file handle given to pyulog: at most ``READS_PER_BYTE`` reads per byte of the file (its resync over a
    damaged stretch reads one or two a byte), then :class:`_Stuck`, which pyulog does not catch.

    pyulog only reads forward (so it ends at the end of the file) until it seeks: at the end of the definitions, to
    an appended-data offset, and in its resync over a damaged stretch, which can seek back for ever. Its reads are
    the plain (C) ones until ``FREE_SEEKS`` seeks, counted from then on (a Python ``read`` per call costs ~40 ms on a
    90-s log)."""

    def __init__(self, path: Path) -> None:
        super().__init__(io.FileIO(str(path), "rb"))
        self.budget = READS_PER_BYTE * path.stat().st_size + 10_000
        self.seeks = 0

    def seek(self, offset: int, whence: int = 0, /) -> int:
        self.seeks += 1
        if self.seeks == FREE_SEEKS + 1:
            self.read = self._counted  # type: ignore[method-assign]
        return super().seek(offset, whence)

    def _counted(self, n: int | None = -1, /) -> bytes:
        self.budget -= 1
        if self.budget < 0:
            raise _Stuck("the parser does not advance in a damaged part")
        return super().read(n)


#: seeks of pyulog before its reads are counted (the definitions' end, appended-data offsets: 1 + up to 3)
FREE_SEEKS = 8
#: reads per byte of a ULog file before pyulog's parse is given up as stuck
READS_PER_BYTE = 3


def read_ulog(path: Path) -> Dataset:
    """Read a PX4 ``.ulg`` with pyulog (instance 0 of each topic)."""
    from pyulog import ULog

    if not _is_ulog(path):
        raise DatasetError(f"{path}: not a PX4 ULog file (expected the 'ULog' header)")
    try:
        with _Bounded(path) as f:
            u = ULog(f, list(all_topics()))
    except Exception as e:  # pyulog raises plain Exceptions on corrupt files
        raise DatasetError(f"{path}: cannot parse as ULog ({' '.join(str(e).split())[:160]})") from None
    topics: dict[str, Topic] = {}
    imus: list[Topic] = []
    for d in sorted(u.data_list, key=lambda d: d.multi_id):
        topics.setdefault(d.name, dict(d.data))
        if d.name == "vehicle_imu":
            imus.append(dict(d.data))
    _select_imu(topics, imus)
    try:
        ds = dataset_from_topics(topics, str(path), "px4-ulog")
    except DatasetError as e:
        raise _named(path, e) from None
    ds.meta["params"] = {k: v for k, v in u.initial_parameters.items() if k.startswith(("EKF2_", "SENS_", "CAL_MAG"))}
    return ds


# ---------------------------------------------------------------------------------------------- ulog2csv folder
def topic_files(folder: Path) -> dict[str, Path]:
    """Topic name → CSV file (instance 0 preferred) in a ulog2csv folder; found by the name inside the file name."""
    files = sorted(folder.glob("*.csv"))
    out: dict[str, Path] = {}
    for topic in all_topics():
        pat = re.compile(rf"(^|_){topic}_(\d+)\.csv$")
        hits = sorted((int(m.group(2)), f.name, f) for f in files if (m := pat.search(f.name)))
        if hits:
            out[topic] = hits[0][2]
    return out


def read_topic_csv(path: Path) -> Topic:
    """One ulog2csv file: a header of field names, then numbers (``inf``/``nan`` allowed)."""
    try:
        text = path.read_bytes().decode("utf-8")
    except UnicodeDecodeError as e:
        line = path.read_bytes()[: e.start].count(b"\n") + 1
        raise DatasetError(f"{path}:{line}: not UTF-8 text (expected a PX4 ulog2csv file)") from None
    lines = text.splitlines()
    rd = csv.reader(lines[:1])
    head = next(rd, None)
    if not head:
        raise DatasetError(f"{path}: empty CSV (expected a ulog2csv header line)")
    if "timestamp" not in head:
        raise DatasetError(f"{path}: no 'timestamp' column (expected a PX4 ulog2csv file)")
    if len(set(head)) != len(head):
        raise DatasetError(f"{path}: a column named twice in the header (expected a PX4 ulog2csv file)")
    body = [ln for ln in lines[1:] if ln.strip()]
    try:
        data = np.loadtxt(body, delimiter=",", ndmin=2, dtype=np.float64) if body else np.zeros((0, len(head)))
    except ValueError as e:
        raise DatasetError(f"{path}: non-numeric data or rows of different lengths ({_one_line(e)})") from None
    if data.size == 0:
        data = np.zeros((0, len(head)))
    if data.shape[1] != len(head):
        raise DatasetError(f"{path}: {data.shape[1]} values a row, {len(head)} columns in the header (expected "
                           "one value per column)")  # fmt: skip
    return {name: data[:, i] for i, name in enumerate(head)}


def _one_line(e: BaseException) -> str:
    t = " ".join(str(e).split())
    return t if len(t) <= 120 else t[:117] + "..."


def _named(path: Path, e: DatasetError) -> DatasetError:
    """``e`` with the file named first (the topic helpers name only the topic)."""
    msg = str(e)
    return e if msg.startswith(str(path)) else DatasetError(f"{path}: {msg}")


def _select_imu(topics: dict[str, Topic], imus: list[Topic]) -> None:
    """``topics["vehicle_imu"]``: of the ``imus`` instances, the one of the accelerometer ``sensor_selection``
    names first (the one ``sensor_combined`` carries, as :func:`onboard_notes` says); kept as it is otherwise."""
    sel = _col(topics.get("sensor_selection", {}), "accel_device_id")
    if sel is None or not len(sel):
        return
    for t in imus:
        a = _col(t, "accel_device_id")
        if a is not None and len(a) and a[0] == sel[0]:
            topics["vehicle_imu"] = t
            return


def _is_px4_csv_dir(path: Path) -> bool:
    return path.is_dir() and not {"sensor_combined", "vehicle_imu"}.isdisjoint(topic_files(path))


def read_px4_csv(path: Path) -> Dataset:
    """Read a PX4 ``ulog2csv`` folder."""
    if not path.is_dir():
        raise DatasetError(f"{path}: not a folder (expected a PX4 ulog2csv folder of topic CSVs)")
    files = topic_files(path)
    if "sensor_combined" not in files and "vehicle_imu" not in files:
        raise DatasetError(f"{path}: no *sensor_combined*.csv or *vehicle_imu*.csv (expected a PX4 ulog2csv folder)")
    topics = {k: read_topic_csv(p) for k, p in files.items()}
    if "sensor_combined" not in topics:
        pat = re.compile(r"(^|_)vehicle_imu_(\d+)\.csv$")
        _select_imu(topics, [read_topic_csv(f) for f in sorted(path.glob("*.csv")) if pat.search(f.name)])
    try:
        return dataset_from_topics(topics, str(path), "px4-csv")
    except DatasetError as e:
        raise _named(path, e) from None


ULOG_READER = Reader("px4-ulog", "a PX4 .ulg file", _is_ulog, read_ulog, suffixes=(".ulg",), family="px4")
CSV_READER = Reader(
    "px4-csv",
    "a PX4 ulog2csv folder (*sensor_combined*.csv or *vehicle_imu*.csv)",
    _is_px4_csv_dir,
    read_px4_csv,
    family="px4",
)
