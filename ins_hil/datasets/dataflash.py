"""ArduPilot DataFlash readers: the binary ``*.bin`` and the text ``*.log`` (Mission Planner's and
MAVExplorer's export: ``FMT, 128, 89, FMT, BBnNZ, …`` lines), each read in one pass by the reader's own parser
(:func:`binary_rows`, :func:`text_rows`: the values pymavlink's ``DFReader`` gives, with its format definitions).

* ``IMU`` (the first IMU: the ``IMU`` name in 3.x logs, the instance ``I`` = 0 in 4.x, as for GPS, BARO and
  MAG): GyrX..Z (rad/s), AccX..Z (m/s²), body FRD, ``TimeUS``; logged samples of the rate, so the
  increments are rate × the IMU's own interval (the ``TimeUS`` difference to the previous sample), stamped
  at the sample;
* ``GPS`` with Status ≥ 3 (3-D): Lat/Lng (deg), Alt (m MSL; + the EGM96 undulation = the WGS84 height),
  Spd/GCrs (ground speed, course deg) and VZ (m/s down) as the NED velocity; σ from ``GPA`` (HAcc, VAcc, SAcc)
  where logged;
* ``BARO`` Alt (m); ``MAG`` MagX..Z (milligauss → tesla); the firmware banner in ``MSG`` as the vehicle type;
* the EKF output ``NKF1`` (EKF2) or ``XKF1`` (EKF3) as the onboard estimate: Roll/Pitch/Yaw (deg), VN/VE/VD,
  PN/PE/PD (m about the EKF origin, which the log does not hold unless ``ORGN`` is there; its Alt is MSL, taken to
  the WGS84 height like the GPS's).

The end of valid data (:func:`end_of_valid_data`): a log that ends in a crash has an impact at the end
(saturated or huge specific force, tumbling rates); the data end before the first such sample.
"""

from __future__ import annotations

import array
import math
import struct
from pathlib import Path
from typing import Any

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
from ins_hil.nav.rotation import quat_from_euler
from ins_hil.types import BaroSample, FixType, GnssFix, ImuSample, MagSample, Vec

DF_HEAD = b"\xa3\x95"
#: the UNIX times (s) a log's GPS date may give: 1980-01-06 to 2100-01-01 (else the date is not used)
UTC_RANGE = (315964800.0, 4102444800.0)
#: how far into a text log (bytes) its first ``FMT`` line is looked for
TEXT_HEAD = 65536
#: a crash: specific force above this (m/s², ≈ 4 g) or a rate above ``CRASH_RATE`` rad/s (≈ 170 °/s, beyond a
#: multicopter's normal envelope)
CRASH_ACCEL = 40.0
CRASH_RATE = 3.0
#: the firmware banner of each vehicle (its first MSG): APM:Copter V3.4.4, ArduCopter V4.5.1, ArduPlane V4.5.1, …
FIRMWARES = ("APM:Copter", "ArduCopter", "APM:Plane", "ArduPlane", "APM:Rover", "ArduRover", "ArduSub", "APM:Sub",
             "Blimp", "AntennaTracker")  # fmt: skip


#: DataFlash format character → (struct code, multiplier, type): pymavlink's ``DFReader.FORMAT_TO_STRUCT``
FORMAT_TO_STRUCT: dict[str, tuple[str, float | None, Any]] = {
    "a": ("64s", None, array.array), "b": ("b", None, int), "B": ("B", None, int), "g": ("e", None, float),
    "h": ("h", None, int), "H": ("H", None, int), "i": ("i", None, int), "I": ("I", None, int), "f": ("f", None, float),
    "n": ("4s", None, str), "N": ("16s", None, str), "Z": ("64s", None, str), "c": ("h", 0.01, float),
    "C": ("H", 0.01, float), "e": ("i", 0.01, float), "E": ("I", 0.01, float), "L": ("i", 1.0e-7, float),
    "d": ("d", None, float), "M": ("b", None, int), "q": ("q", None, int), "Q": ("Q", None, int),
}  # fmt: skip


class DFFormat:
    """One message format (an ``FMT``) as pymavlink's ``DFReader.DFFormat`` defines it, the part the parsers use:
    ``name``, ``len`` (bytes, header included), ``format``, ``columns``, ``colhash`` (column → its last index),
    ``msg_struct``, ``msg_fmts``, ``msg_types``, ``msg_mults``. Kept here so that reading a log does not import
    pymavlink (its ``DFReader`` loads ``mavutil`` and a MAVLink dialect: ~40 ms of every ArduPilot replay);
    ``tests/test_datasets_dataflash_bin.py`` holds it to pymavlink's. ValueError on an unknown format character."""

    def __init__(self, type: int, name: str | bytes, flen: int, format: str, columns: str) -> None:
        self.type = type
        self.name = null_term(name)
        self.len = flen
        self.format = format
        self.columns = [] if columns == "" else columns.split(",")
        st, self.msg_fmts, self.msg_types, self.msg_mults = "<", [], [], []
        for c in format:
            try:
                code, mult, cast = FORMAT_TO_STRUCT[c]
            except KeyError:
                raise ValueError(f"Unsupported format char: {c!r} in message {self.name}") from None
            st += code
            self.msg_fmts.append(c)
            self.msg_mults.append(mult)
            self.msg_types.append(cast)
        self.msg_struct = st
        self.colhash = {c: i for i, c in enumerate(self.columns)}


def null_term(s: str | bytes) -> str:
    """A DataFlash string field up to its first NUL (bytes decoded as UTF-8, undecodable bytes backslash-escaped):
    pymavlink's ``DFReader.null_term``."""
    if isinstance(s, bytes):
        s = s.decode(errors="backslashreplace")
    return s.split("\0", 1)[0]


def _is_dataflash(path: Path) -> bool:
    if not path.is_file():
        return False
    with path.open("rb") as f:
        head = f.read(3)
    return head[:2] == DF_HEAD and head[2:3] == b"\x80"  # the first message is an FMT (id 128)


def first_instance(rows: list[dict[str, Any]]) -> list[dict[str, Any]]:
    """The rows of the first sensor instance: ArduPilot 4.x logs every IMU, GPS, BARO and MAG as one message
    name with an instance field ``I`` (3.x: IMU, IMU2, … as names, no ``I``)."""
    if not rows or "I" not in rows[0]:
        return rows
    inst: list[float] = []
    for d in rows:
        i = d.get("I")
        if not (isinstance(i, int | float) and math.isfinite(i)):
            raise DatasetError(f"a {d.get('mavpackettype', 'sensor')} message with instance I = {i!r} "
                               "(expected an integer)")  # fmt: skip
        inst.append(float(i))
    first = min(inst)
    return [d for d, i in zip(rows, inst, strict=True) if i == first]


#: the fields the reader uses of each message (a log whose FMT defines a message without them is refused)
FIELDS = {
    "IMU": ("TimeUS", "GyrX", "GyrY", "GyrZ", "AccX", "AccY", "AccZ"),
    "GPS": ("TimeUS", "Status", "Lat", "Lng", "Alt", "Spd", "GCrs", "VZ"),
    "GPA": ("TimeUS",),
    "BARO": ("TimeUS", "Alt"),
    "MAG": ("TimeUS", "MagX", "MagY", "MagZ"),
    "NKF1": ("TimeUS", "Roll", "Pitch", "Yaw", "VN", "VE", "VD", "PN", "PE", "PD"),
    "XKF1": ("TimeUS", "Roll", "Pitch", "Yaw", "VN", "VE", "VD", "PN", "PE", "PD"),
    "ORGN": ("Lat", "Lng", "Alt"),
    "MSG": (),
}
#: messages read when the log has them, their fields not required (a row without a number there is not used): the
#: land detector's events (``EV``) and the EKF's solution status (``NKF4``/``XKF4`` ``SS``) for ``t_valid_end``
OPTIONAL_FIELDS = {"EV": ("TimeUS", "Id"), "NKF4": ("TimeUS", "SS"), "XKF4": ("TimeUS", "SS")}
#: ArduPilot's ``LogEvent`` ids (AP_Logger.h): the land detector's "landed" and "in the air"
EV_LAND_COMPLETE, EV_NOT_LANDED = 18, 28
#: the EKF solution status bits (``nav_filter_status``) a valid navigation solution has: attitude, horizontal
#: velocity, vertical velocity, absolute horizontal position (bits 0, 1, 2, 4)
SS_VALID = 0b10111


def all_fields() -> dict[str, tuple[str, ...]]:
    """The messages the reader reads with the fields it needs: its own (:data:`FIELDS`) and the aid sources'
    (:func:`ins_hil.aids.dataflash_messages`)."""
    out = dict(FIELDS)
    for name, cols in aids.dataflash_messages().items():
        out[name] = (*out.get(name, ()), *(c for c in cols if c not in out.get(name, ())))
    return out


def _check_fields(path: Path, rows: dict[str, list[dict[str, Any]]], fields: dict[str, tuple[str, ...]]) -> None:
    """DatasetError naming the message and the missing or non-numeric field (a damaged or redefined FMT)."""
    for name, cols in fields.items():
        for k, d in enumerate(rows[name]):
            for c in cols:
                v = d.get(c)
                if not isinstance(v, int | float):
                    what = "missing" if v is None else f"{v!r}"
                    raise DatasetError(f"{path}: {name} message {k}: field {c} {what} (expected a number; "
                                       f"{name} needs {', '.join(cols)})")  # fmt: skip


def text_rows(path: Path, data: bytes, want: set[str]) -> dict[str, list[dict[str, Any]]]:
    """The messages named in ``want`` of a DataFlash text log (its bytes), as dicts of field → value, in file order.

    Read line by line as pymavlink's ``DFReader_text`` reads one: fields split at ``", "`` (or ``","`` when the
    log's first FMT line is written so), an ``FMT`` line defines a message, a line of an undefined message or with
    fewer fields than its format is skipped; a value is converted with its format's type (``int``, ``float``,
    ``str`` cut at a NUL; ``M`` and ``a`` kept as text; no multiplier: a text log's values are in their units).
    Without pymavlink's whole-log passes (its index and time base) and its Python object per message. A line that
    is not UTF-8, a damaged FMT line, or a value that does not convert is a DatasetError naming the line."""
    delim = ", "
    start = data.find(b"FMT, ")
    if start < 0:
        start, delim = data.find(b"FMT,"), ","
    if start < 0:
        raise DatasetError(f"{path}: no FMT line (expected an ArduPilot DataFlash text log)")
    line0 = data.count(b"\n", 0, start)
    formats: dict[str, Any] = {"FMT": DFFormat(FMT_ID, "FMT", FMT_LEN, "BBnNZ", "Type,Length,Name,Format,Columns")}
    conv: dict[str, list[tuple[str, int, Any]]] = {}
    rows: dict[str, list[dict[str, Any]]] = {k: [] for k in want}
    for n, raw in enumerate(data[start:].split(b"\n"), line0 + 1):
        b = raw.rstrip()
        if not b:
            continue
        try:
            line = b.decode("utf-8")
        except UnicodeDecodeError:
            raise DatasetError(f"{path}:{n}: not UTF-8 text (expected a DataFlash text log line)") from None
        el = line.split(delim)
        if len(el) < 2:
            continue
        if len(el) == 5 and el[-1] == ",":  # an FMT of an empty message, as pymavlink reads it
            el[-1:] = ["", ""]
        fm = formats.get(el[0])
        if fm is None or len(el) < len(fm.format) + 1:
            continue
        name = el[0]
        el = el[1:]
        if name == "FMT":
            if delim == ",":
                el = [*el[0:4], ",".join(el[4:])]
            cols = el[4]
            if el[2] == "FMT" and cols == "Type,Length,Name,Format":  # some logs leave FMT's Columns out
                cols = "Type,Length,Name,Format,Columns"
            try:
                formats[el[2]] = DFFormat(int(el[0]), el[2], int(el[1]), el[3], cols)
            except Exception as e:  # a number that is not one, an unknown format character
                raise DatasetError(f"{path}:{n}: an FMT line that does not parse ({type(e).__name__}: "
                                   f"{' '.join(str(e).split())[:120]})") from None  # fmt: skip
            conv.pop(el[2], None)
            continue
        if name not in want:
            continue
        cv = conv.get(name)
        if cv is None:
            js = [(c, fm.colhash[c]) for c in fm.columns]  # a column named twice: its last value, as pymavlink's
            cv = conv[name] = [(c, j, None if fm.format[j] in "aM" else fm.msg_types[j]) for c, j in js]
        d: dict[str, Any] = {"mavpackettype": name}
        try:
            for c, j, cast in cv:
                v = el[j]
                if cast is not None:
                    v = cast(v)
                    if cast is str:
                        v = v.split("\0", 1)[0]
                d[c] = v
        except (ValueError, IndexError) as e:
            raise DatasetError(f"{path}:{n}: a {name} message that does not parse ({type(e).__name__}: "
                               f"{' '.join(str(e).split())[:120]})") from None  # fmt: skip
        rows[name].append(d)
    return rows


#: parsed FMT definitions by their bytes (every log of a firmware defines the same ones)
_FMT_CACHE: dict[bytes, Any] = {}
#: format characters whose unpacked value is the field's value (no string, no multiplier)
_PLAIN = frozenset("bBhHiIfdgMqQ")
#: per parsed format (by id, the format kept to check it): its plain columns (name, index) and the others
_CONV: dict[int, tuple[Any, list[tuple[str, int]], list[tuple[str, int, str, Any, float | None]]]] = {}
#: DataFlash message id of FMT (the format definitions), its fixed length in bytes (header included)
FMT_ID, FMT_LEN = 0x80, 89


def _df_value(raw: Any, ch: str, cast: Any, mult: float | None) -> Any:
    """One unpacked DataFlash field as pymavlink's DFMessage gives it: strings decoded (UTF-8, else Latin-1)
    and cut at the first NUL, the format's type applied, ``c``/``C``/``e``/``E`` ×0.01 and ``L`` ×1e-7."""
    if isinstance(raw, bytes):
        try:
            raw = raw.decode("utf-8")
        except UnicodeDecodeError:
            raw = raw.decode("ISO-8859-1")
    if ch == "a":
        return raw
    v = cast(raw)
    if isinstance(v, str):
        v = v.split("\0", 1)[0]
    if mult is not None:
        v = v / (1 / mult) if 0.0 < mult < 1.0 else v * mult
    return v


def binary_rows(data: bytes, want: set[str], source: str = "<bytes>") -> dict[str, list[dict[str, Any]]]:
    """The messages named in ``want`` of a DataFlash ``.bin`` (its bytes), as dicts of field → value in
    pymavlink's units (:func:`_df_value`), in file order.

    A sequential read as pymavlink's ``DFReader_binary._parse_next`` does it, without its whole-log passes (the
    time-base search, the index, a Python object per message): a message is ``0xA3 0x95 id`` and the bytes its
    ``FMT`` (id 128, which may be redefined later in the log) gives; bytes that are not the header of a known
    message are skipped one by one; a message whose body does not unpack is skipped after its header; the log
    ends at the first message cut short. Only the messages in ``want`` are unpacked. ``source``: the file, for the
    errors."""
    formats: dict[int, Any] = {FMT_ID: DFFormat(FMT_ID, "FMT", FMT_LEN, "BBnNZ", "Type,Length,Name,Format,Columns")}
    unpack: dict[int, Any] = {}
    # per message id not wanted (nor FMT): its body length (the log ends where one is cut short) and how far to
    # step over it without unpacking it: its length when its body unpacks (its FMT's struct has that size),
    # else 3 (skipped after its header, as when unpacked)
    skip: dict[int, tuple[int, int]] = {}
    rows: dict[str, list[dict[str, Any]]] = {k: [] for k in want}
    end = len(data)
    off = 0
    find = data.find
    while end - off >= 3:
        if data[off] != 0xA3 or data[off + 1] != 0x95 or data[off + 2] not in formats:
            nxt = find(DF_HEAD, off + 1)
            if nxt < 0:
                break
            off = nxt
            continue
        mid = data[off + 2]
        sk = skip.get(mid)
        if sk is not None:
            if end - off - 3 < sk[0]:
                break  # cut short: the end of the log
            off += sk[1]
            continue
        fm = formats[mid]
        body_len = fm.len - 3
        if body_len < 0:  # a damaged FMT's length: pymavlink would step back onto the same message for ever
            off += 3
            continue
        if end - off - 3 < body_len:
            break  # cut short: the end of the log
        body = data[off + 3 : off + 3 + body_len]
        try:
            up = unpack.get(mid)
            if up is None:
                ss = struct.Struct(fm.msg_struct)
                up = unpack[mid] = ss.unpack
                if mid != FMT_ID and fm.name not in want:  # from now on stepped over without unpacking
                    skip[mid] = (body_len, fm.len if ss.size == body_len else 3)
            el = up(body)
        except (struct.error, ValueError):
            off += 3  # as pymavlink: the message is skipped after its header
            continue
        if mid == FMT_ID:
            nf = _FMT_CACHE.get(body)
            if nf is None:
                try:
                    nf = DFFormat(el[0], null_term(el[2]), el[1], null_term(el[3]), null_term(el[4]))
                except Exception:  # an unknown format character: the definition is ignored, as pymavlink does
                    off += 3
                    continue
                if len(_FMT_CACHE) >= 4096:
                    _FMT_CACHE.clear()
                    _CONV.clear()
                _FMT_CACHE[body] = nf
            formats[el[0]] = nf
            unpack.pop(el[0], None)
            skip.pop(el[0], None)
        elif fm.name in want:
            conv = _CONV.get(id(fm))
            if conv is None or conv[0] is not fm:
                cols = fm.columns
                if len(cols) > len(el):
                    raise DatasetError(f"{source}: {fm.name} message at byte {off}: {len(cols)} columns for "
                                       f"{len(el)} values (its FMT is damaged)")  # fmt: skip
                js = [fm.colhash[c] for c in cols]  # a column named twice gives its last value, as pymavlink's
                plain = [(c, j) for c, j in zip(cols, js, strict=True) if fm.msg_fmts[j] in _PLAIN]
                other = [(c, j, fm.msg_fmts[j], fm.msg_types[j], fm.msg_mults[j])
                         for c, j in zip(cols, js, strict=True) if fm.msg_fmts[j] not in _PLAIN]  # fmt: skip
                conv = _CONV[id(fm)] = (fm, plain, other)
            d: dict[str, Any] = {"mavpackettype": fm.name}
            for c, j in conv[1]:
                d[c] = el[j]
            for c, j, ch, cast, mult in conv[2]:
                d[c] = _df_value(el[j], ch, cast, mult)
            rows[fm.name].append(d)
        off += fm.len
    return rows


def _is_dataflash_text(path: Path) -> bool:
    """A text DataFlash log: text (no NUL byte) with a line starting ``FMT,`` near its start."""
    if not path.is_file():
        return False
    with path.open("rb") as f:
        head = f.read(TEXT_HEAD)
    return b"\0" not in head and any(line.lstrip().startswith(b"FMT,") for line in head.splitlines()[:200])


def end_of_valid_data(t: Vec, gyro: Vec, acc: Vec, t_last_gps: float | None) -> tuple[float | None, str]:
    """(t s, why) of the end of valid data: 0.5 s before the first IMU sample with |f| > CRASH_ACCEL or
    |ω| > CRASH_RATE (an impact or a tumble), else None. ``t_last_gps``: the last GNSS sample, reported with it."""
    with np.errstate(over="ignore"):  # a corrupted value near 1e308: its norm is inf, still above the bound
        bad = (np.linalg.norm(acc, axis=1) > CRASH_ACCEL) | (np.linalg.norm(gyro, axis=1) > CRASH_RATE)
    if not np.any(bad):
        return None, ""
    k = int(np.argmax(bad))
    why = (f"loss of control from {t[k]:.2f} s (|f| {_magnitude(acc[k], '.0f', 'm/s²')}, "
           f"|ω| {_magnitude(gyro[k], '.1f', 'rad/s')})"
           + (f"; last GNSS fix {t_last_gps:.2f} s" if t_last_gps is not None else ""))  # fmt: skip
    return float(t[k]) - 0.5, why


def _magnitude(v: Vec, fmt: str, unit: str) -> str:
    """|v| for a message: in ``fmt`` when it is ordinary, else in 3 digits, or "≥ m" (m: the largest component)
    when the norm overflows a double, "not finite" for a non-finite component (a corrupted value must not print as
    "inf")."""
    with np.errstate(over="ignore"):
        n = float(np.linalg.norm(v))
    if math.isfinite(n):
        return f"{format(n, fmt) if n < 1e6 else format(n, '.3g')} {unit}"
    m = float(np.max(np.abs(v)))
    return f"≥ {m:.3g} {unit}" if math.isfinite(m) else "not finite"


def _numbers(rows: list[dict[str, Any]], *cols: str) -> Vec:
    """(N, len(cols)) of the rows whose ``cols`` are all finite numbers (the others left out)."""
    out = [[float(d[c]) for c in cols] for d in rows
           if all(isinstance(d.get(c), int | float) and math.isfinite(d[c]) for c in cols)]  # fmt: skip
    return np.array(out, dtype=np.float64).reshape(-1, len(cols))


def valid_end(rows: dict[str, list[dict[str, Any]]], status: str) -> float | None:
    """The time (s) from which the log says the onboard estimate no longer describes a flight, None if never: the
    land detector's last "landed" (``EV`` LAND_COMPLETE after its last NOT_LANDED), or the start of the EKF's last
    run of solution statuses (``status``: NKF4/XKF4 ``SS``, core 0) without :data:`SS_VALID` after a valid one."""
    ends: list[float] = []
    ev = _numbers(rows.get("EV", []), "TimeUS", "Id")
    air = ev[ev[:, 1] == EV_NOT_LANDED, 0]
    landed = ev[ev[:, 1] == EV_LAND_COMPLETE, 0]
    if len(air) and np.any(landed > air[-1]):
        ends.append(float(landed[landed > air[-1]][0]) * 1e-6)
    ss = _numbers([d for d in rows.get(status, []) if d.get("C", 0) == 0], "TimeUS", "SS")
    if len(ss):
        ok = (ss[:, 1].astype(np.int64) & SS_VALID) == SS_VALID
        if np.any(ok) and not ok[-1]:
            last_ok = int(np.nonzero(ok)[0][-1])
            ends.append(float(ss[last_ok + 1, 0]) * 1e-6)
    return min(ends) if ends else None


def read_dataflash(path: Path) -> Dataset:
    """Read an ArduPilot DataFlash ``.bin``."""
    return _read(path, text=False)


def read_dataflash_text(path: Path) -> Dataset:
    """Read an ArduPilot DataFlash text log (``.log``): the same messages as :func:`read_dataflash`, its values
    already in their units (degrees, not 1e-7 degrees)."""
    return _read(path, text=True)


def _read(path: Path, text: bool) -> Dataset:
    """The dataset of a binary or (``text``) text DataFlash log (:func:`binary_rows`, :func:`text_rows`)."""
    if text:
        ok, fmt = _is_dataflash_text(path), "ardupilot-log"
        what = "an ArduPilot DataFlash text log (expected 'FMT, 128, 89, FMT, …' lines)"
    else:
        ok, fmt = _is_dataflash(path), "ardupilot-bin"
        what = "an ArduPilot DataFlash .bin (expected the 0xA3 0x95 FMT header)"
    if not ok:
        raise DatasetError(f"{path}: not {what}")
    fields = all_fields()
    want = set(fields) | set(OPTIONAL_FIELDS)
    rows = text_rows(path, path.read_bytes(), want) if text else binary_rows(path.read_bytes(), want, str(path))
    if not rows["IMU"]:
        raise DatasetError(f"{path}: no IMU messages in the DataFlash log")
    _check_fields(path, rows, fields)
    try:
        for name in ("IMU", "GPS", "GPA", "BARO", "MAG", *(m for m in aids.dataflash_messages() if m != "BARO")):
            rows[name] = first_instance(rows[name])
    except DatasetError as e:
        raise DatasetError(f"{path}: {e}") from None
    ti = np.array([d["TimeUS"] for d in rows["IMU"]], dtype=np.float64) * 1e-6
    g = np.array([[d["GyrX"], d["GyrY"], d["GyrZ"]] for d in rows["IMU"]], dtype=np.float64)
    a = np.array([[d["AccX"], d["AccY"], d["AccZ"]] for d in rows["IMU"]], dtype=np.float64)
    imu: list[ImuSample] = []
    # the longest increasing run of IMU times: a stamp that jumps back or far ahead costs its sample, and the
    # increments span the interval since the previous kept sample (never a negative or zero one)
    kept = np.nonzero(increasing(np.where(np.isfinite(g).all(axis=1) & np.isfinite(a).all(axis=1), ti, math.nan)))[0]
    for j in range(1, len(kept)):
        k = int(kept[j])
        dt = ti[k] - ti[kept[j - 1]]
        imu.append(ImuSample(float(ti[k]), float(dt), g[k] * dt, a[k] * dt, seq=k))
    gpa = {d["TimeUS"]: d for d in rows["GPA"]}
    gnss: list[GnssFix] = []
    for k, d in enumerate(rows["GPS"]):
        where = f"{path}: GPS message {k} (TimeUS {d['TimeUS']})"
        ft = fix_type_of(d["Status"], where)
        if ft is None or ft < FixType.FIX_3D:
            continue
        c = math.radians(d["GCrs"])
        acc = gpa.get(d["TimeUS"], {})
        lat, lon = math.radians(d["Lat"]), math.radians(d["Lng"])
        gnss.append(GnssFix(
            d["TimeUS"] * 1e-6, lat, lon, ellipsoidal_height(lat, lon, float(d["Alt"])),
            np.array((d["Spd"] * math.cos(c), d["Spd"] * math.sin(c), d["VZ"])),
            std_ne=float(acc.get("HAcc", 2.5)), std_d=float(acc.get("VAcc", 5.0)), std_vel=float(acc.get("SAcc", 0.3)),
            fix_type=ft, num_sats=count_of(d.get("NSats", 0), f"{where}: NSats"),
        ))  # fmt: skip
    baro = [BaroSample(d["TimeUS"] * 1e-6, float(d.get("Press", math.nan)), float(d["Alt"])) for d in rows["BARO"]]
    mag = [MagSample(d["TimeUS"] * 1e-6, np.array((d["MagX"], d["MagY"], d["MagZ"]), dtype=np.float64) * 1e-7)
           for d in rows["MAG"]]  # fmt: skip
    ekf_rows, name = (rows["XKF1"], "XKF1 (EKF3)") if rows["XKF1"] else (rows["NKF1"], "NKF1 (EKF2)")
    onboard = None
    if ekf_rows:
        # EKF3 logs one XKF1 per core (field C): keep the first core
        ekf_rows = [d for d in ekf_rows if d.get("C", 0) == 0]
        te = np.array([d["TimeUS"] for d in ekf_rows], dtype=np.float64) * 1e-6
        q = np.array([quat_from_euler(math.radians(d["Roll"]), math.radians(d["Pitch"]), math.radians(d["Yaw"]))
                      for d in ekf_rows])  # fmt: skip
        v = np.array([[d["VN"], d["VE"], d["VD"]] for d in ekf_rows], dtype=np.float64)
        p = np.array([[d["PN"], d["PE"], d["PD"]] for d in ekf_rows], dtype=np.float64)
        origin = None
        ekf_origin = [o for o in rows["ORGN"] if o.get("Type", 0) == 0]  # Type 1 is the AHRS home (4.x)
        if ekf_origin:
            o = ekf_origin[-1]
            olat, olon = math.radians(o["Lat"]), math.radians(o["Lng"])
            origin = (olat, olon, ellipsoidal_height(olat, olon, float(o["Alt"])))
        onboard = Trajectory(name, te, q, te, v, te, p, origin)
        onboard.t_valid_end = valid_end(rows, "XKF4" if rows["XKF1"] else "NKF4")
    t_end, why = end_of_valid_data(ti, g, a, gnss[-1].t if gnss else None)
    ds = Dataset(imu, gnss, baro, mag, None, onboard, t_end)
    ds.aids, aid_notes = aids.from_dataflash(rows)  # the aid sources' own messages (ins_hil.aids: airspeed, ...)
    if t_end is not None:
        ds.events.append((t_end, "end of valid data"))
        imu_n = sum(1 for s in imu if s.t > t_end)
        ds.meta["end_of_valid_data"] = f"{why}; {imu_n} IMU samples after {t_end:.2f} s not used"
    utc = None
    wk = [d for d in rows["GPS"] if d.get("GWk", 0) > 0]
    if wk:  # GPS time (s since 1980-01-06) → UNIX s (leap seconds ignored: a field-model date)
        utc = 315964800.0 + float(wk[0]["GWk"]) * 604800.0 + float(wk[0].get("GMS", 0.0)) * 1e-3
        utc = utc if math.isfinite(utc) and UTC_RANGE[0] <= utc <= UTC_RANGE[1] else None  # a damaged week
    ds.meta.update({"source": str(path), "format": fmt, "vehicle": "ArduPilot", "notes": aid_notes,
                    "utc_start_s": utc})  # fmt: skip
    fw = next((d["Message"] for d in rows["MSG"] if str(d.get("Message", "")).startswith(FIRMWARES)), None)
    if fw is not None:  # the firmware banner names the vehicle type
        ds.meta["firmware"] = str(fw)
        ds.meta["rotary_wing"] = str(fw).startswith(("APM:Copter", "ArduCopter"))
    return ds


BIN_READER = Reader(
    "ardupilot-bin",
    "an ArduPilot DataFlash .bin",
    _is_dataflash,
    read_dataflash,
    suffixes=(".bin",),
    family="ardupilot",
)
TEXT_READER = Reader(
    "ardupilot-log",
    "an ArduPilot DataFlash text log (.log: 'FMT, 128, 89, FMT, …' lines)",
    _is_dataflash_text,
    read_dataflash_text,
    suffixes=(".log",),
    family="ardupilot",
)
