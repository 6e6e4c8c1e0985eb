"""Reader for the real drive in ``../shared/data/gnss_imu_drive_0708`` (see its README.md).

Files: ``imu_1934.csv`` (acc g, gyro deg/s, tick ms; first/last line may be partial),
``imu_1934.csv.tag`` (RTKLIB time tags) and ``gnss_1934_sf.pos`` (RTKLIB solution,
GPST, velocities ENU with *up*). Times are returned in GPST seconds counted like
Unix time (calendar seconds since 1970 on the GPS time scale).

Vehicle conventions from the README: IMU sensor axes rotated by roll 180°, yaw 180°
from the vehicle body (FRD), plus a residual misalignment (roll 0°, pitch −6.79°,
yaw 5.35°); lever arms from the system origin (FRD): IMU [0, 0, −0.65] m,
antenna [0, −0.05, −0.65] m; IMU time offset −0.125 s.
"""

from __future__ import annotations

import calendar
import math
import struct
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from ins_hil.core import NavConfig
from ins_hil.nav.earth import G0
from ins_hil.nav.rotation import dcm_from_euler
from ins_hil.types import BaroSample, FixType, GnssFix, ImuSample, Vec

DEG = math.pi / 180.0
IMU_TIME_OFFSET = -0.125  # README, for the upstream linear tick map
TAG_TIME_OFFSET = -0.24  # s, IMU latency after the tag map: gyro yaw rate vs RTK position course (docs/accuracy.md)
LEVER_IMU = np.array((0.0, 0.0, -0.65))
LEVER_GNSS = np.array((0.0, -0.05, -0.65))
MOUNT_EULER = (180.0 * DEG, 0.0, 180.0 * DEG)
MISALIGN_EULER = (0.0, -6.79 * DEG, 5.35 * DEG)


def mounting_dcm(order: str = "misalign_then_mount", misalign: tuple[float, float, float] = MISALIGN_EULER) -> Vec:
    """C_s^b: sensor axes → vehicle body FRD.

    The README gives the rotation of the sensor axes from the body axes (ZYX Euler,
    v_b = R v_s) but not the order of the two rotations. ``"misalign_then_mount"``
    (R = R(misalign) R(mount), the residual misalignment expressed in vehicle axes) is
    the default because it is the one the data support: with the other order the yaw
    misalignment acts with the opposite sign and the non-holonomic constraint pulls
    the heading 10.7° off (outage RMS 8.2 m vs 1.9 m, measured with ``ins-hil replay``).
    Both orders level the gravity vector at rest equally (pitch −6.79° on sensor x)."""
    R1 = dcm_from_euler(*MOUNT_EULER)
    R2 = dcm_from_euler(*misalign)
    if order == "mount_then_misalign":
        return R1 @ R2
    if order == "misalign_then_mount":
        return R2 @ R1
    raise ValueError(f"mounting order {order!r}")


@dataclass
class ImuLog:
    """Raw IMU log: acc (N,3) m/s², gyro (N,3) rad/s (sensor axes), tick (N,) ms, t (N,) GPST s."""

    acc: Vec
    gyro: Vec
    tick: Vec
    t: Vec
    bad_lines: int


def read_imu_csv(path: Path, offsets: list[int] | None = None) -> tuple[Vec, Vec, Vec, int]:
    """Parse the IMU csv robustly: lines that do not have 7 numeric fields (partial first/last
    lines, garbage) are skipped and counted. Returns (acc g, gyro deg/s, tick ms, bad_lines).
    ``offsets`` (optional list) receives the byte offset of the END of every kept line and the
    number of lines before it, as ``(end_byte, line_index)`` pairs flattened (for the time tags)."""
    rows = []
    bad = 0
    pos = 0
    with open(path, "rb") as fb:
        for index, raw in enumerate(fb):
            start = pos
            pos += len(raw)
            line = raw.decode("ascii", errors="replace")
            parts = line.strip().split(",")
            if len(parts) != 7:
                bad += 1
                continue
            try:
                vals = [float(p) for p in parts]
            except ValueError:
                bad += 1
                continue
            if not all(math.isfinite(v) for v in vals):
                bad += 1
                continue
            rows.append(vals)
            if offsets is not None:
                offsets.extend((start + len(raw.rstrip(b"\r\n")), index))
    if not rows:
        raise ValueError(f"{path}: no valid IMU line (expected 'ax,ay,az,gx,gy,gz,tick')")
    a = np.array(rows)
    # the first full line can still be truncated on the left (e.g. '13,0.027,...'): drop a
    # leading line whose tick does not continue the sequence
    return a[:, 0:3], a[:, 3:6], a[:, 6], bad


@dataclass
class TimeTag:
    """RTKLIB time-tag file: header tick, GPST start (s), fraction (s), records (tick ms, byte offset)."""

    tick0: int
    start: int
    frac: float
    ticks: Vec
    offsets: Vec

    @property
    def t_start(self) -> float:
        return self.start + self.frac

    @property
    def duration(self) -> float:
        return float(self.ticks[-1]) / 1000.0


def read_timetag(path: Path) -> TimeTag:
    """Parse the little-endian RTKLIB .tag file (60-byte text header, then uint32 tick,
    uint32 start second, float64 fraction, then (uint32 tick, uint32 offset) records)."""
    data = Path(path).read_bytes()
    if len(data) < 76 or not data[:7] == b"TIMETAG":
        raise ValueError(f"{path}: not an RTKLIB time-tag file (header {data[:16]!r})")
    tick0, start = struct.unpack_from("<II", data, 60)
    (frac,) = struct.unpack_from("<d", data, 68)
    body = data[76:]
    n = len(body) // 8
    rec = np.frombuffer(body[: 8 * n], dtype="<u4").reshape(n, 2)
    return TimeTag(int(tick0), int(start), float(frac), rec[:, 0].astype(np.float64), rec[:, 1].astype(np.float64))


@dataclass
class PosLog:
    """RTKLIB .pos solution: t GPST s, lat/lon rad, h m, q, ns, sd (N,3) NEU m, vel_ned (N,3), sdv (N,3)."""

    t: Vec
    lat: Vec
    lon: Vec
    h: Vec
    q: Vec
    ns: Vec
    sd: Vec
    vel_ned: Vec
    sdv: Vec


def read_pos(path: Path) -> PosLog:
    """Parse an RTKLIB .pos file with the columns named in its '%  GPST ...' header line."""
    cols: list[str] | None = None
    rows = []
    times = []
    with open(path, encoding="ascii", errors="replace") as fh:
        for line in fh:
            if line.startswith("%"):
                if "GPST" in line and "latitude" in line:
                    cols = line[1:].split()[1:]  # drop 'GPST' (date+time are two tokens in the data)
                continue
            parts = line.split()
            if len(parts) < 3 or cols is None:
                continue
            try:
                ymd = [int(x) for x in parts[0].split("/")]
                hh, mi, ss = parts[1].split(":")
                sec = float(ss)
                t = calendar.timegm((ymd[0], ymd[1], ymd[2], int(hh), int(mi), 0)) + sec
                vals = [float(x) for x in parts[2 : 2 + len(cols)]]
            except ValueError:
                continue
            if len(vals) != len(cols):
                continue
            times.append(t)
            rows.append(vals)
    if cols is None:
        raise ValueError(f"{path}: no '% GPST latitude(deg) ...' header line")
    a = np.array(rows)

    def col(name: str) -> Vec:
        for i, c in enumerate(cols):
            if c.startswith(name):
                return a[:, i]
        raise ValueError(f"{path}: column {name!r} missing (have {cols})")

    vel = np.column_stack([col("vn"), col("ve"), -col("vu")])  # vu is UP → NED down = −vu
    return PosLog(
        t=np.array(times),
        lat=col("latitude") * DEG,
        lon=col("longitude") * DEG,
        h=col("height"),
        q=col("Q"),
        ns=col("ns"),
        sd=np.column_stack([col("sdn"), col("sde"), col("sdu")]),
        vel_ned=vel,
        sdv=np.column_stack([col("sdvn"), col("sdve"), col("sdvu")]),
    )


@dataclass
class Drive:
    """The drive ready for the core: body-frame IMU samples and GNSS fixes (GPST s)."""

    imu: list[ImuSample]
    gnss: list[GnssFix]
    pos: PosLog
    imu_log: ImuLog
    lever_gnss_b: Vec  # IMU → antenna, body FRD (m)


def tag_arrival_ms(tag: TimeTag, line_end: Vec, line_index: Vec, file_size: int) -> Vec:
    """Arrival time of every csv line (ms after the tag's start time) from the RTKLIB time tags.

    Each tag record is (tick, byte offset) with the offset the file position reached at that tick (the
    last record's offset equals the stream's size). A line has arrived at the first record whose offset
    reaches its last byte. The tags count the bytes of the logged stream, which had CRLF line ends: when
    the last offset exceeds ``file_size`` by the number of lines, one byte per line is added back."""
    end = np.asarray(line_end, dtype=np.float64)
    n_lines = int(np.max(line_index)) + 1 if len(line_index) else 0
    extra = float(tag.offsets[-1]) - float(file_size)
    if extra > 0:
        if abs(extra - n_lines) > 2:
            raise ValueError(
                f"time tags: last byte offset {tag.offsets[-1]:.0f} does not match the csv size {file_size} "
                f"(LF) or its CRLF size {file_size + n_lines}"
            )
        end = end + np.asarray(line_index, dtype=np.float64)  # CRLF: one more byte per earlier line
    k = np.searchsorted(tag.offsets, end, side="left")
    return tag.ticks[np.clip(k, 0, len(tag.ticks) - 1)]


def tag_time_map(tag: TimeTag, tick: Vec, arrival_ms: Vec, calib_s: float = 10.0) -> tuple[Vec, float]:
    """Causal csv-tick → GPST map: t = t_start + (tick + c) / 1000, with c the smallest
    (arrival − tick) over the first ``calib_s`` s of lines (the lower envelope = the fastest transfer,
    IMU clock rate taken as nominal; measured drift vs the tags 13 ppm, 7 ms over the drive).
    Returns (t GPST s, c ms). The logging latency is a separate offset (``load_drive(time_offset=...)``)."""
    first = tick - tick[0] <= calib_s * 1000.0
    c = float(np.min(arrival_ms[first] - tick[first]))
    return tag.t_start + (tick + c) / 1000.0, c


def load_drive(
    directory: Path,
    mounting: str = "misalign_then_mount",
    time_offset: float | None = None,
    misalign: tuple[float, float, float] = MISALIGN_EULER,
    increments: str = "trapezoid",
    time_map: str = "tags",
    accel_lag: float = 0.0,
) -> Drive:
    """Load the drive: IMU rotated into the vehicle body frame and time-tagged (GPST + offset),
    GNSS fixes from the .pos file (only Q ≤ 2 epochs; σ from the file).

    time_map: ``"tags"`` (default) maps every csv line through its arrival time in the RTKLIB time
    tags (:func:`tag_time_map`), then adds ``time_offset`` (default :data:`TAG_TIME_OFFSET`);
    ``"linear"`` is the upstream convention, csv ticks stretched linearly onto
    [start, start + last_tag_tick / 1000] s, plus ``time_offset`` (default the README's −0.125 s). The
    linear map assumes the first csv line arrived at the tag start; it arrived 115 ms later and the
    stretch drifts, so the linear map's time error runs from −123 ms to +10 ms over the drive
    (docs/accuracy.md, cross-correlation of gyro yaw rate with the GNSS course rate)."""
    d = Path(directory)
    ends: list[int] = []
    acc_g, gyro_d, tick, bad = read_imu_csv(d / "imu_1934.csv", ends)
    tag = read_timetag(d / "imu_1934.csv.tag")
    span = float(tick[-1] - tick[0])
    if span <= 0:
        raise ValueError(f"{d}: IMU ticks do not increase")
    if time_map == "tags":
        e = np.array(ends, dtype=np.float64).reshape(-1, 2)
        arrival = tag_arrival_ms(tag, e[:, 0], e[:, 1], (d / "imu_1934.csv").stat().st_size)
        t, _ = tag_time_map(tag, tick, arrival)
        t = t + (TAG_TIME_OFFSET if time_offset is None else time_offset)
    elif time_map == "linear":
        # linear map of the csv ticks onto [start, start + last_tag_tick/1000] (upstream convention)
        t = tag.t_start + (tick - tick[0]) / span * tag.duration
        t = t + (IMU_TIME_OFFSET if time_offset is None else time_offset)
    else:
        raise ValueError(f"load_drive: time_map={time_map!r}: expected 'tags' or 'linear'")
    R = mounting_dcm(mounting, misalign)
    acc = (acc_g * G0) @ R.T
    gyro = (gyro_d * DEG) @ R.T
    if accel_lag:
        # the accelerometer samples lag the gyro samples by ``accel_lag`` s (cross-correlation with the GNSS
        # velocity, docs/accuracy.md): the specific force valid at t was logged at t + accel_lag. Re-stamping
        # needs the samples up to t + accel_lag, i.e. a real-time gateway runs that much later (a latency,
        # handled like the GNSS delay), not a look-ahead.
        acc = np.column_stack([np.interp(t + accel_lag, t, acc[:, i]) for i in range(3)])
    log = ImuLog(acc, gyro, tick, t, bad)
    samples = []
    for k in range(1, len(t)):
        dt = float(t[k] - t[k - 1])
        if not 0.0 < dt < 0.1:
            continue
        if increments == "trapezoid":  # trapezoid of the two rate samples over the interval
            w, a = 0.5 * (gyro[k] + gyro[k - 1]), 0.5 * (acc[k] + acc[k - 1])
        else:  # "end": the sample at the end of the interval held over it (rate = interval mean)
            w, a = gyro[k], acc[k]
        samples.append(ImuSample(t=float(t[k]), dt=dt, dtheta=w * dt, dvel=a * dt, seq=k & 0xFFFF))
    pos = read_pos(d / "gnss_1934_sf.pos")
    fixes = []
    for k in range(len(pos.t)):
        if pos.q[k] > 2:
            continue
        fixes.append(
            GnssFix(t=float(pos.t[k]), lat=float(pos.lat[k]), lon=float(pos.lon[k]), h=float(pos.h[k]),
                    vel_ned=pos.vel_ned[k].copy(), std_ne=float(max(pos.sd[k, 0], pos.sd[k, 1])),
                    std_d=float(pos.sd[k, 2]), std_vel=float(np.max(pos.sdv[k])),
                    fix_type=FixType.RTK_FIXED if pos.q[k] == 1 else FixType.RTK_FLOAT, num_sats=int(pos.ns[k]))
        )  # fmt: skip
    return Drive(samples, fixes, pos, log, LEVER_GNSS - LEVER_IMU)


def outage_windows(t_gnss: Vec, first: float = 40.0, on: float = 30.0, off: float = 15.0, tail: float = 30.0):
    """The README's protocol: 15 s outages starting 40 s after the first GNSS epoch, then
    30 s with GNSS / 15 s without, until 30 s before the last epoch. Returns [(start, end)]."""
    t0, t1 = float(t_gnss[0]), float(t_gnss[-1])
    out = []
    s = t0 + first
    while s + off <= t1 - tail:
        out.append((s, s + off))
        s += off + on
    return out


def cv_outage_windows(t_gnss: Vec, shift: float = 22.5) -> list[tuple[float, float]]:
    """Held-out validation outages for choosing settings without the protocol's truth: the protocol's
    15 s outages shifted by ``shift`` s (15..30), so each lies inside a 30 s GNSS-present interval of
    the protocol and never overlaps a protocol outage (the protocol's outage epochs are never scored)."""
    if not 15.0 <= shift <= 30.0:
        raise ValueError(f"cv_outage_windows: shift={shift} s would overlap the protocol's outages (need 15..30)")
    return outage_windows(t_gnss, first=40.0 + shift)


STARTUP_RESTART = 201.0  # s after the first GNSS epoch: during the stop at 200.8–209.5 s


def startup_validation(
    drive: Drive,
    restart: float = STARTUP_RESTART,
    score_until: float = 220.0,
    yaw_speed: float = NavConfig.gnss_yaw_speed,
) -> tuple[list[ImuSample], list[GnssFix], list[tuple[float, float]]]:
    """A held-out start-up outage (the protocol's first outage comes 0.25 s after the in-motion yaw
    alignment, so the validation windows, which start 57.5 s in, never test a fresh alignment): the
    replay restarts at ``restart`` s after the first GNSS epoch (during the stop at 200.8–209.5 s), and the
    outage runs from 0.25 s after the first fix at ≥ ``yaw_speed`` m/s (when the core enters navigation)
    to ``score_until`` s, where the protocol's next outage begins (its epochs are never scored).
    Returns (IMU samples, fixes, [outage])."""
    t0 = float(drive.pos.t[0])
    a = t0 + restart
    imu = [s for s in drive.imu if s.t >= a]
    gnss = [f for f in drive.gnss if f.t >= a]
    moving = [
        f.t for f in gnss if f.vel_ned is not None and math.hypot(float(f.vel_ned[0]), float(f.vel_ned[1])) >= yaw_speed
    ]
    if not moving or moving[0] + 0.25 >= t0 + score_until:
        raise ValueError(f"startup_validation: no departure between {restart} s and {score_until} s")
    return imu, gnss, [(moving[0] + 0.25, t0 + score_until)]


# (label, white noise σ m per 4 Hz sample, drift random walk m/√s) of the synthetic barometers of the what-if
WHATIF_BAROS = (("good", 0.1, 0.01), ("poor", 0.5, 0.05))


def synthetic_baro(pos: PosLog, white: float, drift: float, seed: int, datum: float = 1601.0) -> list[BaroSample]:
    """A barometer the drive does not have, made from the truth for a what-if study (never a protocol
    figure): at every RTK-fixed (Q = 1) epoch, the RTK ellipsoidal height minus ``datum`` (m) plus white noise
    σ ``white`` (m) and a random-walk drift ``drift`` (m/√s); deterministic for a ``seed``."""
    if white < 0 or drift < 0:
        raise ValueError(f"synthetic_baro: white={white} m and drift={drift} m/√s must be ≥ 0")
    rng = np.random.default_rng(seed)
    ok = pos.q == 1
    t, h = pos.t[ok], pos.h[ok]
    walk = np.cumsum(rng.normal(0.0, 1.0, len(t)) * drift * np.sqrt(np.diff(t, prepend=t[:1])))
    alt = h - datum + walk + rng.normal(0.0, 1.0, len(t)) * white
    return [BaroSample(float(ti), math.nan, altitude=float(a)) for ti, a in zip(t, alt, strict=True)]
