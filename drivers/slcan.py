"""python-can's slcan (Lawicel) bus, read in bulk.

python-can 4.x reads an slcan line one byte per ``read(1)`` call: about 30 system calls per CAN
frame, so a DroneCAN IMU at 1 kHz (7 frames per RawIMU) costs ~200k calls per second and falls
seconds behind. :class:`BulkSlcanBus` reads everything waiting in one call and queues the complete
lines; parsing, writing and the open/close commands stay python-can's.
"""

from __future__ import annotations

import re
from collections import deque
from typing import Any

import can
import serial
from can.interfaces.slcan import slcanBus

#: one slcan line ends at CR (a frame or OK) or BEL (an error)
_LINE = re.compile(rb"[^\r\a]*[\r\a]")


class BulkSlcanBus(slcanBus):
    """:class:`can.interfaces.slcan.slcanBus` with a bulk line reader (same constructor arguments)."""

    def __init__(self, channel: Any, **kwargs: Any) -> None:
        self._lines: deque[str] = deque()
        super().__init__(channel, **kwargs)

    def _read(self, timeout: float | None) -> str | None:
        if self._lines:
            return self._lines.popleft()
        deadline = serial.Timeout(timeout)
        port = self.serialPortOrig
        while True:
            n = port.in_waiting
            if n == 0 and timeout is not None and timeout <= 0:
                return None  # a poll: read(1) would wait the port's own timeout (1 ms) on an empty line
            chunk = port.read(n if n > 0 else 1)
            if chunk:
                buf = self._buffer
                buf.extend(chunk)
                end = 0
                for m in _LINE.finditer(buf):
                    self._lines.append(m.group().decode("ascii", "replace"))
                    end = m.end()
                if end:
                    del buf[:end]
                if self._lines:
                    return self._lines.popleft()
            if deadline.expired():
                return None

    def flush(self) -> None:
        self._lines.clear()
        super().flush()


def open_bus(cfg: dict[str, Any]) -> can.BusABC:
    """``can.Bus(**cfg)``, with the bulk reader for ``interface = "slcan"``."""
    if cfg.get("interface") == "slcan":
        kw = {k: v for k, v in cfg.items() if k not in ("interface", "channel")}
        return BulkSlcanBus(cfg.get("channel"), **kw)
    return can.Bus(**cfg)
