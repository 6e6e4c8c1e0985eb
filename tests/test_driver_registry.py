"""One driver registry (ins_hil.drivers.factory): chosen by ``type``, third-party classes registered or found
through the ``ins_hil.drivers`` entry points, and the gateway builds its inputs through it."""

from __future__ import annotations

import asyncio
from importlib.metadata import EntryPoint
from typing import Any, ClassVar

import pytest
from ins_hil.drivers import factory
from ins_hil.drivers.base import DriverHealth, Sink
from runtime_helpers import sim_config, sim_config_dict

from ins_hil.runtime.loop import Gateway


class ThirdPartyImu:
    """A driver from another package: ``from_config`` and the Driver protocol, nothing else."""

    built: ClassVar[list[dict[str, Any]]] = []

    def __init__(self, name: str) -> None:
        self.name = name
        self.health = DriverHealth(name)

    @classmethod
    def from_config(cls, cfg: dict[str, Any]) -> ThirdPartyImu:
        cls.built.append(dict(cfg))
        return cls(str(cfg.get("name", "third_party")))

    async def run(self, sink: Sink) -> None:
        await asyncio.Event().wait()


@pytest.fixture
def registry(monkeypatch: pytest.MonkeyPatch) -> Any:
    monkeypatch.setattr(factory, "DRIVERS", factory.DRIVERS.copy())
    ThirdPartyImu.built = []
    return factory.DRIVERS


def test_unknown_type_is_a_one_line_error(registry: dict[str, Any]) -> None:
    for kind in ("gps", None, 3):
        with pytest.raises(ValueError) as e:
            factory.make_driver({"type": kind})
        msg = str(e.value)
        assert "\n" not in msg and repr(kind) in msg and "'serial_imu'" in msg and "'mavlink'" in msg


def test_a_registered_class_is_picked_up(registry: dict[str, Any]) -> None:
    factory.register("my_imu", ThirdPartyImu)
    d = factory.make_driver({"type": "my_imu", "name": "x"})
    assert isinstance(d, ThirdPartyImu) and d.name == "x"
    assert ThirdPartyImu.built == [{"type": "my_imu", "name": "x"}]
    with pytest.raises(ValueError, match="'my_imu'"):  # listed among the known types
        factory.make_driver({"type": "other"})


def test_an_entry_point_is_picked_up(registry: dict[str, Any], monkeypatch: pytest.MonkeyPatch) -> None:
    ep = EntryPoint("ep_imu", f"{__name__}:ThirdPartyImu", factory.ENTRY_POINT_GROUP)
    seen: list[str] = []

    def entry_points(group: str) -> list[EntryPoint]:
        seen.append(group)
        return [ep]

    import ins_hil.registry

    monkeypatch.setattr(ins_hil.registry, "entry_points", entry_points)
    d = factory.make_driver({"type": "ep_imu", "name": "y"})
    assert isinstance(d, ThirdPartyImu) and seen == ["ins_hil.drivers"]
    assert factory.DRIVERS["ep_imu"] is ThirdPartyImu  # looked up once


def test_the_config_and_the_gateway_build_inputs_through_the_registry(registry: dict[str, Any]) -> None:
    factory.register("serial_imu", ThirdPartyImu)
    cfg = sim_config(
        sim={"enabled": False},
        inputs=[{"name": "imu0", "type": "serial_imu", "port": "/dev/ins-hil-no-such-tty"}],
        recorder={"enabled": False},
    )
    table = {"type": "serial_imu", "name": "imu0", "port": "/dev/ins-hil-no-such-tty", "baudrate": 921600}
    assert ThirdPartyImu.built == [table]  # the config's start-up check builds it (no device opened)
    gw = Gateway(cfg)  # its parameter store re-validates the config: built again, unopened
    n = len(ThirdPartyImu.built)
    asyncio.run(gw.run(duration=0.2, signals=False))
    assert ThirdPartyImu.built == [table] * (n + 1)  # and the gateway's input, through the same registry
    assert [type(d) for d in gw.drivers] == [ThirdPartyImu]


def test_a_simulated_config_needs_the_devices() -> None:
    gw = Gateway(sim_config(recorder={"enabled": False}))
    with pytest.raises(RuntimeError, match="devices"):
        asyncio.run(gw.run(duration=0.2, signals=False))


def test_a_registered_driver_is_configured_from_toml(registry: dict[str, Any]) -> None:
    """A third-party type in ``[[inputs]]`` with its ``[inputs.options]``: the config takes it (built once to
    check its options), and a key outside the options or a type nobody registered is a one-line error."""
    from ins_hil.config import ConfigError, from_dict

    factory.register("lidar_imu", ThirdPartyImu)
    d = sim_config_dict()
    d["inputs"] = [*d["inputs"], {"name": "li", "type": "lidar_imu", "options": {"rate_hz": 400}}]
    cfg = from_dict(d, source="t")
    ic = next(i for i in cfg.inputs if i.type == "lidar_imu")
    assert ic.driver_table() == {"type": "lidar_imu", "name": "li", "rate_hz": 400}
    assert ThirdPartyImu.built[-1] == {"type": "lidar_imu", "name": "li", "rate_hz": 400}
    d["inputs"][-1] = {"name": "li", "type": "lidar_imu", "port": "/dev/x"}
    with pytest.raises(ConfigError, match=r"inputs\[\d\]\.port: a 'lidar_imu' input takes its keys in"):
        from_dict(d, source="t")
    d["inputs"][-1] = {"name": "li", "type": "radar_imu"}
    with pytest.raises(ConfigError, match="radar_imu"):
        from_dict(d, source="t")
