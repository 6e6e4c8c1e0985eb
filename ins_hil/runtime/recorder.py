"""Recorder of every input the navigation pipeline consumed, in consumption order (``.ihlog``).

File layout (little endian): the magic ``IHLOG1\\n``, a u32 length and a
JSON header (the run's config, core kind, session id, part number), then
records: one type byte and a fixed-size struct per type (below). Floats are
stored as float64, so every value (and the order of the calls) is exactly
what the online pipeline saw: :func:`ins_hil.runtime.replay.replay_log`
reproduces the fused states bit for bit.

Loss on kill: records go to an in-memory buffer on the IMU path (one
``struct.pack`` each, no I/O); :meth:`Recorder.flush` writes it with
``os.write`` and is called every ``flush_period`` (50 ms) by the loop, so a
killed process loses at most the last 50–100 ms (the page cache keeps what
was written). Files rotate when they exceed ``max_bytes``: ``run.ihlog``,
``run.1.ihlog``, ``run.2.ihlog``… each with its own header; a reader follows
the parts.
"""

from __future__ import annotations

import json
import os
import re
import struct
import time
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import numpy as np

from ins_hil.types import BaroSample, FixType, GnssFix, ImuSample, MagSample

MAGIC = b"IHLOG1\n"
SUFFIX = ".ihlog"

T_IMU = 1
T_GNSS = 2
T_BARO = 3
T_MAG = 4

# t, dt, dtheta[3], dvel[3], temperature, t_arrival_ns, seq, imu_id, flags
_IMU = struct.Struct("<9dqHBB")
# t, lat, lon, h, vel[3], std_ne, std_d, std_vel, t_arrival_ns, has_vel, fix_type, num_sats, source
_GNSS = struct.Struct("<10dqBBBB")
# t, pressure, altitude, temperature, t_arrival_ns, source
_BARO = struct.Struct("<4dqB")
# t, field[3], t_arrival_ns, source
_MAG = struct.Struct("<4dqB")
_SIZES = {T_IMU: _IMU.size, T_GNSS: _GNSS.size, T_BARO: _BARO.size, T_MAG: _MAG.size}

Record = ImuSample | GnssFix | BaroSample | MagSample


def encode_record(s: Record) -> bytes:
    """One record (type byte + struct) for a sample."""
    if isinstance(s, ImuSample):
        a, v = s.dtheta, s.dvel
        return bytes((T_IMU,)) + _IMU.pack(
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
    if isinstance(s, GnssFix):
        vel = s.vel_ned if s.vel_ned is not None else (0.0, 0.0, 0.0)
        return bytes((T_GNSS,)) + _GNSS.pack(
            s.t,
            s.lat,
            s.lon,
            s.h,
            float(vel[0]),
            float(vel[1]),
            float(vel[2]),
            s.std_ne,
            s.std_d,
            s.std_vel,
            s.t_arrival_ns,
            s.vel_ned is not None,
            int(s.fix_type),
            s.num_sats & 0xFF,
            s.source & 0xFF,
        )
    if isinstance(s, BaroSample):
        return bytes((T_BARO,)) + _BARO.pack(
            s.t, s.pressure, s.altitude, s.temperature, s.t_arrival_ns, s.source & 0xFF
        )
    if isinstance(s, MagSample):
        f = s.field_b
        return bytes((T_MAG,)) + _MAG.pack(s.t, float(f[0]), float(f[1]), float(f[2]), s.t_arrival_ns, s.source & 0xFF)
    raise TypeError(f"cannot record {type(s).__name__}")


def decode_record(kind: int, body: bytes | memoryview) -> Record:
    if kind == T_IMU:
        t, dt, a0, a1, a2, v0, v1, v2, temp, arr, seq, iid, flags = _IMU.unpack(body)
        return ImuSample(t, dt, np.array((a0, a1, a2)), np.array((v0, v1, v2)), iid, seq, temp, flags, arr)
    if kind == T_GNSS:
        t, lat, lon, h, vn, ve, vd, sne, sd, sv, arr, hv, ft, ns, src = _GNSS.unpack(body)
        return GnssFix(t, lat, lon, h, np.array((vn, ve, vd)) if hv else None, sne, sd, sv, FixType(ft), ns, src, arr)
    if kind == T_BARO:
        t, p, alt, temp, arr, src = _BARO.unpack(body)
        return BaroSample(t, p, alt, temp, src, arr)
    if kind == T_MAG:
        t, f0, f1, f2, arr, src = _MAG.unpack(body)
        return MagSample(t, np.array((f0, f1, f2)), src, arr)
    raise ValueError(f"unknown record type {kind}")


def part_path(base: Path, part: int) -> Path:
    """``run.ihlog`` → part 0 is itself, part k is ``run.k.ihlog``."""
    if part == 0:
        return base
    return base.with_name(f"{base.name[: -len(SUFFIX)]}.{part}{SUFFIX}")


class Recorder:
    """Append-only ``.ihlog`` writer with size rotation and periodic flush.

    ``write(sample)`` is the hot-path call (no I/O). ``flush()`` writes the
    buffer; ``close()`` flushes and closes. ``header`` is stored in every part.
    """

    def __init__(
        self,
        path: str | Path,
        header: dict[str, Any] | None = None,
        max_bytes: int = 256 * 1024 * 1024,
        flush_period: float = 0.05,
    ) -> None:
        p = Path(path)
        if p.suffix != SUFFIX:
            p = p.with_name(p.name + SUFFIX)
        p.parent.mkdir(parents=True, exist_ok=True)
        self.base = p
        self.header = dict(header or {})
        self.header.setdefault("session", f"{os.getpid()}-{time.time_ns()}")
        self.max_bytes = int(max_bytes)
        self.flush_period = flush_period
        self.part = 0
        self.records = 0
        self.bytes_written = 0
        self.flushes = 0
        self._buf = bytearray()
        self._fd = -1
        self._file_bytes = self._head_len = 0
        self.paths: list[Path] = []
        self._open(0)

    def _open(self, part: int) -> None:
        if self._fd >= 0:
            os.close(self._fd)
        self.part = part
        path = part_path(self.base, part)
        self._fd = os.open(path, os.O_WRONLY | os.O_CREAT | os.O_TRUNC, 0o644)
        hdr = json.dumps({**self.header, "part": part}, default=str).encode()
        head = MAGIC + struct.pack("<I", len(hdr)) + hdr
        os.write(self._fd, head)
        self._file_bytes = self._head_len = len(head)
        self.paths.append(path)

    def write(self, s: Record) -> None:
        """Buffer one record (hot path: no I/O)."""
        self._buf += encode_record(s)
        self.records += 1

    def flush(self) -> None:
        """Write the buffer to the file (rotating by size at record boundaries)."""
        if self._fd < 0 or not self._buf:
            return
        data = bytes(self._buf)
        self._buf.clear()
        while self._file_bytes + len(data) > self.max_bytes:
            # split at a record boundary so no record spans two parts
            cut = _record_boundary(data, self.max_bytes - self._file_bytes)
            if cut == 0 and self._file_bytes == self._head_len:
                break  # part is empty: a record larger than a part goes in whole
            self._write(data[:cut])
            self._open(self.part + 1)
            data = data[cut:]
        if data:
            self._write(data)
        self.flushes += 1

    def _write(self, data: bytes) -> None:
        view = memoryview(data)
        while view:
            n = os.write(self._fd, view)
            view = view[n:]
        self._file_bytes += len(data)
        self.bytes_written += len(data)

    def close(self) -> None:
        if self._fd >= 0:
            self.flush()
            os.close(self._fd)
            self._fd = -1


def _record_boundary(data: bytes, limit: int) -> int:
    """Largest offset ≤ limit that ends a whole record (0 if none)."""
    i = 0
    n = len(data)
    while i < n:
        sz = 1 + _SIZES[data[i]]
        if i + sz > limit:
            break
        i += sz
    return i


def read_header(path: str | Path) -> dict[str, Any]:
    with open(path, "rb") as f:
        return _read_head(f.read(4096 * 16), path)[0]


def _read_head(data: bytes, path: str | Path) -> tuple[dict[str, Any], int]:
    if not data.startswith(MAGIC):
        raise ValueError(f"{path}: not an ins_hil log (bad magic)")
    (n,) = struct.unpack_from("<I", data, len(MAGIC))
    off = len(MAGIC) + 4
    return json.loads(data[off : off + n]), off + n


def parts_of(path: str | Path) -> list[Path]:
    """The log's parts in order: the given file and its rotations of the same session."""
    p = Path(path)
    m = re.fullmatch(r"(.*)\.(\d+)" + re.escape(SUFFIX), p.name)
    base = p.with_name(m.group(1) + SUFFIX) if m else p
    if not base.exists():
        base = p
    session = read_header(base).get("session")
    out = [base]
    k = 1
    while True:
        q = part_path(base, k)
        if not q.exists() or read_header(q).get("session") != session:
            break
        out.append(q)
        k += 1
    return out


def read_records(path: str | Path, follow_parts: bool = True) -> Iterator[Record]:
    """Every record of a log (all its parts), in order; a truncated last record is ignored."""
    paths = parts_of(path) if follow_parts else [Path(path)]
    for p in paths:
        data = Path(p).read_bytes()
        _, off = _read_head(data, p)
        n = len(data)
        view = memoryview(data)
        while off < n:
            kind = data[off]
            sz = _SIZES.get(kind)
            if sz is None:
                raise ValueError(f"{p}: corrupt record type {kind} at byte {off}")
            if off + 1 + sz > n:
                break  # cut off by a kill: ignore the partial record
            yield decode_record(kind, view[off + 1 : off + 1 + sz])
            off += 1 + sz
