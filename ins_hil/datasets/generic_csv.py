"""The generic dataset CSV (one file; layout in ``docs/datasets.md``).

The first line is ``# ins-hil dataset csv 1``; then one record per line, the kind first::

    imu,t,dt,gx,gy,gz,ax,ay,az              mean rate (rad/s), mean specific force (m/s²) in the IMU's axes,
                                            t = END of the interval dt (s)
    gnss,t,lat,lon,h,vn,ve,vd,std_ne,std_d,std_vel,fix_type
                                            deg, deg, m (ellipsoidal); m/s NED (empty = none); σ m, m, m/s;
                                            fix type 3 = 3-D … 6 = RTK fixed (empty = 3;
                                            0, 1 = no fix: the record is skipped)
    baro,t,alt                              barometric altitude (m)
    mag,t,mx,my,mz                          magnetic field in the IMU's axes (µT)
    odo,t,speed,sigma                       wheel odometer: speed along the body x axis (m/s; σ m/s, empty =
                                            the configured ``[core.nav.odometer] std``)
    airspeed,t,tas,sigma                    true airspeed (m/s; σ m/s, empty = ``[core.nav.airspeed] std``)
    ref,t,lat,lon,h,vn,ve,vd,roll,pitch,yaw reference trajectory (deg, deg, m, m/s, deg; empty = none)
    onboard,t,…                             the flight controller's estimate, as ``ref``
    event,t,name                            a flight event: ``takeoff`` or ``landing`` (optional; the outage
                                            protocol's ``relative_to = "takeoff"`` counts from the first take-off)

The IMU and magnetometer columns are in the IMU's axes, like every reader's: they are body FRD when the dataset
config has no ``[mounting] imu_to_body_deg`` rotation (the default), and that rotation takes them to body FRD
when it has one (:meth:`ins_hil.datasets.config.DatasetConfig.mounting_dcm`).

Lines starting with ``#`` and empty lines are skipped; any other line that does not parse is an error
naming its line number.
"""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np

from ins_hil import aids
from ins_hil.datasets.dataset import Dataset, DatasetError, Reader, Trajectory, fix_type_of
from ins_hil.nav import earth
from ins_hil.nav.rotation import quat_from_euler
from ins_hil.types import BaroSample, FixType, GnssFix, ImuSample, MagSample

MAGIC = "# ins-hil dataset csv 1"
FIELDS = {"imu": 8, "gnss": 11, "baro": 1, "mag": 3, "ref": 9, "onboard": 9}
#: the minimum number of fields after ``t`` that must be given
REQUIRED = {"imu": 7, "gnss": 3, "baro": 1, "mag": 3, "ref": 3, "onboard": 3}


def _aid_records() -> dict[str, aids.AidSource]:
    """The aid sources' generic-CSV records by kind (``odo``, ``airspeed``: the aid modules declare them)."""
    return {s.csv_kind: s for s in aids.sources() if s.csv_kind}


def _is_generic(path: Path) -> bool:
    if not path.is_file():
        return False
    with path.open("rb") as f:
        return f.read(len(MAGIC)).decode("ascii", "replace") == MAGIC


def _num(s: str) -> float:
    s = s.strip()
    return float(s) if s else math.nan


def _trajectory(name: str, rows: list[list[float]]) -> Trajectory:
    a = np.array(sorted(rows, key=lambda r: r[0]), dtype=np.float64)
    t = a[:, 0]
    origin = (math.radians(a[0, 1]), math.radians(a[0, 2]), float(a[0, 3]))
    pos = np.array([earth.ned_from_geodetic(math.radians(r[1]), math.radians(r[2]), r[3], *origin) for r in a])
    tr = Trajectory(name, t_pos=t, pos_ned=pos, origin=origin)
    if np.all(np.isfinite(a[:, 4:7])):
        tr.t_vel, tr.vel_ned = t, a[:, 4:7]
    if np.all(np.isfinite(a[:, 7:10])):
        tr.t_att = t
        tr.q_nb = np.array([quat_from_euler(*np.radians(r[7:10])) for r in a])
    return tr


#: the flight events an ``event`` record may name
EVENTS = ("takeoff", "landing")


def _event(path: Path, n: int, vals: list[str], line: str) -> tuple[float, str]:
    """An ``event,t,name`` record: (t s, name); DatasetError naming the line otherwise."""
    name = vals[1].strip() if len(vals) == 2 else ""
    try:
        t = float(vals[0]) if vals else math.nan
    except ValueError:
        t = math.nan
    if not (math.isfinite(t) and name in EVENTS):
        raise DatasetError(f"{path}:{n}: event: expected t (s, finite) and one of {', '.join(EVENTS)}: "
                           f"{line[:80]!r}")  # fmt: skip
    return t, name


def read_generic_csv(path: Path) -> Dataset:
    """Read the generic dataset CSV."""
    if not _is_generic(path):
        raise DatasetError(f"{path}: not an ins-hil dataset CSV (expected the first line {MAGIC!r})")
    by_kind = _aid_records()
    fields = {**FIELDS, **{k: len(a.csv_columns) for k, a in by_kind.items()}}
    required = {**REQUIRED, **{k: a.csv_required for k, a in by_kind.items()}}
    recs: dict[str, list[list[float]]] = {k: [] for k in fields}
    events: list[tuple[float, str]] = []
    with path.open("rb") as f:
        for n, raw in enumerate(f, 1):
            try:
                line = raw.decode("utf-8").strip()
            except UnicodeDecodeError:
                raise DatasetError(f"{path}:{n}: not UTF-8 text (expected a CSV record)") from None
            if not line or line.startswith("#"):
                continue
            kind, *vals = line.split(",")
            if kind == "event":
                events.append(_event(path, n, vals, line))
                continue
            if kind not in fields:
                raise DatasetError(f"{path}:{n}: unknown record kind {kind!r} (expected one of "
                                   f"{', '.join(fields)}, event)")  # fmt: skip
            want = fields[kind] + 1
            try:
                row = [_num(v) for v in vals] + [math.nan] * (want - len(vals))
            except ValueError:
                raise DatasetError(f"{path}:{n}: {kind}: a field is not a number: {line[:80]!r}") from None
            if len(vals) > want or any(math.isnan(x) for x in row[: required[kind] + 1]):
                raise DatasetError(f"{path}:{n}: {kind}: expected t and {fields[kind]} fields "
                                   f"(at least {required[kind]} given): {line[:80]!r}")  # fmt: skip
            if not all(math.isfinite(x) for x in row[: required[kind] + 1]):
                raise DatasetError(f"{path}:{n}: {kind}: t and the first {required[kind]} fields must be finite "
                                   f"numbers: {line[:80]!r}")  # fmt: skip
            recs[kind].append(row)
    imu = []
    for r in sorted(recs["imu"], key=lambda r: r[0]):
        dt = r[1]
        if not dt > 0:
            raise DatasetError(f"{path}: imu record at t={r[0]} s has dt={dt} (expected > 0 s)")
        imu.append(ImuSample(r[0], dt, np.array(r[2:5]) * dt, np.array(r[5:8]) * dt))
    gnss = []
    for r in sorted(recs["gnss"], key=lambda r: r[0]):
        ft = fix_type_of(r[10], f"{path}: gnss record at t={r[0]} s") if not math.isnan(r[10]) else FixType.FIX_3D
        if ft is None:  # 0 (no GPS) or 1 (no fix): not a fix
            continue
        vel = np.array(r[4:7]) if all(math.isfinite(x) for x in r[4:7]) else None

        def sd(x: float, d: float) -> float:
            return x if math.isfinite(x) else d

        gnss.append(GnssFix(r[0], math.radians(r[1]), math.radians(r[2]), r[3], vel, sd(r[7], 2.5), sd(r[8], 5.0),
                            sd(r[9], 0.3), ft))  # fmt: skip
    baro = [BaroSample(r[0], math.nan, r[1]) for r in sorted(recs["baro"], key=lambda r: r[0])]
    mag = [MagSample(r[0], np.array(r[1:4]) * 1e-6) for r in sorted(recs["mag"], key=lambda r: r[0])]
    ds = Dataset(imu, gnss, baro, mag, events=sorted(events))
    ds.aids = sorted((a.from_csv(r) for k, a in by_kind.items() for r in recs[k]), key=lambda x: x.t)
    if recs["ref"]:
        ds.reference = _trajectory("reference", recs["ref"])
    if recs["onboard"]:
        ds.onboard = _trajectory("onboard", recs["onboard"])
    ds.meta = {"source": str(path), "format": "csv", "vehicle": "", "notes": []}
    return ds


def write_generic_csv(path: str | Path, ds: Dataset) -> None:
    """Write ``ds`` (IMU, GNSS, baro, magnetometer, the aid samples with a CSV record, take-off and landing events)
    in the generic layout (the reader's inverse) to ``path`` (a str or a Path)."""
    path = Path(path)
    lines = [MAGIC]
    for s in ds.imu:
        w, f = s.dtheta / s.dt, s.dvel / s.dt
        lines.append(f"imu,{s.t:.6f},{s.dt:.6f}," + ",".join(f"{x:.9g}" for x in (*w, *f)))
    for g in ds.gnss:
        v = ",".join(f"{x:.4f}" for x in g.vel_ned) if g.vel_ned is not None else ",,"
        lines.append(f"gnss,{g.t:.6f},{math.degrees(g.lat):.9f},{math.degrees(g.lon):.9f},{g.h:.4f},{v},"
                     f"{g.std_ne:.3f},{g.std_d:.3f},{g.std_vel:.3f},{int(g.fix_type)}")  # fmt: skip
    for b in ds.baro:
        lines.append(f"baro,{b.t:.6f},{b.altitude:.4f}")
    for m in ds.mag:
        lines.append(f"mag,{m.t:.6f}," + ",".join(f"{x * 1e6:.4f}" for x in m.field_b))
    for a in ds.aids:
        src = aids.source_of(a)
        if src.csv_kind:
            lines.append(src.csv_kind + "," + ",".join("" if math.isnan(x) else f"{x:.9g}" for x in src.to_csv(a)))
    for t, e in ds.events:
        if e in EVENTS:
            lines.append(f"event,{t:.6f},{e}")
    path.write_text("\n".join(lines) + "\n")


READER = Reader("csv", f"an ins-hil dataset CSV starting with {MAGIC!r}", _is_generic, read_generic_csv)
