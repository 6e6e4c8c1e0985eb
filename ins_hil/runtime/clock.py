"""Sensor clock ↔ host monotonic clock, from arrival times.

The IMU's own clock (serial frame ``t_us``, CAN timestamps) drives the core.
Aiding inputs whose driver maps times onto the host's monotonic clock (the
MAVLink driver does, with TIMESYNC) are brought onto the IMU clock here:
``t_imu = t_host − offset`` with ``offset = min(arrival − t_sensor)`` over
the IMU samples of the current and previous window (``window_s``). The
minimum is the transport's smallest latency (≈0.1 ms on a pty), and the two
windows let the estimate follow a slow drift between the clocks.
"""

from __future__ import annotations

import math


class SensorClock:
    """Windowed-minimum estimate of (host monotonic s − sensor s) for one sensor."""

    __slots__ = ("_cur", "_prev", "_win_end", "window_s")

    def __init__(self, window_s: float = 10.0) -> None:
        self.window_s = window_s
        self._cur = math.inf
        self._prev = math.inf
        self._win_end = -math.inf

    def update(self, t_sensor: float, arrival_ns: int) -> None:
        """One sample with its sensor time (s) and host arrival time (ns)."""
        if not arrival_ns:
            return
        a = arrival_ns * 1e-9
        if a > self._win_end:
            self._prev, self._cur = self._cur, math.inf
            self._win_end = a + self.window_s
        d = a - t_sensor
        if d < self._cur:
            self._cur = d

    @property
    def offset(self) -> float | None:
        """host − sensor (s), or None before the first sample."""
        o = min(self._cur, self._prev)
        return None if o == math.inf else o

    def to_sensor(self, t_host: float) -> float | None:
        """A host-monotonic time (s) on the sensor's clock (None until the clock is known)."""
        o = self.offset
        return None if o is None else t_host - o
