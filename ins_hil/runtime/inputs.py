"""MAVLink input for the runtime's GNSS/baro (stop-gap until the drivers branch's MAVLink driver lands).

``MavlinkUdpDriver`` reads GNSS/baro MAVLink 2 over UDP and follows the
:class:`ins_hil.drivers.base.Driver` contract (``name``, ``health``,
``async run(sink)``, non-blocking sink, never raise on bad input). The
serial IMU is read by :class:`ins_hil.drivers.serial_imu.SerialImuDriver`.

:class:`MavReceiver` is the signed-link-aware MAVLink 2 parser shared with
the output endpoints: with a key it accepts only correctly signed messages
and counts the rejected ones (``unsigned``, ``bad_signature``).
"""

from __future__ import annotations

import asyncio
import math
import time
from typing import Any

import numpy as np

from ins_hil.drivers.base import DriverHealth, Sink
from ins_hil.sim.sensors import altitude_from_pressure
from ins_hil.types import BaroSample, FixType, GnssFix

_RAD = math.pi / 180.0


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


def decode_aiding(m: Any, t_arrival_ns: int) -> GnssFix | BaroSample | None:
    """GPS_INPUT / GPS_RAW_INT → GnssFix, SCALED_PRESSURE(2/3) → BaroSample (SI units); else None."""
    typ = m.get_type()
    if typ == "GPS_INPUT":
        if m.fix_type < FixType.FIX_2D:
            return None
        return GnssFix(
            t=m.time_usec * 1e-6,
            lat=m.lat * 1e-7 * _RAD,
            lon=m.lon * 1e-7 * _RAD,
            h=float(m.alt),
            vel_ned=np.array((m.vn, m.ve, m.vd), dtype=np.float64),
            std_ne=float(m.horiz_accuracy) if m.horiz_accuracy > 0 else 2.5,
            std_d=float(m.vert_accuracy) if m.vert_accuracy > 0 else 5.0,
            std_vel=float(m.speed_accuracy) if m.speed_accuracy > 0 else 0.3,
            fix_type=FixType(min(int(m.fix_type), 6)),
            num_sats=int(m.satellites_visible),
            source=m.get_srcSystem(),
            t_arrival_ns=t_arrival_ns,
        )
    if typ == "GPS_RAW_INT":
        if m.fix_type < FixType.FIX_2D:
            return None
        alt = getattr(m, "alt_ellipsoid", 0) or m.alt
        return GnssFix(
            t=m.time_usec * 1e-6,
            lat=m.lat * 1e-7 * _RAD,
            lon=m.lon * 1e-7 * _RAD,
            h=alt * 1e-3,
            vel_ned=None,  # GPS_RAW_INT has no vertical velocity
            std_ne=(getattr(m, "h_acc", 0) or 2500) * 1e-3,
            std_d=(getattr(m, "v_acc", 0) or 5000) * 1e-3,
            fix_type=FixType(min(int(m.fix_type), 6)),
            num_sats=int(m.satellites_visible),
            source=m.get_srcSystem(),
            t_arrival_ns=t_arrival_ns,
        )
    if typ in ("SCALED_PRESSURE", "SCALED_PRESSURE2", "SCALED_PRESSURE3"):
        p = m.press_abs * 100.0
        return BaroSample(
            t=m.time_boot_ms * 1e-3,
            pressure=p,
            altitude=altitude_from_pressure(p),
            temperature=m.temperature * 0.01,
            source=m.get_srcSystem(),
            t_arrival_ns=t_arrival_ns,
        )
    return None


class MavlinkUdpDriver:
    """GNSS/baro MAVLink 2 over UDP, listening on ``host:port``; ``key`` → only signed messages."""

    def __init__(self, name: str, host: str, port: int, key: bytes | None = None, sysid: int = 0) -> None:
        self.name = name
        self.host, self.port = host, port
        self.health = DriverHealth(name)
        self.rx = MavReceiver(key)
        self.sysid = sysid  # 0 = any
        self.bound = asyncio.Event()
        self.messages: dict[str, int] = {}

    def _on_data(self, data: bytes, sink: Sink) -> None:
        now = time.monotonic_ns()
        before = dict(self.rx.counts)
        for m in self.rx.feed(data):
            typ = m.get_type()
            self.messages[typ] = self.messages.get(typ, 0) + 1
            if self.sysid and m.get_srcSystem() != self.sysid:
                continue
            try:
                s = decode_aiding(m, now)
            except (ValueError, OverflowError):
                self.health.count("range")
                continue
            if s is not None:
                self.health.seen(now)
                sink(s)
        for k in ("unsigned", "bad_signature", "bad_data"):
            d = self.rx.counts[k] - before[k]
            if d:
                self.health.count(k, d)

    async def run(self, sink: Sink) -> None:
        loop = asyncio.get_running_loop()
        drv = self

        class _Proto(asyncio.DatagramProtocol):
            def datagram_received(self, data: bytes, addr: Any) -> None:
                drv._on_data(data, sink)

        transport, _ = await loop.create_datagram_endpoint(_Proto, local_addr=(self.host, self.port))
        self.port = transport.get_extra_info("sockname")[1]
        self.health.connected = True
        self.bound.set()
        try:
            await asyncio.Future()  # until cancelled
        finally:
            transport.close()
            self.health.connected = False
