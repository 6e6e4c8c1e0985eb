"""The airspeed aid's inputs: MAVLink (AIRSPEED, VFR_HUD), DroneCAN TrueAirspeed, through the drivers with the
decoders the registry builds (the drivers never import the aids)."""

from __future__ import annotations

import asyncio
import math
from typing import Any, ClassVar

import pytest
from ins_hil.drivers import factory
from ins_hil.drivers.base import DriverHealth
from ins_hil.drivers.mavlink_in import MavlinkDriver
from pymavlink.dialects.v20 import ardupilotmega as mavlink

from ins_hil import aids
from ins_hil.aids.airspeed import AirspeedSample, eas2tas, isa_temperature
from ins_hil.types import BaroSample

ON = {"airspeed": {"enabled": True}}


def _driver(nav: dict[str, Any]) -> tuple[MavlinkDriver, list, Any]:
    drv = MavlinkDriver("udpin:127.0.0.1:0", system_id=1)
    drv.set_decoders(aids.decoders("mavlink", nav))
    got: list = []
    drv._sink = got.append
    mav = mavlink.MAVLink(None, srcSystem=1, srcComponent=1)

    def feed(m: Any, now_s: float) -> None:
        drv.feed(m.pack(mav), now_ns=round(now_s * 1e9))
        mav.seq = (mav.seq + 1) % 256

    return drv, got, (mav, feed)


def test_isa_density_ratio() -> None:
    assert eas2tas(101325.0, 288.15) == pytest.approx(1.0, abs=1e-4)  # sea level: TAS = EAS
    assert isa_temperature(101325.0) == pytest.approx(288.15)
    # ISA 3000 m: 70121 Pa, 268.65 K, ρ = 0.9093 kg/m³ → √(1.225/0.9093) = 1.1607
    assert eas2tas(70121.0, isa_temperature(70121.0)) == pytest.approx(1.1607, abs=2e-3)
    assert isa_temperature(70121.0) == pytest.approx(268.65, abs=0.1)


def test_mavlink_airspeed_to_true_airspeed() -> None:
    drv, got, (mav, feed) = _driver(ON)
    feed(mav.airspeed_encode(0, 20.0, 1500, 2.5, 0), 50.0)  # no static pressure yet: not converted
    assert got == [] and drv.health.errors.get("airspeed_no_pressure") == 1
    feed(mav.scaled_pressure_encode(10_000, 900.0, 0.0, 2000), 50.0)
    feed(mav.airspeed_encode(2, 20.0, 1500, 2.5, 0), 50.1)
    feed(mav.airspeed_encode(0, 21.0, 1500, 2.5, mavlink.AIRSPEED_SENSOR_UNHEALTHY), 50.2)
    assert [type(s) for s in got] == [BaroSample, AirspeedSample]  # the baro is still the driver's
    a = got[1]
    rho = 90000.0 / (287.05287 * (15.0 + 273.15))
    assert a.tas_mps == pytest.approx(20.0 * math.sqrt(1.225 / rho), rel=1e-6)
    assert a.source == 2 and a.t_arrival_ns == round(50.1e9) and a.t == pytest.approx(50.1, abs=1e-6)
    assert drv.health.errors.get("airspeed_unhealthy") == 1
    assert aids.source_of(a).validate(None, a) is None


def test_mavlink_vfr_hud_only_when_asked_and_no_airspeed_message() -> None:
    vfr = mavlink.MAVLink_vfr_hud_message(25.0, 24.0, 90, 50, 300.0, 0.5)
    for nav, n in ((ON, 0), ({"airspeed": {"enabled": True, "vfr_hud": True}}, 1)):
        _, got, (mav, feed) = _driver(nav)
        feed(mav.scaled_pressure_encode(10_000, 950.0, 0.0, 4000), 10.0)
        feed(vfr, 10.05)
        tas = [s for s in got if isinstance(s, AirspeedSample)]
        assert len(tas) == n
        if n:  # ISA temperature at 950 hPa (not the board's 40 °C)
            assert tas[0].tas_mps == pytest.approx(25.0 * eas2tas(95000.0, isa_temperature(95000.0)), rel=1e-6)
            feed(mav.airspeed_encode(0, 20.0, 1500, 2.5, 0), 10.1)
            feed(vfr, 10.15)  # the link sends AIRSPEED: VFR_HUD is no longer used
            assert [s.tas_mps for s in got if isinstance(s, AirspeedSample)][-1] == pytest.approx(
                20.0 * eas2tas(95000.0, 288.15), rel=1e-6
            )


def test_no_decoders_when_the_aid_is_off() -> None:
    assert aids.decoders("mavlink", {}) == {}
    assert aids.decoders("mavlink", {"airspeed": {"enabled": False}}) == {}
    _, got, (mav, feed) = _driver({})
    feed(mav.scaled_pressure_encode(10_000, 900.0, 0.0, 2000), 50.0)
    feed(mav.airspeed_encode(0, 20.0, 1500, 2.5, 0), 50.1)
    assert [type(s) for s in got] == [BaroSample]


class _DecodingImu:
    """A driver of a protocol with aid decoders: records the table the gateway hands it."""

    decoder_protocol = "mavlink"
    tables: ClassVar[list[dict[Any, Any]]] = []

    def __init__(self, name: str) -> None:
        self.name, self.health = name, DriverHealth(name)

    @classmethod
    def from_config(cls, cfg: dict[str, Any]) -> _DecodingImu:
        return cls(str(cfg.get("name", "x")))

    def set_decoders(self, table: dict[Any, Any]) -> None:
        self.tables.append(table)

    async def run(self, sink: Any) -> None:
        await asyncio.Event().wait()


def test_the_gateway_hands_the_enabled_aids_decoders_to_its_drivers(monkeypatch: pytest.MonkeyPatch) -> None:
    """Live: the gateway builds the decoders from the registry and the ``[core.nav]`` table."""
    from runtime_helpers import sim_config

    from ins_hil.runtime.loop import Gateway

    monkeypatch.setattr(factory, "DRIVERS", {**factory.DRIVERS, "dec_imu": _DecodingImu})
    inputs = [{"name": "imu0", "type": "dec_imu", "options": {}}]
    for on in (False, True):
        nav = {"filter": {"wind_states": True}, "airspeed": {"enabled": on}}
        cfg = sim_config(sim={"enabled": False}, inputs=inputs, recorder={"enabled": False}, core={"nav": nav})
        gw = Gateway(cfg)
        asyncio.run(gw.run(duration=0.1, signals=False))
    assert [sorted(t) for t in _DecodingImu.tables] == [[], ["AIRSPEED", "SCALED_PRESSURE"]]
