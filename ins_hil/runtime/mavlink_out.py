"""MAVLink 2 output endpoints: to a ground station (as its own vehicle) or to a flight controller.

An endpoint owns one transport (``udp:host:port`` sends to a listener such as
QGroundControl on 14550; ``udpin:host:port`` listens and answers the last
peer; ``tcp:host:port`` connects, with reconnect; ``serial:/dev/ttyX:baud``)
and the loop hands it the newest state with :meth:`MavlinkEndpoint.offer`
(never blocks): every message whose period is due is sent right there (the
transports' writes are non-blocking), the others are coalesced to the newest
state; the endpoint's own task only sends STATUSTEXTs. Messages and rates are
configurable per endpoint. When several messages are due at the same state the
highest-rate one goes first (e.g. ODOMETRY at 50 Hz before ATTITUDE at 10 Hz and
HEARTBEAT at 1 Hz), so the latency-critical stream is not queued behind the slow ones.

Cost on the IMU path: the hot messages (ODOMETRY, ATTITUDE, ATTITUDE_QUATERNION,
GLOBAL_POSITION_INT, LOCAL_POSITION_NED, HEARTBEAT, SYS_STATUS) are computed in scalar
floats (no numpy in the per-message path: the home's ECEF point and NED rotation are
cached when the home is set) and, on an unsigned link, framed by :class:`_Frame`,
a precompiled packer whose bytes are identical to pymavlink's (tested for random
values in ``tests/test_mavlink_out_fast.py``); a signed link uses pymavlink's sender.

role ``gcs``: HEARTBEAT, SYS_STATUS, ATTITUDE, ATTITUDE_QUATERNION,
GLOBAL_POSITION_INT, LOCAL_POSITION_NED, GPS_RAW_INT (pass-through of the
last GNSS fix), VFR_HUD, ESTIMATOR_STATUS, STATUSTEXT (faults, alignment).
role ``fc``: HEARTBEAT, ODOMETRY (external navigation), GPS_INPUT,
HIL_STATE_QUATERNION (PX4 HIL).

Signing (MAVLink 2): with a 32-byte key every outgoing message is signed and
incoming messages on the endpoint are accepted only when correctly signed
(rejections are counted in the metrics as ``rx_unsigned``/``rx_bad_signature``).
"""

from __future__ import annotations

import asyncio
import math
import struct
import time
from collections import deque
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from ins_hil.nav import earth
from ins_hil.nav.rotation import dcm_from_quat, euler_from_quat
from ins_hil.runtime.metrics import RuntimeMetrics
from ins_hil.types import FaultEvent, GnssFix, NavState


def mavlink_module() -> Any:
    """The MAVLink 2 dialect used everywhere (ardupilotmega ⊃ common)."""
    from pymavlink.dialects.v20 import ardupilotmega

    return ardupilotmega


class MavReceiver:
    """Parse MAVLink 2 bytes; with ``key`` (32 bytes) accept only correctly signed messages.

    ``counts``: messages, unsigned, bad_signature, bad_data.
    """

    def __init__(self, key: bytes | None = None, link_id: int = 0) -> None:
        mavlink = mavlink_module()
        self.mav = mavlink.MAVLink(None, srcSystem=0, srcComponent=0)
        self.counts: dict[str, int] = {"messages": 0, "unsigned": 0, "bad_signature": 0, "bad_data": 0}
        if key is not None:
            from ins_hil.sim.devices import signing_timestamp

            s = self.mav.signing
            s.secret_key = key
            s.link_id = link_id
            s.timestamp = signing_timestamp()
            s.allow_unsigned_callback = None  # unsigned → rejected

    def feed(self, data: bytes) -> list[Any]:
        out: list[Any] = []
        mavlink = mavlink_module()
        chunk: bytes = data
        while True:
            s = self.mav.signing
            bad0, rej0 = s.badsig_count, s.reject_count
            try:
                m = self.mav.parse_char(chunk)
            except mavlink.MAVError as e:
                if s.badsig_count > bad0:
                    self.counts["bad_signature"] += 1
                elif s.reject_count > rej0 or "Invalid signature" in str(e):
                    self.counts["unsigned"] += 1
                else:
                    self.counts["bad_data"] += 1
                chunk = b""
                continue
            chunk = b""
            if m is None:
                return out
            if m.get_type() == "BAD_DATA":
                self.counts["bad_data"] += 1
                continue
            self.counts["messages"] += 1
            out.append(m)


GCS_RATES = {
    "HEARTBEAT": 1.0,
    "SYS_STATUS": 1.0,
    "ATTITUDE": 50.0,
    "ATTITUDE_QUATERNION": 50.0,
    "GLOBAL_POSITION_INT": 10.0,
    "LOCAL_POSITION_NED": 10.0,
    "GPS_RAW_INT": 5.0,
    "VFR_HUD": 4.0,
    "ESTIMATOR_STATUS": 2.0,
}
FC_RATES = {"HEARTBEAT": 1.0, "ODOMETRY": 30.0, "GPS_INPUT": 5.0, "HIL_STATE_QUATERNION": 0.0}
ALL_MESSAGES = sorted(set(GCS_RATES) | set(FC_RATES))
SCHEMES = ("udp", "udpin", "tcp", "serial")


def parse_url(url: str) -> tuple[str, str, int]:
    """``udp:host:port`` → (scheme, host, port); ``serial:/dev/ttyUSB0:921600`` → (serial, path, baud)."""
    parts = url.split(":")
    if len(parts) != 3 or parts[0] not in SCHEMES:
        raise ValueError(f"bad endpoint {url!r}: expected one of {', '.join(s + ':HOST:PORT' for s in SCHEMES)}")
    scheme, host, port = parts
    try:
        p = int(port)
    except ValueError:
        raise ValueError(f"bad endpoint {url!r}: port/baud {port!r} is not a number") from None
    if scheme != "serial" and not 0 <= p <= 65535:
        raise ValueError(f"bad endpoint {url!r}: port {p} out of range")
    return scheme, host, p


_HEADER = struct.Struct("<BBBBBB")  # len, incompat_flags, compat_flags, seq, sysid, compid


class _Frame:
    """Precompiled MAVLink 2 framing of one message type for an UNSIGNED link.

    :meth:`frame` takes the field values in wire order (pymavlink's ``ordered_fieldnames``,
    arrays flattened) and returns the same bytes as pymavlink's ``MAVLink.send`` of that
    message: payload packed with the message's own ``struct`` format, trailing zero bytes
    trimmed (MAVLink 2, at least one byte kept), header 0xFD·len·0·0·seq·sysid·compid·msgid(24 bit),
    CRC-16/MCRF4XX over header (without 0xFD) + payload + ``crc_extra``. Signed links must use
    pymavlink (the signature is not produced here).
    """

    __slots__ = ("_crc", "_extra", "_msgid", "_pack")

    def __init__(self, cls: Any) -> None:
        mavlink = mavlink_module()
        self._pack = cls.unpacker.pack
        mid = int(cls.id)
        self._msgid = bytes((mid & 0xFF, (mid >> 8) & 0xFF, mid >> 16))
        self._extra = bytes((int(cls.crc_extra),))
        mc = getattr(mavlink, "mcrf4xx", None)  # fastcrc's CRC-16/MCRF4XX, as pymavlink's x25crc uses
        self._crc = (lambda b: mc(b, 0xFFFF)) if mc is not None else (lambda b: mavlink.x25crc(b).crc)

    def frame(self, mav: Any, *values: Any) -> bytes:
        payload = self._pack(*values).rstrip(b"\x00") or b"\x00"
        body = _HEADER.pack(len(payload), 0, 0, mav.seq, mav.srcSystem, mav.srcComponent) + self._msgid + payload
        crc = self._crc(body + self._extra)
        return b"\xfd" + body + crc.to_bytes(2, "little")


_FRAMES: dict[str, _Frame] = {}


def _frame_of(typ: str) -> _Frame:
    """The cached :class:`_Frame` of a message type name (e.g. ``"ODOMETRY"``)."""
    f = _FRAMES.get(typ)
    if f is None:
        cls = mavlink_module().mavlink_map[getattr(mavlink_module(), "MAVLINK_MSG_ID_" + typ)]
        f = _FRAMES[typ] = _Frame(cls)
    return f


def advance_due(due_ns: int, period_ns: int, now_ns: int) -> int:
    """The next due time of a stream that was due at ``due_ns`` and is sent at ``now_ns``: one period
    after the due time (the rate holds on average, whatever the phase of the states), never in the past
    (a state that comes late does not start a burst of catch-up messages). The first due time is 0: the
    first state goes out at once. (Also the null relay's ODOMETRY schedule, :mod:`ins_hil.soak.relay`.)"""
    return max(due_ns + period_ns, now_ns)


def _floats(a: Any) -> list[float]:
    """Python floats of a small vector (ndarray.tolist is the cheap path)."""
    try:
        return a.tolist()
    except AttributeError:
        return [float(x) for x in a]


@dataclass
class EndpointConfig:
    """One MAVLink output (the ``[[outputs]]`` tables of type mavlink)."""

    name: str = "gcs"
    url: str = "udp:127.0.0.1:14550"
    role: str = "gcs"  # gcs | fc
    sysid: int = 42
    compid: int = 1
    mav_type: str = "QUADROTOR"
    signing_key: str = ""  # 64 hex digits
    rates: dict[str, float] = field(default_factory=dict)

    def effective_rates(self) -> dict[str, float]:
        base = dict(GCS_RATES if self.role == "gcs" else FC_RATES)
        base.update(self.rates)
        return {k: v for k, v in base.items() if v > 0}


class _Transport:
    """Non-blocking byte sink over asyncio; ``write`` never awaits."""

    def __init__(self, url: str, on_data: Any) -> None:
        self.scheme, self.host, self.port = parse_url(url)
        self.on_data = on_data
        self.tr: Any = None
        self.peer: Any = None
        self.errors: dict[str, int] = {}
        self.connected = False
        self.last_error = ""  # why the last open/connect failed (shown once by the gateway)
        self._task: asyncio.Task[None] | None = None

    def _err(self, k: str) -> None:
        self.errors[k] = self.errors.get(k, 0) + 1

    async def open(self) -> None:
        loop = asyncio.get_running_loop()
        outer = self
        if self.scheme in ("udp", "udpin"):

            class _U(asyncio.DatagramProtocol):
                def datagram_received(self, data: bytes, addr: Any) -> None:
                    outer.peer = addr
                    outer.on_data(data)

                def error_received(self, exc: Exception) -> None:
                    outer._err("refused" if isinstance(exc, ConnectionRefusedError) else "send_error")

            if self.scheme == "udp":
                self.tr, _ = await loop.create_datagram_endpoint(_U, remote_addr=(self.host, self.port))
                self.connected = True
            else:
                self.tr, _ = await loop.create_datagram_endpoint(_U, local_addr=(self.host, self.port))
                self.port = self.tr.get_extra_info("sockname")[1]
        else:
            self._task = asyncio.create_task(self._stream_loop())

    async def _stream_loop(self) -> None:
        loop = asyncio.get_running_loop()
        outer = self
        backoff = 0.2

        class _S(asyncio.Protocol):
            def __init__(self) -> None:
                self.lost: asyncio.Future[None] = loop.create_future()

            def data_received(self, data: bytes) -> None:
                outer.on_data(data)

            def connection_lost(self, exc: Exception | None) -> None:
                if not self.lost.done():
                    self.lost.set_result(None)

        while True:
            tr: Any
            proto: Any
            try:
                if self.scheme == "tcp":
                    tr, proto = await loop.create_connection(_S, self.host, self.port)
                else:
                    import serial_asyncio_fast

                    tr, proto = await serial_asyncio_fast.create_serial_connection(
                        loop, _S, self.host, baudrate=self.port
                    )
            except (OSError, ValueError) as e:
                self._err("connect_failed")
                self.last_error = f"open {self.host}: {e}" if self.scheme == "serial" else f"connect: {e}"
                await asyncio.sleep(backoff)
                backoff = min(5.0, backoff * 2)
                continue
            self.tr, self.connected, backoff = tr, True, 0.2
            await proto.lost
            self.connected = False
            self.tr = None
            self._err("disconnected")

    def write(self, data: bytes) -> bool:
        tr = self.tr
        if tr is None:
            return False
        if self.scheme == "udp":
            tr.sendto(data)
        elif self.scheme == "udpin":
            if self.peer is None:
                return False
            tr.sendto(data, self.peer)
        else:
            if tr.get_write_buffer_size() > 65536:  # slow link: drop rather than buffer without bound
                self._err("backpressure")
                return False
            tr.write(data)
        return True

    def close(self) -> None:
        if self._task is not None:
            self._task.cancel()
        if self.tr is not None:
            self.tr.close()
            self.tr = None


class MavlinkEndpoint:
    """One MAVLink output endpoint (see the module docstring)."""

    def __init__(self, cfg: EndpointConfig, metrics: RuntimeMetrics) -> None:
        mavlink = mavlink_module()
        self.cfg = cfg
        self.name = cfg.name
        self.metrics = metrics
        self.rates = cfg.effective_rates()
        self.period_ns = {k: round(1e9 / v) for k, v in self.rates.items()}
        # highest rate first (stable for equal rates): the first message of a state is the fastest stream
        order = sorted(self.rates, key=lambda k: -self.rates[k])
        self.next_ns = dict.fromkeys(order, 0)
        key = bytes.fromhex(cfg.signing_key) if cfg.signing_key else None
        self.rx = MavReceiver(key)
        self.rx_messages: dict[str, int] = {}
        self.tr = _Transport(cfg.url, self._on_data)
        self.mav = mavlink.MAVLink(self, srcSystem=cfg.sysid, srcComponent=cfg.compid)
        if key is not None:
            from ins_hil.sim.devices import signing_timestamp

            self.mav.signing.secret_key = key
            self.mav.signing.link_id = 0
            self.mav.signing.timestamp = signing_timestamp()
            self.mav.signing.sign_outgoing = True
        self.mav_type = getattr(mavlink, "MAV_TYPE_" + cfg.mav_type)
        self._m = mavlink
        # unsigned link: the hot messages are framed by _Frame (bytes identical to pymavlink's)
        self._fast = key is None
        self._senders = [(typ, getattr(self, "_send_" + typ.lower()), self.period_ns[typ]) for typ in order]
        self._latest: tuple[NavState, int, int] | None = None
        self._wake = asyncio.Event()
        self._texts: deque[tuple[int, str]] = deque(maxlen=32)
        self._gnss: GnssFix | None = None
        self._gnss_new = False
        self._home: tuple[float, float, float] | None = None
        self._home_ecef: tuple[float, float, float] = (0.0, 0.0, 0.0)  # ECEF point of the home (m)
        self._home_cen: tuple[float, ...] = (1.0, 0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 1.0)  # C_e^n at home, row-major
        self.sent: dict[str, int] = {}
        self._t0_ns = time.monotonic_ns()
        self._task: asyncio.Task[None] | None = None
        self._next_due_ns = 0  # earliest next_ns of a message that can be sent

    # -- file-like for pymavlink ----------------------------------------------
    def write(self, buf: bytes) -> None:
        if self.tr.write(buf):
            self.metrics.output(self.name, "bytes", len(buf))
        else:
            self.metrics.output(self.name, "not_sent")

    def _emit(self, frame: _Frame, *values: Any) -> None:
        """Send one message framed by ``frame`` (values in wire order), with pymavlink's bookkeeping."""
        mav = self.mav
        buf = frame.frame(mav, *values)
        self.write(buf)
        mav.seq = (mav.seq + 1) % 256
        mav.total_packets_sent += 1
        mav.total_bytes_sent += len(buf)

    def _on_data(self, data: bytes) -> None:
        before = dict(self.rx.counts)
        for m in self.rx.feed(data):
            t = m.get_type()
            self.rx_messages[t] = self.rx_messages.get(t, 0) + 1
        for k in ("unsigned", "bad_signature", "bad_data"):
            d = self.rx.counts[k] - before[k]
            if d:
                self.metrics.output(self.name, "rx_" + k, d)
        d = self.rx.counts["messages"] - before["messages"]
        if d:
            self.metrics.output(self.name, "rx_messages", d)

    # -- called by the loop (never blocks) --------------------------------------
    def offer(self, st: NavState, arrival_ns: int, ready_ns: int) -> None:
        """The newest state: the messages that are due go out now, from the caller (no task wake-up:
        the transports' writes never block), the others wait for their period with this state."""
        self._latest = (st, arrival_ns, ready_ns)
        if time.monotonic_ns() >= self._next_due_ns:
            self._send_safely()

    def offer_gnss(self, g: GnssFix) -> None:
        self._gnss, self._gnss_new = g, True
        self._update_next_due()

    def statustext(self, severity: int, text: str) -> None:
        self._texts.append((severity, text[:50]))
        self._wake.set()

    async def start(self) -> None:
        await self.tr.open()
        self._task = asyncio.create_task(self._run(), name=f"mavlink-{self.name}")

    async def close(self) -> None:
        if self._task is not None:
            self._task.cancel()
            try:
                await self._task
            except asyncio.CancelledError:
                pass
        self.tr.close()

    # -- the sender task -----------------------------------------------------------
    async def _run(self) -> None:
        while True:
            await self._wake.wait()
            self._wake.clear()
            self._send_safely()

    def _send_safely(self) -> None:
        try:
            self._send_due()
        except Exception as e:  # a bad value must not kill the output
            self.metrics.output(self.name, "encode_error")
            self.metrics.warn(f"{self.name}: {type(e).__name__}: {e}")

    def _count(self, typ: str) -> None:
        self.sent[typ] = self.sent.get(typ, 0) + 1
        self.metrics.output(self.name, typ)

    def _send_due(self) -> None:
        """Send every message that is due with the newest state, highest rate first, then queued STATUSTEXTs.

        Latency metric: ``RuntimeMetrics.record_sent`` is called once per state that sends anything,
        at the moment the FIRST due message (the highest-rate one, e.g. ODOMETRY) has been handed
        to the transport, so ``state_to_sent`` = state ready → first message of that state sent
        (before, it was measured after the last due message).
        """
        latest = self._latest
        if latest is not None:
            st, arrival_ns, ready_ns = latest
            now = time.monotonic_ns()
            nxt = self.next_ns
            first = True
            for typ, send, period in self._senders:
                due = nxt[typ]
                if now < due or (typ == "GPS_RAW_INT" and not self._gnss_new):
                    continue
                nxt[typ] = advance_due(due, period, now)
                send(st)
                self._count(typ)
                if first:
                    self.metrics.record_sent(arrival_ns, ready_ns, time.monotonic_ns())
                    first = False
        while self._texts:
            sev, text = self._texts.popleft()
            self.mav.statustext_send(sev, text.encode())
            self._count("STATUSTEXT")
        if latest is not None:
            self._update_next_due()

    def _update_next_due(self) -> None:
        """Earliest time a message is due (GPS_RAW_INT only once a new fix is there)."""
        nxt = self.next_ns
        self._next_due_ns = min((v for k, v in nxt.items() if k != "GPS_RAW_INT" or self._gnss_new), default=1 << 62)

    # -- message builders (units: MAVLink's integer units at the edge) -------------
    def _tboot_ms(self, st: NavState) -> int:
        return round(st.t * 1000) & 0xFFFFFFFF

    def _send_heartbeat(self, st: NavState) -> None:
        m = self._m
        status = m.MAV_STATE_ACTIVE if st.aligned else m.MAV_STATE_CALIBRATING
        if self.cfg.role == "gcs":
            typ, ap = self.mav_type, m.MAV_AUTOPILOT_GENERIC
        else:
            typ, ap = m.MAV_TYPE_ONBOARD_CONTROLLER, m.MAV_AUTOPILOT_INVALID
        if self._fast:  # wire order: custom_mode, type, autopilot, base_mode, system_status, mavlink_version
            self._emit(_frame_of("HEARTBEAT"), 0, typ, ap, 0, status, 3)
        else:
            self.mav.heartbeat_send(typ, ap, 0, 0, status)

    def _send_sys_status(self, st: NavState) -> None:
        m = self._m
        bits = (
            m.MAV_SYS_STATUS_SENSOR_3D_GYRO
            | m.MAV_SYS_STATUS_SENSOR_3D_ACCEL
            | m.MAV_SYS_STATUS_SENSOR_ABSOLUTE_PRESSURE
            | m.MAV_SYS_STATUS_SENSOR_GPS
            | m.MAV_SYS_STATUS_AHRS
        )
        health = (
            bits
            if self.metrics.fdi_state == "ok"
            else bits & ~(m.MAV_SYS_STATUS_SENSOR_3D_GYRO | m.MAV_SYS_STATUS_SENSOR_3D_ACCEL)
        )
        drops = min(10000, self.metrics.dropped_total())
        if self._fast:  # wire order: present, enabled, health, load, voltage, current, drop_rate, errors ×5,
            # battery_remaining, then the three *_extended fields
            self._emit(_frame_of("SYS_STATUS"), bits, bits, health, 0, 0, -1, drops, 0, 0, 0, 0, 0, -1, 0, 0, 0)
        else:
            self.mav.sys_status_send(bits, bits, health, 0, 0, -1, -1, drops, 0, 0, 0, 0, 0)

    def _euler(self, st: NavState) -> list[float]:
        """(roll, pitch, yaw) rad of the state's q_nb as Python floats."""
        return euler_from_quat(st.q_nb).tolist()

    def _send_attitude(self, st: NavState) -> None:
        r, p, y = self._euler(st)
        wx, wy, wz = _floats(st.omega_b)
        if self._fast:
            self._emit(_frame_of("ATTITUDE"), self._tboot_ms(st), r, p, y, wx, wy, wz)
        else:
            self.mav.attitude_send(self._tboot_ms(st), r, p, y, wx, wy, wz)

    def _send_attitude_quaternion(self, st: NavState) -> None:
        q, w = _floats(st.q_nb), _floats(st.omega_b)
        if self._fast:  # repr_offset_q (extension) = zeros, as pymavlink's default
            self._emit(_frame_of("ATTITUDE_QUATERNION"), self._tboot_ms(st), *q, *w, 0.0, 0.0, 0.0, 0.0)
        else:
            self.mav.attitude_quaternion_send(self._tboot_ms(st), *q, *w)

    def _set_home(self, st: NavState) -> None:
        """The first position is the home of LOCAL_POSITION_NED/ODOMETRY (and GLOBAL_POSITION_INT's
        relative altitude); its ECEF point and C_e^n are cached here as floats."""
        self._home = (st.lat, st.lon, st.h)
        self._home_ecef = earth.ecef_xyz(st.lat, st.lon, st.h)
        self._home_cen = tuple(earth.dcm_ecef_to_ned(st.lat, st.lon).ravel().tolist())

    def _home_ned(self, st: NavState) -> tuple[float, float, float]:
        """Exact NED offset (m) of the state from the home: earth.ned_from_geodetic's formula
        (C_e^n(home) · (r_e − r_e,home)) in scalar floats with the home's terms cached."""
        if self._home is None:
            self._set_home(st)
        x, y, z = earth.ecef_xyz(st.lat, st.lon, st.h)
        x0, y0, z0 = self._home_ecef
        dx, dy, dz = x - x0, y - y0, z - z0
        c = self._home_cen
        return (
            c[0] * dx + c[1] * dy + c[2] * dz,
            c[3] * dx + c[4] * dy + c[5] * dz,
            c[6] * dx + c[7] * dy + c[8] * dz,
        )

    def _send_global_position_int(self, st: NavState) -> None:
        vn, ve, vd = _floats(st.vel_ned)
        hdg = math.degrees(self._euler(st)[2]) % 360.0
        rel = st.h - (self._home[2] if self._home else st.h)
        if self._home is None:  # the first position sets the home (LOCAL_POSITION_NED, ODOMETRY)
            self._set_home(st)
        vals = (
            self._tboot_ms(st),
            round(math.degrees(st.lat) * 1e7),
            round(math.degrees(st.lon) * 1e7),
            round(st.h * 1000),
            round(rel * 1000),
            _i16(vn * 100),
            _i16(ve * 100),
            _i16(vd * 100),
            round(hdg * 100) % 36000,
        )
        if self._fast:  # wire order = argument order
            self._emit(_frame_of("GLOBAL_POSITION_INT"), *vals)
        else:
            self.mav.global_position_int_send(*vals)

    def _send_local_position_ned(self, st: NavState) -> None:
        d = self._home_ned(st)
        v = _floats(st.vel_ned)
        if self._fast:
            self._emit(_frame_of("LOCAL_POSITION_NED"), self._tboot_ms(st), *d, *v)
        else:
            self.mav.local_position_ned_send(self._tboot_ms(st), *d, *v)

    def _send_gps_raw_int(self, st: NavState) -> None:
        g = self._gnss
        self._gnss_new = False
        if g is None:
            return
        v = g.vel_ned if g.vel_ned is not None else np.zeros(3)
        gs = math.hypot(v[0], v[1])
        cog = (math.degrees(math.atan2(v[1], v[0])) % 360.0) if gs > 0.2 else 0.0
        self.mav.gps_raw_int_send(
            round(g.t * 1e6),
            int(g.fix_type),
            round(math.degrees(g.lat) * 1e7),
            round(math.degrees(g.lon) * 1e7),
            round(g.h * 1000),
            min(65535, round(g.std_ne * 100)),
            min(65535, round(g.std_d * 100)),
            min(65535, round(gs * 100)),
            round(cog * 100) % 36000,
            g.num_sats,
            round(g.h * 1000),
            round(g.std_ne * 1000),
            round(g.std_d * 1000),
            round(g.std_vel * 1000),
            0,
        )

    def _send_vfr_hud(self, st: NavState) -> None:
        v = st.vel_ned
        gs = math.hypot(v[0], v[1])
        hdg = round(math.degrees(self._euler(st)[2])) % 360
        self.mav.vfr_hud_send(gs, gs, hdg, 0, st.h, -float(v[2]))

    def _send_estimator_status(self, st: NavState) -> None:
        m = mavlink_module()
        tr = st.test_ratios
        flags = 0
        if st.aligned:
            flags = (
                m.ESTIMATOR_ATTITUDE
                | m.ESTIMATOR_VELOCITY_HORIZ
                | m.ESTIMATOR_VELOCITY_VERT
                | m.ESTIMATOR_POS_HORIZ_ABS
                | m.ESTIMATOR_POS_VERT_ABS
            )
        else:
            flags = m.ESTIMATOR_CONST_POS_MODE

        def ratio(*keys: str) -> float:
            vals = [float(v) for k, v in tr.items() if any(s in k.lower() for s in keys)]
            return max(vals) if vals else 0.0

        sp = st.std_pos
        self.mav.estimator_status_send(
            round(st.t * 1e6),
            flags,
            ratio("vel"),
            ratio("pos", "gnss_ne", "horiz"),
            ratio("baro", "hgt", "height", "vert", "_d"),
            ratio("mag"),
            0.0,
            0.0,
            float(math.hypot(sp[0], sp[1])),
            float(sp[2]),
        )

    def _send_odometry(self, st: NavState) -> None:
        m = self._m
        d = self._home_ned(st)
        q = _floats(st.q_nb)
        wx, wy, wz = _floats(st.omega_b)
        # child frame body FRD (MAVLink ODOMETRY convention): v_b = (C_b^n)ᵀ v_n, C_b^n from rotation.dcm_from_quat
        c = dcm_from_quat(st.q_nb).tolist()
        vn, ve, vd = _floats(st.vel_ned)
        vbx = c[0][0] * vn + c[1][0] * ve + c[2][0] * vd
        vby = c[0][1] * vn + c[1][1] * ve + c[2][1] * vd
        vbz = c[0][2] * vn + c[1][2] * ve + c[2][2] * vd
        sp0, sp1, sp2 = _floats(st.std_pos)
        if (sp0 > 0.0 or sp1 > 0.0 or sp2 > 0.0) and not (math.isnan(sp0) or math.isnan(sp1) or math.isnan(sp2)):
            # (that is max(std_pos) > 0) upper-right triangle, row-major: diagonal at 0, 6, 11, 15, 18, 20
            sa0, sa1, sa2 = _floats(st.std_att)
            sv0, sv1, sv2 = _floats(st.std_vel)
            pc = [0.0] * 21
            pc[0], pc[6], pc[11], pc[15], pc[18], pc[20] = sp0**2, sp1**2, sp2**2, sa0**2, sa1**2, sa2**2
            vc = [0.0] * 21
            vc[0], vc[6], vc[11] = sv0**2, sv1**2, sv2**2
        else:  # unknown: NaN first element
            pc = [math.nan] + [0.0] * 20
            vc = list(pc)
        t_us = round(st.t * 1e6)
        quality = 100 if st.aligned else 0
        if self._fast:  # wire order: time, x, y, z, q, v, rates, covariances, frame ids, reset, estimator, quality
            self._emit(
                _frame_of("ODOMETRY"), t_us, *d, *q, vbx, vby, vbz, wx, wy, wz, *pc, *vc,
                m.MAV_FRAME_LOCAL_NED, m.MAV_FRAME_BODY_FRD, 0, m.MAV_ESTIMATOR_TYPE_NAIVE, quality,
            )  # fmt: skip
        else:
            self.mav.odometry_send(
                t_us, m.MAV_FRAME_LOCAL_NED, m.MAV_FRAME_BODY_FRD, *d, q, vbx, vby, vbz, wx, wy, wz, pc, vc,
                0, m.MAV_ESTIMATOR_TYPE_NAIVE, quality,
            )  # fmt: skip

    def _send_gps_input(self, st: NavState) -> None:
        v, sp, sv = st.vel_ned, st.std_pos, st.std_vel
        self.mav.gps_input_send(
            round(st.t * 1e6),
            0,
            0,
            0,
            0,
            3 if st.aligned else 1,
            round(math.degrees(st.lat) * 1e7),
            round(math.degrees(st.lon) * 1e7),
            float(st.h),
            1.0,
            1.0,
            float(v[0]),
            float(v[1]),
            float(v[2]),
            float(max(sv)),
            float(math.hypot(sp[0], sp[1])),
            float(sp[2]),
            12,
        )

    def _send_hil_state_quaternion(self, st: NavState) -> None:
        q, w, v = st.q_nb, st.omega_b, st.vel_ned
        a = st.accel_b / earth.G0 * 1000.0  # mG
        gs = math.hypot(v[0], v[1])
        self.mav.hil_state_quaternion_send(
            round(st.t * 1e6),
            [float(x) for x in q],
            float(w[0]),
            float(w[1]),
            float(w[2]),
            round(math.degrees(st.lat) * 1e7),
            round(math.degrees(st.lon) * 1e7),
            round(st.h * 1000),
            _i16(v[0] * 100),
            _i16(v[1] * 100),
            _i16(v[2] * 100),
            min(65535, round(gs * 100)),
            min(65535, round(gs * 100)),
            _i16(a[0]),
            _i16(a[1]),
            _i16(a[2]),
        )


def _i16(x: float) -> int:
    return max(-32768, min(32767, round(float(x))))


def fault_text(ev: FaultEvent) -> tuple[int, str]:
    """STATUSTEXT (severity, ≤50 chars) for a fault event."""
    m = mavlink_module()
    if ev.cleared:
        return m.MAV_SEVERITY_NOTICE, f"INS fault cleared: {ev.sensor}"
    return m.MAV_SEVERITY_WARNING, f"INS fault {ev.sensor} {ev.mode.name.lower()}"
