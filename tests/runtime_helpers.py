"""Helpers shared by the runtime, recorder, driver and interop tests: configs, free ports, a UDP MAVLink listener,
running an input driver into a list, the measurements due at each IMU sample."""

from __future__ import annotations

import asyncio
import os
import socket
import tomllib
import tty
from collections.abc import Iterable, Iterator, Sequence
from pathlib import Path
from typing import Any, TypeVar

from ins_hil.config import Config, default_path, from_dict

M = TypeVar("M")


def with_due(imu: Iterable[Any], meas: Sequence[M], delay: float = 0.0) -> Iterator[tuple[Any, Sequence[M]]]:
    """Each IMU sample with the measurements (sorted by time) that fall due by it, in order: those whose time of
    validity + ``delay`` (s, the delivery lag) is at or before the sample's time (1 ns slack), each once."""
    j = 0
    for s in imu:
        k = j
        while j < len(meas) and meas[j].t + delay <= s.t + 1e-9:  # type: ignore[attr-defined]
            j += 1
        yield s, meas[k:j]


class BufferSink:
    """Transport stand-in for a MAVLink endpoint: keeps every buffer written."""

    def __init__(self) -> None:
        self.bufs: list[bytes] = []

    def write(self, b: bytes) -> bool:
        self.bufs.append(bytes(b))
        return True


def open_raw_pty() -> tuple[int, str]:
    """A pseudo-terminal in raw mode: (master fd, the slave's device name); the slave fd is closed, a driver opens
    the device by name."""
    master, slave = os.openpty()
    tty.setraw(master)
    name = os.ttyname(slave)
    os.close(slave)
    return master, name


async def start_driver(drv: Any) -> tuple[list[Any], asyncio.Task[Any]]:
    """Run the input driver ``drv`` in a task that appends every sample to a list; return (list, task) once the
    driver reports itself connected."""
    got: list[Any] = []
    task = asyncio.create_task(drv.run(got.append))
    while not drv.health.connected:
        await asyncio.sleep(0.01)
    return got, task


async def wait_for_count(got: list[Any], n: int, timeout: float = 30.0) -> None:
    """Poll every 20 ms until ``got`` holds ``n`` items or ``timeout`` s have passed (the caller checks which);
    the timeout only guards against a hang: a busy machine may take seconds."""
    for _ in range(round(timeout / 0.02)):
        if len(got) >= n:
            return
        await asyncio.sleep(0.02)


def free_port(kind: int = socket.SOCK_DGRAM) -> int:
    with socket.socket(socket.AF_INET, kind) as s:
        s.bind(("127.0.0.1", 0))
        return int(s.getsockname()[1])


def sim_config_dict(**over: Any) -> dict[str, Any]:
    """configs/default.toml as a dict with tables overridden by ``over`` (e.g. outputs=[...], mqtt={...})."""
    d = tomllib.loads(Path(default_path()).read_text())
    d["mqtt"] = {"enabled": False}
    d["outputs"] = []
    for k, v in over.items():
        if isinstance(v, dict) and isinstance(d.get(k), dict):
            d[k] = {**d[k], **v}
        else:
            d[k] = v
    return d


def sim_config(**over: Any) -> Config:
    return from_dict(sim_config_dict(**over), "test")


def sim_gateway(cfg: Config, **kw: Any) -> Any:
    """``Gateway(cfg, **kw)`` with the simulator as its devices (``[sim] enabled`` configs need them)."""
    from functools import partial

    from ins_hil.runtime.loop import Gateway
    from ins_hil.sim.devices import SimDevices

    return Gateway(cfg, devices=partial(SimDevices, cfg.sim), **kw)
