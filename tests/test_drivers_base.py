"""Driver contract helpers: health snapshot (rate, age, counters) and reconnect backoff."""

from __future__ import annotations

import math

from ins_hil.drivers.base import Backoff, DriverHealth


def test_health_rate_age_and_snapshot() -> None:
    h = DriverHealth("imu")
    assert math.isinf(h.age_s(10**9))
    h.rate_hz(0)  # starts the window
    for k in range(1, 201):
        h.seen(k * 5_000_000)  # 200 Hz for 1 s
    assert h.rate_hz(1_000_000_000) == 200.0
    h.count("crc")
    h.count("crc", 2)
    snap = h.snapshot(1_250_000_000)
    assert snap["errors"] == {"crc": 3} and snap["age_s"] == 0.25 and snap["samples"] == 200
    assert h.rate_hz(5_000_000_000) == 0.0  # silent for 4 s: the rate decays to zero


def test_snapshot_before_any_sample() -> None:
    snap = DriverHealth("gnss").snapshot(10**9)
    assert snap["age_s"] is None and snap["rate_hz"] == 0.0 and snap["connected"] is False


def test_backoff_grows_to_cap_and_resets() -> None:
    b = Backoff(first=0.1, cap=1.0)
    d = [b.next_delay() for _ in range(8)]
    assert 0.08 <= d[0] <= 0.12 and all(x <= 1.2 for x in d) and d[-1] >= 0.8
    b.reset()
    assert b.next_delay() <= 0.12
