"""A simulated flight controller speaking MAVLink 2 over UDP (pymavlink), for tests and demos.

It sends HEARTBEAT (1 Hz), GPS_RAW_INT (``gps_hz``, 5–10 Hz; ``alt`` MSL through the EGM96
geoid, ``alt_ellipsoid`` WGS84, as the MAVLink spec has them), an IMU message
(``imu_msg``: HIGHRES_IMU, SCALED_IMU or RAW_IMU at ``imu_hz``, 50–250 Hz),
SCALED_PRESSURE (10 Hz), answers TIMESYNC requests with its own boot clock
(which starts ``boot_offset_s`` before our monotonic clock, so a receiver's
clock-offset estimate can be checked), answers TIMESYNC replies to its own
requests are ignored, and records COMMAND_LONG SET_MESSAGE_INTERVAL requests.
The vehicle sits still, level, at (lat, lon, h): accelerometer reads
(0, 0, −g) (specific force, body FRD), gyro zero, plus optional white noise.

It binds ``bind`` (default 127.0.0.1, any port) and sends to ``target``;
like ArduPilot's UDP client outputs, it also replies to whoever talks to it.
"""

from __future__ import annotations

import asyncio
import math
import time
from dataclasses import dataclass, field
from typing import Any

import numpy as np
from pymavlink.dialects.v20 import ardupilotmega as mavlink

from ins_hil.geoid import msl_height
from ins_hil.nav.earth import pressure_from_altitude

G = 9.80665


@dataclass
class SimFlightController:
    """A pymavlink-based simulated FC (see module doc). Run with ``await fc.run()``."""

    target: tuple[str, int]
    bind: tuple[str, int] = ("127.0.0.1", 0)
    sysid: int = 1
    compid: int = 1
    gps_hz: float = 10.0
    imu_hz: float = 200.0
    imu_msg: str = "HIGHRES_IMU"
    baro_hz: float = 10.0
    lat_deg: float = 50.45
    lon_deg: float = 30.52
    h_m: float = 180.0  # WGS84 ellipsoidal height (m)
    alt_ellipsoid: bool = True  # GPS_RAW_INT fills alt_ellipsoid (else 0: alt, MSL, only)
    boot_offset_s: float = 1234.5  # the FC booted this long before our monotonic zero... roughly
    noise: float = 0.0
    signing_key: bytes | None = None
    seed: int = 1
    sent: dict[str, int] = field(default_factory=dict)
    interval_requests: list[tuple[int, float]] = field(default_factory=list)
    timesync_answered: int = 0

    def __post_init__(self) -> None:
        if self.imu_msg not in ("HIGHRES_IMU", "SCALED_IMU", "RAW_IMU"):
            raise ValueError(f"imu_msg must be HIGHRES_IMU, SCALED_IMU or RAW_IMU, got {self.imu_msg!r}")
        self.mav = mavlink.MAVLink(None, srcSystem=self.sysid, srcComponent=self.compid)
        self.mav.robust_parsing = True
        if self.signing_key is not None:
            self.mav.signing.secret_key = self.signing_key
            self.mav.signing.link_id = 0
            self.mav.signing.sign_outgoing = True
            self.mav.signing.timestamp = int((time.time() - 1420070400) * 100_000)
        self._rng = np.random.default_rng(self.seed)
        self._boot_ns = time.monotonic_ns() - int(self.boot_offset_s * 1e9)
        self._tr: Any = None
        self._peer: tuple[str, int] | None = None
        self.local_address: tuple[str, int] | None = None
        self.tamper: Any = None  # optional callable(bytes) -> bytes|None, to inject faults in tests

    def fc_time_ns(self, mono_s: float | None = None) -> int:
        """The FC's boot clock (ns), now or at our monotonic time ``mono_s``."""
        now = time.monotonic_ns() if mono_s is None else int(mono_s * 1e9)
        return now - self._boot_ns

    # ------------------------------------------------------------ I/O
    def _send(self, msg: Any) -> None:
        buf = msg.pack(self.mav)
        self.mav.seq = (self.mav.seq + 1) % 256
        name = msg.get_type()
        self.sent[name] = self.sent.get(name, 0) + 1
        if self.tamper is not None:
            buf = self.tamper(buf)
            if buf is None:
                return
        if self._tr is not None:
            self._tr.sendto(buf, self._peer or self.target)

    def _received(self, data: bytes, addr: tuple[str, int]) -> None:
        msgs = self.mav.parse_buffer(data) or []
        for m in msgs:
            t = m.get_type()
            if t == "TIMESYNC" and m.tc1 == 0:
                self._send(self.mav.timesync_encode(self.fc_time_ns(), m.ts1))
                self.timesync_answered += 1
            elif t == "COMMAND_LONG" and m.command == mavlink.MAV_CMD_SET_MESSAGE_INTERVAL:
                self.interval_requests.append((int(m.param1), float(m.param2)))
                self._send(self.mav.command_ack_encode(m.command, mavlink.MAV_RESULT_ACCEPTED))

    # ------------------------------------------------------------ messages
    def _imu(self, at: float) -> Any:
        n = self.noise
        acc = np.array([0.0, 0.0, -G]) + (self._rng.normal(0, n, 3) if n else 0.0)
        gyr = np.zeros(3) + (self._rng.normal(0, n * 0.01, 3) if n else 0.0)
        mag_g = (0.19, 0.01, 0.45)  # gauss, body = NED (level, yaw 0)
        t_ns = self.fc_time_ns(at)  # stamped at the sampling instant, not the send time
        if self.imu_msg == "HIGHRES_IMU":
            return self.mav.highres_imu_encode(
                t_ns // 1000, *acc, *gyr, *mag_g, pressure_from_altitude(self.h_m) / 100.0, 0.0, self.h_m, 25.0, 0x1FFF
            )
        g = 1e3 / G
        vals = (*(round(a * g) for a in acc), *(round(w * 1e3) for w in gyr), *(round(m * 1e3) for m in mag_g))
        if self.imu_msg == "SCALED_IMU":
            return self.mav.scaled_imu_encode(t_ns // 1_000_000, *vals, 2500)
        return self.mav.raw_imu_encode(t_ns // 1000, *vals, 0, 2500)

    def _gps(self, at: float) -> Any:
        """GPS_RAW_INT as the spec has it: ``alt`` MSL (EGM96), ``alt_ellipsoid`` WGS84 (``h_m``), or 0 with
        ``alt_ellipsoid = False`` (as ArduPilot sends it when its GPS driver knows no undulation)."""
        msl = msl_height(math.radians(self.lat_deg), math.radians(self.lon_deg), self.h_m)
        return self.mav.gps_raw_int_encode(
            self.fc_time_ns(at) // 1000, 3, round(self.lat_deg * 1e7), round(self.lon_deg * 1e7),
            round(msl * 1e3), 80, 120, 0, 0, 12, round(self.h_m * 1e3) if self.alt_ellipsoid else 0, 1500, 2500, 200,
            0,
        )  # fmt: skip

    def _baro(self, at: float) -> Any:
        p = pressure_from_altitude(self.h_m)
        return self.mav.scaled_pressure_encode(self.fc_time_ns(at) // 1_000_000, p / 100.0, 0.0, 2500)

    async def run(self) -> None:
        """Bind, then send until cancelled (each stream on its own schedule)."""
        loop = asyncio.get_running_loop()
        fc = self

        class P(asyncio.DatagramProtocol):
            def datagram_received(self, data: bytes, addr: tuple[str, int]) -> None:
                fc._received(data, addr)

        self._tr, _ = await loop.create_datagram_endpoint(P, local_addr=self.bind)
        self.local_address = self._tr.get_extra_info("sockname")
        streams = [
            (1.0, lambda at: self.mav.heartbeat_encode(
                mavlink.MAV_TYPE_QUADROTOR, mavlink.MAV_AUTOPILOT_ARDUPILOTMEGA, 0, 0, mavlink.MAV_STATE_ACTIVE)),
            (self.gps_hz, self._gps),
            (self.imu_hz, self._imu),
            (self.baro_hz, self._baro),
        ]  # fmt: skip
        t0 = time.monotonic()
        nxt = [t0] * len(streams)
        try:
            while True:
                now = time.monotonic()
                for i, (hz, make) in enumerate(streams):
                    while hz > 0 and now >= nxt[i]:
                        self._send(make(nxt[i]))
                        nxt[i] += 1.0 / hz
                        if nxt[i] < now - 0.1:  # fell behind (loaded machine): do not burst
                            nxt[i] = now
                wait = min(n for (hz, _), n in zip(streams, nxt) if hz > 0) - time.monotonic()
                await asyncio.sleep(max(0.0, wait))
        finally:
            self._tr.close()


def fix_from_fc(fc: SimFlightController) -> tuple[float, float, float]:
    """(lat rad, lon rad, h m) the simulated FC reports."""
    return math.radians(fc.lat_deg), math.radians(fc.lon_deg), fc.h_m
