"""MAVLink input from a flight controller (pymavlink parser fed from asyncio transports).

Connections (``url``): the link layer's grammar (:mod:`ins_hil.drivers.mavlink_link`, the
same for inputs and outputs, MAVProxy's):

- ``udpin:HOST:PORT``: listen; replies go to the last sender of valid MAVLink;
- ``udpout:HOST:PORT``: send to the FC's port (our HEARTBEAT opens the link);
- ``tcp:HOST:PORT``: connect (e.g. SITL's 5760); ``tcpin:HOST:PORT``: wait for the FC;
- ``serial:DEVICE[:BAUD]`` or ``/dev/DEVICE[,BAUD]`` (default 115200 baud).

Bytes from the transport are fed to pymavlink's parser in the loop's callback: no thread,
no blocking read.

Messages → samples (``ins_hil.types``, SI, body FRD as MAVLink's IMU
messages are):

- GNSS: GPS_RAW_INT (source 0), GPS2_RAW (1), GPS_INPUT (gps_id), HIL_GPS
  (id) → GnssFix. Height: always WGS84 ellipsoidal. ``alt`` of all four is MSL
  in the MAVLink spec (common.xml), so h = alt + N, N the EGM96 undulation
  (:mod:`ins_hil.geoid`); GPS_RAW_INT/GPS2_RAW's ``alt_ellipsoid`` (WGS84) is
  taken as it is when nonzero (ArduPilot sends 0 unless its GPS driver knows the
  undulation). GPS_RAW_INT/GPS2_RAW carry no vertical velocity, so their
  ``vel_ned`` is None; GPS_INPUT and HIL_GPS give vn/ve/vd. Std:
  ``h_acc``/``v_acc``/``vel_acc`` (or GPS_INPUT's accuracies, HIL_GPS's eph/epv
  as HDOP×1 m) when present. Fixes below 2D are dropped (``no_fix``). Each GNSS
  stream (message type and source) must move forward in time: a fix with the
  same time as the last (a flight controller repeating its last GPS_RAW_INT at a
  stream rate above the receiver's) is dropped (``duplicate``), one older than
  the last is dropped (``time_backwards``; more than 5 s back = the FC rebooted:
  the stream restarts, ``gnss_restart``; so it does on a new connection).
  GPS_RAW_INT/GPS2_RAW's ``time_usec`` is the FC's arrival time of the fix
  (ArduPilot ``last_fix_time_ms``, PX4 ``timestamp``), later than its time of
  validity by the FC's GNSS lag: ``fc_gnss_lag_s`` is subtracted.
  GPS_INPUT without ``time_usec`` is timed by its GPS week time (its time of
  validity, through the host's wall clock); a fix with neither by its arrival
  (which must move forward too).

- Baro: SCALED_PRESSURE → BaroSample (hPa → Pa, cdegC → °C).
- IMU where the FC is the IMU source: HIGHRES_IMU and HIL_SENSOR (m/s², rad/s,
  gauss), SCALED_IMU/2/3 and RAW_IMU (mG, mrad/s, mgauss: ArduPilot fills
  RAW_IMU with the SCALED_IMU units) → ImuSample with rates × dt:
  ``dtheta = ω·dt``, ``dvel = f·dt`` where ``dt`` is the FC-time difference
  to the previous message of the same stream (the nominal ``imu_dt`` for the
  first one or after a gap > 0.5 s). These messages are point samples, so the
  increments are rectangular-rule approximations (error O(dt²·ω̇)), fine at
  the 50–250 Hz MAVLink carries. Their magnetometer fields → MagSample
  (gauss → T) when present/updated.

Aid samples (airspeed, ...): decoders handed over by the runtime (:meth:`MavlinkDriver.set_decoders`, built
from the aid registry, ``ins_hil.aids.decoders``: this layer never imports the aids), by message type, called as
``fn(msg, t, arrival_ns)`` with ``t`` the message's ``time_boot_ms``/``time_usec`` on our clock (its arrival
when it has neither); a decoder returns the sample, None, or a reason counted in ``health``. They run beside the
driver's own handling of the same message (e.g. ``SCALED_PRESSURE``: the baro and the air density).

Sources: GNSS is taken only from ``system_id`` (when set) and ``component_id``
(when set), only in the ``gnss_messages`` types, and never from one of our own
MAVLink identities (``own_ids``: every output of the gateway, plus this link's own
``source_system``/``source_component``): a message from our own identity is
refused whole (``own_message``), GNSS from another component or of a type not
accepted is refused (``gnss_refused``). Each kind of refusal is counted and said
once (``on_warn``, else the ``ins_hil`` logger).

Time: the FC's ``time_boot_ms``/``time_usec`` are mapped onto our time base
(``time.monotonic()`` seconds, the base of ``t_arrival_ns``) with a clock offset
estimated from TIMESYNC (:class:`ClockSync`): we send ``tc1=0, ts1=now_ns`` each
``timesync_s`` (every 0.1 s while the offset is unknown or in doubt), the FC answers
``tc1=fc_ns``; a reply counts only for one of our outstanding requests with a round trip
of at most 1 s, and only when its offset agrees with the running estimate (within 10 ms +
half the round trips); the others are counted (``timesync_outlier``) and held, and three
mutually consistent ones replace the estimate (an FC reboot: ``timesync_reset``), so one
hostile or corrupted reply never moves the mapping. Until the first estimate the offset
comes from the first message's arrival (latency biased), re-anchored (``clock_reanchor``)
after three consecutive messages that disagree with it. ``time_usec`` values past year 2001
(> 1e15 µs) are UNIX time and are mapped with the host's wall clock. A sample whose mapped
time is more than ``max_skew_s`` (5 s) from its arrival is dropped (``time_implausible``),
never delivered. FC TIMESYNC requests are answered.

Our HEARTBEAT (each ``timesync_s``): MAV_TYPE_ONBOARD_CONTROLLER from ``source_system``/
``source_component`` (default: ``system_id`` or 1, component 191 = MAV_COMP_ID_ONBOARD_COMPUTER),
never a ground station's identity: ArduPilot counts any message from a GCS system id (MAV_GCS_SYSID,
formerly SYSID_MYGCS, default 255) as "GCS seen" and PX4 any heartbeat of type MAV_TYPE_GCS, which
would mask their ground-station failsafes (module ``HEARTBEAT_TYPE``).

Signing: with ``signing_key`` (32 bytes, 64 hex digits or a passphrase) only correctly
signed MAVLink 2 messages are accepted; unsigned or wrongly signed ones count as
``bad_signature``; our own messages are signed (the link layer's
:func:`~ins_hil.drivers.mavlink_link.configure_signing`).
"""

from __future__ import annotations

import asyncio
import contextlib
import logging
import math
import time
from collections import deque
from collections.abc import Callable, Iterable
from typing import Any

import numpy as np
from ins_hil.drivers.base import Backoff, DriverHealth, Sample, Sink
from ins_hil.drivers.mavlink_link import Link, MavReceiver, configure_signing, parse_url, signing_key_from
from pymavlink.dialects.v20 import ardupilotmega as mavlink

from ins_hil.geoid import ellipsoidal_height
from ins_hil.types import BaroSample, FixType, GnssFix, ImuSample, MagSample, gps_from_unix, unix_from_gps

__all__ = ["ClockSync", "MavlinkDriver", "parse_url", "signing_key_from"]

UNIX_US = 10**15  # time_usec beyond this is UNIX epoch time (after 2001-09-09)
MAX_GYRO = 40.0  # rad/s
MAX_ACCEL = 400.0  # m/s^2
MAX_MAG_GAUSS = 20.0
DEFAULT_REQUEST = {"GPS_RAW_INT": 5.0, "SCALED_PRESSURE": 10.0}
GNSS_MESSAGES = ("GPS_RAW_INT", "GPS2_RAW", "GPS_INPUT", "HIL_GPS")
MAV_COMP_ID_ONBOARD_COMPUTER = 191
#: Our HEARTBEAT's type. Not MAV_TYPE_GCS, and sent from our own system id (never 255): ArduPilot's
#: GCS_MAVLINK::handle_heartbeat (libraries/GCS_MAVLink/GCS_Common.cpp) refreshes "GCS last seen"
#: (sysid_mygcs_seen, FS_GCS) for any heartbeat whose system id is a GCS id (sysid_is_gcs: MAV_GCS_SYSID,
#: formerly SYSID_MYGCS, default 255 = pymavlink's default source system); PX4's
#: MavlinkReceiver::handle_message_heartbeat (src/modules/mavlink/mavlink_receiver.cpp) takes a heartbeat of
#: type MAV_TYPE_GCS from any system as the ground station's (NAV_DLL_ACT).
HEARTBEAT_TYPE = mavlink.MAV_TYPE_ONBOARD_CONTROLLER


class ClockSync:
    """FC clock ↔ our monotonic clock (ns): ``fc_ns = our_ns + offset_ns``, robust to wild replies.

    A TIMESYNC round trip (request sent at our ``ts1``, FC time ``tc1``, reply at our ``now``)
    gives rtt = now − ts1 and offset = tc1 − (ts1 + now)/2, whose error is at most rtt/2
    whatever the path asymmetry (the FC stamped tc1 between ts1 and now). Two samples agree when
    |o_i − o_j| ≤ ``tol_ns`` + (rtt_i + rtt_j)/2 (``tol_ns`` covers the clocks' drift).

    - A reply counts only when ``ts1`` is an outstanding request (:meth:`sent`) and
      0 ≤ rtt ≤ ``max_rtt_ns``; each request yields one accepted sample.
    - Accepted: it agrees with the estimate; it joins the last ``window`` samples and the
      estimate is the offset of their shortest round trip.
    - Otherwise it is held as a candidate (an outlier when an estimate exists); when
      ``confirm`` candidates agree with each other with no accepted sample in between, they
      become the window: the first sync, or a reset (the FC rebooted, its clock restarted).

    Before the first sync :meth:`map_ns` anchors the offset on the first message's arrival
    and re-anchors it after ``confirm`` consecutive messages that all map further than
    ``max_skew_ns`` from their arrival and agree with each other (also when TIMESYNC replies
    stopped for ``sync_timeout_ns``).
    """

    def __init__(
        self,
        window: int = 8,
        confirm: int = 3,
        tol_ns: int = 10_000_000,
        max_rtt_ns: int = 1_000_000_000,
        max_skew_ns: int = 5_000_000_000,
        sync_timeout_ns: int = 10_000_000_000,
    ) -> None:
        self.window, self.confirm, self.tol_ns = window, confirm, tol_ns
        self.max_rtt_ns, self.max_skew_ns, self.sync_timeout_ns = max_rtt_ns, max_skew_ns, sync_timeout_ns
        self.offset_ns: int | None = None
        self.rtt_ns: int | None = None
        self.synced = False
        self.outliers = 0  # replies that disagreed with the estimate
        self.resets = 0  # estimate replaced by a consistent set of new replies
        self.reanchors = 0  # arrival-based anchor moved
        self.last_sync_ns = 0  # our time of the last accepted reply
        self._acc: deque[tuple[int, int]] = deque(maxlen=window)  # accepted (rtt, offset)
        self._cand: dict[int, tuple[int, int]] = {}  # ts1 -> (rtt, offset), insertion ordered
        self._pending: deque[int] = deque(maxlen=32)  # ts1 of our outstanding requests
        self._rough: int | None = None
        self._odd: deque[int] = deque(maxlen=confirm)  # offsets of consecutive implausible messages

    @property
    def unsure(self) -> bool:
        """No estimate yet, or replies that disagree with it are waiting for confirmation."""
        return not self.synced or bool(self._cand)

    def sent(self, ts1: int) -> None:
        """A TIMESYNC request went out with our time ``ts1`` (ns)."""
        self._pending.append(ts1)

    def _agree(self, a: tuple[int, int], b: tuple[int, int]) -> bool:
        return abs(a[1] - b[1]) <= self.tol_ns + (a[0] + b[0]) // 2

    def reply(self, tc1: int, ts1: int, now_ns: int) -> str:
        """A TIMESYNC answer (tc1 = FC ns, ts1 = our ns when sent). The verdict: ``accepted``,
        ``synced`` (first estimate), ``reset`` (estimate replaced), ``outlier`` or ``pending``
        (held), ``invalid`` (round trip or tc1 implausible), ``unmatched`` (not our request)."""
        if ts1 not in self._pending:
            return "unmatched"
        rtt = now_ns - ts1
        if not 0 <= rtt <= self.max_rtt_ns or tc1 <= 0:
            return "invalid"
        smp = (rtt, tc1 - (ts1 + now_ns) // 2)
        if self.offset_ns is not None and self.rtt_ns is not None and self._agree(smp, (self.rtt_ns, self.offset_ns)):
            self._pending.remove(ts1)
            self._cand.clear()
            self._acc.append(smp)
            self.rtt_ns, self.offset_ns = min(self._acc)
            self.last_sync_ns = now_ns
            return "accepted"
        had = self.offset_ns is not None
        if had:
            self.outliers += 1
        self._cand.pop(ts1, None)
        self._cand[ts1] = smp
        while len(self._cand) > self.window:
            del self._cand[next(iter(self._cand))]
        group = [(k, c) for k, c in self._cand.items() if self._agree(c, smp)]
        if len(group) < self.confirm:
            return "outlier" if had else "pending"
        for k, _ in group:
            with contextlib.suppress(ValueError):
                self._pending.remove(k)
        self._cand.clear()
        self._acc.clear()
        self._acc.extend(c for _, c in group)
        self.rtt_ns, self.offset_ns = min(self._acc)
        self.synced = True
        self.last_sync_ns = now_ns
        self._odd.clear()
        if had:
            self.resets += 1
            return "reset"
        return "synced"

    def map_ns(self, fc_ns: int, now_ns: int) -> int | None:
        """FC time → our monotonic ns, or None when it lands more than ``max_skew_ns`` from
        ``now_ns`` (the sample's arrival)."""
        if self.synced and self.offset_ns is not None:
            off = self.offset_ns
        else:
            if self._rough is None:
                self._rough = fc_ns - now_ns
            off = self._rough
        t = fc_ns - off
        if abs(t - now_ns) <= self.max_skew_ns:
            self._odd.clear()
            return t
        o = fc_ns - now_ns
        odd = self._odd
        odd.append(o)
        if (
            len(odd) >= self.confirm
            and max(odd) - min(odd) <= self.max_skew_ns
            and (not self.synced or now_ns - self.last_sync_ns > self.sync_timeout_ns)
        ):
            self.synced = False  # TIMESYNC went quiet: fall back to the arrival anchor
            self._rough = o
            self.reanchors += 1
            odd.clear()
            return now_ns
        return None

    def to_local_s(self, fc_ns: int, now_ns: int) -> float:
        """FC time → our monotonic seconds, without the plausibility bound (the offset in use)."""
        if self.synced and self.offset_ns is not None:
            return (fc_ns - self.offset_ns) * 1e-9
        if self._rough is None:
            self._rough = fc_ns - now_ns
        return (fc_ns - self._rough) * 1e-9


class MavlinkDriver:
    """GNSS / baro / IMU / mag samples from a MAVLink flight controller (and the aids' through their decoders)."""

    #: the protocol of the aid decoders this driver takes (``ins_hil.aids.decoders``)
    decoder_protocol = "mavlink"

    def __init__(
        self,
        url: str,
        name: str = "mavlink",
        system_id: int | None = None,
        source_system: int | None = None,
        source_component: int = MAV_COMP_ID_ONBOARD_COMPUTER,
        signing_key: str | bytes | None = None,
        request: dict[str, float] | None = None,
        emit: set[str] | None = None,
        imu_dt: float = 0.01,
        timesync_s: float = 1.0,
        stale_s: float = 3.0,
        max_skew_s: float = 5.0,
        component_id: int | None = None,
        own_ids: Iterable[tuple[int, int]] = (),
        gnss_messages: Iterable[str] | None = None,
        fc_gnss_lag_s: float = 0.0,
        on_warn: Callable[[str], None] | None = None,
        gnss_refused_why: str = "",
    ) -> None:
        self.link_url = parse_url(url)
        self.kind, self.host, self.port = self.link_url
        self.url = url
        self.name = name
        self.health = DriverHealth(name)
        self.system_id = system_id
        self.emit = set(emit) if emit is not None else {"gnss", "baro", "imu", "mag"}
        bad = self.emit - {"gnss", "baro", "imu", "mag"}
        if bad:
            raise ValueError(f"MAVLink: unknown 'emit' kinds {sorted(bad)} (gnss, baro, imu, mag)")
        self.request = dict(DEFAULT_REQUEST if request is None else request)
        for k, hz in self.request.items():
            if getattr(mavlink, f"MAVLINK_MSG_ID_{k}", None) is None:
                raise ValueError(f"MAVLink: 'request' names unknown message {k!r}")
            if not hz > 0:
                raise ValueError(f"MAVLink: 'request' rate of {k} must be > 0 Hz, got {hz!r}")
        if not imu_dt > 0:
            raise ValueError(f"MAVLink: 'imu_dt' must be positive, got {imu_dt!r}")
        if not timesync_s > 0:
            raise ValueError(f"MAVLink: 'timesync_s' must be positive, got {timesync_s!r}")
        if not 0 < max_skew_s < math.inf:
            raise ValueError(f"MAVLink: 'max_skew_s' must be a positive number of seconds, got {max_skew_s!r}")
        self.gnss_messages = set(GNSS_MESSAGES if gnss_messages is None else gnss_messages)
        bad = self.gnss_messages - set(GNSS_MESSAGES)
        if bad:
            raise ValueError(f"MAVLink: unknown 'gnss_messages' {sorted(bad)} ({', '.join(GNSS_MESSAGES)})")
        if not 0 <= fc_gnss_lag_s <= 1:
            raise ValueError(f"MAVLink: 'fc_gnss_lag_s' must be in [0, 1] s, got {fc_gnss_lag_s!r}")
        src_sys = (system_id or 1) if source_system is None else source_system
        for what, v in (("source_system", src_sys), ("source_component", source_component)):
            if not 1 <= v <= 255:
                raise ValueError(f"MAVLink: '{what}' must be in [1, 255], got {v!r}")
        if src_sys == 255:
            raise ValueError("MAVLink: 'source_system' 255 is a ground station's id (it masks the FC's GCS failsafe)")
        self.component_id = component_id
        self.own_ids = {(int(a), int(b)) for a, b in own_ids} | {(src_sys, source_component)}
        self.fc_gnss_lag_us = round(fc_gnss_lag_s * 1e6)
        self.on_warn = on_warn
        self.gnss_refused_why = gnss_refused_why  # said with a GNSS type refusal (the config's reason)
        self._said: set[Any] = set()
        self._last_gnss: dict[tuple[str, int], int] = {}  # (message type, source) -> last time key (µs)
        self.imu_dt = imu_dt
        self.timesync_s = timesync_s
        self.stale_s = stale_s
        self.max_skew_s = max_skew_s
        self.key = signing_key_from(signing_key) if signing_key is not None else None
        self.mav = mavlink.MAVLink(None, srcSystem=src_sys, srcComponent=source_component)
        configure_signing(self.mav, self.key, link_id=1)
        self.rx = MavReceiver(self.key, on_reject=self._rejected)
        self.clock = ClockSync(
            max_skew_ns=round(max_skew_s * 1e9), sync_timeout_ns=round(max(5.0, 10 * timesync_s) * 1e9)
        )
        self._reanchors = 0
        self._fast_sync = 0  # TIMESYNC requests still to send at the fast cadence
        self.fc: tuple[int, int] | None = None  # (sysid, compid) of the FC once its HEARTBEAT is seen
        self.local_address: Any = None
        self.counts_by_type: dict[str, int] = {}  # handled messages by type
        self.messages = 0  # every valid message (any type) from the accepted system
        self._sink: Sink | None = None
        self._link: Link | None = None
        self._last_seq: dict[tuple[int, int], int] = {}
        self._last_imu: dict[tuple[str, int], int] = {}  # (stream, id) -> FC time ns
        self._last_rx_ns = 0
        self._backoff = Backoff()
        self._decoders: dict[str, tuple[Callable[[Any, float, int], Any], ...]] = {}
        self._last_map: tuple[tuple[int, int] | None, float | None] = (None, None)  # (FC µs, arrival) → t
        self._handlers = {
            "GPS_RAW_INT": self._gps_raw,
            "GPS2_RAW": self._gps_raw,
            "GPS_INPUT": self._gps_input,
            "HIL_GPS": self._hil_gps,
            "SCALED_PRESSURE": self._pressure,
            "HIGHRES_IMU": self._highres,
            "HIL_SENSOR": self._highres,
            "SCALED_IMU": self._scaled,
            "SCALED_IMU2": self._scaled,
            "SCALED_IMU3": self._scaled,
            "RAW_IMU": self._scaled,
            "TIMESYNC": self._timesync,
            "HEARTBEAT": self._heartbeat,
        }

    def set_decoders(self, table: dict[Any, tuple[Callable[[Any, float, int], Any], ...]]) -> None:
        """The aid decoders by MAVLink message type (see the module doc); ValueError naming an unknown type."""
        for k in table:
            if getattr(mavlink, f"MAVLINK_MSG_ID_{k}", None) is None:
                raise ValueError(f"MAVLink: an aid decoder names unknown message {k!r}")
        self._decoders = {str(k): tuple(v) for k, v in table.items()}

    def _decode(self, m: Any, decs: tuple[Callable[[Any, float, int], Any], ...], now: int) -> None:
        """Run the aid decoders of message ``m``: its FC time on our clock (else its arrival); deliver samples."""
        fc_us = m.time_boot_ms * 1000 if hasattr(m, "time_boot_ms") else getattr(m, "time_usec", None)
        if fc_us is None:
            t: float | None = now * 1e-9
        elif self._last_map[0] == (fc_us, now):  # the driver's own handler mapped this message already
            t = self._last_map[1]
        else:
            t = self._time_s(fc_us, now)
        if t is None:
            return
        for fn in decs:
            s = fn(m, t, now)
            if isinstance(s, str):
                self.health.count(s)
            elif s is not None:
                self._deliver(s, now)

    def _rejected(self, reason: str, n: int) -> None:
        """A frame the link layer's receiver rejected (unsigned counts as ``bad_signature`` here)."""
        self.health.count("bad_signature" if reason == "unsigned" else reason, n)

    @classmethod
    def from_config(cls, cfg: dict[str, Any]) -> MavlinkDriver:
        """``{"type": "mavlink", "url": "udpin:127.0.0.1:14550", "system_id": 1, "signing_key": "...",
        "request": {"GPS_RAW_INT": 5}, "emit": ["gnss", "baro"], "imu_dt": 0.01, "stale_s": 3}``."""
        known = {"type", "url", "name", "system_id", "source_system", "source_component", "signing_key"}
        known |= {"request", "emit", "imu_dt", "timesync_s", "stale_s", "max_skew_s", "component_id", "own_ids"}
        known |= {"gnss_messages", "fc_gnss_lag_s", "gnss_refused_why"}
        bad = set(cfg) - known
        if bad:
            raise ValueError(f"MAVLink config: unknown key(s) {sorted(bad)} (known: {sorted(known)})")
        if "url" not in cfg:
            raise ValueError("MAVLink config: missing key 'url' (e.g. 'udpin:127.0.0.1:14550')")
        kw: dict[str, Any] = {k: v for k, v in cfg.items() if k not in ("type", "url")}
        if "emit" in kw:
            kw["emit"] = set(kw["emit"])
        return cls(str(cfg["url"]), **kw)

    # ------------------------------------------------------------ bytes → messages → samples
    def feed(self, data: bytes, now_ns: int | None = None) -> bool:
        """Parse bytes from the transport; deliver samples. True if a valid message was in them."""
        now = time.monotonic_ns() if now_ns is None else now_ns
        h = self.health
        msgs = self.rx.feed(data)  # rejected frames are counted by _rejected
        if not msgs:
            return False
        good = False
        for m in msgs:
            t = m.get_type()
            if t == "UNKNOWN" or t.startswith("UNKNOWN"):
                h.count("unknown_message")
                continue
            sysid, compid = m.get_srcSystem(), m.get_srcComponent()
            if self.system_id is not None and sysid != self.system_id:
                h.count("unknown_system")
                continue
            if (sysid, compid) in self.own_ids:  # an output of ours (or our own traffic) routed back
                h.count("own_message")
                self._say_once(("own", sysid, compid), f"refused messages from {sysid}/{compid}, an identity the "
                               "gateway's outputs send as (our own traffic routed back, or an output configured "
                               "with another device's identity)")  # fmt: skip
                continue
            if t in GNSS_MESSAGES and not self._gnss_source_ok(t, compid):
                continue
            good = True
            self.messages += 1
            self._last_rx_ns = now
            seq = m.get_seq()
            key = (sysid, compid)
            last = self._last_seq.get(key)
            if last is not None:
                d = (seq - last) & 0xFF
                if d == 0:
                    h.count("duplicate")
                    continue
                if 1 < d < 0x80:
                    h.count("seq_gap", d - 1)
            self._last_seq[key] = seq
            fn = self._handlers.get(t)
            decs = self._decoders.get(t)
            if fn is None and decs is None:
                continue
            self.counts_by_type[t] = self.counts_by_type.get(t, 0) + 1
            try:
                if fn is not None:
                    fn(m, now)
                if decs is not None:
                    self._decode(m, decs, now)
            except Exception as e:  # a handler bug must not kill the link
                h.count("internal")
                h.last_error = f"{t}: {type(e).__name__}: {e}"
        return good

    def _gnss_source_ok(self, t: str, compid: int) -> bool:
        """GNSS only in the accepted types and from the accepted component (refusals counted, said once)."""
        if t not in self.gnss_messages:
            self.health.count("gnss_refused")
            why = self.gnss_refused_why or f"not in gnss_messages ({', '.join(sorted(self.gnss_messages))})"
            self._say_once(("type", t), f"refused {t}: {why}")
            return False
        if self.component_id is not None and compid != self.component_id:
            self.health.count("gnss_refused")
            self._say_once(("comp", compid), f"refused GNSS ({t}) from component {compid}: only from component "
                           f"{self.component_id}")  # fmt: skip
            return False
        return True

    def _say_once(self, key: Any, text: str) -> None:
        """A refusal said once per kind (``on_warn``, else the ``ins_hil`` logger); counted by the caller."""
        if key in self._said:
            return
        self._said.add(key)
        self.health.last_error = text
        if self.on_warn is not None:
            self.on_warn(text)
        else:
            logging.getLogger("ins_hil").warning("%s: %s", self.name, text)

    def _deliver(self, s: Sample, now: int) -> None:
        self.health.seen(now)
        if self._sink is not None:
            try:
                self._sink(s)
            except Exception:
                self.health.count("sink_error")

    def _time_s(self, fc_us: int, now: int) -> float | None:
        """FC time (µs since boot, or UNIX µs) → our monotonic seconds; None (counted
        ``time_implausible``) when that is more than ``max_skew_s`` from the arrival ``now``."""
        t = self._map_time(fc_us, now)
        self._last_map = ((fc_us, now), t)  # the aid decoders of the same message map it once (_decode)
        return t

    def _map_time(self, fc_us: int, now: int) -> float | None:
        if fc_us > UNIX_US:  # UNIX epoch µs: map through the wall clock
            t = fc_us * 1e-6 - (time.time() - time.monotonic())
            if abs(t - now * 1e-9) <= self.max_skew_s:
                return t
            skew = t - now * 1e-9
        else:
            c = self.clock
            t_ns = c.map_ns(fc_us * 1000, now)
            if c.reanchors != self._reanchors:
                self.health.count("clock_reanchor", c.reanchors - self._reanchors)
                self._reanchors = c.reanchors
            if t_ns is not None:
                return t_ns * 1e-9
            skew = c.to_local_s(fc_us * 1000, now) - now * 1e-9
        self.health.count("time_implausible")
        self.health.last_error = f"FC time {skew:+.3g} s from arrival (beyond max_skew_s = {self.max_skew_s} s)"
        return None

    def _gnss(
        self, now: int, t_us: int, fix: int, lat: float, lon: float, h: float, vel: Any, std: tuple, sats: int,
        src: int, week: int = 0, tow: float = math.nan, hdop: float = math.nan, vdop: float = math.nan,
        msl: bool = True, stream: str = "", lag_us: int = 0,
    ) -> None:  # fmt: skip
        """One fix: ``h`` MSL (``msl``, the MAVLink ``alt`` fields: + EGM96 undulation) or WGS84 (m); ``t_us``
        the FC/sender time (µs, 0 = none: the GPS week time), ``lag_us`` its lag after the time of validity."""
        if "gnss" not in self.emit:
            return
        if fix < 2:
            self.health.count("no_fix")
            return
        if not all(math.isfinite(x) for x in (lat, lon, h, *std)) or (vel is not None and not np.all(np.isfinite(vel))):
            self.health.count("nonfinite")
            return
        if abs(lat) > 90 or abs(lon) > 180:
            self.health.count("range")
            return
        if msl:
            h = ellipsoidal_height(math.radians(lat), math.radians(lon), h)
        if not -1000 < h < 100_000 or (vel is not None and np.any(np.abs(vel) > 600)):
            self.health.count("range")
            return
        gps_us = round(unix_from_gps(week, tow) * 1e6) if week > 0 and math.isfinite(tow) else 0
        key_us = t_us or gps_us  # the stream's time: the sender's clock, else GPS time, else the arrival
        k = (stream if key_us else stream + "@arrival", src)
        key = key_us or now // 1000
        last = self._last_gnss.get(k)
        if last is not None and key <= last:
            if last - key <= 5_000_000:
                self.health.count("duplicate" if key == last else "time_backwards")
                return
            self.health.count("gnss_restart")  # more than 5 s back: the FC rebooted, the stream restarts
        t = self._time_s(max(t_us - lag_us, 1) if t_us else gps_us, now) if key_us else now * 1e-9
        if t is None:
            return
        self._last_gnss[k] = key
        ft = FixType(min(fix, 6)) if fix <= 6 else FixType.FIX_3D
        self._deliver(
            GnssFix(
                t=t, lat=math.radians(lat), lon=math.radians(lon), h=h, vel_ned=vel,
                std_ne=std[0], std_d=std[1], std_vel=std[2], fix_type=ft, num_sats=sats, source=src,
                t_arrival_ns=now, gps_week=week, gps_tow=tow, hdop=hdop, vdop=vdop,
            ),
            now,
        )  # fmt: skip

    def _gps_raw(self, m: Any, now: int) -> None:
        ell = bool(getattr(m, "alt_ellipsoid", 0))  # WGS84 when the FC fills it, else alt (MSL)
        h_mm = m.alt_ellipsoid if ell else m.alt
        std = (
            m.h_acc * 1e-3 if getattr(m, "h_acc", 0) else (m.eph * 0.01 if 0 < m.eph < 65535 else 2.5),
            m.v_acc * 1e-3 if getattr(m, "v_acc", 0) else (m.epv * 0.01 if 0 < m.epv < 65535 else 5.0),
            m.vel_acc * 1e-3 if getattr(m, "vel_acc", 0) else 0.3,
        )
        src = 1 if m.get_type() == "GPS2_RAW" else 0
        week, tow = gps_from_unix(m.time_usec * 1e-6) if m.time_usec > UNIX_US else (0, math.nan)
        self._gnss(
            now, m.time_usec, m.fix_type, m.lat * 1e-7, m.lon * 1e-7, h_mm * 1e-3, None, std, m.satellites_visible, src,
            week, tow, _dop(m.eph), _dop(m.epv), msl=not ell, stream=m.get_type(), lag_us=self.fc_gnss_lag_us,
        )  # fmt: skip

    def _gps_input(self, m: Any, now: int) -> None:
        ig = m.ignore_flags
        vel = None if ig & (8 | 16) else np.array([m.vn, m.ve, m.vd], dtype=float)
        std = (
            m.horiz_accuracy if not ig & 64 and m.horiz_accuracy > 0 else 2.5,
            m.vert_accuracy if not ig & 128 and m.vert_accuracy > 0 else 5.0,
            m.speed_accuracy if not ig & 32 and m.speed_accuracy > 0 else 0.3,
        )
        week, tow = (m.time_week, m.time_week_ms * 1e-3) if m.time_week > 0 else (0, math.nan)
        hdop = m.hdop if not ig & 2 and m.hdop > 0 else math.nan
        vdop = m.vdop if not ig & 4 and m.vdop > 0 else math.nan
        self._gnss(
            now, m.time_usec, m.fix_type, m.lat * 1e-7, m.lon * 1e-7, m.alt, vel, std, m.satellites_visible, m.gps_id,
            week, tow, hdop, vdop, stream="GPS_INPUT",
        )  # fmt: skip

    def _hil_gps(self, m: Any, now: int) -> None:
        vel = np.array([m.vn, m.ve, m.vd], dtype=float) * 0.01
        std = (m.eph * 0.01 if 0 < m.eph < 65535 else 2.5, m.epv * 0.01 if 0 < m.epv < 65535 else 5.0, 0.3)
        src = getattr(m, "id", 0)
        week, tow = gps_from_unix(m.time_usec * 1e-6) if m.time_usec > UNIX_US else (0, math.nan)
        self._gnss(
            now, m.time_usec, m.fix_type, m.lat * 1e-7, m.lon * 1e-7, m.alt * 1e-3, vel, std, m.satellites_visible, src,
            week, tow, _dop(m.eph), _dop(m.epv), stream="HIL_GPS",
        )  # fmt: skip

    def _pressure(self, m: Any, now: int) -> None:
        if "baro" not in self.emit:
            return
        p = m.press_abs * 100.0
        if not math.isfinite(p):
            self.health.count("nonfinite")
            return
        if not 100.0 <= p <= 120_000.0:
            self.health.count("range")
            return
        t = self._time_s(m.time_boot_ms * 1000, now)
        if t is None:
            return
        self._deliver(
            BaroSample(t=t, pressure=p,
                       temperature=m.temperature * 0.01, t_arrival_ns=now),
            now,
        )  # fmt: skip

    def _imu(
        self, stream: str, iid: int, t_us: int, acc: tuple, gyro: tuple, mag: tuple | None, temp: float, now: int
    ) -> None:
        a0, a1, a2 = acc
        w0, w1, w2 = gyro
        fin = math.isfinite
        if not (fin(a0) and fin(a1) and fin(a2) and fin(w0) and fin(w1) and fin(w2)):
            self.health.count("nonfinite")
            return
        if (
            abs(w0) > MAX_GYRO
            or abs(w1) > MAX_GYRO
            or abs(w2) > MAX_GYRO
            or abs(a0) > MAX_ACCEL
            or abs(a1) > MAX_ACCEL
            or abs(a2) > MAX_ACCEL
        ):
            self.health.count("range")
            return
        fc_ns = t_us * 1000
        key = (stream, iid)
        last = self._last_imu.get(key)
        dt = self.imu_dt
        if last is not None:
            if fc_ns <= last:
                self.health.count("duplicate" if fc_ns == last else "time_backwards")
                if last - fc_ns > 5_000_000_000:  # FC rebooted: restart this stream
                    self._last_imu.pop(key, None)
                return
            d = (fc_ns - last) * 1e-9
            if d <= 0.5:
                dt = d
            else:
                self.health.count("time_jump")
        self._last_imu[key] = fc_ns
        t = self._time_s(t_us, now)
        if t is None:
            return
        if "imu" in self.emit:
            # point samples → increments by the rectangular rule: Δθ = ω·dt, Δv = f·dt
            self._deliver(
                ImuSample(t, dt, np.array((w0 * dt, w1 * dt, w2 * dt)), np.array((a0 * dt, a1 * dt, a2 * dt)), iid,
                          0, temp, 0, now),
                now,
            )  # fmt: skip
        if mag is not None and "mag" in self.emit:
            if not all(fin(x) for x in mag):
                self.health.count("nonfinite")
            elif max(abs(x) for x in mag) > MAX_MAG_GAUSS:
                self.health.count("range")
            else:
                self._deliver(MagSample(t=t, field_b=np.array(mag) * 1e-4, source=iid, t_arrival_ns=now), now)

    def _highres(self, m: Any, now: int) -> None:
        upd = m.fields_updated
        mag = (m.xmag, m.ymag, m.zmag) if upd & 0x1C0 else None
        if upd and not upd & 0x3F:  # neither accel nor gyro updated in this message
            if mag is not None and "mag" in self.emit:
                self._imu_mag_only(m, mag, now)
            return
        self._imu(m.get_type(), getattr(m, "id", 0), m.time_usec, (m.xacc, m.yacc, m.zacc),
                  (m.xgyro, m.ygyro, m.zgyro), mag, m.temperature, now)  # fmt: skip

    def _imu_mag_only(self, m: Any, mag: tuple, now: int) -> None:
        if all(math.isfinite(x) for x in mag) and max(abs(x) for x in mag) <= MAX_MAG_GAUSS:
            t = self._time_s(m.time_usec, now)
            if t is None:
                return
            self._deliver(
                MagSample(t=t, field_b=np.array(mag) * 1e-4, source=getattr(m, "id", 0), t_arrival_ns=now), now
            )
        else:
            self.health.count("range")

    def _scaled(self, m: Any, now: int) -> None:
        t = m.get_type()
        t_us = m.time_usec if t == "RAW_IMU" else m.time_boot_ms * 1000
        iid = {"SCALED_IMU": 0, "SCALED_IMU2": 1, "SCALED_IMU3": 2}.get(t, getattr(m, "id", 0))
        g = 9.80665e-3
        mag = (m.xmag * 1e-3, m.ymag * 1e-3, m.zmag * 1e-3) if (m.xmag or m.ymag or m.zmag) else None
        temp = m.temperature * 0.01 if getattr(m, "temperature", 0) else math.nan
        self._imu(t, iid, t_us, (m.xacc * g, m.yacc * g, m.zacc * g),
                  (m.xgyro * 1e-3, m.ygyro * 1e-3, m.zgyro * 1e-3), mag, temp, now)  # fmt: skip

    def _timesync(self, m: Any, now: int) -> None:
        if m.tc1 == 0:  # the FC asks: answer with our clock
            self.send(self.mav.timesync_encode(now, m.ts1))
            return
        v = self.clock.reply(m.tc1, m.ts1, now)
        if v in ("accepted", "synced"):
            return
        if v == "pending":
            self._fast_sync = max(self._fast_sync, 10)
        elif v in ("outlier", "reset"):
            self.health.count("timesync_outlier")
            self._fast_sync = max(self._fast_sync, 10)  # confirm or refute it quickly
            if v == "reset":
                self.health.count("timesync_reset")
                self.health.last_error = "TIMESYNC: the FC clock jumped (reboot?); offset re-estimated"
        else:
            self.health.count("timesync_bad" if v == "invalid" else "timesync_unmatched")

    def _send_timesync(self) -> None:
        ts1 = time.monotonic_ns()
        self.clock.sent(ts1)
        self.send(self.mav.timesync_encode(0, ts1))

    def _heartbeat(self, m: Any, now: int) -> None:
        if (
            m.type in (mavlink.MAV_TYPE_GCS, mavlink.MAV_TYPE_ONBOARD_CONTROLLER)
            or m.autopilot == mavlink.MAV_AUTOPILOT_INVALID
        ):
            return
        first = self.fc is None
        self.fc = (m.get_srcSystem(), m.get_srcComponent())
        if first:
            self.request_streams()

    # ------------------------------------------------------------ output
    def send(self, msg: Any) -> None:
        """Send one message on the link (signed when a key is set); never blocks."""
        link = self._link
        if link is None:
            return
        try:
            buf = msg.pack(self.mav)
        except Exception as e:
            self.health.count("tx_error")
            self.health.last_error = f"send: {e}"
            return
        self.mav.seq = (self.mav.seq + 1) % 256
        link.write(buf)  # its failures are counted through _link_error

    def request_streams(self) -> None:
        """Ask the FC for the messages we need (MAV_CMD_SET_MESSAGE_INTERVAL each)."""
        if self.fc is None:
            return
        for name, hz in self.request.items():
            mid = getattr(mavlink, f"MAVLINK_MSG_ID_{name}")
            self.send(
                self.mav.command_long_encode(
                    self.fc[0], self.fc[1], mavlink.MAV_CMD_SET_MESSAGE_INTERVAL, 0, mid, 1e6 / hz, 0, 0, 0, 0, 0
                )
            )

    async def _periodic(self) -> None:
        """HEARTBEAT and TIMESYNC each ``timesync_s``; TIMESYNC every 0.1 s while the clock
        offset is unknown or in doubt (at most 10 in a row once nothing answers)."""
        n = 0
        self._fast_sync = 10
        loop = asyncio.get_running_loop()
        while True:
            self.send(self.mav.heartbeat_encode(HEARTBEAT_TYPE, mavlink.MAV_AUTOPILOT_INVALID, 0, 0, 0))
            self._send_timesync()
            n += 1
            if n % 10 == 0:  # re-request: FCs forget after a reboot
                self.request_streams()
            end = loop.time() + self.timesync_s
            while (left := end - loop.time()) > 0:
                fast = self.clock.unsure and self._fast_sync > 0
                await asyncio.sleep(min(left, 0.1) if fast else left)
                if fast and end - loop.time() > 0.05:
                    self._fast_sync -= 1
                    self._send_timesync()

    # ------------------------------------------------------------ run
    def _link_error(self, reason: str) -> None:
        self.health.count(reason)
        if self._link is not None and self._link.last_error:
            self.health.last_error = self._link.last_error

    async def run(self, sink: Sink) -> None:
        """Connect, parse, deliver; re-open with backoff on loss or silence, until cancelled."""
        self._sink = sink
        first = True
        while True:
            link = Link(self.link_url, self.feed, on_error=self._link_error)
            try:
                await link.connect()
            except Exception as e:
                self.health.count("open_failed")
                self.health.last_error = f"open {self.url}: {e}"
                await self._backoff.wait()
                continue
            if not first:
                self.health.reconnects += 1
            first = False
            self._link = link
            self._last_gnss.clear()  # a new connection (the FC may have rebooted): the GNSS streams restart
            self.local_address = link.local_address
            self.health.connected = True
            self._last_rx_ns = time.monotonic_ns()
            n0 = self.health.samples
            periodic = asyncio.create_task(self._periodic())
            lost = link.lost
            assert lost is not None
            try:
                while not lost.done():
                    await asyncio.wait([lost], timeout=min(0.5, self.stale_s))
                    if self.stale_s > 0 and (time.monotonic_ns() - self._last_rx_ns) * 1e-9 > self.stale_s:
                        self.health.count("silence")
                        self.health.last_error = f"no MAVLink for {self.stale_s} s"
                        break
                else:
                    self.health.count("link_lost")
                    self.health.last_error = lost.result()
            finally:
                periodic.cancel()
                self.health.connected = False
                self._link = None
                self.fc = None
                link.close()
                # until the heartbeat task has ended; a cancel of run() itself during this wait propagates
                # (suppressing it here once swallowed the stop and kept the driver re-opening for ever)
                await asyncio.wait([periodic])
            if self.health.samples > n0:
                self._backoff.reset()
            await self._backoff.wait()


def _dop(x100: int) -> float:
    """A dilution of precision from its MAVLink ×100 integer (UINT16_MAX or 0 = unknown: NaN)."""
    return x100 * 0.01 if 0 < x100 < 0xFFFF else math.nan
