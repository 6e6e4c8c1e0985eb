"""Latency histograms and counters of the real-time loop.

Everything here is cheap enough for the IMU path (an O(1) bucket increment
per sample, no allocation). The status view, MQTT health and the soak test
read the same :class:`RuntimeMetrics` through :meth:`RuntimeMetrics.snapshot`,
a plain JSON-able dict.

Latencies are in nanoseconds of ``time.monotonic_ns()``:
``arrival_to_state`` = bytes arrived → fused state ready (core returned),
``state_to_sent`` = state ready → MAVLink message handed to the transport,
``arrival_to_sent`` = the sum, end to end.
"""

from __future__ import annotations

import logging
import math
import time
from dataclasses import dataclass, field
from typing import Any

# log-spaced buckets: 1 µs · 1.04^k, k = 0..N-1 (4 % resolution), up to ~ 60 s
_BASE_NS = 1000.0
_RATIO = 1.04
_LOG_RATIO = math.log(_RATIO)
_NBUCKETS = 460


def _bucket(ns: int) -> int:
    """Bucket index of a duration ns ≥ 0."""
    k = int(math.log(ns / _BASE_NS) / _LOG_RATIO) if ns > _BASE_NS else 0
    return k if k < _NBUCKETS else _NBUCKETS - 1


class LatencyHistogram:
    """Log-bucketed histogram of durations (ns) with exact count, min, max and mean.

    Percentiles are returned as the geometric centre of the bucket that holds
    them (relative error ≤ 2 %); values below 1 µs go to bucket 0.
    """

    __slots__ = ("buckets", "count", "max_ns", "min_ns", "sum_ns")

    def __init__(self) -> None:
        self.buckets = [0] * _NBUCKETS
        self.count = 0
        self.sum_ns = 0
        self.min_ns = 0
        self.max_ns = 0

    def record(self, ns: int) -> None:
        """Add one duration (ns)."""
        if ns < 0:
            ns = 0
        self.add(_bucket(ns), ns)

    def add(self, k: int, ns: int) -> None:
        """Add one duration ``ns`` (≥ 0) whose bucket ``k`` is known (:func:`_bucket`)."""
        self.buckets[k] += 1
        if self.count == 0 or ns < self.min_ns:
            self.min_ns = ns
        if ns > self.max_ns:
            self.max_ns = ns
        self.count += 1
        self.sum_ns += ns

    def reset(self) -> None:
        self.buckets = [0] * _NBUCKETS
        self.count = self.sum_ns = self.min_ns = self.max_ns = 0

    def merge(self, other: LatencyHistogram) -> None:
        for i, c in enumerate(other.buckets):
            self.buckets[i] += c
        if other.count:
            self.min_ns = other.min_ns if not self.count else min(self.min_ns, other.min_ns)
            self.max_ns = max(self.max_ns, other.max_ns)
        self.count += other.count
        self.sum_ns += other.sum_ns

    def percentile(self, p: float) -> float:
        """The p-th percentile (0..100) in ns; nan when empty."""
        if self.count == 0:
            return float("nan")
        target = max(1, math.ceil(self.count * p / 100.0))
        acc = 0
        for k, c in enumerate(self.buckets):
            acc += c
            if acc >= target:
                if k == 0:
                    return min(_BASE_NS, float(self.max_ns))
                v = _BASE_NS * _RATIO ** (k + 0.5)
                return min(max(v, float(self.min_ns)), float(self.max_ns))
        return float(self.max_ns)

    def summary(self) -> dict[str, float]:
        """count, mean, min, p50, p99, p99.9, max (µs)."""
        n = self.count
        return {
            "count": n,
            "mean_us": (self.sum_ns / n) * 1e-3 if n else float("nan"),
            "min_us": self.min_ns * 1e-3 if n else float("nan"),
            "p50_us": self.percentile(50) * 1e-3,
            "p99_us": self.percentile(99) * 1e-3,
            "p999_us": self.percentile(99.9) * 1e-3,
            "max_us": self.max_ns * 1e-3 if n else float("nan"),
        }


@dataclass
class SourceStats:
    """Per-input counters: received samples, drops by reason, rate estimate (Hz)."""

    name: str
    received: int = 0
    dropped: dict[str, int] = field(default_factory=dict)
    clock_events: dict[str, int] = field(default_factory=dict)  # driver clock re-anchors/wraps (not drops)
    rate_hz: float = 0.0
    _win_n: int = 0
    _win_t0: int = 0

    def drop(self, reason: str, n: int = 1) -> None:
        self.dropped[reason] = self.dropped.get(reason, 0) + n

    def driver_drops(self, errors: dict[str, int]) -> None:
        """A driver's (or frame parser's) cumulative error counters as the drops ``driver_<reason>``
        (its count of accepted ``frames``, if any, is no drop; its ``clock_*`` events — a wrap or a
        re-anchor of the sensor clock, drivers/clock.py — go to ``clock_events``)."""
        for k, v in errors.items():
            if k.startswith("clock_"):
                self.clock_events[k] = v
            elif k != "frames":
                self.dropped["driver_" + k] = v

    def tick_rate(self, now_ns: int) -> None:
        """Update ``rate_hz`` over ~1 s windows (called from the status tick)."""
        r = _window_rate(self, self.received, now_ns)
        if r is not None:
            self.rate_hz = r


def _window_rate(w: Any, count: int, now_ns: int) -> float | None:
    """The one ~1 s rate window of ``SourceStats`` and ``SensorHealth`` (fields ``_win_t0`` ns, ``_win_n``):
    the rate (1/s) of cumulative ``count`` over a window that closes at ``now_ns``, else None."""
    if w._win_t0 == 0:
        w._win_t0, w._win_n = now_ns, count
        return None
    el = (now_ns - w._win_t0) * 1e-9
    if el < 1.0:
        return None
    r = (count - w._win_n) / el
    w._win_t0, w._win_n = now_ns, count
    return r


#: sensor kinds of SYS_STATUS / the health view; aiding sample class → kind
SENSOR_KINDS = ("imu", "gnss", "baro", "mag")
_AID_KIND = {"GnssFix": "gnss", "BaroSample": "baro", "MagSample": "mag"}
#: a source with no sample for max(this, ``LOST_PERIODS`` periods at its learnt rate) is lost (s)
LOST_AFTER_S = 0.5
LOST_PERIODS = 5.0


@dataclass
class SensorHealth:
    """Arrival health of one sensor kind (all inputs of that kind together).

    ``configured``: an input that delivers this kind is in the config; ``present``: configured or
    seen. ``rate_hz``: samples/s over the last ~1 s window; ``expected_hz``: the highest window rate
    seen (the source's own rate). ``healthy``: samples arrive, the newest within
    max(LOST_AFTER_S, LOST_PERIODS / expected_hz), and the last window's rate is ≥ half the expected.
    """

    kind: str
    configured: bool = False
    count: int = 0
    last_ns: int = 0
    rate_hz: float = 0.0
    expected_hz: float = 0.0
    healthy: bool = False
    lost_events: int = 0
    _win_n: int = 0
    _win_t0: int = 0
    _rate_t0: int = 0  # start of the window rate_hz was measured over (ns)
    _fresh_since: int = 0  # first sample after the source was last not fresh (ns), 0 = not fresh

    @property
    def present(self) -> bool:
        return self.configured or self.count > 0

    def update(self, count: int, now_ns: int) -> str:
        """New cumulative ``count`` at ``now_ns``; returns "lost", "back" or "" (a transition).

        Fresh: the newest sample within max(LOST_AFTER_S, LOST_PERIODS / expected_hz). Healthy:
        fresh, and the last full ~1 s window that began after the source became fresh again
        has a rate ≥ half the expected one (a window holding the gap is not judged, so a
        source that comes back is "back" after its first full window, without flapping)."""
        if count != self.count:
            self.count, self.last_ns = count, now_ns
        t0 = self._win_t0
        r = _window_rate(self, count, now_ns)
        if r is not None:
            self.rate_hz = r
            self.expected_hz = max(self.expected_hz, r)
            self._rate_t0 = t0
        if self.count == 0:
            return ""
        timeout = LOST_AFTER_S if self.expected_hz <= 0 else max(LOST_AFTER_S, LOST_PERIODS / self.expected_hz)
        fresh = (now_ns - self.last_ns) * 1e-9 <= timeout
        if not fresh:
            self._fresh_since = 0
        elif self._fresh_since == 0:
            self._fresh_since = self.last_ns
        judged = self.expected_hz > 0 and self._rate_t0 >= self._fresh_since
        rate_ok = self.rate_hz >= 0.5 * self.expected_hz
        if self.healthy:
            ok = fresh and (rate_ok or not judged)
        else:
            ok = fresh and (self.expected_hz <= 0 or (judged and rate_ok))
        was, self.healthy = self.healthy, ok
        if was and not ok:
            self.lost_events += 1
            return "lost"
        if ok and not was and self.lost_events:
            return "back"
        return ""


class RuntimeMetrics:
    """All counters and histograms of one gateway run (the API read by status, MQTT and soak).

    ``hist`` holds cumulative histograms, ``window`` the same over the last
    completed window (``roll_window`` swaps them, every ~5 s by the loop).
    """

    HISTS = ("arrival_to_state", "state_to_sent", "arrival_to_sent", "core_step")

    def __init__(self, late_threshold_s: float = 0.005) -> None:
        self.t_start_ns = time.monotonic_ns()
        self.late_threshold_ns = int(late_threshold_s * 1e9)
        self.hist: dict[str, LatencyHistogram] = {k: LatencyHistogram() for k in self.HISTS}
        self.window: dict[str, LatencyHistogram] = {k: LatencyHistogram() for k in self.HISTS}
        self._cur: dict[str, LatencyHistogram] = {k: LatencyHistogram() for k in self.HISTS}
        self.sources: dict[str, SourceStats] = {}
        self.imu_epochs = 0
        self.late = 0
        self.fused: dict[str, int] = {}
        self.outputs: dict[str, dict[str, int]] = {}
        self.faults = 0
        self.last_fault = ""
        self.aligned = False
        self.test_ratios: dict[str, float] = {}
        self.fdi_state = "ok"
        self.queue_depth_max = 0
        self.warnings: list[str] = []
        self.scheduling = ""  # the gateway process's scheduling policy (ins_hil.runtime.rt.policy)
        self.sensors: dict[str, SensorHealth] = {k: SensorHealth(k) for k in SENSOR_KINDS}
        self.sensor_events: list[tuple[int, str]] = []  # (MAV_SEVERITY, text) of lost/back transitions
        self._imu_sources: list[str] = []
        self._aid_counts: dict[str, int] = dict.fromkeys(SENSOR_KINDS, 0)

    # -- recording (hot path) ------------------------------------------------
    def source(self, name: str) -> SourceStats:
        s = self.sources.get(name)
        if s is None:
            s = self.sources[name] = SourceStats(name)
        return s

    def expect_inputs(self, inputs: list[tuple[str, str]]) -> None:
        """The configured inputs as (name, type): IMU counts come from the IMU inputs' ``received``
        (no extra work on the IMU path); a ``mavlink`` input is expected to deliver GNSS and baro."""
        self._imu_sources = [n for n, t in inputs if t in ("serial_imu", "can_imu")]
        self.sensors["imu"].configured = bool(self._imu_sources)
        if any(t == "mavlink" for _, t in inputs):
            self.sensors["gnss"].configured = self.sensors["baro"].configured = True

    def aid_seen(self, s: object) -> None:
        """An aiding sample (GnssFix, BaroSample, MagSample) arrived (aiding rate only)."""
        k = _AID_KIND.get(type(s).__name__)
        if k is not None:
            self._aid_counts[k] += 1

    def record(self, key: str, ns: int) -> None:
        if ns < 0:
            ns = 0
        k = _bucket(ns)  # once for the cumulative and the window histogram
        self.hist[key].add(k, ns)
        self._cur[key].add(k, ns)

    def record_state(self, arrival_ns: int, ready_ns: int, core_ns: int) -> None:
        """One IMU epoch processed: arrival→state latency, core time, late counter."""
        self.imu_epochs += 1
        if arrival_ns:
            d = ready_ns - arrival_ns
            self.record("arrival_to_state", d)
            if d > self.late_threshold_ns:
                self.late += 1
        self.record("core_step", core_ns)

    def record_sent(self, arrival_ns: int, ready_ns: int, sent_ns: int) -> None:
        """A state went out: state ready → the first (highest-rate) MAVLink message of that state handed
        to the transport (``state_to_sent``), and IMU arrival → that moment (``arrival_to_sent``)."""
        self.record("state_to_sent", sent_ns - ready_ns)
        if arrival_ns:
            self.record("arrival_to_sent", sent_ns - arrival_ns)

    def output(self, endpoint: str, what: str, n: int = 1) -> None:
        d = self.outputs.get(endpoint)
        if d is None:
            d = self.outputs[endpoint] = {}
        d[what] = d.get(what, 0) + n

    def warn(self, text: str) -> None:
        """A warning for a person: kept (the last 20: status view, MQTT health) and logged (``ins_hil``)."""
        logging.getLogger("ins_hil").warning(text)
        self.warnings.append(text)
        del self.warnings[:-20]

    # -- periodic ---------------------------------------------------------------
    def roll_window(self) -> None:
        self.window, self._cur = self._cur, self.window
        for h in self._cur.values():
            h.reset()

    def tick(self, now_ns: int | None = None) -> None:
        now = time.monotonic_ns() if now_ns is None else now_ns
        for s in self.sources.values():
            s.tick_rate(now)
        self._tick_sensors(now)

    def _tick_sensors(self, now: int) -> None:
        """Sensor health (:class:`SensorHealth`) and its lost/back transitions as ``sensor_events``."""
        counts = dict(self._aid_counts)
        src = self.sources
        counts["imu"] = sum(src[n].received for n in self._imu_sources if n in src)
        for k, h in self.sensors.items():
            ev = h.update(counts[k], now)
            if ev == "lost":
                self.sensor_events.append((3, f"{k.upper()} lost: no data"))  # MAV_SEVERITY_ERROR
            elif ev == "back":
                self.sensor_events.append((5, f"{k.upper()} back"))  # MAV_SEVERITY_NOTICE
        del self.sensor_events[:-20]

    def drain_sensor_events(self) -> list[tuple[int, str]]:
        ev, self.sensor_events = self.sensor_events, []
        return ev

    # -- reading ------------------------------------------------------------------
    def dropped_total(self) -> int:
        return sum(sum(s.dropped.values()) for s in self.sources.values())

    def snapshot(self) -> dict[str, Any]:
        """A JSON-able copy of every counter and the histogram summaries (µs)."""
        return {
            "uptime_s": (time.monotonic_ns() - self.t_start_ns) * 1e-9,
            "imu_epochs": self.imu_epochs,
            "late": self.late,
            "late_threshold_ms": self.late_threshold_ns * 1e-6,
            "sources": {
                n: {
                    "received": s.received,
                    "rate_hz": s.rate_hz,
                    "dropped": dict(s.dropped),
                    "clock_events": dict(s.clock_events),
                }
                for n, s in self.sources.items()
            },
            "fused": dict(self.fused),
            "outputs": {k: dict(v) for k, v in self.outputs.items()},
            "latency": {k: h.summary() for k, h in self.hist.items()},
            "latency_window": {k: h.summary() for k, h in self.window.items()},
            "faults": self.faults,
            "last_fault": self.last_fault,
            "fdi_state": self.fdi_state,
            "aligned": self.aligned,
            "test_ratios": dict(self.test_ratios),
            "queue_depth_max": self.queue_depth_max,
            "warnings": list(self.warnings),
            "scheduling": self.scheduling,
            "sensors": {
                k: {"present": h.present, "healthy": h.healthy, "rate_hz": h.rate_hz, "expected_hz": h.expected_hz}
                for k, h in self.sensors.items()
            },
        }
