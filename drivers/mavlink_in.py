"""MAVLink input from a flight controller (pymavlink parser fed from asyncio transports).

Connections (``url``), as flight controllers offer them:

- ``udpin:HOST:PORT`` (alias ``udp:``): listen; replies go to the last sender;
- ``udpout:HOST:PORT``: send to the FC's port (our HEARTBEAT opens the link);
- ``tcp:HOST:PORT``: connect (e.g. SITL's 5760);
- ``serial:DEVICE[:BAUD]`` or a bare ``/dev/...`` path (default 115200 baud).

Bytes from the transport are fed to pymavlink's ``MAVLink.parse_buffer`` in
the loop's callback: no thread, no blocking read.

Messages → samples (``ins_hil.types``, SI, body FRD as MAVLink's IMU
messages are):

- GNSS: GPS_RAW_INT (source 0), GPS2_RAW (1), GPS_INPUT (gps_id), HIL_GPS
  (id) → GnssFix. Height: ``alt_ellipsoid`` when the FC fills it, else the
  MSL altitude (the geoid separation is not known here). GPS_RAW_INT/GPS2_RAW
  carry no vertical velocity, so their ``vel_ned`` is None; GPS_INPUT and
  HIL_GPS give vn/ve/vd. Std: ``h_acc``/``v_acc``/``vel_acc`` (or GPS_INPUT's
  accuracies, HIL_GPS's eph/epv as HDOP×1 m) when present. Fixes below 2D are
  dropped (``no_fix``).
- Baro: SCALED_PRESSURE → BaroSample (hPa → Pa, cdegC → °C).
- IMU where the FC is the IMU source: HIGHRES_IMU and HIL_SENSOR (m/s², rad/s,
  gauss), SCALED_IMU/2/3 and RAW_IMU (mG, mrad/s, mgauss: ArduPilot fills
  RAW_IMU with the SCALED_IMU units) → ImuSample with rates × dt:
  ``dtheta = ω·dt``, ``dvel = f·dt`` where ``dt`` is the FC-time difference
  to the previous message of the same stream (the nominal ``imu_dt`` for the
  first one or after a gap > 0.5 s). These messages are point samples, so the
  increments are rectangular-rule approximations (error O(dt²·ω̇)), fine at
  the 50–250 Hz MAVLink carries. Their magnetometer fields → MagSample
  (gauss → T) when present/updated.

Time: the FC's ``time_boot_ms``/``time_usec`` are mapped onto our time base
(``time.monotonic()`` seconds, the base of ``t_arrival_ns``) with a clock
offset estimated by TIMESYNC (we send ``tc1=0, ts1=now_ns`` each
``timesync_s``; the FC answers ``tc1=fc_ns``; offset = tc1 − (ts1+now)/2,
keeping the reply with the smallest round trip of the last 8). Until the
first reply the offset comes from the first message's arrival (latency
biased). ``time_usec`` values past year 2001 (> 1e15 µs) are UNIX time and
are mapped with the host's wall clock. FC TIMESYNC requests are answered.

Signing: with ``signing_key`` (32 bytes) only correctly signed MAVLink 2
messages are accepted; unsigned or wrongly signed ones count as
``bad_signature``; our own messages are signed.
"""

from __future__ import annotations

import asyncio
import contextlib
import hashlib
import math
import time
from collections import deque
from typing import Any

import numpy as np
import serial_asyncio_fast
from ins_hil.drivers.base import Backoff, DriverHealth, Sample, Sink
from pymavlink.dialects.v20 import ardupilotmega as mavlink

from ins_hil.types import BaroSample, FixType, GnssFix, ImuSample, MagSample

UNIX_US = 10**15  # time_usec beyond this is UNIX epoch time (after 2001-09-09)
MAX_GYRO = 40.0  # rad/s
MAX_ACCEL = 400.0  # m/s^2
MAX_MAG_GAUSS = 20.0
DEFAULT_REQUEST = {"GPS_RAW_INT": 5.0, "SCALED_PRESSURE": 10.0}


def signing_key_from(value: str | bytes) -> bytes:
    """A 32-byte MAVLink 2 key: raw 32 bytes, 64 hex digits, or a passphrase (SHA-256, as MAVProxy's)."""
    if isinstance(value, bytes):
        if len(value) != 32:
            raise ValueError(f"MAVLink signing key must be 32 bytes, got {len(value)}")
        return value
    v = value.strip()
    if len(v) == 64:
        with contextlib.suppress(ValueError):
            return bytes.fromhex(v)
    if not v:
        raise ValueError("MAVLink signing key is empty")
    return hashlib.sha256(v.encode()).digest()


def parse_url(url: str) -> tuple[str, str, int]:
    """``udpin:H:P`` / ``udpout:H:P`` / ``tcp:H:P`` / ``serial:DEV[:BAUD]`` → (kind, host-or-device, port-or-baud)."""
    if url.startswith("/"):
        url = "serial:" + url
    kind, _, rest = url.partition(":")
    kind = {"udp": "udpin"}.get(kind, kind)
    if kind in ("udpin", "udpout", "tcp"):
        host, _, port = rest.rpartition(":")
        if not host or not port.isdigit() or not 0 <= int(port) <= 65535:
            raise ValueError(f"MAVLink url {url!r}: expected {kind}:HOST:PORT")
        return kind, host, int(port)
    if kind == "serial":
        dev, _, baud = rest.partition(":")
        if not dev:
            raise ValueError(f"MAVLink url {url!r}: expected serial:DEVICE[:BAUD]")
        if baud and not baud.isdigit():
            raise ValueError(f"MAVLink url {url!r}: baud {baud!r} is not a number")
        return kind, dev, int(baud or 115200)
    raise ValueError(f"MAVLink url {url!r}: unknown kind {kind!r} (udpin, udpout, tcp, serial)")


class ClockSync:
    """FC clock ↔ our monotonic clock (ns): ``fc_ns = our_ns + offset_ns``."""

    def __init__(self, window: int = 8) -> None:
        self.offset_ns: int | None = None
        self.synced = False
        self.rtt_ns: int | None = None
        self._hist: deque[tuple[int, int]] = deque(maxlen=window)  # (rtt, offset)

    def reply(self, tc1: int, ts1: int, now_ns: int) -> bool:
        """A TIMESYNC answer (tc1 = FC ns, ts1 = our ns when sent). False if implausible."""
        rtt = now_ns - ts1
        if not 0 <= rtt < 2_000_000_000 or tc1 <= 0:
            return False
        off = tc1 - (ts1 + now_ns) // 2
        if self._hist and abs(off - min(self._hist)[1]) > 1_000_000_000:
            self._hist.clear()  # the FC rebooted: its clock restarted
        self._hist.append((rtt, off))
        self.rtt_ns, self.offset_ns = min(self._hist)
        self.synced = True
        return True

    def rough(self, fc_ns: int, now_ns: int) -> None:
        """Seed the offset from a message's arrival before TIMESYNC answers."""
        if not self.synced and self.offset_ns is None:
            self.offset_ns = fc_ns - now_ns

    def to_local_s(self, fc_ns: int, now_ns: int) -> float:
        if self.offset_ns is None:
            self.rough(fc_ns, now_ns)
        assert self.offset_ns is not None
        return (fc_ns - self.offset_ns) * 1e-9


class _Stream(asyncio.Protocol, asyncio.DatagramProtocol):
    """One asyncio protocol for UDP, TCP and serial: bytes → driver.feed."""

    def __init__(self, drv: MavlinkDriver) -> None:
        self.drv = drv
        self.lost: asyncio.Future[str] = asyncio.get_running_loop().create_future()
        self.transport: Any = None
        self.peer: Any = None

    def connection_made(self, transport: Any) -> None:
        self.transport = transport

    def data_received(self, data: bytes) -> None:
        self.drv.feed(data)

    def datagram_received(self, data: bytes, addr: Any) -> None:
        if self.drv.kind == "udpin":
            old = self.peer
            self.peer = addr  # reply to the last sender of valid MAVLink
            if not self.drv.feed(data):
                self.peer = old or addr
        else:
            self.drv.feed(data)

    def error_received(self, exc: Exception) -> None:  # UDP: ICMP port unreachable etc.
        self.drv.health.count("socket_error")

    def connection_lost(self, exc: Exception | None) -> None:
        if not self.lost.done():
            self.lost.set_result(f"connection lost: {exc}")


class MavlinkDriver:
    """GNSS / baro / IMU / mag samples from a MAVLink flight controller."""

    def __init__(
        self,
        url: str,
        name: str = "mavlink",
        system_id: int | None = None,
        source_system: int = 255,
        source_component: int = 191,
        signing_key: str | bytes | None = None,
        request: dict[str, float] | None = None,
        emit: set[str] | None = None,
        imu_dt: float = 0.01,
        timesync_s: float = 1.0,
        stale_s: float = 3.0,
    ) -> None:
        self.kind, self.host, self.port = parse_url(url)
        self.url = url
        self.name = name
        self.health = DriverHealth(name)
        self.system_id = system_id
        self.emit = set(emit) if emit is not None else {"gnss", "baro", "imu", "mag"}
        bad = self.emit - {"gnss", "baro", "imu", "mag"}
        if bad:
            raise ValueError(f"MAVLink: unknown 'emit' kinds {sorted(bad)} (gnss, baro, imu, mag)")
        self.request = dict(DEFAULT_REQUEST if request is None else request)
        for k, hz in self.request.items():
            if getattr(mavlink, f"MAVLINK_MSG_ID_{k}", None) is None:
                raise ValueError(f"MAVLink: 'request' names unknown message {k!r}")
            if not hz > 0:
                raise ValueError(f"MAVLink: 'request' rate of {k} must be > 0 Hz, got {hz!r}")
        if not imu_dt > 0:
            raise ValueError(f"MAVLink: 'imu_dt' must be positive, got {imu_dt!r}")
        self.imu_dt = imu_dt
        self.timesync_s = timesync_s
        self.stale_s = stale_s
        self.key = signing_key_from(signing_key) if signing_key is not None else None
        self.mav = self._new_parser(source_system, source_component)
        self.clock = ClockSync()
        self.fc: tuple[int, int] | None = None  # (sysid, compid) of the FC once its HEARTBEAT is seen
        self.local_address: Any = None
        self.counts_by_type: dict[str, int] = {}  # handled messages by type
        self.messages = 0  # every valid message (any type) from the accepted system
        self._sink: Sink | None = None
        self._proto: _Stream | None = None
        self._last_seq: dict[tuple[int, int], int] = {}
        self._last_imu: dict[tuple[str, int], int] = {}  # (stream, id) -> FC time ns
        self._last_rx_ns = 0
        self._backoff = Backoff()
        self._handlers = {
            "GPS_RAW_INT": self._gps_raw,
            "GPS2_RAW": self._gps_raw,
            "GPS_INPUT": self._gps_input,
            "HIL_GPS": self._hil_gps,
            "SCALED_PRESSURE": self._pressure,
            "HIGHRES_IMU": self._highres,
            "HIL_SENSOR": self._highres,
            "SCALED_IMU": self._scaled,
            "SCALED_IMU2": self._scaled,
            "SCALED_IMU3": self._scaled,
            "RAW_IMU": self._scaled,
            "TIMESYNC": self._timesync,
            "HEARTBEAT": self._heartbeat,
        }

    def _new_parser(self, sysid: int, compid: int) -> Any:
        mav = mavlink.MAVLink(None, srcSystem=sysid, srcComponent=compid)
        mav.robust_parsing = True
        if self.key is not None:
            mav.signing.secret_key = self.key
            mav.signing.link_id = 1
            mav.signing.sign_outgoing = True
            # 10 µs units since 2015-01-01 (MAVLink signing spec)
            mav.signing.timestamp = int((time.time() - 1420070400) * 100_000)
            mav.signing.allow_unsigned_callback = None
        return mav

    @classmethod
    def from_config(cls, cfg: dict[str, Any]) -> MavlinkDriver:
        """``{"type": "mavlink", "url": "udpin:0.0.0.0:14550", "system_id": 1, "signing_key": "...",
        "request": {"GPS_RAW_INT": 5}, "emit": ["gnss", "baro"], "imu_dt": 0.01, "stale_s": 3}``."""
        known = {"type", "url", "name", "system_id", "source_system", "source_component", "signing_key"}
        known |= {"request", "emit", "imu_dt", "timesync_s", "stale_s"}
        bad = set(cfg) - known
        if bad:
            raise ValueError(f"MAVLink config: unknown key(s) {sorted(bad)} (known: {sorted(known)})")
        if "url" not in cfg:
            raise ValueError("MAVLink config: missing key 'url' (e.g. 'udpin:0.0.0.0:14550')")
        kw: dict[str, Any] = {k: v for k, v in cfg.items() if k not in ("type", "url")}
        if "emit" in kw:
            kw["emit"] = set(kw["emit"])
        return cls(str(cfg["url"]), **kw)

    # ------------------------------------------------------------ bytes → messages → samples
    def feed(self, data: bytes, now_ns: int | None = None) -> bool:
        """Parse bytes from the transport; deliver samples. True if a valid message was in them."""
        now = time.monotonic_ns() if now_ns is None else now_ns
        h = self.health
        try:
            msgs = self.mav.parse_buffer(data)
        except Exception as e:  # pymavlink raises on some malformed input even when robust
            h.count("parse_error")
            h.last_error = f"{type(e).__name__}: {e}"
            self.mav.buf = bytearray()
            self.mav.buf_index = 0
            return False
        if not msgs:
            return False
        good = False
        for m in msgs:
            t = m.get_type()
            if t == "BAD_DATA":
                reason = str(getattr(m, "reason", ""))
                if "signature" in reason:
                    h.count("bad_signature")
                elif "CRC" in reason:
                    h.count("crc")
                elif "prefix" in reason:
                    h.count("garbage_bytes", len(m.get_msgbuf()))
                elif "length" in reason:
                    h.count("length")
                else:
                    h.count("bad_data")
                continue
            if t == "UNKNOWN" or t.startswith("UNKNOWN"):
                h.count("unknown_message")
                continue
            sysid, compid = m.get_srcSystem(), m.get_srcComponent()
            if self.system_id is not None and sysid != self.system_id:
                h.count("unknown_system")
                continue
            good = True
            self.messages += 1
            self._last_rx_ns = now
            seq = m.get_seq()
            key = (sysid, compid)
            last = self._last_seq.get(key)
            if last is not None:
                d = (seq - last) & 0xFF
                if d == 0:
                    h.count("duplicate")
                    continue
                if 1 < d < 0x80:
                    h.count("seq_gap", d - 1)
            self._last_seq[key] = seq
            fn = self._handlers.get(t)
            if fn is None:
                continue
            self.counts_by_type[t] = self.counts_by_type.get(t, 0) + 1
            try:
                fn(m, now)
            except Exception as e:  # a handler bug must not kill the link
                h.count("internal")
                h.last_error = f"{t}: {type(e).__name__}: {e}"
        return good

    def _deliver(self, s: Sample, now: int) -> None:
        self.health.seen(now)
        if self._sink is not None:
            try:
                self._sink(s)
            except Exception:
                self.health.count("sink_error")

    def _time_s(self, fc_us: int, now: int) -> float:
        if fc_us > UNIX_US:  # UNIX epoch µs: map through the wall clock
            return fc_us * 1e-6 - (time.time() - time.monotonic())
        return self.clock.to_local_s(fc_us * 1000, now)

    def _gnss(
        self, now: int, t_us: int, fix: int, lat: float, lon: float, h: float, vel: Any, std: tuple, sats: int, src: int
    ) -> None:
        if "gnss" not in self.emit:
            return
        if fix < 2:
            self.health.count("no_fix")
            return
        if not all(math.isfinite(x) for x in (lat, lon, h, *std)) or (vel is not None and not np.all(np.isfinite(vel))):
            self.health.count("nonfinite")
            return
        if (
            abs(lat) > 90
            or abs(lon) > 180
            or not -1000 < h < 100_000
            or (vel is not None and np.any(np.abs(vel) > 600))
        ):
            self.health.count("range")
            return
        ft = FixType(min(fix, 6)) if fix <= 6 else FixType.FIX_3D
        self._deliver(
            GnssFix(
                t=self._time_s(t_us, now), lat=math.radians(lat), lon=math.radians(lon), h=h, vel_ned=vel,
                std_ne=std[0], std_d=std[1], std_vel=std[2], fix_type=ft, num_sats=sats, source=src,
                t_arrival_ns=now,
            ),
            now,
        )  # fmt: skip

    def _gps_raw(self, m: Any, now: int) -> None:
        h_mm = m.alt_ellipsoid if getattr(m, "alt_ellipsoid", 0) else m.alt
        std = (
            m.h_acc * 1e-3 if getattr(m, "h_acc", 0) else (m.eph * 0.01 if 0 < m.eph < 65535 else 2.5),
            m.v_acc * 1e-3 if getattr(m, "v_acc", 0) else (m.epv * 0.01 if 0 < m.epv < 65535 else 5.0),
            m.vel_acc * 1e-3 if getattr(m, "vel_acc", 0) else 0.3,
        )
        src = 1 if m.get_type() == "GPS2_RAW" else 0
        self._gnss(
            now, m.time_usec, m.fix_type, m.lat * 1e-7, m.lon * 1e-7, h_mm * 1e-3, None, std, m.satellites_visible, src
        )

    def _gps_input(self, m: Any, now: int) -> None:
        ig = m.ignore_flags
        vel = None if ig & (8 | 16) else np.array([m.vn, m.ve, m.vd], dtype=float)
        std = (
            m.horiz_accuracy if not ig & 64 and m.horiz_accuracy > 0 else 2.5,
            m.vert_accuracy if not ig & 128 and m.vert_accuracy > 0 else 5.0,
            m.speed_accuracy if not ig & 32 and m.speed_accuracy > 0 else 0.3,
        )
        self._gnss(
            now, m.time_usec, m.fix_type, m.lat * 1e-7, m.lon * 1e-7, m.alt, vel, std, m.satellites_visible, m.gps_id
        )

    def _hil_gps(self, m: Any, now: int) -> None:
        vel = np.array([m.vn, m.ve, m.vd], dtype=float) * 0.01
        std = (m.eph * 0.01 if 0 < m.eph < 65535 else 2.5, m.epv * 0.01 if 0 < m.epv < 65535 else 5.0, 0.3)
        src = getattr(m, "id", 0)
        self._gnss(
            now, m.time_usec, m.fix_type, m.lat * 1e-7, m.lon * 1e-7, m.alt * 1e-3, vel, std, m.satellites_visible, src
        )

    def _pressure(self, m: Any, now: int) -> None:
        if "baro" not in self.emit:
            return
        p = m.press_abs * 100.0
        if not math.isfinite(p):
            self.health.count("nonfinite")
            return
        if not 100.0 <= p <= 120_000.0:
            self.health.count("range")
            return
        self._deliver(
            BaroSample(t=self.clock.to_local_s(m.time_boot_ms * 1_000_000, now), pressure=p,
                       temperature=m.temperature * 0.01, t_arrival_ns=now),
            now,
        )  # fmt: skip

    def _imu(
        self, stream: str, iid: int, t_us: int, acc: tuple, gyro: tuple, mag: tuple | None, temp: float, now: int
    ) -> None:
        a0, a1, a2 = acc
        w0, w1, w2 = gyro
        fin = math.isfinite
        if not (fin(a0) and fin(a1) and fin(a2) and fin(w0) and fin(w1) and fin(w2)):
            self.health.count("nonfinite")
            return
        if (
            abs(w0) > MAX_GYRO
            or abs(w1) > MAX_GYRO
            or abs(w2) > MAX_GYRO
            or abs(a0) > MAX_ACCEL
            or abs(a1) > MAX_ACCEL
            or abs(a2) > MAX_ACCEL
        ):
            self.health.count("range")
            return
        fc_ns = t_us * 1000
        key = (stream, iid)
        last = self._last_imu.get(key)
        dt = self.imu_dt
        if last is not None:
            if fc_ns <= last:
                self.health.count("duplicate" if fc_ns == last else "time_backwards")
                if last - fc_ns > 5_000_000_000:  # FC rebooted: restart this stream
                    self._last_imu.pop(key, None)
                return
            d = (fc_ns - last) * 1e-9
            if d <= 0.5:
                dt = d
            else:
                self.health.count("time_jump")
        self._last_imu[key] = fc_ns
        t = self._time_s(t_us, now)
        if "imu" in self.emit:
            # point samples → increments by the rectangular rule: Δθ = ω·dt, Δv = f·dt
            self._deliver(
                ImuSample(t, dt, np.array((w0 * dt, w1 * dt, w2 * dt)), np.array((a0 * dt, a1 * dt, a2 * dt)), iid,
                          0, temp, 0, now),
                now,
            )  # fmt: skip
        if mag is not None and "mag" in self.emit:
            if not all(fin(x) for x in mag):
                self.health.count("nonfinite")
            elif max(abs(x) for x in mag) > MAX_MAG_GAUSS:
                self.health.count("range")
            else:
                self._deliver(MagSample(t=t, field_b=np.array(mag) * 1e-4, source=iid, t_arrival_ns=now), now)

    def _highres(self, m: Any, now: int) -> None:
        upd = m.fields_updated
        mag = (m.xmag, m.ymag, m.zmag) if upd & 0x1C0 else None
        if upd and not upd & 0x3F:  # neither accel nor gyro updated in this message
            if mag is not None and "mag" in self.emit:
                self._imu_mag_only(m, mag, now)
            return
        self._imu(m.get_type(), getattr(m, "id", 0), m.time_usec, (m.xacc, m.yacc, m.zacc),
                  (m.xgyro, m.ygyro, m.zgyro), mag, m.temperature, now)  # fmt: skip

    def _imu_mag_only(self, m: Any, mag: tuple, now: int) -> None:
        if all(math.isfinite(x) for x in mag) and max(abs(x) for x in mag) <= MAX_MAG_GAUSS:
            t = self._time_s(m.time_usec, now)
            self._deliver(
                MagSample(t=t, field_b=np.array(mag) * 1e-4, source=getattr(m, "id", 0), t_arrival_ns=now), now
            )
        else:
            self.health.count("range")

    def _scaled(self, m: Any, now: int) -> None:
        t = m.get_type()
        t_us = m.time_usec if t == "RAW_IMU" else m.time_boot_ms * 1000
        iid = {"SCALED_IMU": 0, "SCALED_IMU2": 1, "SCALED_IMU3": 2}.get(t, getattr(m, "id", 0))
        g = 9.80665e-3
        mag = (m.xmag * 1e-3, m.ymag * 1e-3, m.zmag * 1e-3) if (m.xmag or m.ymag or m.zmag) else None
        temp = m.temperature * 0.01 if getattr(m, "temperature", 0) else math.nan
        self._imu(t, iid, t_us, (m.xacc * g, m.yacc * g, m.zacc * g),
                  (m.xgyro * 1e-3, m.ygyro * 1e-3, m.zgyro * 1e-3), mag, temp, now)  # fmt: skip

    def _timesync(self, m: Any, now: int) -> None:
        if m.tc1 == 0:  # the FC asks: answer with our clock
            self.send(self.mav.timesync_encode(now, m.ts1))
        elif not self.clock.reply(m.tc1, m.ts1, now):
            self.health.count("timesync_bad")

    def _heartbeat(self, m: Any, now: int) -> None:
        if (
            m.type in (mavlink.MAV_TYPE_GCS, mavlink.MAV_TYPE_ONBOARD_CONTROLLER)
            or m.autopilot == mavlink.MAV_AUTOPILOT_INVALID
        ):
            return
        first = self.fc is None
        self.fc = (m.get_srcSystem(), m.get_srcComponent())
        if first:
            self.request_streams()

    # ------------------------------------------------------------ output
    def send(self, msg: Any) -> None:
        p = self._proto
        if p is None or p.transport is None:
            return
        try:
            buf = msg.pack(self.mav)
            self.mav.seq = (self.mav.seq + 1) % 256
            if self.kind == "udpin":
                if p.peer is not None:
                    p.transport.sendto(buf, p.peer)
            elif self.kind == "udpout":
                p.transport.sendto(buf)
            else:
                p.transport.write(buf)
        except Exception as e:
            self.health.count("tx_error")
            self.health.last_error = f"send: {e}"

    def request_streams(self) -> None:
        """Ask the FC for the messages we need (MAV_CMD_SET_MESSAGE_INTERVAL each)."""
        if self.fc is None:
            return
        for name, hz in self.request.items():
            mid = getattr(mavlink, f"MAVLINK_MSG_ID_{name}")
            self.send(
                self.mav.command_long_encode(
                    self.fc[0], self.fc[1], mavlink.MAV_CMD_SET_MESSAGE_INTERVAL, 0, mid, 1e6 / hz, 0, 0, 0, 0, 0
                )
            )

    async def _periodic(self) -> None:
        n = 0
        while True:
            self.send(
                self.mav.heartbeat_encode(mavlink.MAV_TYPE_ONBOARD_CONTROLLER, mavlink.MAV_AUTOPILOT_INVALID, 0, 0, 0)
            )
            self.send(self.mav.timesync_encode(0, time.monotonic_ns()))
            n += 1
            if n % 10 == 0:  # re-request: FCs forget after a reboot
                self.request_streams()
            await asyncio.sleep(self.timesync_s)

    # ------------------------------------------------------------ run
    async def _open(self, loop: asyncio.AbstractEventLoop) -> _Stream:
        tr: Any
        pr: Any
        if self.kind == "udpin":
            tr, pr = await loop.create_datagram_endpoint(lambda: _Stream(self), local_addr=(self.host, self.port))
        elif self.kind == "udpout":
            tr, pr = await loop.create_datagram_endpoint(lambda: _Stream(self), remote_addr=(self.host, self.port))
        elif self.kind == "tcp":
            tr, pr = await loop.create_connection(lambda: _Stream(self), self.host, self.port)
        else:
            tr, pr = await serial_asyncio_fast.create_serial_connection(
                loop, lambda: _Stream(self), self.host, baudrate=self.port
            )
        proto: _Stream = pr
        proto.transport = tr
        with contextlib.suppress(Exception):
            self.local_address = tr.get_extra_info("sockname")
        return proto

    async def run(self, sink: Sink) -> None:
        """Connect, parse, deliver; re-open with backoff on loss or silence, until cancelled."""
        self._sink = sink
        loop = asyncio.get_running_loop()
        first = True
        while True:
            try:
                proto = await self._open(loop)
            except Exception as e:
                self.health.count("open_failed")
                self.health.last_error = f"open {self.url}: {e}"
                await self._backoff.wait()
                continue
            if not first:
                self.health.reconnects += 1
            first = False
            self._proto = proto
            self.health.connected = True
            self._last_rx_ns = time.monotonic_ns()
            n0 = self.health.samples
            periodic = asyncio.create_task(self._periodic())
            try:
                while not proto.lost.done():
                    await asyncio.wait([proto.lost], timeout=min(0.5, self.stale_s))
                    if self.stale_s > 0 and (time.monotonic_ns() - self._last_rx_ns) * 1e-9 > self.stale_s:
                        self.health.count("silence")
                        self.health.last_error = f"no MAVLink for {self.stale_s} s"
                        break
                else:
                    self.health.count("link_lost")
                    self.health.last_error = proto.lost.result()
            finally:
                periodic.cancel()
                with contextlib.suppress(BaseException):
                    await periodic
                self.health.connected = False
                self._proto = None
                self.fc = None
                with contextlib.suppress(Exception):
                    proto.transport.close()
            if self.health.samples > n0:
                self._backoff.reset()
            await self._backoff.wait()
