"""Async CAN IMU driver over python-can (any interface: socketcan, slcan, gs_usb, virtual...).

Two protocols on the bus:

- ``"dronecan"``: RawIMU / Fix2 / magnetometer / static pressure from
  DroneCAN nodes (:mod:`ins_hil.drivers.dronecan_codec`), node-ID filter,
  and our own ``uavcan.protocol.NodeStatus`` published at 1 Hz from
  ``node_id`` (so DroneCAN tools see the gateway).
- ``"dbc"``: a DBC-described IMU (:mod:`ins_hil.drivers.dbc_codec`).

Reading never blocks the event loop: buses with a file descriptor
(socketcan) are read with ``loop.add_reader``; others (slcan, gs_usb) by one
reader thread that hands frames to the loop in batches. Error frames,
bus-off, the interface vanishing or ``stale_s`` of silence close the bus;
it is re-opened with exponential backoff. Sensor times go through one clock
model per source (:mod:`ins_hil.drivers.clock`), kept across re-opens, so
samples stay strictly increasing in time through node reboots, bus re-opens,
counter wraps, jumps and stalls (the ``clock_*`` counters in ``health``).
"""

from __future__ import annotations

import asyncio
import contextlib
import socket
import threading
import time
from typing import Any

import can
from ins_hil.drivers import dronecan_codec as dc
from ins_hil.drivers.base import Backoff, DriverHealth, Sink
from ins_hil.drivers.dbc_codec import DbcImuDecoder, DbcProfile
from ins_hil.drivers.slcan import open_bus

CAN_ERR_BUSOFF = 0x40  # linux/can/error.h: error class bit in the error frame's id


class CanImuDriver:
    """IMU (and DroneCAN GNSS/mag/baro) samples from a CAN bus.

    ``bus_config``: keyword arguments for :class:`can.Bus` (``interface``,
    ``channel``, ``bitrate``, ...). ``protocol``: ``"dronecan"`` or ``"dbc"``.
    ``nodes``: DroneCAN source node ids to accept (None = any).
    ``node_id``: our DroneCAN node id for NodeStatus (None, or 0 in a config, = listen only: nothing is sent).
    ``rcvbuf``: socket receive buffer asked for on socketcan (bytes; 0 = leave the default).
    """

    def __init__(
        self,
        bus_config: dict[str, Any],
        protocol: str = "dronecan",
        name: str = "can_imu",
        nodes: set[int] | None = None,
        node_id: int | None = 100,
        dbc: DbcProfile | None = None,
        stale_s: float = 2.0,
        rcvbuf: int = 4 << 20,
    ) -> None:
        if protocol not in ("dronecan", "dbc"):
            raise ValueError(f"CAN IMU: 'protocol' must be 'dronecan' or 'dbc', got {protocol!r}")
        if "interface" not in bus_config:
            raise ValueError("CAN IMU: 'interface' is required (socketcan, slcan, gs_usb, virtual, ...)")
        if node_id is not None and not 1 <= node_id <= 127:
            raise ValueError(f"CAN IMU: 'node_id' must be 1..127, got {node_id!r}")
        for n in nodes or ():
            if not 1 <= n <= 127:
                raise ValueError(f"CAN IMU: 'nodes' entries must be 1..127, got {n!r}")
        self.name = name
        self.bus_config = dict(bus_config)
        self.protocol = protocol
        self.node_id = node_id
        self.stale_s = stale_s
        self.rcvbuf = rcvbuf
        self.health = DriverHealth(name)
        self.dronecan = dc.DroneCanDecoder(nodes=frozenset(nodes) if nodes else None)
        #: the protocol of the aid decoders this driver takes (``ins_hil.aids.decoders``; "" = none)
        self.decoder_protocol = "dronecan" if protocol == "dronecan" else ""
        self.dbc = DbcImuDecoder(dbc or DbcProfile()) if protocol == "dbc" else None
        self._backoff = Backoff()
        self._bus: can.BusABC | None = None
        self._start_ns = time.monotonic_ns()
        self._ns_tid = 0
        self.node_status_sent = 0
        self.frames_rx = 0  # every CAN frame handed to the driver (good or not)

    def set_decoders(self, table: dict[Any, Any]) -> None:
        """The aid decoders by DroneCAN type name (:meth:`DroneCanDecoder.set_decoders`)."""
        self.dronecan.set_decoders(table)

    @classmethod
    def from_config(cls, cfg: dict[str, Any]) -> CanImuDriver:
        """``{"type": "can_imu", "interface": "socketcan", "channel": "vcan0", "protocol": "dronecan",
        "nodes": [10], "node_id": 100, "bitrate": 1000000, "dbc": {...DbcProfile keys}, "stale_s": 2}``;
        keys other than the driver's own go to :class:`can.Bus`."""
        own = {"type", "protocol", "name", "nodes", "node_id", "dbc", "stale_s", "rcvbuf"}
        bus_cfg = {k: v for k, v in cfg.items() if k not in own}
        dbc = cfg.get("dbc")
        if dbc is not None and not isinstance(dbc, dict):
            raise ValueError(f"CAN IMU config: 'dbc' must be a table of DbcProfile keys, got {dbc!r}")
        nodes = cfg.get("nodes")
        return cls(
            bus_cfg,
            protocol=str(cfg.get("protocol", "dronecan")),
            name=str(cfg.get("name", "can_imu")),
            nodes=set(int(n) for n in nodes) if nodes else None,
            node_id=None if cfg.get("node_id", 100) in (None, 0) else int(cfg.get("node_id", 100)),
            dbc=DbcProfile.from_config(dbc) if dbc else None,
            stale_s=float(cfg.get("stale_s", 2.0)),
            rcvbuf=int(cfg.get("rcvbuf", 4 << 20)),
        )

    # ------------------------------------------------------------ decoding (also for tests/benchmarks)
    def handle(self, msg: can.Message, sink: Sink, now_ns: int) -> None:
        """One received CAN message → zero or one sample to ``sink``."""
        h = self.health
        self.frames_rx += 1
        if msg.is_error_frame:
            h.count("error_frame")
            if msg.arbitration_id & CAN_ERR_BUSOFF:
                h.count("bus_off")
                raise can.CanOperationError("bus-off")
            return
        if msg.is_remote_frame or msg.is_fd:
            h.count("not_classic_data_frame")
            return
        if self.dbc is not None:
            s: Any = self.dbc.feed(msg.arbitration_id, msg.data, now_ns, msg.is_extended_id)
            counts = self.dbc.counts
        else:
            s = self.dronecan.feed(msg.arbitration_id, msg.data, msg.is_extended_id, now_ns)
            counts = self.dronecan.counts
        errs = h.errors
        for k, v in counts.items():
            if errs.get(k) != v:
                errs[k] = v
        if s is not None:
            h.seen(now_ns)
            try:
                sink(s)
            except Exception:
                h.count("sink_error")

    # ------------------------------------------------------------ NodeStatus
    def node_status_message(self, now_ns: int | None = None) -> can.Message:
        """Our uavcan.protocol.NodeStatus (single frame), health OK / mode OPERATIONAL."""
        assert self.node_id is not None
        now = time.monotonic_ns() if now_ns is None else now_ns
        payload = dc.node_status_payload((now - self._start_ns) // 1_000_000_000)
        data = dc.split_transfer(dc.DTID_NODE_STATUS, payload, self._ns_tid)[0]
        self._ns_tid = (self._ns_tid + 1) & 0x1F
        cid = dc.message_can_id(dc.DTID_NODE_STATUS, self.node_id, priority=24)
        return can.Message(arbitration_id=cid, data=data, is_extended_id=True)

    async def _publish_status(self, bus: can.BusABC) -> None:
        while True:
            try:
                bus.send(self.node_status_message(), timeout=0)
                self.node_status_sent += 1
            except Exception:
                self.health.count("tx_error")
            await asyncio.sleep(1.0)

    # ------------------------------------------------------------ run
    async def run(self, sink: Sink) -> None:
        """Open the bus, read, re-open with backoff until cancelled."""
        loop = asyncio.get_running_loop()
        first = True
        while True:
            try:
                bus = await loop.run_in_executor(None, lambda: open_bus(self.bus_config))
            except Exception as e:
                self.health.count("open_failed")
                self.health.last_error = f"open CAN bus {self.bus_config}: {e}"
                await self._backoff.wait()
                continue
            if not first:
                self.health.reconnects += 1
                # partial transfers / half pairs and transfer ids start afresh; the sensors' time bases
                # are kept (the output continues) and re-anchor at once on a node that restarted meanwhile
                self.dronecan.reopen()
                if self.dbc is not None:
                    self.dbc.reopen()
            first = False
            self._bus = bus
            self.health.connected = True
            n0 = self.health.samples
            try:
                await self._read(bus, sink, loop)
            finally:
                self.health.connected = False
                self._bus = None
                with contextlib.suppress(Exception):
                    bus.shutdown()
            if self.health.samples > n0:
                self._backoff.reset()
            await self._backoff.wait()

    async def _read(self, bus: can.BusABC, sink: Sink, loop: asyncio.AbstractEventLoop) -> None:
        lost: asyncio.Future[str] = loop.create_future()
        last_rx = [time.monotonic_ns()]

        def fail(reason: str, detail: str) -> None:
            if not lost.done():
                self.health.count(reason)
                self.health.last_error = detail
                lost.set_result(reason)

        def deliver(msgs: list[can.Message]) -> None:
            now = time.monotonic_ns()
            last_rx[0] = now
            for m in msgs:
                try:
                    self.handle(m, sink, now)
                except can.CanOperationError as e:
                    fail("bus_lost", str(e))
                    return
                except Exception as e:  # never let one frame kill the driver
                    self.health.count("internal")
                    self.health.last_error = f"{type(e).__name__}: {e}"

        fd = -1
        with contextlib.suppress(Exception):
            fd = bus.fileno()
        sock = getattr(bus, "socket", None)
        if sock is not None and self.rcvbuf:
            # IMU bursts (7 frames per DroneCAN RawIMU) overflow the default ~200 kB socket buffer
            # (≈300 frames) as soon as the loop stalls for a few ms; ask for more (FORCE needs root)
            for opt in (33, socket.SO_RCVBUF):  # 33 = SO_RCVBUFFORCE
                try:
                    sock.setsockopt(socket.SOL_SOCKET, opt, self.rcvbuf)
                    break
                except OSError:
                    continue
        stop = threading.Event()
        thread: threading.Thread | None = None
        if fd >= 0:

            def readable() -> None:
                msgs: list[can.Message] = []
                for _ in range(512):  # bounded batch: never starve the loop
                    try:
                        m = bus.recv(0)
                    except (ValueError, IndexError, UnicodeDecodeError):
                        self.health.count("malformed")  # e.g. a garbled slcan line: drop it, go on
                        continue
                    except Exception as e:
                        deliver(msgs)
                        fail("bus_lost", f"{type(e).__name__}: {e}")
                        return
                    if m is None:
                        break
                    msgs.append(m)
                deliver(msgs)

            loop.add_reader(fd, readable)
        else:

            def reader() -> None:
                while not stop.is_set():
                    try:
                        m = bus.recv(0.05)
                    except (ValueError, IndexError, UnicodeDecodeError):
                        loop.call_soon_threadsafe(self.health.count, "malformed")
                        continue
                    except Exception as e:
                        loop.call_soon_threadsafe(fail, "bus_lost", f"{type(e).__name__}: {e}")
                        return
                    if m is None:
                        continue
                    batch = [m]
                    while len(batch) < 256:
                        try:
                            m2 = bus.recv(0)
                        except Exception:
                            break
                        if m2 is None:
                            break
                        batch.append(m2)
                    loop.call_soon_threadsafe(deliver, batch)

            thread = threading.Thread(target=reader, name=f"{self.name}-rx", daemon=True)
            thread.start()
        status_task = asyncio.create_task(self._publish_status(bus)) if self.node_id is not None else None
        try:
            while not lost.done():
                await asyncio.wait([lost], timeout=min(0.5, self.stale_s) if self.stale_s > 0 else 0.5)
                if not lost.done() and self.stale_s > 0 and (time.monotonic_ns() - last_rx[0]) * 1e-9 > self.stale_s:
                    fail("silence", f"no CAN frame for {self.stale_s} s")
        finally:
            if status_task is not None:
                status_task.cancel()
            if fd >= 0:
                loop.remove_reader(fd)
            stop.set()
            if status_task is not None:  # a cancel of run() itself during this wait propagates, never swallowed
                await asyncio.wait([status_task])
            if thread is not None:
                await loop.run_in_executor(None, thread.join, 1.0)
