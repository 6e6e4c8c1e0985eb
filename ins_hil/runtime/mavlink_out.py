"""MAVLink 2 output endpoints: to a ground station (as its own vehicle) or to a flight controller.

An endpoint owns one link of the MAVLink link layer (:mod:`ins_hil.drivers.mavlink_link`,
the URL grammar of the inputs too: ``udpout:host:port`` sends to a listener such as
QGroundControl on 14550; ``udpin:host:port`` listens and answers the last peer;
``tcp:host:port`` connects, with reconnect; ``tcpin:host:port`` serves TCP clients;
``serial:/dev/ttyX:baud``) and the loop hands it the newest state with :meth:`MavlinkEndpoint.offer`
(never blocks): every message whose period is due is sent right there (the
transports' writes are non-blocking), the others are coalesced to the newest
state; the endpoint's own task only sends STATUSTEXTs. Messages and rates are
configurable per endpoint. When several messages are due at the same state the
highest-rate one goes first (e.g. ODOMETRY at 50 Hz before ATTITUDE at 10 Hz and
HEARTBEAT at 1 Hz), so the latency-critical stream is not queued behind the slow ones.

The messages, by role, are built in :mod:`ins_hil.runtime.mavlink_msgs` (mixins of the endpoint):
role ``gcs`` (:mod:`~ins_hil.runtime.mavlink_msgs.gcs`): HEARTBEAT, SYS_STATUS, ATTITUDE,
ATTITUDE_QUATERNION, GLOBAL_POSITION_INT, LOCAL_POSITION_NED, GPS_RAW_INT, VFR_HUD, ESTIMATOR_STATUS,
EXTENDED_SYS_STATE, BATTERY_STATUS, HOME_POSITION, STATUSTEXT (faults, alignment, sensors lost/back); role ``fc``
(:mod:`~ins_hil.runtime.mavlink_msgs.fc`): HEARTBEAT, ODOMETRY, GPS_INPUT, HIL_STATE_QUATERNION (only
of a usable solution), SET_GPS_GLOBAL_ORIGIN.
Cost on the IMU path: the hot messages (ODOMETRY, ATTITUDE, ATTITUDE_QUATERNION, GLOBAL_POSITION_INT,
LOCAL_POSITION_NED, HEARTBEAT, SYS_STATUS) are computed in scalar floats and, on an unsigned link,
framed by :class:`~ins_hil.runtime.mavlink_msgs.common._Frame` (bytes identical to pymavlink's); a
signed link uses pymavlink's sender.

The vehicle is always there: the endpoint's task sends HEARTBEAT (and SYS_STATUS,
ESTIMATOR_STATUS, EXTENDED_SYS_STATE, BATTERY_STATUS) at their rate when no state did within
50 ms of their due time (no IMU, no solution yet), with the sensor health of
:class:`~ins_hil.runtime.metrics.SensorHealth`. It answers a ground station
(:mod:`~ins_hil.runtime.mavlink_msgs.requests`: parameters, commands, message intervals, mission
count, FTP NAK). See docs/flight_controller.md.

Signing (MAVLink 2): with a 32-byte key (``signing_key``, or ``signing_key_file`` written by
``ins-hil keygen``) every outgoing message is signed and incoming messages on the endpoint are
accepted only when correctly signed (rejections are counted in the metrics as
``rx_unsigned``/``rx_bad_signature``). Parameter writes, saves and state-changing commands are
obeyed only from the system ids in ``allowed_gcs_sysids`` (:mod:`~ins_hil.runtime.mavlink_msgs.requests`).
"""

from __future__ import annotations

import asyncio
import math
import time
from collections import deque

from ins_hil.drivers.mavlink_link import Link, MavReceiver, configure_signing, parse_url, signing_key_from
from ins_hil.runtime.mavlink_msgs.common import (
    ALL_MESSAGES,
    FC_RATES,
    GCS_RATES,
    SOLUTION_TIMEOUT_S,
    EndpointConfig,
    _Frame,
    _frame_of,
    fault_text,
    mavlink_module,
)
from ins_hil.runtime.mavlink_msgs.fc import FcMessages
from ins_hil.runtime.mavlink_msgs.gcs import GcsMessages
from ins_hil.runtime.mavlink_msgs.requests import _HANDLED, _STATELESS, Requests
from ins_hil.runtime.metrics import RuntimeMetrics
from ins_hil.types import GnssFix, NavState

# re-exported: the one URL grammar (the link layer's), the streams, rates and message helpers
__all__ = [
    "ALL_MESSAGES",
    "FC_RATES",
    "GCS_RATES",
    "SOLUTION_TIMEOUT_S",
    "EndpointConfig",
    "MavlinkEndpoint",
    "_Frame",
    "_frame_of",
    "advance_due",
    "fault_text",
    "mavlink_module",
    "parse_url",
]

#: s within which the same STATUSTEXT (severity and text) is not sent again
TEXT_REPEAT_S = 2.0
_BEAT_GRACE_NS = 50_000_000  # the task sends the 1 Hz group when no state has sent it 50 ms after it was due


def advance_due(due_ns: int, period_ns: int, now_ns: int) -> int:
    """The next due time of a stream that was due at ``due_ns`` and is sent at ``now_ns``: one period
    after the due time (the rate holds on average, whatever the phase of the states), never in the past
    (a state that comes late does not start a burst of catch-up messages). The first due time is 0: the
    first state goes out at once. (Also the null relay's ODOMETRY schedule, :mod:`ins_hil.soak.relay`.)"""
    return max(due_ns + period_ns, now_ns)


class MavlinkEndpoint(Requests, GcsMessages, FcMessages):
    """One MAVLink output endpoint (see the module docstring); the message builders by role are in
    :mod:`ins_hil.runtime.mavlink_msgs`."""

    def __init__(self, cfg: EndpointConfig, metrics: RuntimeMetrics) -> None:
        mavlink = mavlink_module()
        self.cfg = cfg
        self.name = cfg.name
        self.metrics = metrics
        self.rates = cfg.effective_rates()
        self.period_ns = {k: round(1e9 / v) for k, v in self.rates.items()}
        # highest rate first (stable for equal rates): the first message of a state is the fastest stream
        order = sorted(self.rates, key=lambda k: -self.rates[k])
        self.next_ns = dict.fromkeys(order, 0)
        secret = cfg.signing_secret()  # signing_key, or the content of signing_key_file
        key = signing_key_from(secret) if secret else None
        self.rx = MavReceiver(key)
        self.rx_messages: dict[str, int] = {}
        self.tr = Link(cfg.url, self._on_data, on_error=lambda why: metrics.output(cfg.name, "link_" + why))
        self.mav = mavlink.MAVLink(self, srcSystem=cfg.sysid, srcComponent=cfg.compid)
        configure_signing(self.mav, key, link_id=0)
        self.mav_type = getattr(mavlink, "MAV_TYPE_" + cfg.mav_type)
        self._m = mavlink
        # unsigned link: the hot messages are framed by _Frame (bytes identical to pymavlink's)
        self._fast = key is None
        self._senders = [(typ, getattr(self, "_send_" + typ.lower()), self.period_ns[typ]) for typ in order]
        self._latest: tuple[NavState, int, int] | None = None
        self._wake = asyncio.Event()
        self._texts: deque[tuple[int, str]] = deque(maxlen=32)
        self._text_sent: dict[tuple[int, str], int] = {}  # (severity, text) → when it was last queued (ns)
        self._text_id = 0  # id of the last chunked STATUSTEXT
        self._gnss: GnssFix | None = None
        self._gnss_new = False
        self._home: tuple[float, float, float] | None = None
        self._home_ecef: tuple[float, float, float] = (0.0, 0.0, 0.0)  # ECEF point of the home (m)
        self._home_cen: tuple[float, ...] = (1.0, 0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 1.0)  # C_e^n at home, row-major
        self.sent: dict[str, int] = {}
        self._t0_ns = time.monotonic_ns()
        self._task: asyncio.Task[None] | None = None
        self._next_due_ns = 0  # earliest next_ns of a message that can be sent
        self._init_vehicle()

    # -- file-like for pymavlink ----------------------------------------------
    def write(self, buf: bytes) -> None:
        if self.tr.write(buf):
            self.metrics.output(self.name, "bytes", len(buf))
            self._write_ok = True
        else:
            self.metrics.output(self.name, "not_sent")
            self._write_ok = False

    def _on_data(self, data: bytes) -> None:
        before = dict(self.rx.counts)
        for m in self.rx.feed(data):
            t = m.get_type()
            self.rx_messages[t] = self.rx_messages.get(t, 0) + 1
            if t in _HANDLED:
                self._handle(m, t)
        for k in ("unsigned", "bad_signature", "bad_data"):
            d = self.rx.counts[k] - before[k]
            if d:
                self.metrics.output(self.name, "rx_" + k, d)
        d = self.rx.counts["messages"] - before["messages"]
        if d:
            self.metrics.output(self.name, "rx_messages", d)

    # -- called by the loop (never blocks) --------------------------------------
    def offer(self, st: NavState, arrival_ns: int, ready_ns: int) -> None:
        """The newest state: the messages that are due go out now, from the caller (no task wake-up:
        the transports' writes never block), the others wait for their period with this state."""
        self._latest = (st, arrival_ns, ready_ns)
        if time.monotonic_ns() >= self._next_due_ns:
            self._send_safely()

    def offer_gnss(self, g: GnssFix) -> None:
        self._gnss, self._gnss_new = g, True
        self._update_next_due()

    def statustext(self, severity: int, text: str) -> None:
        """Queue a STATUSTEXT (sent by the endpoint's task). A text longer than 50 characters goes out in
        chunks (MAVLink 2's ``id``/``chunk_seq``; MAVProxy and MAVSDK put them together). The same text again
        within ``TEXT_REPEAT_S`` is dropped (counted as ``statustext_repeated``): a state that flaps, or a
        client retrying a refused request, gives one line, not one per event."""
        now = time.monotonic_ns()
        last = self._text_sent.get((severity, text))
        if last is not None and now - last < TEXT_REPEAT_S * 1e9:
            self.metrics.output(self.name, "statustext_repeated")
            return
        if len(self._text_sent) > 64:  # forget the old ones
            self._text_sent = {k: v for k, v in self._text_sent.items() if now - v < TEXT_REPEAT_S * 1e9}
        self._text_sent[(severity, text)] = now
        self._texts.append((severity, text))
        self._wake.set()

    async def start(self) -> None:
        await self.tr.open()
        self._task = asyncio.create_task(self._run(), name=f"mavlink-{self.name}")

    async def close(self) -> None:
        if self._task is not None:
            self._task.cancel()
            try:
                await self._task
            except asyncio.CancelledError:
                pass
        self.tr.close()

    # -- the sender task -----------------------------------------------------------
    async def _run(self) -> None:
        """STATUSTEXTs, replies, and the HEARTBEAT/SYS_STATUS/ESTIMATOR_STATUS group when no state has
        sent them within ``_BEAT_GRACE_NS`` of their due time (no IMU, no solution yet)."""
        wake = self._wake
        while True:
            due = self.next_ns.get("HEARTBEAT")
            timeout = None if due is None else max(0.0, (due + _BEAT_GRACE_NS - time.monotonic_ns()) * 1e-9)
            if timeout is None or timeout > 0.0:
                try:
                    await asyncio.wait_for(wake.wait(), timeout)
                except TimeoutError:
                    pass
            wake.clear()
            try:
                self._send_texts()  # the state's messages go out from offer() only: never a stale state again
                self._send_replies()
                self._beat()
            except Exception as e:  # a bad value must not kill the output
                self.metrics.output(self.name, "encode_error")
                self.metrics.warn(f"{self.name}: {type(e).__name__}: {e}")

    def _send_safely(self) -> None:
        try:
            self._send_due()
        except Exception as e:  # a bad value must not kill the output
            self.metrics.output(self.name, "encode_error")
            self.metrics.warn(f"{self.name}: {type(e).__name__}: {e}")

    def _count(self, typ: str) -> None:
        self.sent[typ] = self.sent.get(typ, 0) + 1
        self.metrics.output(self.name, typ)

    def _send_due(self) -> None:
        """Send every message that is due with the newest state, highest rate first, then queued STATUSTEXTs.

        Latency metric: ``RuntimeMetrics.record_sent`` is called once per state that sends anything,
        at the moment the FIRST due message (the highest-rate one, e.g. ODOMETRY) has been handed
        to the transport, so ``state_to_sent`` = state ready → first message of that state sent
        (before, it was measured after the last due message).
        """
        latest = self._latest
        if latest is not None:
            st, arrival_ns, ready_ns = latest
            now = time.monotonic_ns()
            nxt = self.next_ns
            first = True
            for typ, send, period in self._senders:
                due = nxt[typ]
                if now < due or (typ == "GPS_RAW_INT" and not self._gnss_new):
                    continue
                nxt[typ] = advance_due(due, period, now)
                if send(st) is False:  # nothing went out: no usable solution (fc role), no home yet (gcs)
                    continue
                self._count(typ)
                if first:
                    self.metrics.record_sent(arrival_ns, ready_ns, time.monotonic_ns())
                    first = False
        self._send_texts()
        if latest is not None:
            self._update_next_due()

    def _send_texts(self) -> None:
        while self._texts:
            sev, text = self._texts.popleft()
            raw = text.encode()
            if len(raw) <= 50:
                self.mav.statustext_send(sev, raw)
                self._count("STATUSTEXT")
                continue
            self._text_id = self._text_id % 0xFFFF + 1  # 1..65535: 0 is "a single-chunk text"
            # 50-byte chunks; a last chunk of exactly 50 bytes is followed by an empty one (the NUL ends it)
            for k, i in enumerate(range(0, len(raw) + 1, 50)):
                self.mav.statustext_send(sev, raw[i : i + 50], self._text_id, k)
                self._count("STATUSTEXT")

    def _update_next_due(self) -> None:
        """Earliest time a message is due (GPS_RAW_INT only once a new fix is there)."""
        nxt = self.next_ns
        self._next_due_ns = min((v for k, v in nxt.items() if k != "GPS_RAW_INT" or self._gnss_new), default=1 << 62)

    def _beat(self) -> None:
        """HEARTBEAT (and SYS_STATUS, ESTIMATOR_STATUS when streamed) when no state sent them in time."""
        nxt = self.next_ns
        due = nxt.get("HEARTBEAT")
        now = time.monotonic_ns()
        if due is None or now < due + _BEAT_GRACE_NS:
            return
        st = self._latest[0] if self._latest is not None and self._solution_valid() else None
        for typ in _STATELESS:
            d = nxt.get(typ)
            if d is not None and now >= d:
                nxt[typ] = advance_due(d, self.period_ns[typ], now)
                getattr(self, "_send_" + typ.lower())(st)
                self._count(typ)
        self._update_next_due()

    def set_rate(self, typ: str, hz: float) -> None:
        """Stream ``typ`` at ``hz`` (0 = off) from now on (PARAM_SET SR_*, MAV_CMD_SET_MESSAGE_INTERVAL)."""
        if typ not in ALL_MESSAGES:
            raise ValueError(f"{typ}: not a streamed message (known: {', '.join(ALL_MESSAGES)})")
        if not (hz >= 0.0 and math.isfinite(hz)):
            raise ValueError(f"{typ}: rate {hz!r} must be ≥ 0 Hz")
        rates = {k: v for k, v in self.rates.items() if k != typ}
        if hz > 0:
            rates[typ] = hz
        self.rates = rates
        self.period_ns = {k: round(1e9 / v) for k, v in rates.items()}
        order = sorted(rates, key=lambda k: -rates[k])
        self.next_ns = {k: self.next_ns.get(k, 0) for k in order}
        self._senders = [(t, getattr(self, "_send_" + t.lower()), self.period_ns[t]) for t in order]
        self._update_next_due()
        self._wake.set()  # the heartbeat task re-reads its due time
