"""The gateway's own settings dataclasses: ``[gateway]``, ``[[inputs]]``, ``[recorder]`` (each key's unit, range and
help in its field's metadata, :mod:`ins_hil.settings`). Loaded and checked by :mod:`ins_hil.config`, described by
:mod:`ins_hil.config_schema`; here, below both, so that neither imports the other's caller."""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any, Protocol

from ins_hil.drivers.mavlink_in import GNSS_MESSAGES as MAVLINK_GNSS_MESSAGES
from ins_hil.runtime.mavlink_out import EndpointConfig
from ins_hil.settings import setting


class Gateway(Protocol):
    """What an input's driver table needs of the whole configuration (:class:`ins_hil.config.Config`)."""

    outputs: list[EndpointConfig]

    def mavlink_ids(self) -> list[tuple[int, int]]: ...


@dataclass
class GatewaySettings:
    name: str = setting("ins-hil", help="the gateway's name (status view, recording header)", nonempty=True)
    late_threshold_ms: float = setting(
        5.0, "ms", "(0, 10000]", "an IMU sample whose arrival → state latency exceeds this is 'late'"
    )
    queue_size: int = setting(4096, "samples", "[1, 10000000]", "bounded input queue; overflow is dropped and counted")
    status_period: float = setting(0.5, "s", "[0.01, 3600]", "period of the live status view")
    rt_priority: int = setting(
        0, "", "[0, 99]", "SCHED_FIFO priority with mlockall (root or CAP_SYS_NICE/CAP_IPC_LOCK); 0 = off"
    )
    input_timeout: float = setting(
        10.0, "s", "[0, 86400]", "ins-hil run exits 3 when an input delivered nothing by then; 0 = wait for ever"
    )


@dataclass
class InputConfig:
    """One ``[[inputs]]`` table: ``serial_imu`` (port, baud), ``mavlink`` (url, signing_key, sysid, compid,
    gnss_messages, fc_gnss_lag_s) or ``can_imu`` (``[inputs.options]``: the CAN IMU driver's keys,
    ins_hil.drivers.can_imu)."""

    name: str = setting("", help="the input's name (status view, counters)", nonempty=True, doc_default="input<N>")
    type: str = setting(
        "serial_imu",
        help=(
            "serial_imu: IMU frames on a serial port; mavlink: GNSS/baro from MAVLink; can_imu: CAN IMU; or a type "
            "a driver package registers (ins_hil.drivers entry points), its keys in [inputs.options]"
        ),
        choices=("serial_imu", "mavlink", "can_imu"),
    )
    port: str = setting(
        "sim", help="serial_imu: the device (/dev/ttyUSB0), or 'sim' for the simulator's pty", nonempty=True
    )
    baud: int = setting(921600, "bit/s", "[1, 20000000]", "serial_imu: baud rate")
    url: str = setting(
        "udpin:127.0.0.1:0",
        help="mavlink: udpin:HOST:PORT (0 = any free port), udpout:HOST:PORT, tcp:HOST:PORT, serial:DEV[:BAUD]",
    )
    signing_key: str = setting(
        "", help="mavlink: accept only messages signed with this key (32 bytes); '' = any", hex_bytes=32
    )
    sysid: int = setting(
        1,
        "",
        "[0, 255]",
        (
            "mavlink: take GNSS/baro only from this system id (the flight controller's; ArduPilot and PX4: 1); 0 = any "
            "(not on a shared network)"
        ),
    )
    compid: int = setting(
        0,
        "",
        "[0, 255]",
        (
            "mavlink: take GNSS only from this component; 0 = any (messages from the gateway's own output identities "
            "are always refused)"
        ),
    )
    gnss_messages: list[str] = setting(
        factory=list,
        help=(
            "mavlink: the GNSS messages taken (of GPS_RAW_INT, GPS2_RAW, GPS_INPUT, HIL_GPS); [] = all, less "
            "GPS_RAW_INT from a system an fc output sends GPS_INPUT to (its echo); naming GPS_RAW_INT while one "
            "does is a config error"
        ),
        type="list[str]",
    )
    fc_gnss_lag_s: float = setting(
        0.0,
        "s",
        "[0, 1]",
        (
            "mavlink: the flight controller's GNSS lag, removed from GPS_RAW_INT/GPS2_RAW time (their time is the FC's "
            "arrival, not the fix's time of validity)"
        ),
    )
    options: dict[str, Any] = setting(factory=dict, help="can_imu: the [inputs.options] table")

    def driver_table(self, cfg: Gateway | None = None) -> dict[str, Any]:
        """The ``ins_hil.drivers.factory.make_driver`` table of this input. The gateway's MAVLink input
        emits GNSS and baro only (the IMU comes from its own input); with the gateway's configuration ``cfg``
        it refuses messages from the gateway's own MAVLink identities (:meth:`Config.mavlink_ids`) and, when
        ``gnss_messages`` is left empty, GPS_RAW_INT from a system an ``fc`` output sends GPS_INPUT to."""
        if self.type == "serial_imu":
            return {"type": self.type, "name": self.name, "port": self.port, "baudrate": self.baud}
        if self.type == "mavlink":
            gnss = list(self.gnss_messages or MAVLINK_GNSS_MESSAGES)
            echo = gps_input_echo(self, cfg) if cfg is not None and not self.gnss_messages else None
            if echo is not None:
                gnss.remove("GPS_RAW_INT")
            return {"type": self.type, "name": self.name, "url": self.url, "system_id": self.sysid or None,
                    "component_id": self.compid or None, "gnss_messages": gnss, "fc_gnss_lag_s": self.fc_gnss_lag_s,
                    "own_ids": cfg.mavlink_ids() if cfg is not None else [],
                    "gnss_refused_why": f"{echo} (GPS1_TYPE = 14 echoes it back as GPS_RAW_INT)" if echo else "",
                    "signing_key": self.signing_key or None, "emit": ["gnss", "baro"]}  # fmt: skip
        return {"type": self.type, "name": self.name, **self.options}


@dataclass
class RecorderConfig:
    enabled: bool = setting(True, help="record every input to an .ihlog file (ins-hil replay reproduces the run)")
    dir: str = setting("recordings", help="directory of the recordings (ins-hil-<time>.ihlog)", nonempty=True)
    max_mb: float = setting(256.0, "MiB", "[0.01, 1048576]", "rotate files at this size")
    flush_period: float = setting(0.05, "s", "(0, 0.1]", "a killed process loses at most about this much")
    total_mb: float = setting(
        8192.0,
        "MiB",
        "[0.01, 16777216]",
        "all parts of one run; its oldest parts are deleted first (8192 ≈ 25 h at 1 kHz)",
    )
    dir_total_mb: float = setting(
        0.0, "MiB", "[0, 16777216]", "every .ihlog in dir; other runs' oldest files deleted first; 0 = no limit"
    )


def gps_input_echo(ic: InputConfig, cfg: Gateway) -> str | None:
    """Why GPS_RAW_INT from the MAVLink input ``ic``'s source may be our own fix echoed ("outputs[j] sends GPS_INPUT
    to system S"), or None: an ``fc`` output sends GPS_INPUT to the system the input takes GNSS from (ArduPilot
    with GPS1_TYPE = 14 sends it back as its GPS_RAW_INT)."""
    for j, o in enumerate(cfg.outputs):
        if o.role == "fc" and o.effective_rates().get("GPS_INPUT", 0) > 0 and ic.sysid in (0, o.sysid):
            return f"outputs[{j}] sends GPS_INPUT to system {o.sysid}"
    return None
