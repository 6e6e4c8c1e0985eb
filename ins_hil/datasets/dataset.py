"""The ``Dataset`` a reader returns, and the registry of readers (chosen by format or detected from the path).

Everything inside is in the project's conventions: SI units, body FRD, NED, Hamilton scalar-first q_nb
(body → NED), times in s on the log's own clock (the flight controller's time since boot for PX4 and
ArduPilot). IMU samples are increments over the interval stamped at the interval END
(:class:`ins_hil.types.ImuSample`); GNSS fixes are stamped at their time of validity.
"""

from __future__ import annotations

import contextlib
import math
import operator
import os
import struct
from collections.abc import Callable, Iterable, Iterator
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from ins_hil.registry import Registry
from ins_hil.types import BaroSample, FixType, GnssFix, ImuSample, MagSample, Vec


class DatasetError(ValueError):
    """A file or folder that no reader accepts, or a reader that cannot use it (one-line message)."""


#: what a reader's code may raise on damaged input that it did not foresee: :func:`read_dataset` turns it into a
#: DatasetError naming the file and the reader (the readers check what they know of first)
READ_ERRORS = (KeyError, IndexError, ValueError, TypeError, ZeroDivisionError, OverflowError, UnicodeError,
               RecursionError, AttributeError, struct.error, EOFError)  # fmt: skip
#: the largest fix-type number of the flight stacks (PX4 8 = extrapolated): 7 and 8 are read as 6 (RTK fixed)
FIX_TYPE_MAX = 8


def fix_type_of(x: Any, where: str) -> FixType | None:
    """A log's fix-type number as a :class:`FixType`: 0 (MAVLink NO_GPS) and 1 (NO_FIX) are ``None`` (no fix),
    2–6 their FixType, 7–8 RTK fixed; anything else (NaN, ±inf, a fraction, out of 0–8) is a DatasetError naming
    ``where`` (the file and the record)."""
    x = x.item() if isinstance(x, np.generic) else x
    try:
        v = float(x)
    except (TypeError, ValueError):
        v = math.nan
    if not (math.isfinite(v) and v == int(v) and 0 <= v <= FIX_TYPE_MAX):
        raise DatasetError(f"{where}: fix type {x!r}: expected an integer 0 (no GPS) to {FIX_TYPE_MAX}")
    n = int(v)
    return None if n < FixType.FIX_2D else FixType(min(n, FixType.RTK_FIXED))


def increasing(t: Any) -> Vec:
    """A mask (bool, len(t)) of the longest strictly increasing run of the finite times ``t`` (not necessarily
    contiguous): a time that jumps ahead and back (one stamp an hour off) or back and ahead loses that sample only,
    a clock that restarts keeps its longer part. All true for times that already increase. O(n log n)."""
    import bisect

    t = np.asarray(t, dtype=np.float64)
    n = len(t)
    keep = np.zeros(n, dtype=bool)
    if n and bool(np.all(np.diff(t) > 0)) and math.isfinite(float(t[0])) and math.isfinite(float(t[-1])):
        keep[:] = True
        return keep
    tails: list[float] = []  # the smallest last time of an increasing run of each length
    tail_i: list[int] = []
    prev = np.full(n, -1, dtype=np.int64)
    for k in range(n):
        x = float(t[k])
        if not math.isfinite(x):
            continue
        j = bisect.bisect_left(tails, x)
        if j == len(tails):
            tails.append(x)
            tail_i.append(k)
        elif x < tails[j]:
            tails[j], tail_i[j] = x, k
        else:
            continue  # equal to a run's end: that earlier sample stays
        prev[k] = tail_i[j - 1] if j else -1
    k = tail_i[-1] if tail_i else -1
    while k >= 0:
        keep[k] = True
        k = int(prev[k])
    return keep


def count_of(x: Any, where: str, hi: int = 255) -> int:
    """A count field (satellites used): an integer 0–``hi``; DatasetError naming ``where`` otherwise."""
    x = x.item() if isinstance(x, np.generic) else x
    try:
        v = float(x)
    except (TypeError, ValueError):
        v = math.nan
    if not (math.isfinite(v) and v == int(v) and 0 <= v <= hi):
        raise DatasetError(f"{where}: {x!r}: expected an integer 0 to {hi}")
    return int(v)


@dataclass
class Trajectory:
    """A time series of navigation states: a reference trajectory, or a flight controller's own estimate.

    ``t`` (N,) s. Any of the blocks may be None. ``q_nb`` (N, 4) body → NED at the times ``t_att``;
    ``vel_ned`` (N, 3) m/s at ``t_vel``; ``pos_ned`` (N, 3) m about ``origin`` = (lat rad, lon rad, h m)
    at ``t_pos``; ``origin`` None when the estimator's origin is not in the log (positions are then
    compared after removing the mean offset). ``lever_b``: body FRD lever arm (m) from the IMU to the point
    the positions refer to. ``name``: e.g. "EKF2", "NKF1 (EKF2)". ``vel_ned_unaided``: the estimator's
    velocity at ``t_vel`` where it flags its horizontal velocity as unaided (NaN in ``vel_ned`` there, not
    compared; NaN elsewhere), None when it flags none: what :func:`ins_hil.datasets.compare.rotor_drag` checks.
    ``origin_datum``, ``t_valid_end``: below.
    """

    name: str
    t_att: Vec | None = None
    q_nb: Vec | None = None
    t_vel: Vec | None = None
    vel_ned: Vec | None = None
    t_pos: Vec | None = None
    pos_ned: Vec | None = None
    origin: tuple[float, float, float] | None = None
    lever_b: Vec = field(default_factory=lambda: np.zeros(3))
    vel_ned_unaided: Vec | None = None
    #: the datum of ``origin``'s height: "wgs84" (ellipsoidal, ours) or "msl" (the comparison converts it with
    #: the EGM96 undulation, ``ins_hil.geoid.ellipsoidal_height``)
    origin_datum: str = "wgs84"
    #: the time (s) from which the estimator's own status says its solution is invalid (None: valid to the end)
    t_valid_end: float | None = None

    def vel_ned_all(self) -> Vec | None:
        """The estimator's velocity (m/s, NED) at ``t_vel`` with its unaided samples filled in (``vel_ned``
        where it is valid, ``vel_ned_unaided`` where the estimator flags it)."""
        if self.vel_ned is None or self.vel_ned_unaided is None:
            return self.vel_ned
        return np.where(np.isnan(self.vel_ned), self.vel_ned_unaided, self.vel_ned)


@dataclass
class Dataset:
    """One recording, read by a reader of :data:`READERS`.

    imu / gnss / baro / mag: time-ordered samples (see the module docstring); ``aids``: the samples of the
    other aid sources (:mod:`ins_hil.aids`: odometer, airspeed), time-ordered. ``reference``: an
    independent reference trajectory (None for a flight log). ``onboard``: the flight controller's own
    estimate (EKF2, EKF3; None if not logged). ``t_end_valid``: the end of the valid data (s; e.g. the
    last sample before a crash), None = the end of the log. ``events``: (t s, text) flight events
    (take-off, landing, crash). ``meta``: source, format, vehicle, sensor rates (Hz), notes, ``rotary_wing``
    (True / False from the log's vehicle type, absent when the log does not say).
    """

    imu: list[ImuSample]
    gnss: list[GnssFix] = field(default_factory=list)
    baro: list[BaroSample] = field(default_factory=list)
    mag: list[MagSample] = field(default_factory=list)
    reference: Trajectory | None = None
    onboard: Trajectory | None = None
    t_end_valid: float | None = None
    events: list[tuple[float, str]] = field(default_factory=list)
    meta: dict[str, Any] = field(default_factory=dict)
    aids: list[Any] = field(default_factory=list)

    @classmethod
    def of_samples(cls, imu: list[ImuSample], aiding: Iterable[Any], **kw: Any) -> Dataset:
        """A dataset of ``imu`` and the aiding samples ``aiding`` (any order), each list time-ordered: GNSS, baro
        and magnetometer by their ``kind`` into their lists, the other aid sources' samples into ``aids``."""
        lists: dict[str, list[Any]] = {"gnss": [], "baro": [], "mag": []}
        rest: list[Any] = []
        for m in aiding:
            lists.get(m.kind, rest).append(m)
        by_t = operator.attrgetter("t")
        return cls(imu, sorted(lists["gnss"], key=by_t), sorted(lists["baro"], key=by_t),
                   sorted(lists["mag"], key=by_t), aids=sorted(rest, key=by_t), **kw)  # fmt: skip

    @property
    def t0(self) -> float:
        return self.imu[0].t if self.imu else 0.0

    @property
    def t1(self) -> float:
        end = self.imu[-1].t if self.imu else 0.0
        return min(end, self.t_end_valid) if self.t_end_valid is not None else end

    def event(self, name: str) -> float | None:
        """The time (s) of the first event called ``name`` (e.g. "takeoff"), None if none."""
        return next((t for t, e in self.events if e == name), None)

    def rates(self) -> dict[str, float]:
        """Mean sample rate (Hz) of each stream."""

        def rate(ts: list[float]) -> float:
            return (len(ts) - 1) / (ts[-1] - ts[0]) if len(ts) > 1 and ts[-1] > ts[0] else 0.0

        return {k: round(rate([s.t for s in v]), 2) for k, v in
                (("imu", self.imu), ("gnss", self.gnss), ("baro", self.baro), ("mag", self.mag))}  # fmt: skip


@dataclass(frozen=True)
class Reader:
    """A registered reader: ``detect(path) -> bool`` (cheap), ``read(path) -> Dataset`` (``configured``:
    ``read(path, cfg)``, the dataset config's file names and conventions, e.g. the ``[rtklib]`` table);
    ``expects`` describes what it reads (for the error message); ``suffixes``, the file names it is usually
    given (``.ulg``), so that a file so named that it does not take is said to be a damaged one of its kind;
    ``family``, the flight stack whose logs it reads in another form (``.bin`` / ``.log``), so that one dataset
    config serves both."""

    name: str
    expects: str
    detect: Callable[[Path], bool]
    read: Callable[..., Dataset]
    configured: bool = False
    suffixes: tuple[str, ...] = ()
    family: str = ""


#: the readers by name, in the order detection tries them: (module, attribute) imported when first used
#: (:class:`ins_hil.registry.Registry`; a reader module imports this one, never the other way round)
READERS: Registry[Reader] = Registry(
    "dataset format",
    {
        "ardupilot-bin": ("ins_hil.datasets.dataflash", "BIN_READER"),
        "ardupilot-log": ("ins_hil.datasets.dataflash", "TEXT_READER"),
        "csv": ("ins_hil.datasets.generic_csv", "READER"),
        "ihlog": ("ins_hil.datasets.ihlog", "READER"),
        "px4-ulog": ("ins_hil.datasets.px4", "ULOG_READER"),
        "px4-csv": ("ins_hil.datasets.px4", "CSV_READER"),
        "rtklib": ("ins_hil.datasets.rtklib", "READER"),
    },
)


def register(reader: Reader) -> Reader:
    """Add a reader (another package's) after the built-in ones."""
    READERS.register(reader.name, reader)
    return reader


def _load_builtin() -> None:
    """Kept for callers: the registry imports a reader when it is first used."""


def expected() -> str:
    """One line naming the accepted inputs."""
    _load_builtin()
    return "; ".join(f"{r.name}: {r.expects}" for r in READERS.values())


def detect_format(path: Path) -> str:
    """The name of the reader that accepts ``path``; DatasetError naming what is expected otherwise."""
    _load_builtin()
    path = Path(path)
    if not path.exists():
        raise DatasetError(f"{path}: no such file or directory")
    name = _detected(path)
    if name is None:
        raise DatasetError(misnamed(path) or f"{path}: not a supported dataset (expected {expected()})")
    return name


def _detected(path: Path) -> str | None:
    """The first reader that takes ``path`` (which exists), None if none does."""
    for r in READERS.values():
        try:
            if r.detect(path):
                return r.name
        except OSError as e:
            raise DatasetError(f"{path}: cannot read ({e.strerror or e})") from None
    return None


def misnamed(path: Path) -> str | None:
    """Why a file that no reader takes looks like a dataset all the same: its name says one format (a damaged
    ``.ulg``), or it is one file of a folder format (a ulog2csv topic); None otherwise."""
    if not path.is_file():
        return None
    named = [r for r in READERS.values() if path.suffix.lower() in r.suffixes]
    if named:
        return f"{path}: its name says {named[0].name} but its content is not {named[0].expects}"
    folder = next((r for r in READERS.values() if r.detect(path.parent)), None)
    if folder is not None:
        return f"{path}: one file of {folder.expects}: give the folder {path.parent}"
    return None


def reader_for(path: Path, fmt: str | None) -> str | None:
    """The reader of ``path`` under a dataset config that names ``fmt`` (None: detected when read): ``fmt`` when
    it takes the file, else the reader detected from it if that is of ``fmt``'s family (a text ``.log`` with a
    ``.bin``'s config). A log of another format, or a misnamed file (:func:`misnamed`), is a DatasetError;
    anything else stays with ``fmt``, whose reader then says what it expects (it may also take folders it does
    not detect: an RTKLIB folder with the config's own file names)."""
    _load_builtin()
    if fmt is None or not path.exists():
        return fmt
    r = READERS[fmt]
    if r.detect(path):
        return fmt
    other = _detected(path)
    if other is None:
        hint = misnamed(path)
        if hint is not None:
            raise DatasetError(hint)
        return fmt
    if r.family and READERS[other].family == r.family:
        return other
    a = "an" if other[:1] in "aeiou" else "a"  # an ardupilot-bin, a px4-ulog
    raise DatasetError(f"{path}: {a} {other} recording, but the dataset config names format = {fmt!r} "
                       f"(a config for {other}, or one without a format, reads it)")  # fmt: skip


@contextlib.contextmanager
def _quiet() -> Iterator[None]:
    """pyulog and pymavlink print what they skip of a damaged file, a line per byte (Python prints and C writes
    on stdout and stderr): sent to /dev/null while a reader runs, file descriptors 1 and 2 included."""
    import sys

    saved: list[tuple[int, int]] = []
    with open(os.devnull, "w") as null, contextlib.redirect_stdout(null), contextlib.redirect_stderr(null):
        try:
            for fd in (1, 2):
                try:
                    saved.append((fd, os.dup(fd)))
                    os.dup2(null.fileno(), fd)
                except OSError:
                    pass
            yield
        finally:
            for stream in (sys.__stdout__, sys.__stderr__):
                if stream is not None:
                    try:
                        stream.flush()
                    except (OSError, ValueError):
                        pass
            for fd, copy in saved:
                os.dup2(copy, fd)
                os.close(copy)


def _short(e: BaseException) -> str:
    """An exception's text on one short line."""
    t = " ".join(str(e).split())
    return t if len(t) <= 160 else t[:157] + "..."


def read_dataset(path: Path, fmt: str | None = None, cfg: Any = None) -> Dataset:
    """Read ``path`` with the reader ``fmt`` (a name of :data:`READERS`), detected when None; ``cfg`` (a
    :class:`ins_hil.datasets.config.DatasetConfig`) goes to the readers that take one."""
    _load_builtin()
    path = Path(path)
    if fmt is None:
        fmt = detect_format(path)
    elif fmt not in READERS:
        raise DatasetError(f"unknown dataset format {fmt!r} (known: {', '.join(READERS)})")
    elif not path.exists():
        raise DatasetError(f"{path}: no such file or directory")
    r = READERS[fmt]
    try:
        with _quiet():
            ds = r.read(path, cfg) if r.configured else r.read(path)
    except DatasetError:
        raise
    except OSError as e:
        raise DatasetError(f"{path}: cannot read ({e.strerror or e})") from None
    except MemoryError:
        raise DatasetError(f"{path}: too large to read as {r.expects}") from None
    except READ_ERRORS as e:  # a damage the reader did not foresee: still one line naming the file
        raise DatasetError(f"{path}: damaged or not {r.expects} ({type(e).__name__}: {_short(e)})") from None
    if not ds.imu:
        raise DatasetError(f"{path}: no IMU samples ({r.name} expects {r.expects})")
    ds.meta.setdefault("source", str(path))
    ds.meta.setdefault("format", r.name)
    ds.meta["rates_hz"] = ds.rates()
    return ds
