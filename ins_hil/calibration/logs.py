"""Recorded logs for calibration: CSV and the runtime recorder's ``.ihlog`` into arrays.

CSV columns (header row required, SI units, body FRD; see docs/calibration.md):

* IMU logs: ``t`` (s, end of interval) and either increments
  ``dtheta_x,dtheta_y,dtheta_z`` (rad), ``dvel_x,dvel_y,dvel_z`` (m/s) with ``dt`` (s)
  — the :class:`~ins_hil.types.ImuSample` form — or rates ``gyro_x..z`` (rad/s) and
  ``accel_x..z`` (m/s²). Optional ``step`` (int: position/rate step, −1 = transit;
  without it quiet segments are detected), ``flags`` (ImuFlags bits; saturation
  bits are checked), ``imu_id``.
* Magnetometer logs: ``t``, ``mag_x,mag_y,mag_z`` (T).
"""

from __future__ import annotations

import csv
from collections.abc import Callable, Iterable
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from ins_hil.nav import calibration as cal
from ins_hil.types import ImuSample, MagSample, Vec


@dataclass
class LogData:
    """What the calibration needs from a log (arrays over N samples; None when absent)."""

    t: Vec
    dt: float
    gyro: Vec | None = None  # (N, 3) rad/s
    accel: Vec | None = None  # (N, 3) m/s²
    dtheta: Vec | None = None  # (N, 3) rad
    dvel: Vec | None = None  # (N, 3) m/s
    mag: Vec | None = None  # (N, 3) T
    step: Vec | None = None  # (N,) int
    flags: Vec | None = None  # (N,) int
    imu_id: int | None = None


def read_csv_log(path: Path, imu_id: int | None = None) -> LogData:
    """Read a calibration CSV (columns in the module doc); CalibrationError names missing columns.

    With an ``imu_id`` column, ``imu_id`` selects the rows of one IMU (required when there are several).
    """
    try:
        with path.open(newline="") as f:
            header = next(csv.reader(f), None)
    except (OSError, UnicodeDecodeError) as e:
        raise cal.CalibrationError(f"{path}: cannot read ({getattr(e, 'strerror', None) or e})") from e
    if not header:
        raise cal.CalibrationError(f"{path}: empty file; a header row with column names is required")
    cols = [h.strip() for h in header]
    try:
        data = np.loadtxt(path, delimiter=",", skiprows=1, ndmin=2)
    except ValueError as e:
        raise cal.CalibrationError(f"{path}: not a numeric CSV after the header ({e})") from e
    if data.shape[0] == 0:
        raise cal.CalibrationError(f"{path}: no data rows")
    if data.shape[1] != len(cols):
        raise cal.CalibrationError(f"{path}: {data.shape[1]} values per row but {len(cols)} header names")
    ix = {c: i for i, c in enumerate(cols)}
    if "imu_id" in ix:
        ids = sorted(int(i) for i in np.unique(data[:, ix["imu_id"]]))
        if imu_id is not None:
            data = data[data[:, ix["imu_id"]] == imu_id]
            if len(data) == 0:
                raise cal.CalibrationError(f"{path}: no samples of IMU {imu_id}; the log has IMUs {ids}")
        elif len(ids) > 1:
            raise cal.CalibrationError(f"{path}: samples of IMUs {ids}; choose one with --imu-id")

    def get3(prefix: str) -> Vec | None:
        names = [f"{prefix}_{a}" for a in "xyz"]
        have = [n in ix for n in names]
        if any(have) and not all(have):
            raise cal.CalibrationError(f"{path}: column(s) {[n for n in names if n not in ix]} missing")
        return data[:, [ix[n] for n in names]] if all(have) else None

    if "t" not in ix:
        raise cal.CalibrationError(f"{path}: column 't' (time, s) missing; columns are {cols}")
    vec = {p: get3(p) for p in ("dtheta", "dvel", "mag", "gyro", "accel")}
    t = data[:, ix["t"]]
    if len(t) > 1 and np.any(np.diff(t) <= 0):
        raise cal.CalibrationError(f"{path}: column 't' must increase strictly (row {int(np.argmin(np.diff(t))) + 2})")
    if "dt" in ix:
        dts = data[:, ix["dt"]]
        dt = float(np.median(dts))
    elif len(t) > 1:
        dts = np.diff(t, prepend=t[0] - (t[1] - t[0]))
        dt = float(np.median(np.diff(t)))
    else:
        raise cal.CalibrationError(f"{path}: one row and no 'dt' column")
    log = LogData(t=t, dt=dt, dtheta=vec["dtheta"], dvel=vec["dvel"], mag=vec["mag"])
    log.gyro = vec["gyro"]
    log.accel = vec["accel"]
    if log.dtheta is not None and log.gyro is None:
        log.gyro = log.dtheta / dts[:, None]
    if log.dvel is not None and log.accel is None:
        log.accel = log.dvel / dts[:, None]
    if log.gyro is not None and log.dtheta is None:
        log.dtheta = log.gyro * dts[:, None]
    if log.accel is not None and log.dvel is None:
        log.dvel = log.accel * dts[:, None]
    if "step" in ix:
        log.step = data[:, ix["step"]].astype(np.int64)
    if "flags" in ix:
        log.flags = data[:, ix["flags"]].astype(np.int64)
    if "imu_id" in ix:
        log.imu_id = int(data[0, ix["imu_id"]])
    return log


def log_from_records(records: Iterable[Any], imu_id: int | None = None, where: str = "log") -> LogData:
    """LogData from recorded samples (``ImuSample``/``MagSample``; other records are skipped).

    This is how ``.ihlog`` files of the runtime recorder are read: no step labels (the quiet
    segments are detected), flags and imu_id from the samples.
    """
    imu: list[ImuSample] = []
    mag: list[MagSample] = []
    for r in records:
        if r.kind == "imu":
            imu.append(r)
        elif r.kind == "mag":
            mag.append(r)
    ids = sorted({s.imu_id for s in imu})
    if imu_id is not None:
        imu = [s for s in imu if s.imu_id == imu_id]
        if not imu and ids:
            raise cal.CalibrationError(f"{where}: no samples of IMU {imu_id}; the log has IMUs {ids}")
    elif len(ids) > 1:
        raise cal.CalibrationError(f"{where}: samples of IMUs {ids}; choose one with --imu-id")
    mag_arr = np.array([m.field_b for m in mag], dtype=np.float64).reshape(-1, 3) if mag else None
    if imu:
        t = np.array([s.t for s in imu])
        dts = np.array([s.dt for s in imu])
        dth = np.array([s.dtheta for s in imu], dtype=np.float64)
        dv = np.array([s.dvel for s in imu], dtype=np.float64)
        return LogData(
            t=t,
            dt=float(np.median(dts)),
            gyro=dth / dts[:, None],
            accel=dv / dts[:, None],
            dtheta=dth,
            dvel=dv,
            mag=mag_arr,
            flags=np.array([s.flags for s in imu], dtype=np.int64),
            imu_id=imu[0].imu_id,
        )
    if mag_arr is not None:
        t = np.array([m.t for m in mag])
        return LogData(t=t, dt=float(np.median(np.diff(t))) if len(t) > 1 else 0.0, mag=mag_arr)
    raise cal.CalibrationError(f"{where}: no IMU or magnetometer samples")


def _read_ihlog(path: Path, imu_id: int | None = None) -> LogData:
    """The runtime recorder's ``.ihlog`` (``ins_hil.runtime.recorder.read_records``, all parts)."""
    try:
        from ins_hil.runtime import recorder  # type: ignore[attr-defined,unused-ignore]
    except ImportError as e:
        raise cal.CalibrationError(
            f"{path}: .ihlog logs need ins_hil.runtime.recorder (not in this build); "
            "export the log to CSV (columns: docs/calibration.md)"
        ) from e
    try:
        records = list(recorder.read_records(path))
    except (OSError, ValueError) as e:
        raise cal.CalibrationError(f"{path}: cannot read the recording ({e})") from e
    return log_from_records(records, imu_id, str(path))


#: log readers by file suffix: (path, imu_id or None) → LogData
LOG_READERS: dict[str, Callable[[Path, int | None], LogData]] = {".csv": read_csv_log, ".ihlog": _read_ihlog}


def read_log(path: Path, imu_id: int | None = None) -> LogData:
    """The log at ``path`` by its suffix (:data:`LOG_READERS`); CalibrationError for an unknown type."""
    reader = LOG_READERS.get(path.suffix.lower())
    if reader is None:
        raise cal.CalibrationError(f"{path}: unknown log type {path.suffix!r}; known: {sorted(LOG_READERS)}")
    return reader(path, imu_id)


def write_csv_log(path: Path, t: Vec, dt: float, columns: dict[str, Vec]) -> None:
    """Write a CSV log with ``t``, ``dt`` and named (N,) or (N, 3) columns (…_x/_y/_z)."""
    names = ["t", "dt"]
    cols = [t, np.full(len(t), dt)]
    for k, v in columns.items():
        v = np.asarray(v)
        if v.ndim == 2:
            names += [f"{k}_{a}" for a in "xyz"]
            cols += [v[:, 0], v[:, 1], v[:, 2]]
        else:
            names.append(k)
            cols.append(v)
    fmt = ["%.6f", "%.6g"] + ["%d" if k in ("step", "flags", "imu_id") else "%.10e" for k in names[2:]]
    np.savetxt(path, np.column_stack(cols), delimiter=",", header=",".join(names), comments="", fmt=fmt)


def read_plan(path: Path) -> Vec:
    """References (K, 3) of a calibration plan CSV with columns step, ref_x, ref_y, ref_z (SI, body FRD),
    ordered by step; CalibrationError names what is wrong."""
    try:
        d = np.genfromtxt(path, delimiter=",", names=True)
    except OSError as e:
        raise cal.CalibrationError(f"--plan {path}: cannot read ({e})") from e
    need = ("step", "ref_x", "ref_y", "ref_z")
    if d.dtype.names is None or any(n not in d.dtype.names for n in need):
        raise cal.CalibrationError(f"--plan {path}: needs columns {list(need)}, has {d.dtype.names}")
    d = np.atleast_1d(d)
    order = np.argsort(d["step"])
    refs = np.column_stack([d["ref_x"][order], d["ref_y"][order], d["ref_z"][order]])
    if not np.all(np.isfinite(refs)) or not np.all(np.isfinite(d["step"])):
        raise cal.CalibrationError(f"--plan {path}: every row needs numeric step, ref_x, ref_y, ref_z")
    if np.any(np.diff(d["step"][order]) == 0):
        raise cal.CalibrationError(f"--plan {path}: a step number appears twice")
    return refs
