"""Soak null relay: the gateway's place in the soak with no gateway in it (the platform floor).

Started by the orchestrator instead of :mod:`ins_hil.soak.gateway` (``--gateway relay``) with the
same command line, CPU and SCHED_FIFO priority. It builds the same gateway config
(:func:`ins_hil.soak.gateway.gateway_config`: the same ptys and baud rate, GNSS input, ground-station
address, ODOMETRY rate, MAVLink system/component ids) and then does the least a gateway can do:

* opens each IMU pty as the gateway's serial driver does (pyserial, the configured baud rate), but
  reads it with a plain blocking ``os.read`` loop (no asyncio, no event loop: one wake-up per read;
  with several links ``poll`` on them), decodes the frames with the project's
  :class:`~ins_hil.drivers.serial_frame.FrameParser` and, with redundant IMUs, takes an epoch as
  complete once every unit's sample of that sensor time has arrived;
* sends one MAVLink 2 ODOMETRY to the ground-station client whenever an epoch completes at or after
  the stream's due time, with the gateway's own rule (:func:`ins_hil.runtime.mavlink_out.advance_due`:
  the gateway decides on the monotonic clock when a state is ready, not on sensor time), ``time_usec``
  = the epoch's sensor time as the gateway encodes it (``round(t·1e6)``), framed by the gateway's
  packer (:func:`~ins_hil.runtime.mavlink_out._frame_of`); the message carries no navigation (zero
  position, identity attitude, unknown covariance) and is the size of the gateway's ground-station
  ODOMETRY before it is aligned (quality −1, as an aligned gateway's 100: no byte trimmed);
* drains the GNSS/baro UDP input (so the simulator's datagrams are received) and does nothing with it.

No navigation, no FDI, no recorder, no other MAVLink stream: the end-to-end latency the analysis
computes for this run is what the transport and the wake-up chain alone (emitter → pty kernel
worker → this process → UDP → client) cost on this machine. The garbage collector is frozen and
disabled (the loop makes no reference cycles), as in the other measurement processes.

Writes the gateway's files in their layout (:class:`~ins_hil.runtime.metrics.RuntimeMetrics`):
``gateway.json`` (``"kind": "relay"``; ``arrival_to_state`` = bytes read → epoch decoded,
``state_to_sent`` = decoded → ODOMETRY handed to the socket; parser counters as the gateway's
``driver_*`` drops) and ``gateway_ts.jsonl`` (once a second). The bookkeeping runs right after an
ODOMETRY was sent, in the ~21 ms before the next one is due. Prints ``{"ready": true}`` once open.
"""

from __future__ import annotations

import argparse
import errno
import gc
import json
import math
import os
import select
import signal
import socket
import sys
import termios
import time
from pathlib import Path
from typing import Any

from ins_hil.config import from_dict
from ins_hil.drivers.mavlink_link import parse_url
from ins_hil.drivers.serial_frame import FrameParser
from ins_hil.runtime.mavlink_out import _frame_of, advance_due, mavlink_module
from ins_hil.runtime.metrics import RuntimeMetrics
from ins_hil.runtime.rt import enter_realtime, policy
from ins_hil.soak.gateway import build_parser, gateway_config
from ins_hil.soak.orchestrate import RELAY_LABEL
from ins_hil.soak.simproc import die_with_parent, pin
from ins_hil.types import ImuSample

KIND = "relay"


class _Stop(Exception):
    pass


def open_link(port: str, baud: int) -> Any:
    """Open a serial IMU link with pyserial as the gateway's driver does (``serial_for_url``, ``baud``),
    then make its fd a plain blocking one: O_NONBLOCK cleared, VMIN 1 / VTIME 0 (pyserial leaves
    VMIN 0, with which a blocking read returns at once with nothing). Returns the pyserial object."""
    import serial

    ser = serial.serial_for_url(port, baudrate=baud)
    fd = ser.fileno()
    os.set_blocking(fd, True)
    attrs = termios.tcgetattr(fd)
    attrs[6][termios.VMIN] = 1
    attrs[6][termios.VTIME] = 0
    termios.tcsetattr(fd, termios.TCSANOW, attrs)
    return ser


def odometry_tail() -> tuple[Any, ...]:
    """The ODOMETRY fields after ``time_usec``, in wire order: no navigation (position 0, identity
    quaternion, zero velocity and rates, unknown covariances = NaN first element, as the gateway sends
    before its covariance is known), LOCAL_NED / BODY_FRD, reset counter 0, estimator VIO (as the gateway),
    quality −1 (invalid: the gateway's ground-station ODOMETRY before alignment)."""
    m = mavlink_module()
    cov = (math.nan, *([0.0] * 20))
    return (0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, *cov, *cov,
            m.MAV_FRAME_LOCAL_NED, m.MAV_FRAME_BODY_FRD, 0, m.MAV_ESTIMATOR_TYPE_VIO, -1)  # fmt: skip


def odometry_message(mav: Any, t: float, tail: tuple[Any, ...] | None = None) -> bytes:
    """One ODOMETRY for sensor time ``t`` (s), framed by the gateway's packer for ``mav`` (its seq advances):
    ``time_usec`` = ``round(t·1e6)`` as :meth:`MavlinkEndpoint._send_odometry
    <ins_hil.runtime.mavlink_out.MavlinkEndpoint._send_odometry>`, the rest :func:`odometry_tail`."""
    buf = _frame_of("ODOMETRY").frame(mav, round(t * 1e6), *(odometry_tail() if tail is None else tail))
    mav.seq = (mav.seq + 1) % 256
    return buf


class Schedule:
    """The gateway's due rule of one MAVLink stream (:meth:`MavlinkEndpoint._send_due
    <ins_hil.runtime.mavlink_out.MavlinkEndpoint._send_due>`): a state is sent when the monotonic clock
    at that state is at or past the due time, which then advances by :func:`advance_due`; the first
    state goes out at once (due time 0)."""

    def __init__(self, rate_hz: float) -> None:
        self.period_ns = round(1e9 / rate_hz)  # as MavlinkEndpoint.period_ns
        self.next_ns = 0

    def due(self, now_ns: int) -> bool:
        """Whether a state ready at ``now_ns`` goes out (and if so, the next due time is set)."""
        if now_ns < self.next_ns:
            return False
        self.next_ns = advance_due(self.next_ns, self.period_ns, now_ns)
        return True


class Epochs:
    """Redundant IMUs: an epoch (one sensor time) is complete once every unit's sample has arrived.

    A minimal form of the pipeline's grouping (:meth:`ins_hil.runtime.pipeline.Pipeline._group`, which also
    runs an epoch incomplete after a wait bound): an older epoch still missing a unit when a newer one
    completes is given up (``incomplete``), a sample for an epoch already completed or given up is
    counted (``late``) and ignored."""

    def __init__(self, n_units: int) -> None:
        self.n = n_units
        self.pending: dict[int, int] = {}  # sensor time (µs) → units arrived
        self.last_key = -(1 << 62)
        self.incomplete = 0
        self.late = 0

    def complete(self, s: ImuSample) -> bool:
        """Add one unit's sample; True when it completes its epoch."""
        if self.n == 1:
            return True
        key = round(s.t * 1e6)
        if key <= self.last_key:
            self.late += 1
            return False
        pend = self.pending
        k = pend.get(key, 0) + 1
        if k < self.n:
            pend[key] = k
            return False
        pend.pop(key, None)
        if pend:  # older epochs still missing a unit are given up (no list built on the common path)
            for old in [o for o in pend if o < key]:
                del pend[old]
                self.incomplete += 1
        self.last_key = key
        return True


class SlcanParser:
    """slcan (Lawicel) lines in, DroneCAN IMU samples out, with the gateway's decoder
    (:class:`~ins_hil.drivers.dronecan_codec.DroneCanDecoder`: reassembly, CRC, DSDL, clock model);
    a line that is no extended data frame counts as ``malformed``. ``counts``: the decoder's counters."""

    def __init__(self, nodes: list[int] | None = None) -> None:
        from ins_hil.drivers.dronecan_codec import DroneCanDecoder

        self.dec = DroneCanDecoder(nodes=frozenset(nodes) if nodes else None)
        self.counts = self.dec.counts
        self.buf = b""

    def feed(self, data: bytes, arrival_ns: int) -> list[ImuSample]:
        """Bytes read at ``arrival_ns``; the IMU samples of the RawIMU transfers they complete."""
        buf = self.buf + data
        lines = buf.split(b"\r")
        self.buf = lines.pop()
        out: list[ImuSample] = []
        feed = self.dec.feed
        for ln in lines:
            try:
                if ln[:1] != b"T":
                    raise ValueError
                n = int(ln[9:10])
                s = feed(int(ln[1:9], 16), bytes.fromhex(ln[10 : 10 + 2 * n].decode()), True, arrival_ns)
            except (ValueError, UnicodeDecodeError):
                if ln.strip():  # a bare CR is an slcan acknowledgement
                    self.counts["malformed"] = self.counts.get("malformed", 0) + 1
                continue
            except Exception:  # as the gateway's CAN driver: one frame never stops the reader, it is counted
                self.counts["internal"] = self.counts.get("internal", 0) + 1
                continue
            if s is not None and s.kind == "imu":
                out.append(s)
        return out


class Relay:
    """The relay's state: links, parsers, epoch assembly, the ODOMETRY schedule and the metrics."""

    def __init__(self, a: argparse.Namespace) -> None:
        cfg = from_dict(gateway_config(a), source="soak relay")
        self.out = Path(a.out)
        self.n_imus = int(a.imus)
        self.metrics = RuntimeMetrics(cfg.gateway.late_threshold_ms * 1e-3)
        self.rt_priority = cfg.gateway.rt_priority
        imus = [ic for ic in cfg.inputs if ic.type in ("serial_imu", "can_imu")]
        gnss = next(ic for ic in cfg.inputs if ic.type == "mavlink")
        ep = next(e for e in cfg.outputs if e.role == "gcs")
        self.out_name = ep.name
        self.schedule = Schedule(ep.effective_rates()["ODOMETRY"])
        self.names = [ic.name for ic in imus]
        self.serials = [open_link(ic.options["channel"] if ic.type == "can_imu" else ic.port, ic.baud) for ic in imus]
        self.fds = [s.fileno() for s in self.serials]
        self.parsers: list[Any] = [
            SlcanParser(ic.options.get("nodes")) if ic.type == "can_imu" else FrameParser() for ic in imus
        ]
        self.stats = [self.metrics.source(n) for n in self.names]
        _, host, port = parse_url(gnss.url)
        self.gnss = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        self.gnss.bind((host, port))
        self.gnss.setblocking(False)
        self.gnss_datagrams = self.gnss_bytes = 0
        _, host, port = parse_url(ep.url)
        self.sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        self.sock.connect((host, port))  # as the gateway's udpout: output (a connected datagram socket)
        self.sock.setblocking(False)
        self.mav = mavlink_module().MAVLink(None, srcSystem=ep.sysid, srcComponent=ep.compid)
        self.tail = odometry_tail()
        self.sent = 0
        self.send_errors: dict[str, int] = {}
        self.epochs = Epochs(self.n_imus)
        self._ts: Any = None
        self._t_tick = self._t_roll = 0
        self.stopped_reason = "duration"

    # -- the hot path ---------------------------------------------------------------------
    def on_bytes(self, link: int, data: bytes, arrival_ns: int) -> None:
        """Bytes read from one link at ``arrival_ns``: decode, complete epochs, send what is due."""
        samples = self.parsers[link].feed(data, arrival_ns)
        if not samples:
            return
        self.stats[link].received += len(samples)
        complete = self.epochs.complete
        for s in samples:
            if complete(s):
                self._epoch(s, arrival_ns)

    def _epoch(self, s: ImuSample, arrival_ns: int) -> None:
        m = self.metrics
        ready = time.monotonic_ns()
        m.imu_epochs += 1
        d = ready - arrival_ns
        m.record("arrival_to_state", d)
        if d > m.late_threshold_ns:
            m.late += 1
        if not self.schedule.due(ready):
            return
        buf = odometry_message(self.mav, s.t, self.tail)
        try:
            self.sock.send(buf)
        except OSError as e:
            key = "refused" if e.errno == errno.ECONNREFUSED else "send_error"
            self.send_errors[key] = self.send_errors.get(key, 0) + 1
            m.output(self.out_name, "not_sent")
            self._slack()  # the GNSS drain and the once-a-second rows go on while the client is away
            return
        m.record_sent(arrival_ns, ready, time.monotonic_ns())
        self.sent += 1
        self._slack()

    # -- bookkeeping, in the slack after an ODOMETRY ---------------------------------------
    def _slack(self) -> None:
        self.drain_gnss()
        now = time.monotonic_ns()
        if now - self._t_tick < 1_000_000_000:
            return
        self._t_tick = now
        m = self.metrics
        m.tick(now)
        self._copy_counts()
        if now - self._t_roll >= 5_000_000_000:
            self._t_roll = now
            m.roll_window()
        if self._ts is not None:
            w = m.window["arrival_to_state"].summary()
            row = {"mono_ns": now, "epochs": m.imu_epochs, "late": m.late, "queue_max_1s": 0, "queue_depth_max": 0,
                   "received": {st.name: st.received for st in self.stats}, "dropped": m.dropped_total(),
                   "aligned": False, "faults": 0, "odometry_sent": self.sent,
                   "window": {"arrival_to_state": w}}  # fmt: skip
            self._ts.write(json.dumps(row, default=float) + "\n")
            self._ts.flush()

    def drain_gnss(self) -> None:
        """Read every waiting GNSS/baro datagram and discard it."""
        while True:
            try:
                data = self.gnss.recv(65536)
            except (BlockingIOError, InterruptedError):
                return
            except OSError:
                return
            self.gnss_datagrams += 1
            self.gnss_bytes += len(data)

    def _copy_counts(self) -> None:
        """The parsers' counters as the gateway's ``driver_*`` drops (Gateway._housekeeping)."""
        for st, p in zip(self.stats, self.parsers, strict=True):
            st.driver_drops(p.counts)

    # -- the loop ---------------------------------------------------------------------------
    def loop(self) -> None:
        """Blocking reads until stopped (:class:`_Stop` from a signal handler) or a link is gone."""
        mono, read = time.monotonic_ns, os.read
        try:
            if len(self.fds) == 1:
                fd = self.fds[0]
                on_bytes = self.on_bytes
                while True:
                    data = read(fd, 4096)
                    if not data:  # hang-up (never with VMIN 1 on a live pty)
                        break
                    on_bytes(0, data, mono())
            else:
                pl = select.poll()
                index = {fd: j for j, fd in enumerate(self.fds)}
                for fd in self.fds:
                    pl.register(fd, select.POLLIN)
                while True:
                    for fd, _ev in pl.poll():
                        data = read(fd, 4096)
                        if not data:
                            self.stopped_reason = "link closed"
                            return
                        self.on_bytes(index[fd], data, mono())
            self.stopped_reason = "link closed"
        except OSError as e:  # EIO: the simulator closed its side of the pty
            if e.errno != errno.EIO:
                raise
            self.stopped_reason = "link closed"

    def snapshot(self, wall_s: float) -> dict[str, Any]:
        """``gateway.json``: the metrics snapshot in the gateway's layout and the relay's own counters."""
        self._copy_counts()
        snap = self.metrics.snapshot()
        snap.update(
            kind=KIND,
            label=RELAY_LABEL,
            loop_period=None,
            loop_jitter=None,
            fault_events=[],
            fault_events_not_kept=0,
            wall_s=wall_s,
            stopped_reason=self.stopped_reason,
            odometry_sent=self.sent,
            send_errors=self.send_errors,
            epochs_incomplete=self.epochs.incomplete,
            late_unit_samples=self.epochs.late,
            gnss_udp={"datagrams": self.gnss_datagrams, "bytes": self.gnss_bytes},
        )
        return snap


def run(a: argparse.Namespace) -> int:
    pin(a.cpu)
    r = Relay(a)
    if r.rt_priority:
        why = enter_realtime(r.rt_priority)
        if why:
            r.metrics.warn(f"rt priority: {why}")
    r.metrics.scheduling = policy()

    def on_stop(signum: int, _frame: Any) -> None:
        r.stopped_reason = "duration" if signum == signal.SIGALRM else signal.Signals(signum).name
        raise _Stop

    signal.signal(signal.SIGTERM, on_stop)
    signal.signal(signal.SIGINT, on_stop)
    signal.signal(signal.SIGALRM, on_stop)
    # measurement apparatus: no collector pause on the path (nothing here makes reference cycles)
    gc.collect()
    gc.freeze()
    gc.disable()
    t0 = time.monotonic()
    with open(r.out / "gateway_ts.jsonl", "w") as ts:
        r._ts = ts
        print(json.dumps({"ready": True, "kind": KIND, "scheduling": policy()}), flush=True)
        try:
            signal.setitimer(signal.ITIMER_REAL, a.duration)
            r.loop()
        except _Stop:
            pass
        finally:
            signal.setitimer(signal.ITIMER_REAL, 0)
            for sig in (signal.SIGTERM, signal.SIGINT):  # a second stop request must not cut the files short
                signal.signal(sig, signal.SIG_IGN)
        r._ts = None
    from ins_hil.runtime.mqtt_out import clean_json

    (r.out / "gateway.json").write_text(json.dumps(clean_json(r.snapshot(time.monotonic() - t0)), indent=1))
    for s in r.serials:
        s.close()
    return 0


def main(argv: list[str] | None = None) -> int:
    die_with_parent()
    a = build_parser("soak null relay process (see ins_hil.soak.relay)").parse_args(argv)
    return run(a)


if __name__ == "__main__":
    sys.exit(main())
