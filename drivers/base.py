"""The contract between drivers and the runtime.

A driver turns bytes from one transport into typed samples
(:mod:`ins_hil.types`) and hands each to a ``sink`` callable supplied by the
runtime. ``sink`` never blocks (the runtime's bounded queue counts any drop).
``run`` loops until cancelled: it opens the transport, reconnects with
backoff when the device disappears, and never raises for bad input (it
drops the bad frame and counts the reason in ``health``).
"""

from __future__ import annotations

import time
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Protocol, runtime_checkable

from ins_hil.types import BaroSample, GnssFix, ImuSample, MagSample

Sample = ImuSample | GnssFix | BaroSample | MagSample
Sink = Callable[[Sample], None]


@dataclass
class DriverHealth:
    """Health of one driver, read by the runtime's status view and MQTT health.

    ``errors`` counts every dropped frame or byte run by reason (e.g. "crc",
    "seq_gap", "nonfinite", "unknown_node"); ``connected`` says whether the
    transport is open; ``reconnects`` counts re-opens after a loss.
    """

    name: str
    connected: bool = False
    samples: int = 0
    last_sample_ns: int = 0
    reconnects: int = 0
    errors: dict[str, int] = field(default_factory=dict)

    def count(self, reason: str, n: int = 1) -> None:
        self.errors[reason] = self.errors.get(reason, 0) + n

    def seen(self, now_ns: int | None = None) -> None:
        self.samples += 1
        self.last_sample_ns = time.monotonic_ns() if now_ns is None else now_ns

    def age_s(self, now_ns: int | None = None) -> float:
        """Seconds since the last good sample (inf if none yet)."""
        if not self.last_sample_ns:
            return float("inf")
        now = time.monotonic_ns() if now_ns is None else now_ns
        return (now - self.last_sample_ns) * 1e-9


@runtime_checkable
class Driver(Protocol):
    """An input driver (serial IMU, CAN IMU, MAVLink GNSS/baro/IMU)."""

    name: str
    health: DriverHealth

    async def run(self, sink: Sink) -> None:
        """Read, decode and deliver samples until cancelled."""
        ...
