"""Codec for the ins_hil serial IMU frame, version 1 (spec: drivers/SERIAL_FRAME.md).

Pure byte-level code: encode one frame, decode one frame, and a streaming
parser that resynchronises after garbage and counts every reason a byte or
frame was dropped.
"""

from __future__ import annotations

import binascii
import math
import struct
from dataclasses import dataclass, field

import numpy as np
from ins_hil.drivers.clock import SourceClock

from ins_hil.types import ImuSample

SYNC = b"\xa5\x5a"
VERSION = 1
FRAME_LEN = 41
_BODY = struct.Struct("<BBHIH3f3fhB")  # version .. flags (bytes 2..38)
_CRC = struct.Struct("<H")
assert 2 + _BODY.size + _CRC.size == FRAME_LEN
TEMP_INVALID = -32768
#: the decoder's plausibility bounds per interval (beyond is not a physical reading: the frame is dropped as
#: ``range``, before it can touch the clock model); the physical ranges of the gateway are the validation
#: boundary's (ins_hil.validation), which every decoded sample passes before the pipeline uses it
MAX_ABS_DTHETA = 1.0  # rad per interval (≈ 57 °/interval)
MAX_ABS_DVEL = 50.0  # m/s per interval


def crc16_ccitt(data: bytes, init: int = 0xFFFF) -> int:
    """CRC-16/CCITT-FALSE (poly 0x1021, init 0xFFFF)."""
    return binascii.crc_hqx(data, init)


def encode(sample: ImuSample) -> bytes:
    """Encode an ImuSample as one 41-byte frame (times wrap as the spec says)."""
    t_us = round(sample.t * 1e6) & 0xFFFFFFFF
    dt_us = round(sample.dt * 1e6)
    if not 1 <= dt_us <= 0xFFFF:
        raise ValueError(f"dt {sample.dt} s out of range for the frame (1..65535 µs)")
    temp = sample.temperature
    tc = TEMP_INVALID if not math.isfinite(temp) else max(-32767, min(32767, round(temp * 100)))
    body = _BODY.pack(
        VERSION,
        sample.imu_id & 0xFF,
        sample.seq & 0xFFFF,
        t_us,
        dt_us,
        float(sample.dtheta[0]),
        float(sample.dtheta[1]),
        float(sample.dtheta[2]),
        float(sample.dvel[0]),
        float(sample.dvel[1]),
        float(sample.dvel[2]),
        tc,
        sample.flags & 0xFF,
    )
    return SYNC + body + _CRC.pack(crc16_ccitt(body))


class FrameError(ValueError):
    """A frame that fails a check; ``reason`` is a counter key."""

    def __init__(self, reason: str, msg: str = "") -> None:
        super().__init__(msg or reason)
        self.reason = reason


def decode(frame: bytes | memoryview, t_arrival_ns: int = 0) -> ImuSample:
    """Decode one complete frame. Raises FrameError with a reason on any fault: the same checks as
    :meth:`FrameParser.feed` (length, sync, crc, version, nonfinite, range: ``dt_us`` = 0 or an increment
    beyond :data:`MAX_ABS_DTHETA` / :data:`MAX_ABS_DVEL`).

    The returned ``t`` is the wrapped 32-bit µs time in seconds; stream
    receivers unwrap it (see FrameParser).
    """
    if len(frame) != FRAME_LEN:
        raise FrameError("length")
    if bytes(frame[0:2]) != SYNC:
        raise FrameError("sync")
    body = bytes(frame[2:39])
    if crc16_ccitt(body) != _CRC.unpack_from(frame, 39)[0]:
        raise FrameError("crc")
    ver, imu_id, seq, t_us, dt_us, a0, a1, a2, v0, v1, v2, tc, flags = _BODY.unpack(body)
    if ver != VERSION:
        raise FrameError("version")
    if dt_us == 0:
        raise FrameError("range", "dt_us = 0")
    vals = (a0, a1, a2, v0, v1, v2)
    if not all(math.isfinite(x) for x in vals):
        raise FrameError("nonfinite")
    if max(abs(a0), abs(a1), abs(a2)) > MAX_ABS_DTHETA or max(abs(v0), abs(v1), abs(v2)) > MAX_ABS_DVEL:
        raise FrameError("range", f"increment beyond {MAX_ABS_DTHETA} rad / {MAX_ABS_DVEL} m/s per interval")
    return ImuSample(
        t=t_us * 1e-6,
        dt=dt_us * 1e-6,
        dtheta=np.array((a0, a1, a2)),
        dvel=np.array((v0, v1, v2)),
        imu_id=imu_id,
        seq=seq,
        temperature=float("nan") if tc == TEMP_INVALID else tc * 0.01,
        flags=flags,
        t_arrival_ns=t_arrival_ns,
    )


@dataclass
class FrameParser:
    """Streaming parser: ``feed(bytes)`` returns the good samples, in order.

    Sensor time goes through one :class:`~ins_hil.drivers.clock.SourceClock` per imu_id
    (32-bit µs counter, 16-bit sequence): unwrapped, re-anchored after a sensor reboot, a
    forward jump or a stall, never backwards (SERIAL_FRAME.md, "Receiver clock model").
    Counters (in ``counts``): frames (accepted), garbage_bytes, crc, version, nonfinite,
    range, seq_gap (frames that never arrived), duplicate, seq_backwards, time_backwards,
    time_jump, and the clock events clock_wrap, clock_reanchor_reboot, clock_reanchor_jump,
    clock_reanchor_stall. Every CRC-valid frame is accepted or counted once.
    ``reopen()`` after a re-plug keeps the time bases, so the output continues.
    """

    max_abs_dtheta: float = MAX_ABS_DTHETA  # rad per interval: beyond is not physical
    max_abs_dvel: float = MAX_ABS_DVEL  # m/s per interval
    max_time_jump_us: int = 100_000  # sensor-time step beyond (seq step × dt) that counts as a jump
    counts: dict[str, int] = field(default_factory=dict)
    _buf: bytearray = field(default_factory=bytearray)
    clocks: dict[int, SourceClock] = field(default_factory=dict)

    def _count(self, key: str, n: int = 1) -> None:
        self.counts[key] = self.counts.get(key, 0) + n

    def clock(self, iid: int) -> SourceClock:
        """The clock model of one imu_id (created on its first frame)."""
        c = self.clocks.get(iid)
        if c is None:
            tol = self.max_time_jump_us * 1e-6
            c = self.clocks[iid] = SourceClock(32, 1e-6, self.counts, seq_bits=16, jump_tol_s=tol)
        return c

    def reopen(self) -> None:
        """The link was re-opened (re-plug): drop partial bytes, keep every imu_id's time base."""
        self._buf.clear()
        for c in self.clocks.values():
            c.reopen()

    def feed(self, data: bytes, t_arrival_ns: int = 0) -> list[ImuSample]:
        """Bytes in (``t_arrival_ns``: host monotonic arrival, 0 = unknown), accepted samples out."""
        buf = self._buf
        buf += data
        out: list[ImuSample] = []
        i = 0
        n = len(buf)
        mv = memoryview(buf)
        mth, mdv = self.max_abs_dtheta, self.max_abs_dvel
        crc_hqx, unpack_body, isfinite, nan = binascii.crc_hqx, _BODY.unpack_from, math.isfinite, math.nan
        clocks = self.clocks
        counts = self.counts
        while True:
            j = buf.find(SYNC, i)
            if j < 0:
                # keep a trailing 0xA5 that may start a sync word
                # (only an unconsumed byte: the last byte of a frame just decoded may be 0xA5 too)
                keep = 1 if n > i and buf[n - 1] == 0xA5 else 0
                self._count("garbage_bytes", max(0, n - i - keep)) if n - i - keep > 0 else None
                i = n - keep
                break
            if j > i:
                self._count("garbage_bytes", j - i)
            if n - j < FRAME_LEN:
                i = j
                break
            # inline decode (same checks as decode(), no allocation for dropped frames)
            if crc_hqx(mv[j + 2 : j + 39], 0xFFFF) != buf[j + 39] | (buf[j + 40] << 8):
                self._count("crc")
                self._count("garbage_bytes", 1)
                i = j + 1
                continue
            ver, iid, seq, t_us, dt_us, a0, a1, a2, v0, v1, v2, tc, flags = unpack_body(buf, j + 2)
            i = j + FRAME_LEN
            if ver != VERSION:
                self._count("version")
                self._count("garbage_bytes", 1)
                i = j + 1
                continue
            clk = clocks.get(iid)
            if clk is None:
                clk = self.clock(iid)
            if not (isfinite(a0) and isfinite(a1) and isfinite(a2) and isfinite(v0) and isfinite(v1) and isfinite(v2)):
                self._count("nonfinite")
                clk.rejected(seq)
                continue
            if (
                dt_us == 0
                or abs(a0) > mth
                or abs(a1) > mth
                or abs(a2) > mth
                or abs(v0) > mdv
                or abs(v1) > mdv
                or abs(v2) > mdv
            ):
                self._count("range")
                clk.rejected(seq)
                continue
            t = clk.accept(t_us, seq, dt_us, t_arrival_ns)
            if t is not None:
                counts["frames"] = counts.get("frames", 0) + 1
                out.append(
                    ImuSample(
                        t, dt_us * 1e-6, np.array((a0, a1, a2)), np.array((v0, v1, v2)), iid, seq,
                        nan if tc == TEMP_INVALID else tc * 0.01, flags, t_arrival_ns,
                    )
                )  # fmt: skip
        mv.release()
        del buf[:i]
        return out
