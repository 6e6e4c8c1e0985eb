"""Build a driver from one configuration table (e.g. a ``[[inputs]]`` entry of the runtime's TOML).

``type`` selects the driver; the other keys are the driver's own (see each
``from_config``). Unknown types and keys raise ValueError naming them.

    serial_imu: port, baudrate, name, stale_s
    can_imu:    interface, channel, (bitrate, ... any can.Bus keyword), protocol ("dronecan"|"dbc"),
                nodes, node_id, dbc {dbc, gyro_message, gyro_signals, accel_message, accel_signals,
                status_message, counter_signal, crc_signal, rate_hz}, name, stale_s
    mavlink:    url, system_id, source_system, source_component, signing_key, request {MSG: Hz},
                emit [gnss, baro, imu, mag], imu_dt, timesync_s, max_skew_s, name, stale_s
"""

from __future__ import annotations

from typing import Any

from ins_hil.drivers.base import Driver

TYPES = ("serial_imu", "can_imu", "mavlink")


def make_driver(cfg: dict[str, Any]) -> Driver:
    """A driver instance for ``cfg`` (its ``type`` key: serial_imu, can_imu or mavlink)."""
    kind = cfg.get("type")
    if kind == "serial_imu":
        from ins_hil.drivers.serial_imu import SerialImuDriver

        return SerialImuDriver.from_config(cfg)
    if kind == "can_imu":
        from ins_hil.drivers.can_imu import CanImuDriver

        return CanImuDriver.from_config(cfg)
    if kind == "mavlink":
        from ins_hil.drivers.mavlink_in import MavlinkDriver

        return MavlinkDriver.from_config(cfg)
    raise ValueError(f"driver config: 'type' must be one of {list(TYPES)}, got {kind!r}")
