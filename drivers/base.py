"""The contract between drivers and the runtime.

A driver turns bytes from one transport into typed samples
(:mod:`ins_hil.types`) and hands each to a ``sink`` callable supplied by the
runtime. ``sink`` never blocks (the runtime's bounded queue counts any drop).
``run`` loops until cancelled: it opens the transport, reconnects with
backoff when the device disappears, and never raises for bad input (it
drops the bad frame and counts the reason in ``health``).
"""

from __future__ import annotations

import asyncio
import math
import random
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Protocol, runtime_checkable

from ins_hil.types import Sample

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
    last_error: str = ""
    _rate_n0: int = 0
    _rate_t0_ns: int = -1
    _rate_hz: float = 0.0

    def count(self, reason: str, n: int = 1) -> None:
        self.errors[reason] = self.errors.get(reason, 0) + n

    def seen(self, now_ns: int | None = None) -> None:
        self.samples += 1
        self.last_sample_ns = time.monotonic_ns() if now_ns is None else now_ns

    def rate_hz(self, now_ns: int | None = None, window_s: float = 1.0) -> float:
        """Good samples per second, averaged over windows of about ``window_s``.

        Cheap enough to call from a status view at any rate; decays to 0 when
        the source goes silent.
        """
        now = time.monotonic_ns() if now_ns is None else now_ns
        if self._rate_t0_ns < 0:
            self._rate_t0_ns, self._rate_n0 = now, self.samples
            return 0.0
        span = (now - self._rate_t0_ns) * 1e-9
        if span >= window_s:
            self._rate_hz = (self.samples - self._rate_n0) / span
            self._rate_t0_ns, self._rate_n0 = now, self.samples
        elif self.last_sample_ns and (now - self.last_sample_ns) * 1e-9 > 2 * window_s:
            self._rate_hz = 0.0
        return self._rate_hz

    def snapshot(self, now_ns: int | None = None) -> dict[str, object]:
        """A JSON-friendly summary: rate (Hz), last-seen age (s), counters."""
        age = self.age_s(now_ns)
        return {
            "name": self.name,
            "connected": self.connected,
            "samples": self.samples,
            "rate_hz": round(self.rate_hz(now_ns), 2),
            "age_s": None if math.isinf(age) else round(age, 3),
            "reconnects": self.reconnects,
            "errors": dict(self.errors),
            "last_error": self.last_error,
        }

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


class Backoff:
    """Exponential reconnect backoff with jitter: 0.1 s, 0.2 s, ... up to ``cap`` s.

    ``reset()`` after a connection delivered data; ``await wait()`` before
    each re-open.
    """

    def __init__(self, first: float = 0.1, cap: float = 5.0, factor: float = 2.0) -> None:
        self.first, self.cap, self.factor = first, cap, factor
        self.delay = first

    def reset(self) -> None:
        self.delay = self.first

    def next_delay(self) -> float:
        d = self.delay
        self.delay = min(self.cap, self.delay * self.factor)
        return d * (0.8 + 0.4 * random.random())

    async def wait(self) -> None:
        await asyncio.sleep(self.next_delay())


def finite(*xs: float) -> bool:
    """True if every value is finite (no NaN/Inf)."""
    return all(math.isfinite(x) for x in xs)
