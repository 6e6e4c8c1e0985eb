"""MAVLink 2 output endpoints: to a ground station (as its own vehicle) or to a flight controller.

An endpoint owns one link of the MAVLink link layer (:mod:`ins_hil.drivers.mavlink_link`,
the URL grammar of the inputs too: ``udpout:host:port`` sends to a listener such as
QGroundControl on 14550; ``udpin:host:port`` listens and answers the last peer;
``tcp:host:port`` connects, with reconnect; ``tcpin:host:port`` serves TCP clients;
``serial:/dev/ttyX:baud``) and the loop hands it the newest state with :meth:`MavlinkEndpoint.offer`
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
last GNSS fix), VFR_HUD, ESTIMATOR_STATUS, STATUSTEXT (faults, alignment, sensors lost/back),
HOME_POSITION. role ``fc``: HEARTBEAT, ODOMETRY (external navigation), GPS_INPUT,
HIL_STATE_QUATERNION (PX4 HIL). Altitudes in MSL fields are EGM96 (:mod:`ins_hil.runtime.geoid`).

The vehicle is always there: the endpoint's task sends HEARTBEAT (and SYS_STATUS,
ESTIMATOR_STATUS) at their rate when no state did within 50 ms of their due time (no IMU, no
solution yet), with the sensor health of :class:`~ins_hil.runtime.metrics.SensorHealth`. It
answers a ground station (messages to this system id or broadcast): the parameter protocol
(:mod:`ins_hil.runtime.mavlink_params`), COMMAND_LONG/COMMAND_INT (always a COMMAND_ACK),
MAV_CMD_REQUEST_MESSAGE, MAV_CMD_SET_/GET_MESSAGE_INTERVAL, MAV_CMD_PREFLIGHT_STORAGE,
MISSION_REQUEST_LIST (MISSION_COUNT 0) and MAVLink FTP (a NAK). See docs/flight_controller.md.

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

from ins_hil.drivers.mavlink_link import Link, MavReceiver, configure_signing, signing_key_from
from ins_hil.drivers.mavlink_link import parse_url as parse_url  # re-exported: the one URL grammar
from ins_hil.nav import earth
from ins_hil.nav.rotation import dcm_from_quat, euler_from_quat
from ins_hil.runtime.geoid import undulation
from ins_hil.runtime.metrics import RuntimeMetrics
from ins_hil.types import FaultEvent, GnssFix, NavState, unix_from_gps


def mavlink_module() -> Any:
    """The MAVLink 2 dialect used everywhere (ardupilotmega ⊃ common)."""
    from pymavlink.dialects.v20 import ardupilotmega

    return ardupilotmega


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


#: a state older than this (s) is no valid solution (IMU lost): ESTIMATOR_STATUS flags drop, CRITICAL
SOLUTION_TIMEOUT_S = 0.5
_BEAT_GRACE_NS = 50_000_000  # the task sends the 1 Hz group when no state has sent it 50 ms after it was due
_BEAT_RETRY_NS = 100_000_000  # a heartbeat the link could not take is tried again after 0.1 s
_HANDLED = frozenset(
    ("PARAM_REQUEST_LIST", "PARAM_REQUEST_READ", "PARAM_SET", "COMMAND_LONG", "COMMAND_INT",
     "MISSION_REQUEST_LIST", "FILE_TRANSFER_PROTOCOL")
)  # fmt: skip
_FTP_ERR_UNKNOWN_COMMAND = 7  # MAVLink FTP error code UnknownCommand


def _msg_names() -> dict[int, str]:
    m = mavlink_module()
    return {int(getattr(m, "MAVLINK_MSG_ID_" + t)): t for t in ALL_MESSAGES}


_MSG_NAMES = _msg_names()  # message id → name of the streamed messages


def _sensor_bits() -> dict[str, int]:
    m = mavlink_module()
    return {
        "imu": m.MAV_SYS_STATUS_SENSOR_3D_GYRO | m.MAV_SYS_STATUS_SENSOR_3D_ACCEL,
        "gnss": m.MAV_SYS_STATUS_SENSOR_GPS,
        "baro": m.MAV_SYS_STATUS_SENSOR_ABSOLUTE_PRESSURE,
        "mag": m.MAV_SYS_STATUS_SENSOR_3D_MAG,
    }


_SENSOR_BITS = _sensor_bits()


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
    url: str = "udpout:127.0.0.1:14550"
    role: str = "gcs"  # gcs | fc
    sysid: int = 42
    compid: int = 1
    mav_type: str = "QUADROTOR"
    signing_key: str = ""  # 64 hex digits
    rates: dict[str, float] = field(default_factory=dict)
    params_file: str = ""  # parameter override file (default: <config>.params.toml), ins_hil.runtime.mavlink_params
    # ODOMETRY frame_id: LOCAL_NED (PX4) or LOCAL_FRD (ArduPilot accepts only LOCAL_FRD; same values: x north)
    odometry_frame: str = "LOCAL_NED"

    def effective_rates(self) -> dict[str, float]:
        base = dict(GCS_RATES if self.role == "gcs" else FC_RATES)
        base.update(self.rates)
        return {k: v for k, v in base.items() if v > 0}


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
        key = signing_key_from(cfg.signing_key) if cfg.signing_key else None
        self.rx = MavReceiver(key)
        self.rx_messages: dict[str, int] = {}
        self.tr = Link(cfg.url, self._on_data, on_error=lambda why: metrics.output(cfg.name, "link_" + why))
        self.mav = mavlink.MAVLink(self, srcSystem=cfg.sysid, srcComponent=cfg.compid)
        configure_signing(self.mav, key, link_id=0)
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
        self._init_vehicle()

    # -- file-like for pymavlink ----------------------------------------------
    def write(self, buf: bytes) -> None:
        if self.tr.write(buf):
            self.metrics.output(self.name, "bytes", len(buf))
            self._write_ok = True
        else:
            self.metrics.output(self.name, "not_sent")
            self._write_ok = False

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
            if t in _HANDLED:
                self._handle(m, t)
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
        """STATUSTEXTs, replies, and the HEARTBEAT/SYS_STATUS/ESTIMATOR_STATUS group when no state has
        sent them within ``_BEAT_GRACE_NS`` of their due time (no IMU, no solution yet)."""
        wake = self._wake
        while True:
            due = self.next_ns.get("HEARTBEAT")
            timeout = None if due is None else max(0.0, (due + _BEAT_GRACE_NS - time.monotonic_ns()) * 1e-9)
            if timeout is None or timeout > 0.0:
                try:
                    await asyncio.wait_for(wake.wait(), timeout)
                except TimeoutError:
                    pass
            wake.clear()
            try:
                self._send_texts()  # the state's messages go out from offer() only: never a stale state again
                self._send_replies()
                self._beat()
            except Exception as e:  # a bad value must not kill the output
                self.metrics.output(self.name, "encode_error")
                self.metrics.warn(f"{self.name}: {type(e).__name__}: {e}")

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
        self._send_texts()
        if latest is not None:
            self._update_next_due()

    def _send_texts(self) -> None:
        while self._texts:
            sev, text = self._texts.popleft()
            self.mav.statustext_send(sev, text.encode())
            self._count("STATUSTEXT")

    def _update_next_due(self) -> None:
        """Earliest time a message is due (GPS_RAW_INT only once a new fix is there)."""
        nxt = self.next_ns
        self._next_due_ns = min((v for k, v in nxt.items() if k != "GPS_RAW_INT" or self._gnss_new), default=1 << 62)

    # -- message builders (units: MAVLink's integer units at the edge) -------------
    def _tboot_ms(self, st: NavState) -> int:
        return round(st.t * 1000) & 0xFFFFFFFF

    def _send_heartbeat(self, st: NavState | None) -> None:
        m = self._m
        status = self._vehicle_status()[4]
        if self.cfg.role == "gcs":
            typ, ap = self.mav_type, m.MAV_AUTOPILOT_GENERIC
        else:
            typ, ap = m.MAV_TYPE_ONBOARD_CONTROLLER, m.MAV_AUTOPILOT_INVALID
        if self._fast:  # wire order: custom_mode, type, autopilot, base_mode, system_status, mavlink_version
            self._emit(_frame_of("HEARTBEAT"), 0, typ, ap, 0, status, 3)
        else:
            self.mav.heartbeat_send(typ, ap, 0, 0, status)
        if not self._write_ok and "HEARTBEAT" in self.next_ns:  # link not up yet (TCP, serial, udpin: no peer)
            self.next_ns["HEARTBEAT"] = time.monotonic_ns() + _BEAT_RETRY_NS
        elif self._gnss is not None and self._gnss.gps_week > 0:
            self._send_system_time(st)  # with the 1 Hz HEARTBEAT, once the GNSS gives GPS time

    def _send_system_time(self, st: NavState | None) -> bool:
        """SYSTEM_TIME: UNIX time (µs) from the last fix's GPS time moved on to the state's time (the fix's
        own time without a state); time_boot_ms the state's. False (nothing sent) without GPS time."""
        g = self._gnss
        if g is None or g.gps_week <= 0 or not math.isfinite(g.gps_tow):
            return False
        t = st.t if st is not None else g.t
        unix = unix_from_gps(g.gps_week, g.gps_tow + (t - g.t))
        self.mav.system_time_send(round(unix * 1e6), round(t * 1000) & 0xFFFFFFFF)
        self._count("SYSTEM_TIME")
        return True

    def _send_sys_status(self, st: NavState | None) -> None:
        present, enabled, health, _, _ = self._vehicle_status()
        drops = min(10000, self.metrics.dropped_total())
        # battery unknown (the spec's values): voltage UINT16_MAX, current −1, remaining −1
        if self._fast:  # wire order: present, enabled, health, load, voltage, current, drop_rate, errors ×5,
            # battery_remaining, then the three *_extended fields
            self._emit(
                _frame_of("SYS_STATUS"), present, enabled, health, 0, 0xFFFF, -1, drops, 0, 0, 0, 0, 0, -1, 0, 0, 0
            )
        else:
            self.mav.sys_status_send(present, enabled, health, 0, 0xFFFF, -1, -1, drops, 0, 0, 0, 0, 0)

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
        if self.cfg.role == "gcs":
            self._reply_pending.append("HOME_POSITION")  # sent by the endpoint's task, off the IMU path
            self._wake.set()

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
            round(self._msl(st.lat, st.lon, st.h) * 1000),  # MSL (EGM96); relative_alt: above the home
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
        if g.vel_ned is not None:
            v = g.vel_ned
            gs = math.hypot(v[0], v[1])
            vel = min(65534, round(gs * 100))
            cog = round((math.degrees(math.atan2(v[1], v[0])) % 360.0) * 100) % 36000 if gs > 0.2 else 0xFFFF
        else:
            vel = cog = 0xFFFF  # unknown
        # eph/epv are HDOP/VDOP × 100 where the source gave them, else UINT16_MAX (unknown); the accuracies go
        # to h_acc/v_acc (mm) and vel_acc (mm/s). alt is MSL (EGM96), alt_ellipsoid the WGS84 height.
        hdop, vdop = _dop(g, "hdop"), _dop(g, "vdop")
        sats = g.num_sats if g.num_sats > 0 else 255  # 0 with a fix: not reported by the source
        self.mav.gps_raw_int_send(
            round(g.t * 1e6),
            int(g.fix_type),
            round(math.degrees(g.lat) * 1e7),
            round(math.degrees(g.lon) * 1e7),
            round(self._msl(g.lat, g.lon, g.h) * 1000),
            hdop,
            vdop,
            vel,
            cog,
            sats,
            round(g.h * 1000),
            _u32(g.std_ne * 1000),
            _u32(g.std_d * 1000),
            _u32(g.std_vel * 1000),
            0,
        )

    def _send_vfr_hud(self, st: NavState) -> None:
        v = st.vel_ned
        gs = math.hypot(v[0], v[1])
        hdg = round(math.degrees(self._euler(st)[2])) % 360
        self.mav.vfr_hud_send(gs, gs, hdg, 0, self._msl(st.lat, st.lon, st.h), -float(v[2]))  # alt: MSL

    def _send_estimator_status(self, st: NavState | None) -> None:
        """Flags only while the solution is valid (aligned, fresh: IMU not lost); without a state
        (sent by the 1 Hz task) every flag is clear, the ratios and accuracies 0."""
        m = mavlink_module()
        if st is None or not self._solution_valid():
            t_us = round((time.monotonic_ns() - self._t0_ns) * 1e-3)  # no state: time since the endpoint started
            self.mav.estimator_status_send(t_us, 0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0)
            return
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
        # estimator_type VIO: PX4 reads the covariances only when it is not NAIVE (an inertial + aided estimate)
        if self._fast:  # wire order: time, x, y, z, q, v, rates, covariances, frame ids, reset, estimator, quality
            self._emit(
                _frame_of("ODOMETRY"), t_us, *d, *q, vbx, vby, vbz, wx, wy, wz, *pc, *vc,
                self._odom_frame, m.MAV_FRAME_BODY_FRD, 0, m.MAV_ESTIMATOR_TYPE_VIO, quality,
            )  # fmt: skip
        else:
            self.mav.odometry_send(
                t_us, self._odom_frame, m.MAV_FRAME_BODY_FRD, *d, q, vbx, vby, vbz, wx, wy, wz, pc, vc,
                0, m.MAV_ESTIMATOR_TYPE_VIO, quality,
            )  # fmt: skip

    def _send_gps_input(self, st: NavState) -> None:
        """The fused state as a MAVLink GPS (ArduPilot GPS1_TYPE = 14). hdop/vdop from the last fix where its
        source gave them, else UINT16_MAX with GPS_INPUT_IGNORE_FLAG_HDOP|VDOP; time_week/time_week_ms: the
        GPS time of the last fix moved on to the state's time, or 0/0 (which ArduPilot takes as "no GPS
        time") while the source gives none; satellites from the last fix, 0 when the source gives none.
        alt: MSL (EGM96)."""
        m = self._m
        v, sp, sv = st.vel_ned, st.std_pos, st.std_vel
        g = self._gnss
        ignore = m.GPS_INPUT_IGNORE_FLAG_HDOP | m.GPS_INPUT_IGNORE_FLAG_VDOP
        hdop = vdop = 65535.0
        if g is not None and _dop(g, "hdop") != 0xFFFF:
            hdop, ignore = _dop(g, "hdop") * 0.01, ignore & ~m.GPS_INPUT_IGNORE_FLAG_HDOP
        if g is not None and _dop(g, "vdop") != 0xFFFF:
            vdop, ignore = _dop(g, "vdop") * 0.01, ignore & ~m.GPS_INPUT_IGNORE_FLAG_VDOP
        week, week_ms = _gps_week(g, st.t)
        self.mav.gps_input_send(
            round(st.t * 1e6),
            0,
            ignore,
            week_ms,
            week,
            3 if st.aligned else 1,
            round(math.degrees(st.lat) * 1e7),
            round(math.degrees(st.lon) * 1e7),
            float(self._msl(st.lat, st.lon, st.h)),
            hdop,
            vdop,
            float(v[0]),
            float(v[1]),
            float(v[2]),
            float(max(sv)),
            float(math.hypot(sp[0], sp[1])),
            float(sp[2]),
            min(254, g.num_sats) if g is not None else 0,
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
            round(self._msl(st.lat, st.lon, st.h) * 1000),  # MSL, as PX4 reads it (AMSL)
            _i16(v[0] * 100),
            _i16(v[1] * 100),
            _i16(v[2] * 100),
            min(65535, round(gs * 100)),
            min(65535, round(gs * 100)),
            _i16(a[0]),
            _i16(a[1]),
            _i16(a[2]),
        )

    # -- the vehicle: status, the 1 Hz group without states, the GCS protocols ---------------------
    def _init_vehicle(self) -> None:
        self.params: Any = None  # ins_hil.runtime.mavlink_params.ParamStore (attached by the gateway)
        self.params_index = 0
        self._seen: Any = None  # the newest state as last seen by _state_age_ns, and when (monotonic ns)
        self._seen_ns = 0
        self._reply_pending: list[Any] = []  # messages to send once, after the ACK / off the IMU path
        self._geoid_at = (math.inf, math.inf)
        self._geoid_n = 0.0
        self.rx_ignored = 0  # messages addressed to another system
        frames = {"LOCAL_NED": self._m.MAV_FRAME_LOCAL_NED, "LOCAL_FRD": self._m.MAV_FRAME_LOCAL_FRD}
        if self.cfg.odometry_frame not in frames:
            raise ValueError(f"{self.name}.odometry_frame = {self.cfg.odometry_frame!r}: LOCAL_NED or LOCAL_FRD")
        self._odom_frame = frames[self.cfg.odometry_frame]
        self._had_solution = False  # a valid solution was seen (then CRITICAL when it is lost)
        self._write_ok = True  # the last write reached the transport

    def _msl(self, lat: float, lon: float, h: float) -> float:
        """Height above MSL (m, EGM96) of ``h`` (WGS84); the undulation is re-evaluated when the point
        moved by more than 1e-5 rad (~60 m: the 1° grid changes by < 1 cm over that)."""
        a, b = self._geoid_at
        if abs(lat - a) + abs(lon - b) > 1e-5:
            self._geoid_at = (lat, lon)
            self._geoid_n = undulation(lat, lon)
        return h - self._geoid_n

    def _state_age_ns(self, lt: tuple[NavState, int, int]) -> int:
        """Age of the newest state: from its ready time (the loop's monotonic stamp), or, without one
        (0, tests and tools), from when this endpoint first saw it here (1–2 Hz checks; nothing is
        added to :meth:`offer`)."""
        now = time.monotonic_ns()
        if lt[2]:
            return now - lt[2]
        if lt is not self._seen:
            self._seen, self._seen_ns = lt, now
        return now - self._seen_ns

    def _solution_valid(self) -> bool:
        """A state within the last ``SOLUTION_TIMEOUT_S`` that is aligned, and the IMU not lost."""
        lt = self._latest
        if lt is None or not lt[0].aligned:
            return False
        if self._state_age_ns(lt) > SOLUTION_TIMEOUT_S * 1e9:
            return False
        imu = self.metrics.sensors["imu"]
        return not (imu.present and imu.count and not imu.healthy)

    def _vehicle_status(self) -> tuple[int, int, int, bool, int]:
        """SYS_STATUS (present, enabled, health) bits, solution valid, HEARTBEAT system_status.

        Per sensor kind (RuntimeMetrics.sensors): present = configured or seen, enabled = present,
        healthy = arriving at its rate; the IMU bits are unhealthy while FDI reports a fault; AHRS
        healthy = valid solution. system_status: STANDBY before the first aligned solution, ACTIVE
        when the solution is valid and every present sensor healthy, CRITICAL when the IMU is lost,
        or after a solution when it is invalid (no state for 0.5 s) or a sensor is lost (dead reckoning)."""
        m = self._m
        present = health = 0
        all_ok = True
        for kind, h in self.metrics.sensors.items():
            bit = _SENSOR_BITS[kind]
            if h.present:
                present |= bit
                if h.healthy:
                    health |= bit
                else:
                    all_ok = False
        if self.metrics.fdi_state != "ok":
            health &= ~(m.MAV_SYS_STATUS_SENSOR_3D_GYRO | m.MAV_SYS_STATUS_SENSOR_3D_ACCEL)
        valid = self._solution_valid()
        present |= m.MAV_SYS_STATUS_AHRS
        if valid:
            health |= m.MAV_SYS_STATUS_AHRS
            self._had_solution = True
        imu = self.metrics.sensors["imu"]
        if valid and all_ok:
            status = m.MAV_STATE_ACTIVE
        elif self._had_solution or (imu.count and not imu.healthy):  # solution lost, or the IMU lost
            status = m.MAV_STATE_CRITICAL
        else:
            status = m.MAV_STATE_STANDBY
        return present, present, health, valid, status

    def _beat(self) -> None:
        """HEARTBEAT (and SYS_STATUS, ESTIMATOR_STATUS when streamed) when no state sent them in time."""
        nxt = self.next_ns
        due = nxt.get("HEARTBEAT")
        now = time.monotonic_ns()
        if due is None or now < due + _BEAT_GRACE_NS:
            return
        st = self._latest[0] if self._latest is not None and self._solution_valid() else None
        for typ in ("HEARTBEAT", "SYS_STATUS", "ESTIMATOR_STATUS"):
            d = nxt.get(typ)
            if d is not None and now >= d:
                nxt[typ] = advance_due(d, self.period_ns[typ], now)
                getattr(self, "_send_" + typ.lower())(st)
                self._count(typ)
        self._update_next_due()

    def set_rate(self, typ: str, hz: float) -> None:
        """Stream ``typ`` at ``hz`` (0 = off) from now on (PARAM_SET SR_*, MAV_CMD_SET_MESSAGE_INTERVAL)."""
        if typ not in ALL_MESSAGES:
            raise ValueError(f"{typ}: not a streamed message (known: {', '.join(ALL_MESSAGES)})")
        if not (hz >= 0.0 and math.isfinite(hz)):
            raise ValueError(f"{typ}: rate {hz!r} must be ≥ 0 Hz")
        rates = {k: v for k, v in self.rates.items() if k != typ}
        if hz > 0:
            rates[typ] = hz
        self.rates = rates
        self.period_ns = {k: round(1e9 / v) for k, v in rates.items()}
        order = sorted(rates, key=lambda k: -rates[k])
        self.next_ns = {k: self.next_ns.get(k, 0) for k in order}
        self._senders = [(t, getattr(self, "_send_" + t.lower()), self.period_ns[t]) for t in order]
        self._update_next_due()
        self._wake.set()  # the heartbeat task re-reads its due time

    # -- incoming (GCS) messages -----------------------------------------------------------------
    def _handle(self, msg: Any, typ: str) -> None:
        """Answer a ground station's request addressed to this system (target 0 = broadcast)."""
        target = getattr(msg, "target_system", 0)
        if target not in (0, self.cfg.sysid):
            self.rx_ignored += 1
            self.metrics.output(self.name, "rx_other_system")
            return
        try:
            getattr(self, "_on_" + typ.lower())(msg)
        except Exception as e:  # a malformed request must not kill the link
            self.metrics.output(self.name, "rx_error")
            self.metrics.warn(f"{self.name}: {typ}: {type(e).__name__}: {e}")
        self._send_replies()

    def _param_value(self, name: str, index: int) -> None:
        value, ptype = self.params.get(self.params_index, name)
        count = len(self.params.names(self.params_index))
        self.mav.param_value_send(name.encode(), float(value), ptype, count, index)
        self._count("PARAM_VALUE")

    def _on_param_request_list(self, msg: Any) -> None:
        if self.params is None:
            return
        for i, name in enumerate(self.params.names(self.params_index)):
            self._param_value(name, i)

    def _on_param_request_read(self, msg: Any) -> None:
        if self.params is None:
            return
        names = self.params.names(self.params_index)
        name = _param_name(msg.param_id)
        if msg.param_index >= 0:
            if msg.param_index < len(names):
                self._param_value(names[msg.param_index], msg.param_index)
        elif name in names:
            self._param_value(name, names.index(name))

    def _on_param_set(self, msg: Any) -> None:
        if self.params is None:
            return
        from ins_hil.runtime.mavlink_params import ParamError

        names = self.params.names(self.params_index)
        name = _param_name(msg.param_id)
        if name not in names:
            self.statustext(self._m.MAV_SEVERITY_WARNING, f"param {name}: unknown")
            return
        try:
            self.params.set(self.params_index, name, float(msg.param_value), int(msg.param_type))
        except ParamError as e:
            self.metrics.output(self.name, "param_refused")
            self.statustext(self._m.MAV_SEVERITY_WARNING, str(e))
            self.metrics.warn(f"{self.name}: PARAM_SET refused: {e}")
        else:
            self.metrics.output(self.name, "param_set")
            for w in self.params.warnings:
                self.metrics.warn(w)
            self.params.warnings.clear()
        self._param_value(name, names.index(name))  # the value in force: new, or unchanged when refused

    def _on_command_long(self, msg: Any) -> None:
        p = (msg.param1, msg.param2, msg.param3, msg.param4, msg.param5, msg.param6, msg.param7)
        self._command(msg, int(msg.command), p)

    def _on_command_int(self, msg: Any) -> None:
        p = (msg.param1, msg.param2, msg.param3, msg.param4, float(msg.x), float(msg.y), msg.z)
        self._command(msg, int(msg.command), p)

    def _command(self, msg: Any, cmd: int, p: tuple[float, ...]) -> None:
        """Every command is acknowledged (COMMAND_ACK); what is not handled is MAV_RESULT_UNSUPPORTED."""
        m = self._m
        result = m.MAV_RESULT_UNSUPPORTED
        if cmd == m.MAV_CMD_REQUEST_MESSAGE:
            result = self._request_message(int(p[0]))
        elif cmd == m.MAV_CMD_REQUEST_AUTOPILOT_CAPABILITIES:
            result = self._request_message(m.MAVLINK_MSG_ID_AUTOPILOT_VERSION)
        elif cmd == m.MAV_CMD_SET_MESSAGE_INTERVAL:
            result = self._set_interval(int(p[0]), p[1])
        elif cmd == m.MAV_CMD_GET_MESSAGE_INTERVAL:
            typ = _MSG_NAMES.get(int(p[0]))
            if typ is None:
                result = m.MAV_RESULT_DENIED
            else:
                self._reply_pending.append(("MESSAGE_INTERVAL", int(p[0])))  # after the ACK
                result = m.MAV_RESULT_ACCEPTED
        elif cmd == m.MAV_CMD_PREFLIGHT_STORAGE:
            result = self._storage(int(p[0]))
        elif cmd == m.MAV_CMD_COMPONENT_ARM_DISARM:
            result = m.MAV_RESULT_DENIED  # a navigation gateway has nothing to arm
        self.mav.command_ack_send(cmd, result, 0, 0, msg.get_srcSystem(), msg.get_srcComponent())
        self._count("COMMAND_ACK")

    def _storage(self, action: int) -> int:
        m = self._m
        if action != 1 or self.params is None:  # 1 = write parameters; reading/reset are not offered
            return int(m.MAV_RESULT_UNSUPPORTED)
        try:
            path = self.params.save()
        except (OSError, ValueError) as e:
            self.statustext(m.MAV_SEVERITY_ERROR, f"params not saved: {e}")
            self.metrics.warn(f"{self.name}: parameters not saved: {e}")
            return int(m.MAV_RESULT_FAILED)
        self.statustext(m.MAV_SEVERITY_INFO, f"params saved: {path.name}")
        return int(m.MAV_RESULT_ACCEPTED)

    def _set_interval(self, msg_id: int, interval_us: float) -> int:
        m = self._m
        typ = _MSG_NAMES.get(msg_id)
        if typ is None:
            return int(m.MAV_RESULT_DENIED)  # not a message this endpoint streams
        if interval_us < 0:
            hz = 0.0
        elif interval_us == 0:  # the default rate of the endpoint's role/config
            hz = EndpointConfig(role=self.cfg.role, rates=self.cfg.rates).effective_rates().get(typ, 0.0)
        else:
            hz = 1e6 / interval_us
        if self.params is not None:
            from ins_hil.runtime.mavlink_params import RATE_PARAM, REAL32, ParamError

            try:
                self.params.set(self.params_index, RATE_PARAM[typ], hz, REAL32)  # validated, SR_* follows
            except ParamError as e:
                self.statustext(m.MAV_SEVERITY_WARNING, str(e))
                return int(m.MAV_RESULT_DENIED)
        else:
            self.set_rate(typ, hz)
        return int(m.MAV_RESULT_ACCEPTED)

    def _request_message(self, msg_id: int) -> int:
        m = self._m
        if msg_id == m.MAVLINK_MSG_ID_AUTOPILOT_VERSION:
            self._reply_pending.append("AUTOPILOT_VERSION")
            return int(m.MAV_RESULT_ACCEPTED)
        if msg_id == m.MAVLINK_MSG_ID_HOME_POSITION:
            if self._home is None:
                return int(m.MAV_RESULT_TEMPORARILY_REJECTED)  # no position yet
            self._reply_pending.append("HOME_POSITION")
            return int(m.MAV_RESULT_ACCEPTED)
        if msg_id == m.MAVLINK_MSG_ID_SYSTEM_TIME:
            if self._gnss is None or self._gnss.gps_week <= 0:
                return int(m.MAV_RESULT_TEMPORARILY_REJECTED)  # no GPS time yet
            self._reply_pending.append("SYSTEM_TIME")
            return int(m.MAV_RESULT_ACCEPTED)
        typ = _MSG_NAMES.get(msg_id)
        if typ is None:
            return int(m.MAV_RESULT_UNSUPPORTED)  # includes PROTOCOL_VERSION (not in the dialect)
        if typ == "GPS_RAW_INT":
            if self._gnss is None:
                return int(m.MAV_RESULT_TEMPORARILY_REJECTED)
        elif typ not in ("HEARTBEAT", "SYS_STATUS", "ESTIMATOR_STATUS") and self._latest is None:
            return int(m.MAV_RESULT_TEMPORARILY_REJECTED)  # no state yet
        self._reply_pending.append(typ)
        return int(m.MAV_RESULT_ACCEPTED)

    def _on_mission_request_list(self, msg: Any) -> None:
        """No mission: MISSION_COUNT 0 of the requested type, so a ground station stops asking."""
        self.mav.mission_count_send(msg.get_srcSystem(), msg.get_srcComponent(), 0, msg.mission_type)
        self._count("MISSION_COUNT")

    def _on_file_transfer_protocol(self, msg: Any) -> None:
        """MAVLink FTP is not offered: every request gets a NAK (UnknownCommand) so the client stops."""
        req = bytes(msg.payload)
        seq = int.from_bytes(req[0:2], "little")
        opcode = req[3] if len(req) > 3 else 0
        if opcode in (128, 129):  # an ACK/NAK from the peer: not a request
            return
        head = struct.pack("<HBBBBBBI", (seq + 1) & 0xFFFF, req[2] if len(req) > 2 else 0, 129, 1, opcode, 0, 0, 0)
        payload = head + bytes((_FTP_ERR_UNKNOWN_COMMAND,))
        self.mav.file_transfer_protocol_send(0, msg.get_srcSystem(), msg.get_srcComponent(),
                                             list(payload.ljust(251, b"\x00")))  # fmt: skip
        self._count("FILE_TRANSFER_PROTOCOL")

    def _send_replies(self) -> None:
        while self._reply_pending:
            typ = self._reply_pending.pop(0)
            if isinstance(typ, tuple):  # ("MESSAGE_INTERVAL", message id): −1 = not streamed
                hz = self.rates.get(_MSG_NAMES.get(typ[1], ""), 0.0)
                self.mav.message_interval_send(typ[1], round(1e6 / hz) if hz > 0 else -1)
                typ = typ[0]
            elif typ == "AUTOPILOT_VERSION":
                self._send_autopilot_version()
            elif typ == "HOME_POSITION":
                self._send_home_position()
            elif typ == "SYSTEM_TIME":
                self._send_system_time(self._latest[0] if self._latest is not None else None)
                continue  # counted by the builder
            else:
                st = self._latest[0] if self._latest is not None else None
                if st is None and typ not in ("HEARTBEAT", "SYS_STATUS", "ESTIMATOR_STATUS"):
                    continue
                if typ == "GPS_RAW_INT":
                    self._gnss_new = True
                getattr(self, "_send_" + typ.lower())(st)
            self._count(typ)

    def _send_autopilot_version(self) -> None:
        m = self._m
        caps = (
            m.MAV_PROTOCOL_CAPABILITY_MAVLINK2
            | m.MAV_PROTOCOL_CAPABILITY_PARAM_FLOAT
            | m.MAV_PROTOCOL_CAPABILITY_COMMAND_INT
            | m.MAV_PROTOCOL_CAPABILITY_PARAM_ENCODE_C_CAST  # INT32 parameters sent as their float value
        )
        from ins_hil import __version__

        parts = [int(x) if x.isdigit() else 0 for x in [*__version__.split("."), "0", "0"][:3]]
        sw = (parts[0] << 24) | (parts[1] << 16) | (parts[2] << 8) | 0xFF  # FIRMWARE_VERSION_TYPE_OFFICIAL
        self.mav.autopilot_version_send(caps, sw, 0, 0, 0, [0] * 8, [0] * 8, [0] * 8, 0, 0, self.cfg.sysid)

    def _send_home_position(self) -> None:
        if self._home is None:
            return
        lat, lon, h = self._home
        self.mav.home_position_send(
            round(math.degrees(lat) * 1e7), round(math.degrees(lon) * 1e7), round(self._msl(lat, lon, h) * 1000),
            0.0, 0.0, 0.0, [1.0, 0.0, 0.0, 0.0], 0.0, 0.0, 0.0,
            round((time.monotonic_ns() - self._t0_ns) * 1e-3),
        )  # fmt: skip


def _i16(x: float) -> int:
    return max(-32768, min(32767, round(float(x))))


def _u32(x: float) -> int:
    return max(0, min(0xFFFFFFFF, round(float(x))))


def _dop(g: GnssFix, name: str) -> int:
    """HDOP/VDOP × 100 of a fix where its source gives it (a ``hdop``/``vdop`` attribute), else UINT16_MAX."""
    v = getattr(g, name, None)
    if v is None or not math.isfinite(v) or v < 0:
        return 0xFFFF
    return min(0xFFFE, round(v * 100))


def _gps_week(g: GnssFix | None, t: float | None = None) -> tuple[int, int]:
    """(GPS week, ms of week) at sensor time ``t`` (s; default the fix's own) from a fix whose source gives
    GPS time (``gps_week`` > 0, ``gps_tow`` s), else (0, 0): ArduPilot takes week 0 as "no GPS time"."""
    if g is None or g.gps_week <= 0 or not math.isfinite(g.gps_tow):
        return 0, 0
    total = g.gps_week * 604_800 + g.gps_tow + ((t - g.t) if t is not None else 0.0)
    week = int(total // 604_800)
    return week, round((total - week * 604_800) * 1000) % 604_800_000


def _param_name(pid: Any) -> str:
    """A PARAM_* param_id (16 chars, NUL-padded; pymavlink gives str or bytes) as a str."""
    if isinstance(pid, bytes | bytearray):
        pid = pid.decode("ascii", "replace")
    return str(pid).split("\x00", 1)[0].strip()


def fault_text(ev: FaultEvent) -> tuple[int, str]:
    """STATUSTEXT (severity, ≤50 chars) for a fault event."""
    m = mavlink_module()
    if ev.cleared:
        return m.MAV_SEVERITY_NOTICE, f"INS fault cleared: {ev.sensor}"
    return m.MAV_SEVERITY_WARNING, f"INS fault {ev.sensor} {ev.mode.name.lower()}"
