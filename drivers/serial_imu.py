"""Async serial IMU driver: ins_hil serial frames (SERIAL_FRAME.md) from a UART or pty.

The port is opened with pyserial (baud rate, raw mode); a device with a file descriptor (a UART, a pty)
is read with one non-blocking ``os.read`` each time the event loop reports it readable
(``loop.add_reader``: nothing blocks the event loop; pyserial's own ``read`` would add a ``select``
before and after each read), any other pyserial URL through pyserial-asyncio-fast. Bytes are fed to the streaming
:class:`~ins_hil.drivers.serial_frame.FrameParser` and every accepted
:class:`~ins_hil.types.ImuSample` goes to ``sink``. Up to 921600 baud /
2 kHz frames. The port vanishing (USB unplugged, pty closed) or going silent
for ``stale_s`` closes it; it is re-opened with exponential backoff.
"""

from __future__ import annotations

import asyncio
import errno
import os
import time
from typing import Any

import serial_asyncio_fast
from ins_hil.drivers.base import Backoff, DriverHealth, Sink
from ins_hil.drivers.serial_frame import FrameParser


class _Proto(asyncio.Protocol):
    def __init__(self, drv: SerialImuDriver, sink: Sink) -> None:
        self.drv, self.sink = drv, sink
        self.lost: asyncio.Future[Exception | None] = asyncio.get_running_loop().create_future()
        self.last_rx_ns = time.monotonic_ns()

    def data_received(self, data: bytes) -> None:
        now = time.monotonic_ns()
        self.last_rx_ns = now
        self.drv.feed(data, self.sink, now)

    def connection_lost(self, exc: Exception | None) -> None:
        if not self.lost.done():
            self.lost.set_result(exc)


class _FdReader:
    """A pyserial port with a file descriptor on the event loop: each readiness, one ``os.read`` (the fd is
    non-blocking, pyserial opens it so) and the bytes to the driver with their arrival time. ``lost``
    resolves when the port goes (EOF, EIO of a closed pty, a vanished USB device) or is closed."""

    def __init__(self, drv: SerialImuDriver, sink: Sink, ser: Any, loop: asyncio.AbstractEventLoop) -> None:
        self.drv, self.sink, self.ser, self.loop = drv, sink, ser, loop
        self.fd = ser.fileno()
        os.set_blocking(self.fd, False)
        self.lost: asyncio.Future[Exception | None] = loop.create_future()
        self.last_rx_ns = time.monotonic_ns()
        loop.add_reader(self.fd, self._ready)

    def _ready(self) -> None:
        try:
            data = os.read(self.fd, 4096)
        except (BlockingIOError, InterruptedError):
            return
        except OSError as e:
            self._lose(e)
            return
        if not data:
            self._lose(OSError(errno.EIO, "end of file"))
            return
        now = time.monotonic_ns()
        self.last_rx_ns = now
        self.drv.feed(data, self.sink, now)

    def _lose(self, exc: Exception | None) -> None:
        self.loop.remove_reader(self.fd)
        if not self.lost.done():
            self.lost.set_result(exc)

    def close(self) -> None:
        self._lose(None)
        self.ser.close()


class SerialImuDriver:
    """IMU frames over a serial port.

    ``port``: device path (``/dev/ttyUSB0``, a pty slave) or any pyserial URL;
    ``baudrate``: up to 921600; ``stale_s``: re-open the port after this many
    seconds without a byte (0 = never). Error counters (``health.errors``):
    the parser's (crc, sync/garbage_bytes, version, nonfinite, range,
    seq_gap, duplicate, seq_backwards, time_backwards, time_jump) and
    clock events (clock_wrap, clock_reanchor_reboot/jump/stall: see
    SERIAL_FRAME.md) plus open_failed, port_lost, silence, sink_error.
    """

    def __init__(self, port: str, baudrate: int = 921600, name: str = "serial_imu", stale_s: float = 2.0) -> None:
        if not port:
            raise ValueError("serial IMU: 'port' must name a device, e.g. /dev/ttyUSB0")
        if not isinstance(baudrate, int) or baudrate <= 0:
            raise ValueError(f"serial IMU: 'baudrate' must be a positive integer, got {baudrate!r}")
        self.name = name
        self.port = port
        self.baudrate = baudrate
        self.stale_s = stale_s
        self.health = DriverHealth(name)
        self.parser = FrameParser()
        self._backoff = Backoff()

    @classmethod
    def from_config(cls, cfg: dict[str, Any]) -> SerialImuDriver:
        """``{"type": "serial_imu", "port": "/dev/ttyUSB0", "baudrate": 921600, "name": ..., "stale_s": 2}``."""
        known = {"type", "port", "baudrate", "name", "stale_s"}
        bad = set(cfg) - known
        if bad:
            raise ValueError(f"serial IMU config: unknown key(s) {sorted(bad)} (known: {sorted(known)})")
        if "port" not in cfg:
            raise ValueError("serial IMU config: missing key 'port'")
        return cls(
            str(cfg["port"]),
            int(cfg.get("baudrate", 921600)),
            str(cfg.get("name", "serial_imu")),
            float(cfg.get("stale_s", 2.0)),
        )

    def feed(self, data: bytes, sink: Sink, now_ns: int) -> None:
        """Parse bytes and deliver the good samples (also used by tests/benchmarks). Several samples of one read
        (redundant IMUs' frames on one link) go in one call when the sink takes them (its ``many`` attribute: the
        gateway's, which then runs the core once for them), in order; else one call each. ``many`` gets an
        iterator of the read's samples and takes them one at a time, in order: if it raises, the sample it was
        taking is lost (one ``sink_error``) and the ones it had not taken yet go to ``sink`` one call each."""
        h = self.health
        out = self.parser.feed(data, now_ns)
        many = getattr(sink, "many", None) if len(out) > 1 else None
        if many is not None:
            h.samples += len(out) - 1
            h.seen(now_ns)
            rest = iter(out)
            try:
                many(rest)
            except Exception:  # a faulty sink must not kill the driver, nor lose the read's other samples
                h.count("sink_error")
                for s in rest:
                    try:
                        sink(s)
                    except Exception:
                        h.count("sink_error")
        else:
            for s in out:
                h.seen(now_ns)
                try:
                    sink(s)
                except Exception:  # a faulty sink must not kill the driver
                    h.count("sink_error")
        counts = self.parser.counts
        errs = h.errors
        for k, v in counts.items():
            if k != "frames" and errs.get(k) != v:
                errs[k] = v

    async def _open(self, loop: asyncio.AbstractEventLoop, sink: Sink) -> tuple[Any, _FdReader | _Proto]:
        """Open the port: (what to close, the reader with ``lost`` and ``last_rx_ns``)."""
        import serial

        ser = serial.serial_for_url(self.port, baudrate=self.baudrate, do_not_open=True)
        ser.timeout = 0
        ser.open()
        try:
            ser.fileno()
        except Exception:  # a pyserial URL without a file descriptor: pyserial-asyncio-fast's transport
            ser.close()
            transport, proto = await serial_asyncio_fast.create_serial_connection(
                loop, lambda: _Proto(self, sink), self.port, baudrate=self.baudrate
            )
            return transport, proto  # type: ignore[return-value]
        try:
            r = _FdReader(self, sink, ser, loop)
        except BaseException:  # e.g. epoll refuses the descriptor: the port is not left open (run() retries)
            ser.close()
            raise
        return r, r

    async def run(self, sink: Sink) -> None:
        """Open, read, and re-open with backoff until cancelled."""
        loop = asyncio.get_running_loop()
        first = True
        while True:
            # a re-plugged device may restart its sequence and clock: the parser keeps every imu_id's
            # time base (its clock model re-anchors on the new clock), so the output time continues
            self.parser.reopen()
            try:
                transport, proto = await self._open(loop, sink)
            except Exception as e:  # port missing, permission, busy
                self.health.count("open_failed")
                self.health.last_error = f"open {self.port}: {e}"
                await self._backoff.wait()
                continue
            if not first:
                self.health.reconnects += 1
            first = False
            self.health.connected = True
            n0 = self.health.samples
            try:
                while True:
                    timeout = self.stale_s if self.stale_s > 0 else None
                    try:
                        exc = await asyncio.wait_for(asyncio.shield(proto.lost), timeout)
                    except TimeoutError:
                        if (time.monotonic_ns() - proto.last_rx_ns) * 1e-9 >= self.stale_s:
                            self.health.count("silence")
                            self.health.last_error = f"no data for {self.stale_s} s"
                            break
                        continue
                    self.health.count("port_lost")
                    self.health.last_error = f"port lost: {exc}"
                    break
            finally:
                self.health.connected = False
                transport.close()
            if self.health.samples > n0:
                self._backoff.reset()
            await self._backoff.wait()
