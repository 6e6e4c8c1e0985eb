"""RTKLIB recordings: an IMU csv, its RTKLIB time-tag file (``*.tag``) and an RTKLIB solution (``*.pos``).

The file names and the conventions come from the dataset config's ``[rtklib]`` table (``docs/datasets.md``)::

    imu_csv, time_tag, pos   file names in the folder (default: the folder's only *.csv with a *.csv.tag, its
                             tag, its only *.pos)
    imu_columns              the csv columns, names of ax ay az gx gy gz tick ("-" = ignored);
                             default ["ax", "ay", "az", "gx", "gy", "gz", "tick"]
    acc_unit, gyro_unit      "g" | "m/s2", "deg/s" | "rad/s" (default g, deg/s); tick in ms
    velocity_up              the .pos third velocity is up (RTKLIB's vu; NED down = −vu), default true
    time_map                 "tags": every csv line through its arrival time in the tags (:func:`tag_time_map`),
                             "linear": ticks stretched onto the tag span; then ``mounting.imu_time_offset_s``
    time_calib_s             the start span (s) whose fastest transfer fixes the tag map (default 10)
    increments               "trapezoid" (mean of the two rate samples) | "end" (the end sample held)
    accel_lag_s              the accelerometer lags the gyro by this much (s; re-stamped, default 0)
    max_q                    epochs with RTKLIB quality Q ≤ max_q are used (1 fix … 6 PPP; default 2)

Times are GPST seconds counted like Unix time. The mounting (``mounting.imu_to_body_deg``) and the IMU time
offset are applied here, to the rate samples before the increments are formed (rotating trapezoid increments
afterwards is the same rotation but not the same floating-point sums); the dataset's ``meta["mounted"]`` records
what was applied, and :func:`ins_hil.datasets.run.prepare` applies only a config's difference from it (e.g. a
trial offset of ``ins_hil.datasets.offset``).
"""

from __future__ import annotations

import calendar
import math
import struct
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

from ins_hil.datasets.dataset import Dataset, DatasetError, Reader
from ins_hil.nav.earth import G0
from ins_hil.types import FixType, GnssFix, ImuSample, Vec

if TYPE_CHECKING:
    from ins_hil.datasets.config import DatasetConfig

DEG = math.pi / 180.0
IMU_COLUMNS = ("ax", "ay", "az", "gx", "gy", "gz", "tick")
#: RTKLIB solution quality Q → fix type
Q_FIX = {1: FixType.RTK_FIXED, 2: FixType.RTK_FLOAT, 3: FixType.DGPS, 4: FixType.DGPS, 5: FixType.FIX_3D,
         6: FixType.FIX_3D}  # fmt: skip
#: ``[rtklib]`` keys and their types (checked by ins_hil.datasets.config)
OPTIONS: dict[str, type | tuple[type, ...]] = {
    "imu_csv": str, "time_tag": str, "pos": str, "imu_columns": list, "acc_unit": str, "gyro_unit": str,
    "velocity_up": bool, "time_map": str, "time_calib_s": (int, float), "increments": str,
    "accel_lag_s": (int, float), "max_q": int,
}  # fmt: skip
CHOICES = {"acc_unit": ("g", "m/s2"), "gyro_unit": ("deg/s", "rad/s"), "time_map": ("tags", "linear"),
           "increments": ("trapezoid", "end")}  # fmt: skip


def check_options(o: dict[str, Any], source: str) -> None:
    """ValueError (one line) for a bad ``[rtklib]`` value (the types are checked by the config)."""
    for k, allowed in CHOICES.items():
        if k in o and o[k] not in allowed:
            raise ValueError(f"{source}: rtklib.{k} = {o[k]!r}: expected one of {', '.join(allowed)}")
    cols = o.get("imu_columns", list(IMU_COLUMNS))
    named = [c for c in cols if c != "-"] if all(isinstance(c, str) for c in cols) else []
    if sorted(named) != sorted(IMU_COLUMNS):
        raise ValueError(f"{source}: rtklib.imu_columns = {cols!r}: expected each of {', '.join(IMU_COLUMNS)} "
                         "once ('-' for a column to ignore)")  # fmt: skip


@dataclass
class ImuLog:
    """Raw IMU log: acc (N,3) m/s², gyro (N,3) rad/s (body axes after the mounting), tick (N,) ms, t (N,) s."""

    acc: Vec
    gyro: Vec
    tick: Vec
    t: Vec
    bad_lines: int


def read_imu_csv(
    path: Path, offsets: list[int] | None = None, columns: tuple[str, ...] | list[str] = IMU_COLUMNS
) -> tuple[Vec, Vec, Vec, int]:
    """Parse the IMU csv robustly: lines that do not have ``len(columns)`` numeric fields (partial first/last
    lines, garbage) are skipped and counted. Returns (acc, gyro, tick, bad_lines) in the file's units.
    ``offsets`` (optional list) receives the byte offset of the END of every kept line and the number of
    lines before it, as ``(end_byte, line_index)`` pairs flattened (for the time tags).

    Every line is checked: the lines with ``len(columns)`` fields are converted at once (numpy's conversion of
    each field's bytes, Python's ``float`` of them), the rows with a non-finite value dropped; when a field does
    not convert, every line is read one by one (:func:`_csv_rows`), with the same result."""
    data = Path(path).read_bytes()
    lines = data.split(b"\n")
    if lines[-1] == b"":  # the newline that ends the last line (or an empty file)
        lines.pop()
    width = len(columns)
    cand = [i for i, ln in enumerate(lines) if ln.count(b",") == width - 1]
    try:
        vals = np.array(b",".join([lines[i] for i in cand]).split(b",") if cand else [], dtype=np.float64)
    except ValueError:  # a field that is not a number: line by line
        kept, a = _csv_rows(lines, width)
    else:
        vals = vals.reshape(len(cand), width)
        ok = np.isfinite(vals).all(axis=1)
        a = vals[ok]
        kept = np.asarray(cand, dtype=np.int64)[ok].tolist()
    bad = len(lines) - len(kept)
    if not kept:
        raise ValueError(f"{path}: no valid IMU line (expected '{','.join(columns)}')")
    if offsets is not None:  # each kept line's start + its length without the line end
        size = np.array([len(ln) + 1 for ln in lines], dtype=np.int64)
        k = np.asarray(kept, dtype=np.int64)
        end = (np.cumsum(size) - size)[k] + np.array([len(lines[i].rstrip(b"\r")) for i in kept], dtype=np.int64)
        offsets.extend(np.column_stack((end, k)).ravel().tolist())
    ix = {c: i for i, c in enumerate(columns)}
    if tuple(columns) == IMU_COLUMNS:
        return a[:, 0:3], a[:, 3:6], a[:, 6], bad
    acc = a[:, [ix["ax"], ix["ay"], ix["az"]]]
    gyro = a[:, [ix["gx"], ix["gy"], ix["gz"]]]
    return acc, gyro, a[:, ix["tick"]], bad


def _csv_rows(lines: list[bytes], width: int) -> tuple[list[int], Vec]:
    """The csv lines one by one: (the indices of the lines of ``width`` finite numbers, their values (N, width))."""
    kept: list[int] = []
    rows = []
    for index, raw in enumerate(lines):
        parts = raw.decode("ascii", errors="replace").strip().split(",")
        if len(parts) != width:
            continue
        try:
            vals = [float(p) for p in parts]
        except ValueError:
            continue
        if not all(math.isfinite(v) for v in vals):
            continue
        rows.append(vals)
        kept.append(index)
    return kept, np.array(rows).reshape(-1, width)


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
    if n == 0:
        raise ValueError(f"{path}: a time-tag header without records (expected (tick, offset) records after it)")
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


def read_pos(path: Path, velocity_up: bool = True) -> PosLog:
    """Parse an RTKLIB .pos file with the columns named in its '%  GPST ...' header line. ``velocity_up``: the
    third velocity column (vu) is up, as RTKLIB writes it (NED down = −vu); False: it is already down."""
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
    if not rows:
        raise ValueError(f"{path}: a header without solution lines (expected 'yyyy/mm/dd hh:mm:ss.s lat lon ...')")
    a = np.array(rows)

    def col(name: str) -> Vec:
        for i, c in enumerate(cols):
            if c.startswith(name):
                return a[:, i]
        raise ValueError(f"{path}: column {name!r} missing (have {cols})")

    vel = np.column_stack([col("vn"), col("ve"), -col("vu") if velocity_up else col("vu")])
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


def tag_arrival_ms(tag: TimeTag, line_end: Vec, line_index: Vec, file_size: int) -> Vec:
    """Arrival time of every csv line (ms after the tag's start time) from the RTKLIB time tags.

    Each tag record is (tick, byte offset) with the offset the file position reached at that tick (the
    last record's offset equals the stream's size). A line has arrived at the first record whose offset
    reaches its last byte. The tags count the bytes of the logged stream, which may have had CRLF line ends:
    when the last offset exceeds ``file_size`` by the number of lines, one byte per line is added back."""
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
    IMU clock rate taken as nominal). Returns (t GPST s, c ms). The logging latency is a separate offset
    (``mounting.imu_time_offset_s``)."""
    first = tick - tick[0] <= calib_s * 1000.0
    c = float(np.min(arrival_ms[first] - tick[first]))
    return tag.t_start + (tick + c) / 1000.0, c


@dataclass
class Recording:
    """An RTKLIB recording read with its config: the dataset, the raw IMU log and the .pos solution."""

    dataset: Dataset
    imu_log: ImuLog
    pos: PosLog


def _files(d: Path, o: dict[str, Any]) -> tuple[Path, Path, Path]:
    """(IMU csv, time tag, .pos) in folder ``d``: the config's names, else the folder's only candidates."""
    if "imu_csv" in o:
        csv = d / o["imu_csv"]
    else:
        cands = sorted(p for p in d.glob("*.csv") if p.with_name(p.name + ".tag").is_file())
        if len(cands) != 1:
            raise DatasetError(f"{d}: expected one *.csv with a *.csv.tag beside it (found {len(cands)}); "
                               "name it in the dataset config (rtklib.imu_csv)")  # fmt: skip
        csv = cands[0]
    tag = d / o.get("time_tag", csv.name + ".tag")
    if "pos" in o:
        pos = d / o["pos"]
    else:
        ps = sorted(d.glob("*.pos"))
        if len(ps) != 1:
            raise DatasetError(f"{d}: expected one *.pos (found {len(ps)}); name it in the dataset config (rtklib.pos)")
        pos = ps[0]
    for p in (csv, tag, pos):
        if not p.is_file():
            raise DatasetError(f"{d}: {p.name} missing (an RTKLIB recording: IMU csv, its .tag, a .pos)")
    return csv, tag, pos


def load(directory: Path, cfg: DatasetConfig | None = None) -> Recording:
    """Read the RTKLIB recording in ``directory`` with the config's ``[rtklib]`` conventions, mounting and IMU
    time offset: IMU increments in body FRD, time-tagged (GPST + offset); GNSS fixes from the .pos file
    (epochs with Q ≤ max_q; σ from the file)."""
    from ins_hil.datasets.config import DatasetConfig

    c = cfg if cfg is not None else DatasetConfig(name=Path(directory).name)
    o = c.rtklib
    d = Path(directory)
    csv, tag_path, pos_path = _files(d, o)
    ends: list[int] = []
    acc_raw, gyro_raw, tick, bad = read_imu_csv(csv, ends, o.get("imu_columns", IMU_COLUMNS))
    tag = read_timetag(tag_path)
    span = float(tick[-1] - tick[0])
    if span <= 0:
        raise DatasetError(f"{csv}: IMU ticks do not increase")
    if o.get("time_map", "tags") == "tags":
        e = np.array(ends, dtype=np.float64).reshape(-1, 2)
        arrival = tag_arrival_ms(tag, e[:, 0], e[:, 1], csv.stat().st_size)
        t, _ = tag_time_map(tag, tick, arrival, float(o.get("time_calib_s", 10.0)))
    else:  # linear map of the csv ticks onto [start, start + last_tag_tick/1000] (upstream convention)
        t = tag.t_start + (tick - tick[0]) / span * tag.duration
    t = t + c.imu_time_offset
    R = c.mounting_dcm()
    acc = (acc_raw * G0 if o.get("acc_unit", "g") == "g" else acc_raw) @ R.T
    gyro = (gyro_raw * DEG if o.get("gyro_unit", "deg/s") == "deg/s" else gyro_raw) @ R.T
    lag = float(o.get("accel_lag_s", 0.0))
    if lag:
        # the accelerometer samples lag the gyro samples by ``lag`` s: the specific force valid at t was logged at
        # t + lag. Re-stamping needs the samples up to t + lag, i.e. a real-time gateway runs that much later
        # (a latency, handled like the GNSS delay), not a look-ahead.
        acc = np.column_stack([np.interp(t + lag, t, acc[:, i]) for i in range(3)])
    log = ImuLog(acc, gyro, tick, t, bad)
    trapezoid = o.get("increments", "trapezoid") == "trapezoid"
    dts = np.diff(t)
    if trapezoid:  # trapezoid of the two rate samples over the interval
        w, a = 0.5 * (gyro[1:] + gyro[:-1]), 0.5 * (acc[1:] + acc[:-1])
    else:  # the sample at the end of the interval held over it (rate = interval mean)
        w, a = gyro[1:], acc[1:]
    with np.errstate(all="ignore"):
        dth, dv = w * dts[:, None], a * dts[:, None]  # the products sample by sample, all at once
    # one sample per interval of 0 < dt < 0.1 s (its increments: rows of dth, dv, as views)
    samples = [ImuSample(t=tk, dt=dt, dtheta=th, dvel=v, seq=k & 0xFFFF)
               for k, tk, dt, th, v in zip(range(1, len(t)), t[1:].tolist(), dts.tolist(), dth, dv)
               if 0.0 < dt < 0.1]  # fmt: skip
    pos = read_pos(pos_path, bool(o.get("velocity_up", True)))
    max_q = int(o.get("max_q", 2))
    # the epochs with 1 ≤ Q ≤ max_q (RTKLIB's Q is 1 (fix) … 6 (PPP); NaN fails), their columns as Python floats
    use = np.flatnonzero((pos.q >= 1) & (pos.q <= max_q))
    vel = pos.vel_ned[use]
    fixes = [
        GnssFix(t=tk, lat=la, lon=lo, h=hk, vel_ned=vel[i], std_ne=max(sn, se), std_d=sd, std_vel=sv,
                fix_type=Q_FIX.get(int(q), FixType.FIX_3D), num_sats=int(ns) if 0 <= ns <= 255 else 0)
        for i, (tk, la, lo, hk, sn, se, sd, sv, q, ns) in enumerate(zip(
            pos.t[use].tolist(), pos.lat[use].tolist(), pos.lon[use].tolist(), pos.h[use].tolist(),
            pos.sd[use, 0].tolist(), pos.sd[use, 1].tolist(), pos.sd[use, 2].tolist(),
            np.max(pos.sdv[use], axis=1).tolist(), pos.q[use].tolist(), pos.ns[use].tolist()))
    ]  # fmt: skip
    notes = [] if cfg is not None else ["no dataset config: identity mounting, no IMU time offset, no lever arm"]
    mounted = {"imu_time_offset_s": c.imu_time_offset, "imu_to_body": c.imu_to_body.copy()}
    meta = {"source": str(d), "format": "rtklib", "vehicle": "", "notes": notes, "mounted": mounted,
            "utc_start_s": float(pos.t[0]) if len(pos.t) else None, "csv_bad_lines": bad}  # fmt: skip
    return Recording(Dataset(samples, fixes, meta=meta), log, pos)


def _is_rtklib(path: Path) -> bool:
    return path.is_dir() and any(path.glob("*.pos")) and any(path.glob("*.csv.tag"))


def _read(path: Path, cfg: DatasetConfig | None = None) -> Dataset:
    try:
        return load(path, cfg).dataset
    except DatasetError:
        raise
    except ValueError as e:
        msg = " ".join(str(e).split())
        raise DatasetError(msg if msg.startswith(str(path)) else f"{path}: {msg}") from None


READER = (Reader("rtklib", "a folder with an IMU csv, its RTKLIB time tag (*.csv.tag) and an RTKLIB *.pos",
                _is_rtklib, _read, configured=True))  # fmt: skip
