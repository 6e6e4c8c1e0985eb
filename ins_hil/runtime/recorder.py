"""Recorder of every input the navigation pipeline consumed, in consumption order (``.ihlog``).

Format 2 (written; little endian). Each part is::

    "IHLOG2\\n"  u32 n  JSON header (n bytes)  u32 CRC-32(n, header)
    frame*  [end frame]

with one frame per record::

    sync A9 1E | type u8 | length u8 | payload (length bytes) | u32 CRC-32 of all before it

The CRC-32 of a frame is seeded with the four bytes before it: the previous frame's CRC, or the
header's for the first frame of a part. So the records are chained: a valid record copied or moved
elsewhere (a splice, a duplicated block) fails at its new place, not only a damaged byte.

The payload is a fixed struct per type: the IMU's below, each aiding sample's in its aid source's module
(:mod:`ins_hil.aids`: ``record`` type byte, ``record_fmt``, ``fields``/``build``; GNSS 2, baro 3,
magnetometer 4, odometer 5, airspeed 6); floats are float64, so every
value (and the order of the calls) is exactly what the online pipeline saw:
:func:`ins_hil.runtime.replay.replay_log` reproduces the fused states bit for
bit. Any damaged byte fails the frame's CRC (or its sync, type or length), so
a reader never returns a silently wrong value; the sync word lets a reader
resynchronise on the next valid frame (``skip_damaged``).

The header is an object holding the run's config, ``format`` (2),
``session`` (the run id), ``part`` (index), ``prev`` (the previous part's file
name, null for part 0) and ``prev_records`` (records in the parts before).
The end frame (``T_END``) closes a part: records in the part, records of the
run so far, and whether a next part follows. So a missing, foreign, cut or
damaged part is detected and reported, never silently skipped.

Format 1 (``IHLOG1``: no CRC, one type byte + struct per record) is still read.

Loss on kill: records go to an in-memory buffer on the IMU path (one
``struct.pack`` and one ``zlib.crc32`` each, no I/O); :meth:`Recorder.flush`
writes it with ``os.write`` and is called every ``flush_period`` (50 ms) by the
loop, so a killed process loses at most the last 50–100 ms (a record cut by
the kill at the end of the last part is ignored). Files rotate when they
would exceed ``max_bytes``: ``run.ihlog``, ``run.1.ihlog``, ``run.2.ihlog``…

Retention: ``max_total_bytes`` / ``max_parts`` bound what one run keeps (its
oldest parts are deleted first, each deletion reported through
``on_message``); ``dir_max_bytes`` (off by default) also deletes the oldest
``.ihlog`` files of other runs in the same directory.
"""

from __future__ import annotations

import json
import math
import os
import re
import struct
import time
import zlib
from collections.abc import Callable, Iterator
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from ins_hil import aids
from ins_hil.types import ImuSample, Sample

MAGIC_V1 = b"IHLOG1\n"
MAGIC = b"IHLOG2\n"
FORMAT = 2
SUFFIX = ".ihlog"
SYNC = b"\xa9\x1e"

T_IMU = 1
T_GNSS = aids.by_name()["gnss"].record
T_BARO = aids.by_name()["baro"].record
T_MAG = aids.by_name()["mag"].record
T_END = 15

# t, dt, dtheta[3], dvel[3], temperature, t_arrival_ns, seq, imu_id, flags
_IMU = struct.Struct("<9dqHBB")
# records in this part, records of the run up to the end of this part, 1 = a next part follows
_END = struct.Struct("<QQB")
#: the aid sources' payloads by record type (their modules' ``record_fmt``)
_AID = {k: (src, struct.Struct("<" + src.record_fmt)) for k, src in aids.by_record().items()}
_SIZES = {T_IMU: _IMU.size, **{k: st.size for k, (_, st) in _AID.items()}}
_SIZES_V2 = {**_SIZES, T_END: _END.size}
_U32 = struct.Struct("<I")
FRAME_OVERHEAD = len(SYNC) + 2 + 4  # sync, type, length, CRC-32 (bytes)
# whole frames without their CRC: sync, type, length, payload
_IMU_F = struct.Struct("<2sBB" + _IMU.format[1:])
_END_F = struct.Struct("<2sBB" + _END.format[1:])
_FRAME_SIZE = {k: v + FRAME_OVERHEAD for k, v in _SIZES_V2.items()}
#: the frame packer of each aiding sample type: (record type, payload size, frame struct, the source's fields)
_PACK = {
    src.sample: (k, st.size, struct.Struct("<2sBB" + st.format[1:]), src.fields)
    for k, (src, st) in _AID.items()
    if src.sample is not None
}

#: a recorded sample (the one sample union, :data:`ins_hil.types.Sample`)
Record = Sample


class RecordError(ValueError):
    """A damaged, cut or incomplete recording; ``str()`` is one line naming file, part and byte offset."""

    def __init__(self, msg: str, path: Path | None = None, part: int | None = None, offset: int | None = None) -> None:
        super().__init__(msg)
        self.path = path
        self.part = part
        self.offset = offset


def frame_size(kind: int) -> int:
    """Bytes of one format-2 frame of record type ``kind``."""
    return _FRAME_SIZE[kind]


def bytes_per_hour(imu_hz: float, gnss_hz: float = 0.0, baro_hz: float = 0.0, mag_hz: float = 0.0) -> float:
    """Recording growth (bytes/h) of a run with these input rates (Hz), from the frame sizes."""
    per_s = imu_hz * _FRAME_SIZE[T_IMU] + gnss_hz * _FRAME_SIZE[T_GNSS]
    per_s += baro_hz * _FRAME_SIZE[T_BARO] + mag_hz * _FRAME_SIZE[T_MAG]
    return 3600.0 * per_s


def encode_record(s: Record, prev: int = 0) -> bytes:
    """One format-2 frame (sync, type, length, payload, CRC-32 seeded with ``prev``, the CRC of the frame
    before it or the header's) for a sample."""
    return _frame(s, prev)[0]


def _frame(s: Record, prev: int) -> tuple[bytes, int]:
    """:func:`encode_record`'s frame and its CRC (the next frame's seed)."""
    if type(s) is ImuSample:  # the hot path first
        a, v = s.dtheta, s.dvel
        f = _IMU_F.pack(
            SYNC,
            T_IMU,
            _IMU.size,
            s.t,
            s.dt,
            float(a[0]),
            float(a[1]),
            float(a[2]),
            float(v[0]),
            float(v[1]),
            float(v[2]),
            s.temperature,
            s.t_arrival_ns,
            s.seq & 0xFFFF,
            s.imu_id & 0xFF,
            s.flags & 0xFF,
        )
    elif (p := _PACK.get(type(s))) is not None:  # an aiding sample: its aid source's record
        kind, size, fs, fields = p
        f = fs.pack(SYNC, kind, size, *fields(s))
    else:
        raise TypeError(f"cannot record {type(s).__name__}")
    c = zlib.crc32(f, prev)
    return f + _U32.pack(c), c


def _end_frame(part_records: int, total_records: int, more: bool, prev: int) -> bytes:
    f = _END_F.pack(SYNC, T_END, _END.size, part_records, total_records, int(more))
    return f + _U32.pack(zlib.crc32(f, prev))


def _rechain(data: bytes, seed: int) -> tuple[bytes, int]:
    """Whole frames re-chained from ``seed`` (their CRCs recomputed: the first part of a rotation's tail now
    follows the new part's header), and the last CRC (``seed`` for no frame)."""
    out = bytearray(data)
    i, n, crc = 0, len(out), seed
    while i < n:
        sz = _FRAME_SIZE[out[i + 2]]
        crc = zlib.crc32(memoryview(out)[i : i + sz - 4], crc)
        _U32.pack_into(out, i + sz - 4, crc)
        i += sz
    return bytes(out), crc


def decode_record(kind: int, body: bytes | memoryview) -> Record:
    """The sample of one record payload (raises ``struct.error``/``ValueError`` on a wrong size or type)."""
    if kind == T_IMU:
        t, dt, a0, a1, a2, v0, v1, v2, temp, arr, seq, iid, flags = _IMU.unpack(body)
        return ImuSample(t, dt, np.array((a0, a1, a2)), np.array((v0, v1, v2)), iid, seq, temp, flags, arr)
    a = _AID.get(kind)
    if a is not None:
        return a[0].build(a[1].unpack(body))
    raise ValueError(f"unknown record type {kind}")


def part_path(base: Path, part: int) -> Path:
    """``run.ihlog`` → part 0 is itself, part k is ``run.k.ihlog``."""
    if part == 0:
        return base
    return base.with_name(f"{base.name[: -len(SUFFIX)]}.{part}{SUFFIX}")


def _head_bytes(header: dict[str, Any]) -> bytes:
    hdr = json.dumps(header, default=str).encode()
    n = _U32.pack(len(hdr))
    return MAGIC + n + hdr + _U32.pack(zlib.crc32(n + hdr))


class Recorder:
    """Append-only ``.ihlog`` writer (format 2) with size rotation, retention and periodic flush.

    ``write(sample)`` is the hot-path call (no I/O). ``flush()`` writes the
    buffer (rotating and applying retention); ``close()`` flushes, writes the
    end frame and closes. ``header`` is stored in every part. Sizes in bytes;
    0 means no limit. ``on_message`` receives one line per deleted part.
    """

    def __init__(
        self,
        path: str | Path,
        header: dict[str, Any] | None = None,
        max_bytes: int = 256 * 1024 * 1024,
        flush_period: float = 0.05,
        max_total_bytes: int = 0,
        max_parts: int = 0,
        dir_max_bytes: int = 0,
        on_message: Callable[[str], None] | None = None,
    ) -> None:
        p = Path(path)
        if p.suffix != SUFFIX:
            p = p.with_name(p.name + SUFFIX)
        p.parent.mkdir(parents=True, exist_ok=True)
        self.base = p
        self.header = dict(header or {})
        self.header.setdefault("session", f"{os.getpid()}-{time.time_ns()}")
        self.max_bytes = int(max_bytes)
        self.max_total_bytes = int(max_total_bytes)
        self.max_parts = int(max_parts)
        self.dir_max_bytes = int(dir_max_bytes)
        self.on_message = on_message
        self.flush_period = flush_period
        self.part = 0
        self.records = 0
        self.bytes_written = 0
        self.flushes = 0
        self._buf = bytearray()
        self._fd = -1
        self._file_bytes = self._head_len = 0
        self._written = 0  # records in the files
        self._part_records = 0
        self._crc = 0  # CRC of the last frame buffered (the next one's seed)
        self._file_crc = 0  # CRC of the last frame (or header) written to the current part
        self.paths: list[Path] = []  # every part written (deleted ones included)
        self.kept: list[Path] = []  # the parts still on disk
        self.deleted: list[Path] = []
        self.messages: list[str] = []
        self._open(0)

    def _open(self, part: int) -> None:
        if self._fd >= 0:
            self._write(_end_frame(self._part_records, self._written, True, self._file_crc))
            os.close(self._fd)
        self.part = part
        path = part_path(self.base, part)
        self._fd = os.open(path, os.O_WRONLY | os.O_CREAT | os.O_TRUNC, 0o644)
        prev = part_path(self.base, part - 1).name if part else None
        head = _head_bytes({**self.header, "format": FORMAT, "part": part, "prev": prev, "prev_records": self._written})
        os.write(self._fd, head)
        self._file_crc = self._crc = _U32.unpack_from(head, len(head) - 4)[0]
        self._file_bytes = self._head_len = len(head)
        self._part_records = 0
        self.paths.append(path)
        self.kept.append(path)
        self._retain()  # at the start too: a directory limit already exceeded by older runs

    def write(self, s: Record) -> None:
        """Buffer one record (hot path: no I/O)."""
        fr, self._crc = _frame(s, self._crc)
        self._buf += fr
        self.records += 1

    def flush(self) -> None:
        """Write the buffer to the file (rotating by size at record boundaries)."""
        if self._fd < 0 or not self._buf:
            return
        data = bytes(self._buf)
        self._buf.clear()
        pending = self.records - self._written
        room = _FRAME_SIZE[T_END]  # every part keeps room for its end frame
        while self._file_bytes + len(data) + room > self.max_bytes:
            # split at a record boundary so no record spans two parts
            cut, nrec = _record_boundary(data, self.max_bytes - self._file_bytes - room)
            if cut == 0 and self._file_bytes == self._head_len:
                break  # part is empty: a record larger than a part goes in whole
            self._write(data[:cut])
            self._part_records += nrec
            self._written += nrec
            pending -= nrec
            self._open(self.part + 1)
            data, self._crc = _rechain(data[cut:], self._file_crc)  # the tail now follows the new header
        if data:
            self._write(data)
        self._part_records += pending
        self._written += pending
        self.flushes += 1

    def _write(self, data: bytes) -> None:
        if len(data) >= 4:
            self._file_crc = _U32.unpack_from(data, len(data) - 4)[0]
        view = memoryview(data)
        while view:
            n = os.write(self._fd, view)
            view = view[n:]
        self._file_bytes += len(data)
        self.bytes_written += len(data)

    def _say(self, msg: str) -> None:
        self.messages.append(msg)
        del self.messages[:-50]
        if self.on_message is not None:
            self.on_message(msg)

    def _retain(self) -> None:
        """Delete the oldest parts of this run (then, if set, other runs' files) beyond the limits."""
        closed = self.kept[:-1]
        sizes = {p: _size(p) for p in closed}
        total = sum(sizes.values()) + self.max_bytes  # the current part may grow to max_bytes
        while closed and (
            (self.max_total_bytes and total > self.max_total_bytes)
            or (self.max_parts and len(closed) + 1 > self.max_parts)
        ):
            p = closed.pop(0)
            self._delete(p, sizes[p], "this run's oldest part", "recorder.total_mb/max_parts")
            total -= sizes[p]
        self.kept = [*closed, self.kept[-1]]
        if not self.dir_max_bytes:
            return
        own = set(self.kept)
        others = [q for q in self.base.parent.glob(f"*{SUFFIX}") if q not in own and q.is_file()]
        others.sort(key=lambda q: (_mtime(q), q.name))
        total += sum(_size(q) for q in others)
        while others and total > self.dir_max_bytes:
            q = others.pop(0)
            n = _size(q)
            self._delete(q, n, "another run's oldest file", "recorder.dir_total_mb")
            total -= n

    def _delete(self, p: Path, size: int, what: str, limit: str) -> None:
        try:
            p.unlink()
        except OSError as e:
            self._say(f"recorder: cannot delete {p} ({e})")
            return
        self.deleted.append(p)
        self._say(f"recorder: deleted {what} {p} ({size / 1048576:.1f} MiB): total kept over {limit}")

    def close(self) -> None:
        """Flush, write the end frame (no next part) and close."""
        if self._fd >= 0:
            self.flush()
            self._write(_end_frame(self._part_records, self._written, False, self._file_crc))
            os.close(self._fd)
            self._fd = -1


def _size(p: Path) -> int:
    try:
        return p.stat().st_size
    except OSError:
        return 0


def _mtime(p: Path) -> float:
    try:
        return p.stat().st_mtime
    except OSError:
        return 0.0


def _frame_prefix(data: bytes, pos: int) -> bool:
    """The bytes from ``pos`` to the end could begin a valid frame (a record cut by a kill)."""
    rest = data[pos : pos + 4]
    if not SYNC.startswith(rest[:2]):
        return False
    if len(rest) > 2 and rest[2] not in _SIZES_V2:
        return False
    return len(rest) < 4 or rest[3] == _SIZES_V2[rest[2]]


def _record_boundary(data: bytes, limit: int) -> tuple[int, int]:
    """Largest offset ≤ limit that ends a whole frame (0 if none), and the frames before it."""
    i = k = 0
    n = len(data)
    while i < n:
        sz = _FRAME_SIZE[data[i + 2]]
        if i + sz > limit:
            break
        i += sz
        k += 1
    return i, k


# -- reading ---------------------------------------------------------------------------------


def read_header(path: str | Path) -> dict[str, Any]:
    """The JSON header of one part (raises :class:`RecordError` if damaged, ``OSError`` if unreadable)."""
    with open(path, "rb") as f:
        data = f.read(4096 * 16)
        while True:  # a header larger than the first read
            try:
                return _read_head(data, Path(path), 0)[0]
            except _Short:
                more = f.read(len(data))
                if not more:
                    raise RecordError(f"{path}: part header cut off ({len(data)} bytes)", Path(path), None, 0) from None
                data += more


class _Short(Exception):
    pass


def _read_head(data: bytes, path: Path, part: int | None) -> tuple[dict[str, Any], int, int]:
    """(header, offset of the first record, format) of a part's bytes."""
    where = f"{path}: part {part}" if part is not None else f"{path}"
    if data.startswith(MAGIC):
        fmt = 2
    elif data.startswith(MAGIC_V1):
        fmt = 1
    else:
        if len(data) < len(MAGIC) and (MAGIC.startswith(data) or MAGIC_V1.startswith(data)):
            raise _Short
        raise RecordError(f"{where}: not an ins_hil log (bad magic at byte 0)", path, part, 0)
    off = len(MAGIC)
    if len(data) < off + 4:
        raise _Short
    (n,) = _U32.unpack_from(data, off)
    end = off + 4 + n + (4 if fmt == 2 else 0)
    if end > len(data):
        raise _Short
    raw = data[off + 4 : off + 4 + n]
    if fmt == 2 and zlib.crc32(data[off : off + 4 + n]) != _U32.unpack_from(data, off + 4 + n)[0]:
        raise RecordError(f"{where}: damaged header (CRC mismatch, bytes 0–{end})", path, part, 0)
    try:
        hdr = json.loads(raw)
    except (UnicodeDecodeError, ValueError) as e:
        why = str(e).splitlines()[0][:60]
        raise RecordError(f"{where}: damaged header (not JSON: {why})", path, part, off + 4) from None
    if not isinstance(hdr, dict):
        raise RecordError(f"{where}: damaged header (JSON {type(hdr).__name__}, not an object)", path, part, off + 4)
    return hdr, end, fmt


def _index(p: Path) -> tuple[Path, int]:
    """(part-0 path, part index) of a part's path."""
    m = re.fullmatch(r"(.*)\.(\d+)" + re.escape(SUFFIX), p.name)
    if m:
        return p.with_name(m.group(1) + SUFFIX), int(m.group(2))
    return p, 0


def _present(base: Path) -> list[int]:
    """Indices of the parts of ``base`` on disk."""
    stem = base.name[: -len(SUFFIX)] if base.name.endswith(SUFFIX) else base.name
    pat = re.compile(re.escape(stem) + r"\.(\d+)" + re.escape(SUFFIX))
    idx = [int(m.group(1)) for q in base.parent.glob(f"{glob_escape(stem)}.*{SUFFIX}") if (m := pat.fullmatch(q.name))]
    if base.exists():
        idx.append(0)
    return sorted(set(i for i in idx if i == 0 or part_path(base, i).name == f"{stem}.{i}{SUFFIX}"))


def glob_escape(s: str) -> str:
    return re.sub(r"([*?\[])", r"[\1]", s)


def parts_of(path: str | Path) -> list[Path]:
    """The log's parts in order: the contiguous run of parts of the same session the file belongs to.

    Starts at the first part on disk (earlier ones may have been deleted by retention) and ends
    before the first missing, foreign or unreadable part (:class:`LogReader` reports which).
    """
    p = Path(path)
    base, _ = _index(p)
    if not p.exists():
        return [p]
    session = read_header(p).get("session")
    present = _present(base) or [0]
    out: list[Path] = []
    for k in range(present[0], present[-1] + 1):
        q = part_path(base, k)
        try:
            if read_header(q).get("session") != session:
                break
        except (OSError, ValueError):
            break
        out.append(q)
    return out or [p]


@dataclass
class ReadStats:
    """What a read used and what it found (counts of records; sensor time in s)."""

    records: int = 0
    t_first: float = math.nan
    t_last: float = math.nan
    parts: list[Path] = field(default_factory=list)
    damaged: int = 0  # damaged stretches skipped (skip_damaged) or 1 for the one that stopped the read
    skipped_bytes: int = 0
    problems: list[str] = field(default_factory=list)  # one line each: damage, missing/foreign parts
    notes: list[str] = field(default_factory=list)  # not damage: a kill's cut tail, parts deleted by retention
    stopped: str = ""  # the problem that ended the read before the end ("" = read to the end)
    closed: bool = False  # the last part read ends with its end frame (recording closed cleanly)

    def prefix(self) -> str:
        """One line: the records used and their sensor time span."""
        if not self.records:
            return "0 records used"
        return f"{self.records} records used, sensor time {self.t_first:.3f}–{self.t_last:.3f} s"


class LogReader:
    """Iterate a recording's records (every part, both formats) checking every frame.

    Strict (default): stops at the first damaged record, cut or missing part; the records
    before it are yielded, ``stats.stopped`` holds the one-line reason and, with
    ``raise_errors``, a :class:`RecordError` is raised after them. With ``skip_damaged`` a
    damaged stretch is skipped (resync on the next valid frame), counted and reported in
    ``stats.problems``; missing or foreign parts are skipped and reported the same way.
    """

    def __init__(
        self, path: str | Path, follow_parts: bool = True, skip_damaged: bool = False, raise_errors: bool = False
    ) -> None:
        self.path = Path(path)
        self.follow_parts = follow_parts
        self.skip_damaged = skip_damaged
        self.raise_errors = raise_errors
        self.stats = ReadStats()

    def message(self) -> str:
        """One line: how the read ended (empty if the whole recording was read without a problem)."""
        s = self.stats
        if s.stopped:
            return f"{s.stopped}; intact prefix: {s.prefix()}"
        if s.problems:
            more = f" (+{len(s.problems) - 1} more)" if len(s.problems) > 1 else ""
            skipped = f"{s.damaged} damaged stretch(es) skipped ({s.skipped_bytes} bytes)"
            return f"{skipped}: {s.problems[0]}{more}; {s.prefix()}"
        return ""

    def _problem(self, msg: str, part: int | None, offset: int | None, fatal: bool = False) -> None:
        s = self.stats
        s.problems.append(msg)
        if fatal or not self.skip_damaged:
            s.stopped = msg
            if self.raise_errors:
                raise RecordError(f"{msg}; intact prefix: {s.prefix()}", self.path, part, offset)

    def __iter__(self) -> Iterator[Record]:
        s = self.stats
        p = self.path
        base, k0 = _index(p)
        data = p.read_bytes()
        try:
            hdr, _, _ = _read_head(data, p, k0)
        except _Short:
            self._problem(f"{p}: part {k0}: cut inside the header ({len(data)} bytes)", k0, 0, fatal=True)
            return
        except RecordError as e:
            self._problem(str(e), k0, e.offset, fatal=True)
            return
        if not self.follow_parts:
            yield from self._part(p, k0, data, last=True)
            return
        session = hdr.get("session")
        present = _present(base) or [k0]
        first = present[0]
        if first > 0:
            gone = f"parts 0–{first - 1} not on disk (deleted by retention or removed)"
            s.notes.append(f"{base}: {gone}; read from part {first}")
        expect_records: int | None = None
        last_index = present[-1]
        for k in range(first, last_index + 1):
            q = part_path(base, k)
            if k not in present:
                self._problem(f"{q}: part {k} missing (parts up to {last_index} exist)", k, None)
                if s.stopped:
                    return
                expect_records = None
                continue
            qdata = data if q == p else q.read_bytes()
            try:
                qh, _, _ = _read_head(qdata, q, k)
            except _Short:
                self._problem(f"{q}: part {k}: cut inside the header ({len(qdata)} bytes)", k, 0)
                if s.stopped:
                    return
                continue
            except RecordError as e:
                self._problem(str(e), k, e.offset)
                if s.stopped:
                    return
                continue
            if qh.get("session") != session:
                self._problem(f"{q}: part {k} belongs to another run (session {qh.get('session')!r})", k, 0)
                if s.stopped:
                    return
                continue
            if "part" in qh and qh.get("part") != k:
                self._problem(f"{q}: part {k}: header says part {qh.get('part')!r}", k, 0)
                if s.stopped:
                    return
                continue
            pr = qh.get("prev_records")
            if expect_records is not None and isinstance(pr, int) and pr != expect_records and not s.problems:
                self._problem(f"{q}: part {k}: {pr} records before it, {expect_records} read", k, 0)
                if s.stopped:
                    return
            yield from self._part(q, k, qdata, last=k == last_index)
            if s.stopped:
                return
            expect_records = self._part_total

    _part_total: int | None = None

    def _part(self, p: Path, k: int, data: bytes, last: bool) -> Iterator[Record]:
        s = self.stats
        s.parts.append(p)
        s.closed = False
        self._part_total = None
        _, off, fmt = _read_head(data, p, k)
        if fmt == 1:
            yield from self._part_v1(p, k, data, off, last)
            return
        n = len(data)
        view = memoryview(data)
        crc32 = zlib.crc32
        u32 = _U32.unpack_from
        sizes = _SIZES_V2
        count = 0
        pos = off
        while pos < n:
            bad = ""
            if data[pos] == 0xA9 and pos + 4 <= n and data[pos + 1] == 0x1E:
                kind = data[pos + 2]
                size = sizes.get(kind)
                if size is not None and data[pos + 3] == size:
                    end = pos + 4 + size
                    if end + 4 > n:
                        bad = "cut"
                    elif crc32(view[pos:end], u32(data, pos - 4)[0]) == u32(data, end)[0]:
                        if kind == T_END:
                            in_part, total, more = _END.unpack_from(data, pos + 4)
                            self._part_total = total
                            s.closed = not more
                            if in_part != count:
                                self._problem(f"{p}: part {k}: end frame says {in_part} records, {count} read", k, pos)
                            if end + 4 < n:
                                extra = f"{n - end - 4} bytes after the end frame at byte {end + 4}"
                                self._problem(f"{p}: part {k}: {extra}", k, end + 4)
                            if more and last:
                                self._problem(f"{p}: part {k}: says a next part follows, none on disk", k, None)
                            return
                        try:
                            rec = decode_record(kind, view[pos + 4 : end])
                        except ValueError as e:  # a CRC-valid frame this version cannot decode
                            self._problem(f"{p}: part {k}: undecodable record at byte {pos} ({e})", k, pos)
                            if s.stopped:
                                return
                            s.damaged += 1
                            s.skipped_bytes += end + 4 - pos
                            pos = end + 4
                            continue
                        if not s.records:
                            s.t_first = rec.t
                        s.t_last = rec.t
                        s.records += 1
                        count += 1
                        yield rec
                        pos = end + 4
                        continue
                    else:
                        bad = "CRC mismatch"
                else:
                    bad = f"bad type {kind} / length {data[pos + 3]}"
            elif pos + 4 > n and _frame_prefix(data, pos):
                bad = "cut"
            else:
                bad = "no sync word"
            if bad == "cut":
                if last:
                    s.notes.append(f"{p}: part {k}: last record cut at byte {pos} ({n - pos} bytes ignored: killed)")
                else:
                    self._problem(f"{p}: part {k}: cut at byte {pos} inside a record (part not closed)", k, pos)
                return
            self._problem(f"{p}: part {k}: damaged record at byte {pos} ({bad})", k, pos)
            if s.stopped:
                return
            nxt = self._resync(data, view, pos + 1)
            s.damaged += 1
            s.skipped_bytes += nxt - pos
            pos = nxt
        if not last:
            self._problem(f"{p}: part {k}: no end frame (part cut at byte {n})", k, n)

    @staticmethod
    def _resync(data: bytes, view: memoryview, start: int) -> int:
        """The offset of the next valid frame at or after ``start`` (``len(data)`` if none)."""
        n = len(data)
        i = data.find(SYNC, start)
        while 0 <= i and i + 4 <= n:
            size = _SIZES_V2.get(data[i + 2])
            if size is not None and data[i + 3] == size:
                end = i + 4 + size
                seed = _U32.unpack_from(data, i - 4)[0] if i >= 4 else 0
                if end + 4 <= n and zlib.crc32(view[i:end], seed) == _U32.unpack_from(data, end)[0]:
                    return i
            i = data.find(SYNC, i + 1)
        return n

    def _part_v1(self, p: Path, k: int, data: bytes, off: int, last: bool) -> Iterator[Record]:
        """Format 1 (no CRC, no sync): a bad type byte stops the part; values cannot be checked."""
        s = self.stats
        n = len(data)
        view = memoryview(data)
        while off < n:
            kind = data[off]
            sz = _SIZES.get(kind)
            if sz is None:
                self._problem(f"{p}: part {k}: corrupt record type {kind} at byte {off} (format 1: no resync)", k, off)
                if not s.stopped:
                    s.damaged += 1
                    s.skipped_bytes += n - off
                return
            if off + 1 + sz > n:
                if last:
                    s.notes.append(f"{p}: part {k}: last record cut at byte {off} (recording killed)")
                else:
                    self._problem(f"{p}: part {k}: cut at byte {off} inside a record", k, off)
                return
            try:
                rec = decode_record(kind, view[off + 1 : off + 1 + sz])
            except ValueError as e:
                self._problem(f"{p}: part {k}: undecodable record at byte {off} ({e}; format 1: no resync)", k, off)
                if not s.stopped:
                    s.damaged += 1
                    s.skipped_bytes += n - off
                return
            if not s.records:
                s.t_first = rec.t
            s.t_last = rec.t
            s.records += 1
            yield rec
            off += 1 + sz
        if last:
            s.closed = True  # format 1 has no end mark


def read_records(path: str | Path, follow_parts: bool = True, skip_damaged: bool = False) -> Iterator[Record]:
    """Every record of a log (all its parts), in order; a record cut by a kill at the very end is ignored.

    Raises :class:`RecordError` (a ``ValueError``, one line: file, part, byte offset, the intact
    prefix) after the records before the first damage, or, with ``skip_damaged``, skips and
    counts damaged stretches (use :class:`LogReader` to see the counts).
    """
    return iter(LogReader(path, follow_parts, skip_damaged, raise_errors=True))
