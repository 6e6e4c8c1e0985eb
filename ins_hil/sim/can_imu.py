"""Simulated CAN IMU nodes on a python-can bus: a DroneCAN node and a DBC-profile IMU.

``DroneCanImuNode`` sends ``uavcan.equipment.ahrs.RawIMU`` (multi-frame,
7 frames per sample) at ``rate_hz`` plus, at ``aux_hz``, Fix2,
MagneticFieldStrength2, StaticPressure and its NodeStatus; ``DbcImuNode``
sends IMU_GYRO / IMU_ACCEL pairs of ``configs/imu_dbc.dbc``. Both sit still
and level (accelerometer (0, 0, −g), body FRD) with optional noise, and can
``frames(n)`` ahead of time for benchmarks. ``send_frames`` writes a list of
frames to a bus, pacing itself so a receiver's socket buffer is not flooded.
"""

from __future__ import annotations

import asyncio
import math
import time
from collections.abc import Iterator
from dataclasses import dataclass, field

import can
import numpy as np

from ins_hil.drivers import dronecan_codec as dc
from ins_hil.drivers.dbc_codec import DEFAULT_DBC, encode_imu_frames
from ins_hil.types import GnssFix, ImuSample

G = 9.80665


@dataclass
class DroneCanImuNode:
    """A DroneCAN IMU/GNSS/mag/baro node (node id ``node_id``) — see module doc."""

    node_id: int = 10
    rate_hz: float = 200.0
    aux_hz: float = 5.0
    noise: float = 0.0
    lat_deg: float = 50.45
    lon_deg: float = 30.52
    h_m: float = 180.0
    seed: int = 1
    t0_us: int = 1_000_000
    _n: int = 0
    _tids: dict[int, int] = field(default_factory=dict)

    def __post_init__(self) -> None:
        self._rng = np.random.default_rng(self.seed)

    def _tid(self, dtid: int) -> int:
        t = self._tids.get(dtid, 0)
        self._tids[dtid] = (t + 1) & 0x1F
        return t

    def _frames(self, dtid: int, payload: bytes, priority: int = 16) -> list[can.Message]:
        cid = dc.message_can_id(dtid, self.node_id, priority)
        return [
            can.Message(arbitration_id=cid, data=d, is_extended_id=True)
            for d in dc.split_transfer(dtid, payload, self._tid(dtid))
        ]

    def imu_sample(self) -> ImuSample:
        """The next (still, level) sample."""
        dt = 1.0 / self.rate_hz
        self._n += 1
        f = np.array([0.0, 0.0, -G])
        w = np.zeros(3)
        if self.noise:
            f = f + self._rng.normal(0, self.noise, 3)
            w = w + self._rng.normal(0, self.noise * 0.01, 3)
        return ImuSample(t=self.t0_us * 1e-6 + self._n * dt, dt=dt, dtheta=w * dt, dvel=f * dt, seq=self._n)

    def imu_frames(self) -> list[can.Message]:
        return self._frames(dc.DTID_RAW_IMU, dc.raw_imu_payload(self.imu_sample()))

    def aux_frames(self) -> list[can.Message]:
        """Fix2 + MagneticFieldStrength2 + StaticPressure + NodeStatus."""
        fix = GnssFix(
            t=0.0, lat=math.radians(self.lat_deg), lon=math.radians(self.lon_deg), h=self.h_m,
            vel_ned=np.zeros(3), num_sats=12,
        )  # fmt: skip
        from ins_hil.nav.earth import pressure_from_altitude

        usec = round(self.t0_us + self._n * 1e6 / self.rate_hz)
        out = self._frames(dc.DTID_FIX2, dc.fix2_payload(fix, usec))
        out += self._frames(dc.DTID_MAG2, dc.mag_payload((19e-6, 1e-6, 45e-6)))
        out += self._frames(dc.DTID_STATIC_PRESSURE, dc.pressure_payload(pressure_from_altitude(self.h_m)))
        out += self._frames(dc.DTID_NODE_STATUS, dc.node_status_payload(self._n // max(1, int(self.rate_hz))), 24)
        return out

    def frames(self, n: int) -> Iterator[can.Message]:
        """Frames of ``n`` IMU samples, with the aux messages interleaved at ``aux_hz``."""
        every = max(1, round(self.rate_hz / self.aux_hz)) if self.aux_hz > 0 else 0
        for i in range(n):
            yield from self.imu_frames()
            if every and i % every == 0:
                yield from self.aux_frames()


@dataclass
class DbcImuNode:
    """An IMU speaking the DBC profile (IMU_GYRO + IMU_ACCEL per sample)."""

    dbc: str = str(DEFAULT_DBC)
    rate_hz: float = 200.0
    noise: float = 0.0
    seed: int = 1
    _n: int = 0

    def __post_init__(self) -> None:
        import cantools

        self.db = cantools.database.load_file(self.dbc)
        self._rng = np.random.default_rng(self.seed)

    def sample_frames(self) -> list[can.Message]:
        w = np.zeros(3)
        f = np.array([0.0, 0.0, -G])
        if self.noise:
            f = f + self._rng.normal(0, self.noise, 3)
            w = w + self._rng.normal(0, self.noise * 0.01, 3)
        fr = encode_imu_frames(self.db, (w[0], w[1], w[2]), (f[0], f[1], f[2]), self._n)
        self._n += 1
        return [can.Message(arbitration_id=i, data=d, is_extended_id=False) for i, d in fr]

    def frames(self, n: int) -> Iterator[can.Message]:
        for _ in range(n):
            yield from self.sample_frames()


async def send_frames(bus: can.BusABC, frames: list[can.Message], rate_hz: float, burst: int = 64) -> int:
    """Send ``frames`` at about ``rate_hz`` frames/s, ``burst`` at a time; returns how many were sent.

    A full TX queue (ENOBUFS) waits and retries instead of dropping."""
    sent = 0
    t0 = time.monotonic()
    for i in range(0, len(frames), burst):
        for m in frames[i : i + burst]:
            for _ in range(200):
                try:
                    bus.send(m, timeout=0.01)
                    break
                except can.CanOperationError:
                    await asyncio.sleep(0.001)
            else:
                continue
            sent += 1
        due = t0 + (i + burst) / rate_hz
        await asyncio.sleep(max(0.0, due - time.monotonic()))
    return sent
