"""Helpers shared by the runtime, recorder and interop tests: configs, free ports, a UDP MAVLink listener."""

from __future__ import annotations

import socket
import tomllib
from pathlib import Path
from typing import Any

from ins_hil.config import Config, default_path, from_dict


class BufferSink:
    """Transport stand-in for a MAVLink endpoint: keeps every buffer written."""

    def __init__(self) -> None:
        self.bufs: list[bytes] = []

    def write(self, b: bytes) -> bool:
        self.bufs.append(bytes(b))
        return True


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
