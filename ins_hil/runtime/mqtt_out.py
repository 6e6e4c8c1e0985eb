"""MQTT publisher (aiomqtt): fused state, health (retained) and fault events (QoS 1).

Topics under ``topic_prefix`` (default ``ins_hil``):

- ``<prefix>/state``: JSON, QoS 0, at ``state_rate`` Hz (newest state, older ones coalesced)::

    {"t": 12.345,                 # sensor time (s)
     "seq": 1234,                 # state message counter
     "lat_deg": 50.45, "lon_deg": 30.52, "h_m": 180.2,   # WGS84, ellipsoidal height
     "vel_ned": [vn, ve, vd],     # m/s
     "q_nb": [q0, q1, q2, q3],    # Hamilton, scalar first, body FRD → NED
     "euler_deg": [roll, pitch, yaw],
     "std_pos_m": [n, e, d], "std_vel_ms": [n, e, d], "std_att_deg": [n, e, d],
     "gyro_bias": [...],          # rad/s, body FRD
     "accel_bias": [...],         # m/s², body FRD
     "aligned": true, "test_ratios": {"...": 0.3}}

- ``<prefix>/fault``: JSON per FaultEvent, QoS 1 (kept in a bounded queue
  while the broker is away and sent after reconnect)::

    {"t": 30.0, "sensor": "gyro[3]", "mode": "STEP_BIAS", "magnitude": 0.01,
     "isolated": true, "cleared": false, "detail": ""}

- ``<prefix>/health``: JSON, QoS 1, retained, every second: the runtime
  metrics snapshot (rates, latencies, counters, FDI state) with the host's
  wall-clock time of publication, ``"time_utc"`` (ISO 8601 UTC, e.g.
  ``"2026-01-05T12:00:00.123Z"``) and ``"time_unix"`` (s since 1970, UTC).
- ``<prefix>/online``: retained ``"1"`` while running; ``"0"`` on a clean stop
  (published before disconnecting) and as the last will (process killed,
  link lost).

Security: ``username``/``password`` log in to the broker (a password needs a user name); ``tls = true``
encrypts the connection and checks the broker's certificate (``tls_ca``: its CA, else the system's;
``tls_cert``/``tls_key``: a client certificate; ``tls_insecure``: no certificate check at all, for tests). A password
without TLS is warned about at start: it would cross the network in clear text.

The publisher is its own task: a broker outage never touches the IMU path.
It reconnects with exponential backoff (0.2 s … 5 s); states due while
disconnected are counted as ``state_dropped_offline``. Connecting, losing
the broker and each new connect error are reported once (log and
``metrics.warn``), not on every retry.
"""

from __future__ import annotations

import asyncio
import contextlib
import datetime
import json
import logging
import math
import ssl
import time
from collections import deque
from dataclasses import dataclass
from typing import Any

from ins_hil.nav.rotation import euler_from_quat
from ins_hil.runtime.metrics import RuntimeMetrics
from ins_hil.settings import setting
from ins_hil.types import FaultEvent, NavState

_log = logging.getLogger("ins_hil")


@dataclass
class MqttConfig:
    """The ``[mqtt]`` table."""

    enabled: bool = setting(True, help="publish state/fault/health to an MQTT broker (reconnects with backoff)")
    host: str = setting("127.0.0.1", help="broker host", nonempty=True)
    port: int = setting(1883, "", "[1, 65535]", "broker port")
    topic_prefix: str = setting(
        "ins_hil", help="topics <prefix>/state, <prefix>/fault, <prefix>/health (no + or #)", nonempty=True
    )
    state_rate: float = setting(10.0, "Hz", "0 | [0.01, 1000]", "state messages per second; 0 = none")
    health_period: float = setting(1.0, "s", "[0.01, 3600]", "period of the health message")
    client_id: str = setting("", help="MQTT client id; '' = generated")
    username: str = setting("", help="'' = anonymous")
    password: str = setting("", help="with username")
    tls: bool = setting(False, help="TLS to the broker")
    tls_ca: str = setting("", help="CA certificate file; '' = system CAs", file=True)
    tls_cert: str = setting("", help="client certificate file; '' = none", file=True)
    tls_key: str = setting("", help="client key file; '' = none", file=True)
    tls_insecure: bool = setting(False, help="do not verify the broker's certificate nor its host name (tests only)")
    keepalive: int = setting(10, "s", "[1, 65535]", "MQTT keep-alive")


def state_json(st: NavState, seq: int) -> dict[str, Any]:
    e = euler_from_quat(st.q_nb)
    return {
        "t": st.t,
        "seq": seq,
        "lat_deg": math.degrees(st.lat),
        "lon_deg": math.degrees(st.lon),
        "h_m": st.h,
        "vel_ned": [float(x) for x in st.vel_ned],
        "q_nb": [float(x) for x in st.q_nb],
        "euler_deg": [math.degrees(float(x)) for x in e],
        "std_pos_m": [float(x) for x in st.std_pos],
        "std_vel_ms": [float(x) for x in st.std_vel],
        "std_att_deg": [math.degrees(float(x)) for x in st.std_att],
        "gyro_bias": [float(x) for x in st.gyro_bias],
        "accel_bias": [float(x) for x in st.accel_bias],
        "aligned": bool(st.aligned),
        "test_ratios": {k: float(v) for k, v in st.test_ratios.items()},
    }


def wall_clock(t: float | None = None) -> dict[str, Any]:
    """The host's wall-clock time ``t`` (s since 1970, UTC; default now) as the health fields
    ``time_utc`` (ISO 8601, UTC, ms) and ``time_unix`` (s)."""
    t = time.time() if t is None else t
    iso = datetime.datetime.fromtimestamp(t, datetime.UTC).isoformat(timespec="milliseconds")
    return {"time_utc": iso.replace("+00:00", "Z"), "time_unix": t}


def fault_json(ev: FaultEvent) -> dict[str, Any]:
    mag = ev.magnitude
    return {
        "t": ev.t,
        "sensor": ev.sensor,
        "mode": ev.mode.name,
        "magnitude": mag if math.isfinite(mag) else None,
        "isolated": ev.isolated,
        "cleared": ev.cleared,
        "detail": ev.detail,
    }


class MqttPublisher:
    """State/health/fault publisher with reconnect; ``offer_*`` never block."""

    def __init__(self, cfg: MqttConfig, metrics: RuntimeMetrics) -> None:
        self.cfg = cfg
        self.metrics = metrics
        self.name = "mqtt"
        self.connected = False
        self.connects = 0
        self._latest: NavState | None = None
        self._faults: deque[FaultEvent] = deque(maxlen=1000)
        self._wake = asyncio.Event()
        self._seq = 0
        self._period_ns = round(1e9 / cfg.state_rate) if cfg.state_rate > 0 else 0
        self._next_ns = 0
        self._task: asyncio.Task[None] | None = None
        self.last_error = ""
        self._closing = False  # close() asked the connected client to say online "0" and disconnect
        self._reported = ""  # the connect error last reported (once per distinct text)

    def offer(self, st: NavState, arrival_ns: int, ready_ns: int) -> None:
        self._latest = st
        if not self._period_ns:
            return
        now = time.monotonic_ns()
        if now >= self._next_ns:
            self._next_ns = max(self._next_ns + self._period_ns, now)
            if self.connected:
                self._wake.set()
            else:
                self.metrics.output(self.name, "state_dropped_offline")

    def offer_fault(self, ev: FaultEvent) -> None:
        if len(self._faults) == self._faults.maxlen:
            self.metrics.output(self.name, "fault_dropped_overflow")
        self._faults.append(ev)
        self._wake.set()

    async def start(self) -> None:
        c = self.cfg
        if c.password and not c.tls:
            self.metrics.warn(f"mqtt: the password for {c.username!r} goes to {c.host}:{c.port} in clear text "
                              "(set tls = true, and the broker's TLS port, usually 8883)")  # fmt: skip
        self._task = asyncio.create_task(self._run(), name="mqtt")

    async def close(self) -> None:
        """Stop: when connected, publish the last health and ``online`` = "0" (retained) and disconnect
        cleanly (at most ~3 s); else just stop retrying."""
        if self._task is None:
            return
        if self.connected and not self._task.done():
            self._closing = True
            self._wake.set()
            with contextlib.suppress(TimeoutError, asyncio.CancelledError):
                await asyncio.wait_for(asyncio.shield(self._task), 3.0)
        if not self._task.done():
            self._task.cancel()
        with contextlib.suppress(asyncio.CancelledError, TimeoutError):
            await asyncio.wait_for(self._task, 5.0)

    def _offline(self, err: str) -> None:
        """A connect failure or a lost broker: reported once per distinct error text."""
        self.last_error = err
        was = self.connected
        self.connected = False
        if was or err != self._reported:
            self._reported = err
            c = self.cfg
            what = "lost the broker" if was else "cannot connect to"
            self.metrics.warn(f"mqtt: {what} {c.host}:{c.port}: {err} (retrying)")

    async def _run(self) -> None:
        import aiomqtt

        c = self.cfg
        p = c.topic_prefix
        backoff = 0.2
        tls_context = None
        if c.tls:
            tls_context = ssl.create_default_context(cafile=c.tls_ca or None)
            if c.tls_cert:
                tls_context.load_cert_chain(c.tls_cert, c.tls_key or None)
            if c.tls_insecure:
                tls_context.check_hostname = False
                tls_context.verify_mode = ssl.CERT_NONE
        while True:
            try:
                async with aiomqtt.Client(
                    c.host,
                    c.port,
                    identifier=c.client_id or None,
                    username=c.username or None,
                    password=c.password or None,
                    keepalive=c.keepalive,
                    tls_context=tls_context,
                    tls_insecure=c.tls_insecure if c.tls else None,
                    will=aiomqtt.Will(f"{p}/online", b"0", qos=1, retain=True),
                    timeout=3.0,
                ) as client:
                    self.connected = True
                    self.connects += 1
                    self._reported = ""
                    backoff = 0.2
                    self.metrics.output(self.name, "connects")
                    _log.info("mqtt: connected to %s:%d (topics %s/...)", c.host, c.port, p)
                    await client.publish(f"{p}/online", b"1", qos=1, retain=True, timeout=2.0)
                    await self._serve(client)
                    if self._closing:  # online "0" published: leave (the context disconnects cleanly)
                        self.connected = False
                        return
            except (aiomqtt.MqttError, OSError) as e:
                if self._closing:
                    self.connected = False
                    return
                self._offline(str(e) or type(e).__name__)
            self.connected = False
            await asyncio.sleep(backoff)
            backoff = min(5.0, backoff * 2)

    async def _serve(self, client: Any) -> None:
        p = self.cfg.topic_prefix
        next_health = 0.0
        while True:
            try:
                await asyncio.wait_for(self._wake.wait(), timeout=self.cfg.health_period)
            except TimeoutError:
                pass
            self._wake.clear()
            closing = self._closing
            while self._faults:
                ev = self._faults[0]
                await client.publish(f"{p}/fault", json.dumps(clean_json(fault_json(ev))), qos=1, timeout=2.0)
                self._faults.popleft()
                self.metrics.output(self.name, "faults")
            st = self._latest
            if st is not None and self._period_ns:
                self._latest = None
                self._seq += 1
                await client.publish(
                    f"{p}/state", json.dumps(clean_json(state_json(st, self._seq))), qos=0, timeout=2.0
                )
                self.metrics.output(self.name, "states")
            now = time.monotonic()
            if now >= next_health or closing:
                next_health = now + self.cfg.health_period
                snap = {**self.metrics.snapshot(), **wall_clock()}
                await client.publish(f"{p}/health", json.dumps(clean_json(snap)), qos=1, retain=True, timeout=2.0)
                self.metrics.output(self.name, "health")
            if closing:
                await client.publish(f"{p}/online", b"0", qos=1, retain=True, timeout=2.0)
                self.metrics.output(self.name, "offline_sent")
                return


def clean_json(x: Any) -> Any:
    """Replace non-finite floats by None (JSON has no NaN/inf)."""
    if isinstance(x, float):
        return x if math.isfinite(x) else None
    if isinstance(x, dict):
        return {k: clean_json(v) for k, v in x.items()}
    if isinstance(x, list | tuple):
        return [clean_json(v) for v in x]
    return x
