"""DroneCAN (UAVCAN v0) codec: frames ⇄ transfers ⇄ typed samples, no I/O.

Data types come from the ``dronecan`` package's DSDL definitions
(``dronecan.TYPENAMES``): their field lists are compiled once into
``struct`` layouts (:class:`DsdlLayout`) for every type whose fields are
byte-aligned (RawIMU, MagneticFieldStrength2, StaticPressure, NodeStatus),
because dronecan's own bit-string (un)packer costs ~3 ms per RawIMU; other
types (Fix2, with its 37-bit fields) go through dronecan's generic decoder.
The tests hold both paths against dronecan's encoder/decoder.

Transport (DroneCAN spec "CAN bus transport layer"): 29-bit id
``prio<<24 | dtid<<8 | service<<7 | src_node``; each frame ends with a tail
byte ``SOT<<7 | EOT<<6 | toggle<<5 | transfer_id``; a multi-frame transfer
starts with the transfer CRC (CRC-16/CCITT-FALSE seeded with the type's
signature CRC, little endian), the toggle alternates from 0.

Sample mapping (SI, body FRD as DroneCAN's ahrs types use it):

- ``uavcan.equipment.ahrs.RawIMU`` (1003): ImuSample with ``dtheta`` =
  ``rate_gyro_integral`` (rad), ``dvel`` = ``accelerometer_integral`` (m/s),
  ``dt`` = ``integration_interval`` (s: 1e-5..1 s and within 4× of the node's
  running nominal period, else ``range``), ``t`` = ``timestamp.usec`` through the
  node's clock model (:class:`~ins_hil.drivers.clock.SourceClock`, 56-bit µs:
  node time, re-anchored after a reboot or jump so it never goes back; a sample
  with ``usec = 0``, "unknown", gets host time for that sample only);
  ``imu_id`` = source node id.
- ``uavcan.equipment.gnss.Fix2`` (1063): GnssFix (deg·1e8 → rad, mm → m);
  status NO_FIX / TIME_ONLY is not a fix (``no_fix``, as on the MAVLink path);
  ``t`` = node time mapped onto host monotonic time
  (:class:`~ins_hil.drivers.clock.HostTimeMap`, from the node's RawIMU and Fix2
  stamps), as every aiding time the runtime receives.
- ``uavcan.equipment.ahrs.MagneticFieldStrength2`` (1002) and
  ``MagneticFieldStrength`` (1001): MagSample, gauss → tesla (×1e-4), host time.
- ``uavcan.equipment.air_data.StaticPressure`` (1028): BaroSample (Pa), host time.
- Aid types (e.g. ``uavcan.equipment.air_data.TrueAirspeed``, 1020, for the airspeed aid): the decoders handed
  over by the runtime (:meth:`DroneCanDecoder.set_decoders`, built from the aid registry: this layer never
  imports the aids), by DSDL type name, each called as ``fn(fields, t, arrival_ns)`` with the transfer's
  decoded fields (plus ``source_node``) and the host time; it returns the sample, None, or a reason counted.
  DroneCAN has no standard wheel-speed / odometer message (``uavcan.equipment.*`` as dronecan's DSDL ships
  it), so the odometer aid declares no DroneCAN decoder.
- ``uavcan.protocol.NodeStatus`` (341): an uptime going back is a node restart
  (``clock_node_restart``): its transfer ids and time map start afresh and its
  IMU clock re-anchors on the first sample of the new time base.
"""

from __future__ import annotations

import binascii
import math
import struct
import time
from collections.abc import Callable, Iterable
from dataclasses import dataclass, field
from typing import Any

import dronecan
import numpy as np
from ins_hil.drivers.clock import HostTimeMap, SourceClock

from ins_hil.types import BaroSample, FixType, GnssFix, ImuSample, MagSample, Sample

DTID_RAW_IMU = 1003
DTID_FIX2 = 1063
DTID_MAG = 1001
DTID_MAG2 = 1002
DTID_STATIC_PRESSURE = 1028
DTID_NODE_STATUS = 341

TYPE_NAMES = {
    DTID_RAW_IMU: "uavcan.equipment.ahrs.RawIMU",
    DTID_FIX2: "uavcan.equipment.gnss.Fix2",
    DTID_MAG: "uavcan.equipment.ahrs.MagneticFieldStrength",
    DTID_MAG2: "uavcan.equipment.ahrs.MagneticFieldStrength2",
    DTID_STATIC_PRESSURE: "uavcan.equipment.air_data.StaticPressure",
    DTID_NODE_STATUS: "uavcan.protocol.NodeStatus",
}
GAUSS = 1e-4  # tesla per gauss
MAX_TRANSFER = 256  # bytes: the largest payload we accept (Fix2 with full covariance is ~100)


def dsdl_type(dtid: int) -> Any:
    """The dronecan DSDL compound type of a message data type id."""
    return dronecan.TYPENAMES[TYPE_NAMES[dtid]]


def transfer_crc(dtid: int, payload: bytes) -> int:
    """Transfer CRC of a multi-frame transfer: CRC-16/CCITT-FALSE seeded with the
    type's signature CRC (same value as dronecan.dsdl.common.crc16_from_bytes)."""
    seed = _CRC_SEED.get(dtid)
    if seed is None:
        seed = _CRC_SEED[dtid] = dsdl_type(dtid).base_crc
    return binascii.crc_hqx(payload, seed)


_CRC_SEED: dict[int, int] = {}


# ---------------------------------------------------------------- DSDL → struct layouts
_STRUCT_FOR = {(3, 16): "e", (3, 32): "f", (3, 64): "d", (1, 8): "B", (1, 16): "H", (1, 32): "I", (1, 64): "Q"}
_STRUCT_FOR.update({(2, 8): "b", (2, 16): "h", (2, 32): "i", (2, 64): "q", (0, 8): "B"})


@dataclass
class DsdlLayout:
    """A byte-aligned DSDL message type compiled into one ``struct`` format.

    ``names``: dotted field names in order; ``counts``: elements per field
    (1 = scalar); ``widths``: for integers whose width is not 8/16/32/64 bits
    (e.g. uint56 timestamps) the byte width, else 0. A trailing dynamic array
    of a byte-aligned primitive uses tail-array optimisation (no length
    prefix, as DSDL specifies for the last field of a single-transfer type).
    """

    dtid: int
    fmt: struct.Struct
    names: list[str]
    counts: list[int]
    odd: list[tuple[int, int, bool]]  # (index in the raw tuple, byte width, signed)
    tail: tuple[str, str, int, int] | None  # (name, struct char, element size, max count)

    def unpack(self, payload: bytes | bytearray | memoryview) -> dict[str, Any]:
        """Decode a payload; raises ValueError if it is too short or too long."""
        n = self.fmt.size
        if len(payload) < n:
            raise ValueError("truncated")
        raw = self.fmt.unpack_from(payload, 0)
        if self.odd:
            lst = list(raw)
            for i, _w, signed in self.odd:
                lst[i] = int.from_bytes(lst[i], "little", signed=signed)
            raw = tuple(lst)
        out: dict[str, Any] = {}
        i = 0
        for name, c in zip(self.names, self.counts):
            out[name] = raw[i] if c == 1 else raw[i : i + c]
            i += c
        rest = len(payload) - n
        if self.tail is not None:
            tname, ch, size, mx = self.tail
            k = rest // size
            if k > mx:
                raise ValueError("oversize")
            out[tname] = struct.unpack_from(f"<{k}{ch}", payload, n) if k else ()
        elif rest:
            raise ValueError("oversize")
        return out

    def pack(self, values: dict[str, Any]) -> bytes:
        """Encode field values (dotted names; arrays as sequences)."""
        flat: list[Any] = []
        for name, c in zip(self.names, self.counts):
            v = values.get(name, 0)
            if c == 1:
                flat.append(v)
            else:
                flat.extend(v)
        for i, w, signed in self.odd:
            flat[i] = int(flat[i]).to_bytes(w, "little", signed=signed)
        b = self.fmt.pack(*flat)
        if self.tail is not None:
            tname, ch, _size, mx = self.tail
            tv = list(values.get(tname, ()))[:mx]
            b += struct.pack(f"<{len(tv)}{ch}", *tv)
        return b


def compile_layout(dtid: int) -> DsdlLayout | None:
    """Compile a DSDL message type to a struct layout, or None if it is not byte-aligned."""
    t = dsdl_type(dtid)
    fmt: list[str] = ["<"]
    names: list[str] = []
    counts: list[int] = []
    odd: list[tuple[int, int, bool]] = []
    tail: list[tuple[str, str, int, int]] = []
    raw_i = 0

    def prim(ty: Any) -> tuple[str, int, bool] | None:
        kind, bits = ty.kind, ty.bitlen
        if bits % 8:
            return None
        ch = _STRUCT_FOR.get((kind, bits))
        if ch is not None:
            return ch, 0, False
        if kind in (1, 2):  # odd-width integer, byte multiple
            return f"{bits // 8}s", bits // 8, kind == 2
        return None

    def walk(fields: Iterable[Any], prefix: str, last_level: bool) -> bool:
        nonlocal raw_i
        fl = [f for f in fields if f.type.category != 3 or f.type.bitlen % 8 == 0]
        for k, f in enumerate(fl):
            ty, name = f.type, prefix + f.name
            is_last = last_level and k == len(fl) - 1
            if ty.category == 3:  # void padding, byte multiple
                fmt.append(f"{ty.bitlen // 8}x")
            elif ty.category == 0:
                p = prim(ty)
                if p is None:
                    return False
                fmt.append(p[0])
                if p[1]:
                    odd.append((raw_i, p[1], p[2]))
                names.append(name)
                counts.append(1)
                raw_i += 1
            elif ty.category == 1:
                vt = ty.value_type
                if vt.category != 0:
                    return False
                p = prim(vt)
                if p is None or p[1]:
                    return False
                if ty.mode == 0:  # static
                    fmt.append(f"{ty.max_size}{p[0]}")
                    names.append(name)
                    counts.append(ty.max_size)
                    raw_i += ty.max_size
                elif is_last:  # dynamic, tail-array optimised
                    tail.append((name, p[0], vt.bitlen // 8, ty.max_size))
                else:
                    return False
            elif ty.category == 2:
                if getattr(ty, "union", False):
                    return False
                if not walk(ty.fields, name + ".", is_last):
                    return False
            else:
                return False
        return True

    if getattr(t, "union", False) or not walk(t.fields, "", True):
        return None
    return DsdlLayout(dtid, struct.Struct("".join(fmt)), names, counts, odd, tail[0] if tail else None)


def _value_to_dict(v: Any, prefix: str, out: dict[str, Any]) -> None:
    """Flatten a dronecan CompoundValue into dotted names (arrays → tuples)."""
    for name, fv in dronecan.get_fields(v).items():
        key = prefix + name
        cat = fv._type.category
        if cat == 0:
            out[key] = fv.value
        elif cat == 1:
            out[key] = tuple(x.value if hasattr(x, "value") else x for x in fv)
        elif cat == 2:
            _value_to_dict(fv, key + ".", out)


def dronecan_decode(dtid: int, payload: bytes) -> dict[str, Any]:
    """Decode with dronecan's own (slow, generic) DSDL unpacker; flat dict."""
    obj = dsdl_type(dtid)()
    obj._unpack(dronecan.transport.bits_from_bytes(bytearray(payload)), True)
    out: dict[str, Any] = {}
    _value_to_dict(obj, "", out)
    return out


def dronecan_encode(dtid: int, **fields: Any) -> bytes:
    """Encode a message with dronecan's own DSDL packer (reference encoder)."""
    obj = dsdl_type(dtid)()
    for k, v in fields.items():
        target = obj
        parts = k.split(".")
        for p in parts[:-1]:
            target = getattr(target, p)
        setattr(target, parts[-1], v)
    return bytes(dronecan.transport.Transfer(payload=obj).payload)


LAYOUTS: dict[int, DsdlLayout | None] = {d: compile_layout(d) for d in TYPE_NAMES}


def decode_payload(dtid: int, payload: bytes) -> dict[str, Any]:
    """Fast struct path where the type allows it, else dronecan's decoder."""
    lay = LAYOUTS.get(dtid)
    if lay is not None:
        return lay.unpack(payload)
    return dronecan_decode(dtid, payload)


def encode_payload(dtid: int, values: dict[str, Any]) -> bytes:
    lay = LAYOUTS.get(dtid)
    if lay is not None:
        return lay.pack(values)
    return dronecan_encode(dtid, **values)


# ---------------------------------------------------------------- frames
def message_can_id(dtid: int, source_node: int, priority: int = 16) -> int:
    """29-bit CAN id of a message transfer (non-anonymous)."""
    if not 1 <= source_node <= 127:
        raise ValueError(f"DroneCAN node id must be 1..127, got {source_node}")
    return ((priority & 0x1F) << 24) | ((dtid & 0xFFFF) << 8) | source_node


def split_transfer(dtid: int, payload: bytes, transfer_id: int) -> list[bytes]:
    """Payload → classic-CAN frame data (≤ 8 bytes each) with tail bytes and, for
    multi-frame transfers, the leading transfer CRC."""
    tid = transfer_id & 0x1F
    if len(payload) <= 7:
        return [bytes(payload) + bytes((0xC0 | tid,))]
    crc = transfer_crc(dtid, payload)
    data = bytes((crc & 0xFF, crc >> 8)) + payload
    out = []
    toggle = 0
    for i in range(0, len(data), 7):
        chunk = data[i : i + 7]
        tail = (0x80 if i == 0 else 0) | (0x40 if i + 7 >= len(data) else 0) | toggle | tid
        out.append(chunk + bytes((tail,)))
        toggle ^= 0x20
    return out


@dataclass
class _Partial:
    transfer_id: int
    toggle: int
    data: bytearray
    t0_ns: int


@dataclass
class Reassembler:
    """Multi-frame transfer reassembly with toggle, transfer-id and CRC checks.

    ``push(can_id, data, now_ns)`` returns ``(dtid, source, transfer_id,
    payload)`` when a transfer completes, else None; drop reasons go to
    ``counts`` (empty_frame, toggle, transfer_id, no_start, incomplete,
    truncated, transfer_crc, oversize, transfer_timeout).
    """

    timeout_ns: int = 500_000_000
    counts: dict[str, int] = field(default_factory=dict)
    _open: dict[int, _Partial] = field(default_factory=dict)

    def _count(self, key: str) -> None:
        self.counts[key] = self.counts.get(key, 0) + 1

    def push(self, can_id: int, data: bytes, now_ns: int) -> tuple[int, int, int, bytes] | None:
        n = len(data)
        if n == 0:
            self._count("empty_frame")
            return None
        tail = data[n - 1]
        tid = tail & 0x1F
        sot, eot, tog = tail & 0x80, tail & 0x40, tail & 0x20
        part = self._open.get(can_id)
        if (
            part is not None
            and not sot
            and not eot
            and n == 8
            and tid == part.transfer_id
            and tog == part.toggle
            and now_ns - part.t0_ns <= self.timeout_ns
        ):
            # fast path: a middle frame of an open transfer
            part.data += data[:7]
            part.toggle = tog ^ 0x20
            if len(part.data) > MAX_TRANSFER + 2:
                self._count("oversize")
                del self._open[can_id]
            return None
        dtid = (can_id >> 8) & 0xFFFF
        src = can_id & 0x7F
        if part is not None and now_ns - part.t0_ns > self.timeout_ns:
            self._count("transfer_timeout")
            del self._open[can_id]
            part = None
        if sot:
            if part is not None:
                self._count("incomplete")
                del self._open[can_id]
            if tog:
                self._count("toggle")
                return None
            if eot:
                return dtid, src, tid, bytes(data[: n - 1])
            if n != 8:  # every frame but the last of a multi-frame transfer is full
                self._count("truncated")
                return None
            self._open[can_id] = _Partial(tid, 0x20, bytearray(data[:7]), now_ns)
            return None
        if part is None:
            self._count("no_start")
            return None
        if tid != part.transfer_id:
            self._count("transfer_id")
            del self._open[can_id]
            return None
        if tog != part.toggle:
            self._count("toggle")
            del self._open[can_id]
            return None
        if not eot and n != 8:
            self._count("truncated")
            del self._open[can_id]
            return None
        part.data += data[: n - 1]
        part.toggle ^= 0x20
        if len(part.data) > MAX_TRANSFER + 2:
            self._count("oversize")
            del self._open[can_id]
            return None
        if not eot:
            return None
        del self._open[can_id]
        buf = part.data
        if len(buf) < 3:
            self._count("truncated")
            return None
        payload = bytes(buf[2:])
        if dtid not in TYPE_NAMES:
            return dtid, src, tid, payload  # CRC seed unknown: the caller ignores the type
        if transfer_crc(dtid, payload) != (buf[0] | (buf[1] << 8)):
            self._count("transfer_crc")
            return None
        return dtid, src, tid, payload


# ---------------------------------------------------------------- payload → samples
_FIX_STATUS = {0: FixType.NO_FIX, 1: FixType.NO_FIX, 2: FixType.FIX_2D, 3: FixType.FIX_3D}
_LOG4 = math.log(4.0)
MIN_DT = 1e-5  # s: the shortest RawIMU integration interval taken as physical


#: the shortest transfer period (ns) the lost-transfer count from host time assumes (10 kHz)
MIN_PERIOD_NS = 100_000.0


@dataclass
class DroneCanDecoder:
    """Frames in, samples out, every drop counted (``counts``).

    ``nodes``: accepted source node ids (None = any); frames of other nodes
    count as ``unknown_node``. Per (node, type) the 5-bit transfer id gives
    ``duplicate`` (the same id again within 16 of the source's transfer periods,
    at most ``tid_timeout_s``, and for a RawIMU with a node time that moved by
    less than 16 integration intervals) and ``seq_gap`` (transfers missing; a gap of 32
    or more is counted from the host time elapsed). RawIMU node time goes
    through one clock model per node (``time_backwards``, ``time_jump`` and the
    ``clock_*`` events of :mod:`ins_hil.drivers.clock`). Values: ``nonfinite``,
    ``range``, ``decode`` (payload too short/long for its type), ``no_fix``.
    Frames of types we do not use count as ``ignored`` (not an error).
    Standard-id, remote and error frames count as ``not_dronecan``.
    ``reopen()`` after a bus re-open forgets partial transfers and transfer ids.
    """

    nodes: frozenset[int] | None = None
    max_abs_dtheta: float = 1.0  # rad per interval
    max_abs_dvel: float = 50.0  # m/s per interval
    max_time_jump_s: float = 0.1  # node-time step off (interval) and off the host time elapsed: a jump
    tid_timeout_s: float = 2.0  # the same transfer id after this long is a new transfer (DroneCAN's default)
    counts: dict[str, int] = field(default_factory=dict)
    reasm: Reassembler = field(default_factory=Reassembler)

    def __post_init__(self) -> None:
        self.reasm.counts = self.counts  # one counter dict for frames and transfers

    _last_tid: dict[tuple[int, int], tuple[int, int, int]] = field(default_factory=dict)  # (tid, host ns, node µs)
    _period: dict[tuple[int, int], float] = field(default_factory=dict)  # ns between transfers, running mean
    clocks: dict[int, SourceClock] = field(default_factory=dict)
    _hostmap: dict[int, HostTimeMap] = field(default_factory=dict)
    _nominal: dict[int, float] = field(default_factory=dict)  # RawIMU integration interval per node (s)
    _uptime: dict[int, int] = field(default_factory=dict)
    _seq: dict[int, int] = field(default_factory=dict)

    _aid: dict[int, tuple[Callable[[dict[str, Any], float, int], Any], ...]] = field(default_factory=dict)

    def set_decoders(self, table: dict[Any, Any]) -> None:
        """The aid decoders by DroneCAN message type name (see the module doc); ValueError naming an unknown
        type."""
        aid: dict[int, tuple[Callable[[dict[str, Any], float, int], Any], ...]] = {}
        for name, fns in table.items():
            ty = dronecan.TYPENAMES.get(name)
            dtid = getattr(ty, "default_dtid", None)
            if not isinstance(dtid, int) or dtid in _HANDLERS:
                raise ValueError(f"DroneCAN: an aid decoder names {name!r}, not a free DroneCAN message type")
            if dtid not in TYPE_NAMES:
                TYPE_NAMES[dtid] = str(name)
                LAYOUTS[dtid] = compile_layout(dtid)
            aid[dtid] = tuple(fns)
        self._aid = aid

    def _aid_sample(self, dtid: int, src: int, v: dict[str, Any], now_ns: int) -> Sample | None:
        out = None
        for fn in self._aid[dtid]:
            s = fn({**v, "source_node": src}, now_ns * 1e-9, now_ns)
            if isinstance(s, str):
                self._count(s)
            elif s is not None and out is None:
                out = s
        return out

    def reopen(self) -> None:
        """The bus was re-opened: partial transfers and transfer ids start afresh; the nodes' time
        bases are kept (the output continues) and re-anchor at once if a node restarted meanwhile."""
        self.reasm._open.clear()
        self._last_tid.clear()
        self._period.clear()
        for c in self.clocks.values():
            c.reopen()

    def _clock(self, src: int) -> SourceClock:
        c = self.clocks.get(src)
        if c is None:
            c = self.clocks[src] = SourceClock(56, 1e-6, self.counts, jump_tol_s=self.max_time_jump_s)
        return c

    def _map(self, src: int) -> HostTimeMap:
        m = self._hostmap.get(src)
        if m is None:
            m = self._hostmap[src] = HostTimeMap()
        return m

    def _transfer_id(
        self, key: tuple[int, int], tid: int, now_ns: int, node_us: int = 0, interval_s: float = 0.0
    ) -> bool:
        """Transfer-id check of one complete transfer that decoded; False (counted ``duplicate``) if it repeats
        the last accepted one.

        The same 5-bit id again is a duplicate only if it came within the duplicate window (16 of the
        source's transfer periods, at most ``tid_timeout_s``) *and*, when the transfer carries the node's
        time (RawIMU: ``node_us`` µs with its ``interval_s``), that time moved by less than 16 intervals: a
        re-sent transfer repeats its node time, while after 31 (or 63, ...) lost transfers the node time
        has moved on by 32 (64, ...) intervals. The host time alone cannot tell them apart when the period
        is not learnt yet (the first transfers) or is learnt too long (frames handed over in batches)."""
        last = self._last_tid.get(key)
        if last is not None:
            d = (tid - last[0]) & 0x1F
            el = now_ns - last[1]
            per = self._period.get(key, 0.0)
            if d == 0:
                window = self.tid_timeout_s * 1e9
                if 0 < per and 16 * per < window:
                    window = 16 * per
                moved = node_us and last[2] and 0 < interval_s and abs(node_us - last[2]) >= 16e6 * interval_s
                if el < window and not moved:
                    self._count("duplicate")
                    return False
            k = 0
            if per > 0:  # whole rounds of 32 transfer ids that went by unseen, from the host time
                k = max(0, round((el / max(per, MIN_PERIOD_NS) - d) / 32))
            if d == 0:
                k = max(k, 1)
            if d + 32 * k > 1:
                self._count("seq_gap", d + 32 * k - 1)
            elif el > 0:  # the mean spacing of consecutive transfers; frames handed over in one batch (one
                # host stamp, el = 0) say nothing about it and would pull it towards 0
                self._period[key] = float(el) if per == 0 else per + (el - per) * 0.125
        self._last_tid[key] = (tid, now_ns, node_us)
        return True

    def _count(self, key: str, n: int = 1) -> None:
        self.counts[key] = self.counts.get(key, 0) + n

    def feed(self, can_id: int, data: bytes, extended: bool = True, now_ns: int | None = None) -> Sample | None:
        """One CAN frame; returns a sample when a wanted transfer completes."""
        if now_ns is None:
            now_ns = time.monotonic_ns()
        # fast path: a middle frame of a transfer already open (its SOT passed every filter below)
        part = self.reasm._open.get(can_id)
        if part is not None and extended and len(data) == 8:
            tail = data[7]
            if (
                not tail & 0xC0
                and (tail & 0x1F) == part.transfer_id
                and (tail & 0x20) == part.toggle
                and now_ns - part.t0_ns <= self.reasm.timeout_ns
                and len(part.data) <= MAX_TRANSFER
            ):
                part.data += data[:7]
                part.toggle ^= 0x20
                return None
        if not extended:
            self._count("not_dronecan")
            return None
        if can_id & 0x80:  # service transfers: not ours
            self._count("ignored")
            return None
        dtid = (can_id >> 8) & 0xFFFF
        src = can_id & 0x7F
        if dtid not in _HANDLERS and dtid not in self._aid:
            self._count("ignored")
            return None
        if src == 0:  # anonymous transfers carry no usable source
            self._count("unknown_node")
            return None
        if self.nodes is not None and src not in self.nodes:
            self._count("unknown_node")
            return None
        r = self.reasm.push(can_id, data, now_ns)
        if r is None:
            return None
        dtid, src, tid, payload = r
        try:
            vals = decode_payload(dtid, payload)
        except Exception:
            self._count("decode")
            return None
        # the transfer id is taken only from a transfer that decodes: a damaged frame that happens to read as
        # a single-frame transfer (DroneCAN has no CRC on those) must not make the next real transfer with
        # that id look like its duplicate; a NodeStatus is read even when its id repeats (a restarted node
        # starts again at 0)
        if dtid == DTID_RAW_IMU:
            iv = vals["integration_interval"]
            iv = iv if math.isfinite(iv) else 0.0
            if not self._transfer_id((src, dtid), tid, now_ns, vals["timestamp.usec"], iv):
                return None
        elif dtid != DTID_NODE_STATUS and not self._transfer_id((src, dtid), tid, now_ns):
            return None
        h = _HANDLERS.get(dtid)
        return h(self, src, vals, now_ns) if h is not None else self._aid_sample(dtid, src, vals, now_ns)

    def _imu(self, src: int, v: dict[str, Any], now_ns: int) -> ImuSample | None:
        dt = v["integration_interval"]
        a = v["rate_gyro_integral"]
        w = v["accelerometer_integral"]
        if not (math.isfinite(dt) and math.isfinite(a[0]) and math.isfinite(a[1]) and math.isfinite(a[2])) or not (
            math.isfinite(w[0]) and math.isfinite(w[1]) and math.isfinite(w[2])
        ):
            self._count("nonfinite")
            return None
        mx, mv = self.max_abs_dtheta, self.max_abs_dvel
        if (
            not MIN_DT <= dt <= 1.0
            or abs(a[0]) > mx
            or abs(a[1]) > mx
            or abs(a[2]) > mx
            or abs(w[0]) > mv
            or abs(w[1]) > mv
            or abs(w[2]) > mv
        ):
            self._count("range")
            return None
        # the interval within 4x of the node's nominal period (a running log-mean that follows a real
        # rate change in a few samples, a lone outlier moving it by at most 4^(1/4) = 1.41x)
        nom = self._nominal.get(src)
        if nom is None:
            self._nominal[src] = dt
        elif dt != nom:
            r = math.log(dt / nom)
            self._nominal[src] = nom * math.exp(max(-_LOG4, min(_LOG4, r)) * 0.25)
            if abs(r) > _LOG4:
                self._count("range")
                return None
        usec = v["timestamp.usec"]
        clk = self._clock(src)
        if usec:
            self._map(src).update(usec * 1e-6, now_ns)
            t = clk.accept(usec, 0, max(1, round(dt * 1e6)), now_ns)
            if t is None:
                return None
        else:  # DSDL: 0 = time unknown: host time for this sample only
            t = clk.host_sample(dt, now_ns)
        seq = self._seq.get(src, -1) + 1
        self._seq[src] = seq
        return ImuSample(
            t=t, dt=dt, dtheta=np.array(a, dtype=float), dvel=np.array(w, dtype=float), imu_id=src, seq=seq & 0xFFFF,
            t_arrival_ns=now_ns,
        )  # fmt: skip

    def _fix(self, src: int, v: dict[str, Any], now_ns: int) -> GnssFix | None:
        lat = v["latitude_deg_1e8"] * 1e-8
        lon = v["longitude_deg_1e8"] * 1e-8
        h = v["height_ellipsoid_mm"] * 1e-3
        vel = v["ned_velocity"]
        if not all(math.isfinite(x) for x in vel):
            self._count("nonfinite")
            return None
        if abs(lat) > 90 or abs(lon) > 180 or abs(h) > 1e5 or any(abs(x) > 600 for x in vel):
            self._count("range")
            return None
        cov = [c for c in v.get("covariance", ()) if math.isfinite(c)]
        std_ne, std_d, std_vel = 2.5, 5.0, 0.3
        if len(cov) in (6, 36):  # diagonal or full 6×6 (pos NED m², vel NED (m/s)²)
            diag = cov if len(cov) == 6 else [cov[i * 7] for i in range(6)]
            std_ne = math.sqrt(max(diag[0], diag[1], 0.0)) or std_ne
            std_d = math.sqrt(max(diag[2], 0.0)) or std_d
            std_vel = math.sqrt(max(diag[3], diag[4], diag[5], 0.0)) or std_vel
        status = v["status"]
        if status < 2:  # NO_FIX, TIME_ONLY: not a position (the MAVLink path drops these too)
            self._count("no_fix")
            return None
        ft = _FIX_STATUS.get(status, FixType.NO_FIX)
        if status == 3 and v["mode"] == 1:
            ft = FixType.DGPS
        elif status == 3 and v["mode"] == 2:
            ft = FixType.RTK_FIXED if v["sub_mode"] == 1 else FixType.RTK_FLOAT
        usec = v["timestamp.usec"]
        # node time → host monotonic (the runtime takes every aiding time as host time)
        t = self._map(src).to_host(usec * 1e-6, now_ns) if usec else now_ns * 1e-9
        return GnssFix(
            t=t, lat=math.radians(lat), lon=math.radians(lon), h=h,
            vel_ned=np.array(vel, dtype=float), std_ne=std_ne, std_d=std_d, std_vel=std_vel, fix_type=ft,
            num_sats=v["sats_used"], source=src, t_arrival_ns=now_ns,
        )  # fmt: skip

    def _mag(self, src: int, v: dict[str, Any], now_ns: int) -> MagSample | None:
        m = v["magnetic_field_ga"]
        if not all(math.isfinite(x) for x in m):
            self._count("nonfinite")
            return None
        if any(abs(x) > 20.0 for x in m):  # gauss; Earth's field is < 0.7 G
            self._count("range")
            return None
        return MagSample(t=now_ns * 1e-9, field_b=np.array(m, dtype=float) * GAUSS, source=src, t_arrival_ns=now_ns)

    def _baro(self, src: int, v: dict[str, Any], now_ns: int) -> BaroSample | None:
        p = v["static_pressure"]
        if not math.isfinite(p):
            self._count("nonfinite")
            return None
        if not 100.0 <= p <= 120_000.0:
            self._count("range")
            return None
        return BaroSample(t=now_ns * 1e-9, pressure=p, source=src, t_arrival_ns=now_ns)

    def _status(self, src: int, v: dict[str, Any], now_ns: int) -> None:
        """NodeStatus: an uptime going back is a node restart (nothing is delivered)."""
        up = v["uptime_sec"]
        last = self._uptime.get(src)
        self._uptime[src] = up
        if last is not None and up < last:
            self._count("clock_node_restart")
            c = self.clocks.get(src)
            if c is not None:
                c.hint_reset()
            m = self._hostmap.get(src)
            if m is not None:
                m.reset()
            for key in [k for k in self._last_tid if k[0] == src]:
                del self._last_tid[key]
        return None


_HANDLERS: dict[int, Callable[[DroneCanDecoder, int, dict[str, Any], int], Sample | None]] = {
    DTID_RAW_IMU: DroneCanDecoder._imu,
    DTID_FIX2: DroneCanDecoder._fix,
    DTID_MAG: DroneCanDecoder._mag,
    DTID_MAG2: DroneCanDecoder._mag,
    DTID_STATIC_PRESSURE: DroneCanDecoder._baro,
    DTID_NODE_STATUS: DroneCanDecoder._status,
}


# ---------------------------------------------------------------- encoders (simulator, tests)
def raw_imu_payload(s: ImuSample, rate_latest: bool = True) -> bytes:
    """RawIMU payload of an ImuSample (timestamp = t in µs; latest = mean rates)."""
    dt = s.dt
    return encode_payload(
        DTID_RAW_IMU,
        {
            "timestamp.usec": round(s.t * 1e6) & 0xFFFFFFFFFFFFFF,
            "integration_interval": dt,
            "rate_gyro_latest": [float(x) / dt for x in s.dtheta] if rate_latest else [0.0] * 3,
            "rate_gyro_integral": [float(x) for x in s.dtheta],
            "accelerometer_latest": [float(x) / dt for x in s.dvel] if rate_latest else [0.0] * 3,
            "accelerometer_integral": [float(x) for x in s.dvel],
        },
    )


def fix2_payload(f: GnssFix, usec: int) -> bytes:
    """Fix2 payload of a GnssFix (via dronecan's packer: Fix2 is not byte-aligned)."""
    vel = [0.0, 0.0, 0.0] if f.vel_ned is None else [float(x) for x in f.vel_ned]
    return dronecan_encode(
        DTID_FIX2,
        **{
            "timestamp.usec": usec,
            "latitude_deg_1e8": round(math.degrees(f.lat) * 1e8),
            "longitude_deg_1e8": round(math.degrees(f.lon) * 1e8),
            "height_ellipsoid_mm": round(f.h * 1e3),
            "height_msl_mm": round(f.h * 1e3),
            "ned_velocity": vel,
            "sats_used": f.num_sats,
            "status": 3,
            "covariance": [f.std_ne**2, f.std_ne**2, f.std_d**2] + [f.std_vel**2] * 3,
        },
    )


def mag_payload(field_t: Iterable[float], sensor_id: int = 0) -> bytes:
    return encode_payload(DTID_MAG2, {"sensor_id": sensor_id, "magnetic_field_ga": [x / GAUSS for x in field_t]})


def pressure_payload(p: float, variance: float = 1.0) -> bytes:
    return encode_payload(DTID_STATIC_PRESSURE, {"static_pressure": p, "static_pressure_variance": variance})


def node_status_payload(uptime_s: int, health: int = 0, mode: int = 0, vendor_status: int = 0) -> bytes:
    """uavcan.protocol.NodeStatus: uptime (s), health (0 OK..3 critical), mode (0 operational)."""
    return dronecan_encode(
        DTID_NODE_STATUS,
        uptime_sec=uptime_s & 0xFFFFFFFF,
        health=health,
        mode=mode,
        sub_mode=0,
        vendor_specific_status_code=vendor_status,
    )
