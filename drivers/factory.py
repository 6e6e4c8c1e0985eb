"""Build a driver from one configuration table (e.g. a ``[[inputs]]`` entry of the runtime's TOML).

One registry, :data:`DRIVERS` (an :class:`ins_hil.registry.Registry`: name → (module, class), imported
when first named, as python-can's ``BACKENDS``), maps the table's ``type`` to a driver class with
``from_config(table)``; the gateway (``ins_hil.runtime.loop``) builds every input
through :func:`make_driver`. A third-party driver registers itself with
:func:`register`, or is found by name in the Python entry points group ``ins_hil.drivers``
(``[project.entry-points."ins_hil.drivers"] my_imu = "my_pkg.imu:MyImuDriver"``).
The other keys are the driver's own (see each ``from_config``). Unknown types and
keys raise ValueError naming them, in one line.

    serial_imu: port, baudrate, name, stale_s
    can_imu:    interface, channel, (bitrate, ... any can.Bus keyword), protocol ("dronecan"|"dbc"),
                nodes, node_id, dbc {dbc, gyro_message, gyro_signals, accel_message, accel_signals,
                status_message, counter_signal, crc_signal, rate_hz}, name, stale_s
    mavlink:    url, system_id, source_system, source_component, signing_key, request {MSG: Hz},
                emit [gnss, baro, imu, mag], imu_dt, timesync_s, max_skew_s, name, stale_s
"""

from __future__ import annotations

from typing import Any, Protocol

from ins_hil.drivers.base import Driver

from ins_hil.registry import Registry

#: the entry points group searched for a ``type`` that is not registered
ENTRY_POINT_GROUP = "ins_hil.drivers"


class DriverClass(Protocol):
    """What the registry holds: a class that builds its driver from a configuration table."""

    def from_config(self, cfg: dict[str, Any]) -> Driver: ...


#: ``type`` → the driver class, ``(module, class)`` imported on first use (a serial-only setup never imports
#: python-can)
DRIVERS: Registry[DriverClass] = Registry(
    "driver type",
    {
        "serial_imu": ("ins_hil.drivers.serial_imu", "SerialImuDriver"),
        "can_imu": ("ins_hil.drivers.can_imu", "CanImuDriver"),
        "mavlink": ("ins_hil.drivers.mavlink_in", "MavlinkDriver"),
    },
    group=ENTRY_POINT_GROUP,
)
TYPES = tuple(DRIVERS)  # the built-in types


def register(kind: str, cls: DriverClass | str) -> None:
    """Make ``type = kind`` build ``cls`` (a class with ``from_config``, or ``"module:Class"``)."""
    if isinstance(cls, str):
        module, _, name = cls.partition(":")
        DRIVERS.register(kind, (module, name))
    else:
        DRIVERS.register(kind, cls)


def driver_class(kind: Any) -> DriverClass:
    """The class registered for ``kind`` (:data:`DRIVERS`, then the entry points); ValueError if none."""
    try:
        return DRIVERS[kind]
    except KeyError:
        raise ValueError(f"driver config: 'type' must be one of {sorted(DRIVERS)}, got {kind!r}") from None


def make_driver(cfg: dict[str, Any]) -> Driver:
    """A driver instance for ``cfg``: the class registered for its ``type`` key, ``from_config(cfg)``."""
    return driver_class(cfg.get("type")).from_config(cfg)
