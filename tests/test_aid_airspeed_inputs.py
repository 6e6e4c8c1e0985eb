"""The airspeed aid's inputs: MAVLink (AIRSPEED, VFR_HUD), DroneCAN TrueAirspeed, through the drivers with the
decoders the registry builds (the drivers never import the aids)."""

from __future__ import annotations

import asyncio
import math
import struct
from pathlib import Path
from typing import Any, ClassVar, cast

import dronecan
import numpy as np
import pytest
from ins_hil.drivers import factory
from ins_hil.drivers.base import DriverHealth
from ins_hil.drivers.mavlink_in import MavlinkDriver
from pymavlink.dialects.v20 import ardupilotmega as mavlink

from ins_hil import aids
from ins_hil.aids.airspeed import AirspeedSample, eas2tas, isa_temperature
from ins_hil.datasets.dataset import DatasetError, read_dataset
from ins_hil.runtime.pipeline import nav_config
from ins_hil.types import BaroSample

ON = nav_config({"airspeed": {"enabled": True}})


def _driver(nav: Any) -> tuple[MavlinkDriver, list, Any]:
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


def test_a_message_with_aid_decoders_is_timed_once() -> None:
    """SCALED_PRESSURE feeds the baro and the airspeed's density: an implausible FC time is counted once."""
    drv, got, (mav, feed) = _driver(ON)
    feed(mav.scaled_pressure_encode(10_000, 900.0, 0.0, 2000), 50.0)  # anchors the FC clock
    feed(mav.scaled_pressure_encode(110_000, 900.0, 0.0, 2000), 50.1)  # 100 s ahead of its arrival
    assert drv.health.errors.get("time_implausible") == 1 and len(got) == 1


def test_mavlink_vfr_hud_only_when_asked_and_no_airspeed_message() -> None:
    vfr = mavlink.MAVLink_vfr_hud_message(25.0, 24.0, 90, 50, 300.0, 0.5)
    for nav, n in ((ON, 0), (nav_config({"airspeed": {"enabled": True, "vfr_hud": True}}), 1)):
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
    assert aids.decoders("mavlink", nav_config({})) == {}
    assert aids.decoders("mavlink", nav_config({"airspeed": {"enabled": False}})) == {}
    _, got, (mav, feed) = _driver(nav_config({}))
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


# ------------------------------------------------------------------------------------------------ readers
def _df(mid: int, name: str, form: str, cols: str) -> bytes:
    length = 3 + struct.calcsize("<" + form)
    return b"\xa3\x95\x80" + struct.pack("<BB4s16s64s", mid, length, name.encode(), form.encode(), cols.encode())


def test_dataflash_arsp_is_read_as_true_airspeed(tmp_path: Path) -> None:
    """A DataFlash .bin with ARSP (EAS, two sensors, an unhealthy row) and BARO: TAS with BARO's pressure."""
    log = bytearray(_df(0x81, "IMU", "Qffffff", "TimeUS,GyrX,GyrY,GyrZ,AccX,AccY,AccZ"))
    log += _df(0x82, "BARO", "Qff", "TimeUS,Alt,Press") + _df(0x83, "ARSP", "QBffB", "TimeUS,I,Airspeed,Temp,H")
    for k in range(100):
        log += b"\xa3\x95\x81" + struct.pack("<Qffffff", 10_000 * k, 0.0, 0.0, 0.0, 0.0, 0.0, -9.8)
        if k % 10 == 0:
            log += b"\xa3\x95\x82" + struct.pack("<Qff", 10_000 * k, 1000.0, 89_000.0)
            log += b"\xa3\x95\x83" + struct.pack("<QBffB", 10_000 * k + 5000, 0, 22.0, 5.0, int(k != 50))
            log += b"\xa3\x95\x83" + struct.pack("<QBffB", 10_000 * k + 5000, 1, 99.0, 5.0, 1)  # second sensor
    p = tmp_path / "fw.bin"
    p.write_bytes(bytes(log))
    ds = read_dataset(p)
    assert all(isinstance(a, AirspeedSample) for a in ds.aids) and len(ds.aids) == 9  # k = 50 unhealthy
    rho = 89_000.0 / (287.05287 * 278.15)
    assert ds.aids[0].tas_mps == pytest.approx(22.0 * math.sqrt(1.225 / rho), rel=1e-6)
    assert ds.aids[0].t == pytest.approx(0.005)


def test_px4_airspeed_topics() -> None:
    from ins_hil.datasets.px4 import _time

    def airspeed_from_topics(topics: dict) -> tuple[list, str]:  # the aid's reader hook, as the ULog reader calls it
        got, note = aids.by_name()["airspeed"].from_ulog(topics, _time)
        return got, note.rsplit(" ", 1)[-1] if note else ""

    ts = np.arange(5) * 1e5
    validated = {"timestamp": ts, "true_airspeed_m_s": np.array([20.0, 21.0, 22.0, np.nan, 24.0]),
                 "airspeed_source": np.array([1, 0, 2, 1, 4])}  # fmt: skip
    got, name = airspeed_from_topics({"airspeed_validated": validated})
    assert name == "airspeed_validated" and [a.tas_mps for a in got] == [20.0, 22.0]
    assert [a.t for a in got] == pytest.approx([0.0, 0.2])
    sensor = {"timestamp": ts + 50, "timestamp_sample": ts, "true_airspeed_m_s": np.full(5, 18.0)}
    got, name = airspeed_from_topics({"airspeed_validated": validated, "airspeed": sensor})
    assert name == "airspeed" and len(got) == 5 and got[1].t == pytest.approx(0.1)
    assert airspeed_from_topics({}) == ([], "")


def test_generic_csv_odometer_and_airspeed_records(tmp_path: Path) -> None:
    from ins_hil.aids.odometer import OdometerSample
    from ins_hil.datasets.generic_csv import MAGIC, read_generic_csv, write_generic_csv

    p = tmp_path / "d.csv"
    p.write_text(f"{MAGIC}\nimu,0.01,0.01,0,0,0,0,0,-9.8\nimu,0.02,0.01,0,0,0,0,0,-9.8\n"
                 "odo,0.015,12.5,\nairspeed,0.012,20.5,0.4\nodo,0.005,-1.5,0.1\n")  # fmt: skip
    ds = read_generic_csv(p)
    assert [type(a).__name__ for a in ds.aids] == ["OdometerSample", "AirspeedSample", "OdometerSample"]
    assert ds.aids[0] == OdometerSample(0.005, -1.5, 0.1)
    assert ds.aids[1].tas_mps == 20.5 and ds.aids[1].sigma == 0.4 and math.isnan(ds.aids[2].sigma)
    q = tmp_path / "again.csv"
    write_generic_csv(q, ds)
    assert read_generic_csv(q).aids == ds.aids
    p.write_text(f"{MAGIC}\nimu,0.01,0.01,0,0,0,0,0,-9.8\nodo,0.015\n")
    with pytest.raises(DatasetError, match=r"d.csv:3: odo: expected t and 2 fields \(at least 1 given\)"):
        read_generic_csv(p)


# ------------------------------------------------------------------------------------------------ DroneCAN
def test_dronecan_true_airspeed_through_the_driver() -> None:
    """uavcan.equipment.air_data.TrueAirspeed (1020), encoded by dronecan itself, through the CAN driver's decoder
    with the registry's table; without the table it is an ignored type, as before."""
    from ins_hil.drivers import dronecan_codec as dc
    from ins_hil.drivers.can_imu import CanImuDriver

    obj = dronecan.TYPENAMES["uavcan.equipment.air_data.TrueAirspeed"]()
    obj.true_airspeed, obj.true_airspeed_variance = 23.5, 0.25
    payload = bytes(dronecan.transport.Transfer(payload=obj).payload)
    frames = dc.split_transfer(1020, payload, transfer_id=3)
    can_id = dc.message_can_id(1020, source_node=42)

    plain = CanImuDriver({"interface": "virtual"})
    assert plain.dronecan.feed(can_id, frames[0], True, 10**9) is None and plain.dronecan.counts == {"ignored": 1}

    drv = CanImuDriver({"interface": "virtual"})
    assert drv.decoder_protocol == "dronecan"
    drv.set_decoders(aids.decoders("dronecan", ON))
    got = [drv.dronecan.feed(can_id, f, True, 7 * 10**9) for f in frames]
    a = got[-1]
    assert isinstance(a, AirspeedSample) and got[:-1] == [None] * (len(frames) - 1)
    assert a.tas_mps == pytest.approx(23.5, abs=0.02) and a.sigma == pytest.approx(0.5, abs=1e-3)
    assert a.source == 42 and a.t == 7.0 and a.t_arrival_ns == 7 * 10**9
    assert aids.source_of(a).validate(None, a) is None
    with pytest.raises(ValueError, match="not a free DroneCAN message type"):
        drv.set_decoders({"uavcan.equipment.ahrs.RawIMU": ()})
    odo = nav_config({"odometer": {"enabled": True}})
    assert aids.decoders("dronecan", odo) == {}  # no standard wheel-speed message


# ------------------------------------------------------------------------------------------------ replay
@pytest.mark.parametrize("seed", [1, 2, 3])
def test_a_fixed_wing_log_with_airspeed_replays_through_the_pipeline_and_learns_the_wind(
    tmp_path: Path, seed: int
) -> None:
    """A simulated fixed-wing (rest, take-off, sweeping coordinated turns at 20 m/s, wind (5, −3) m/s) written as a
    generic CSV with ``airspeed`` records, read back and replayed through the runtime's Pipeline (its GNSS drift
    monitor on): with the aid the wind is learnt (error/σ: seed 1 (−0.31, +0.58), seed 2 (+0.37, +0.57), seed 3
    (−0.41, −0.34); seed 2 was (−4.5, +0.1) with the first-order update: the drift monitor excluded the GNSS),
    without it the wind σ stays at 5 m/s."""
    from ins_hil.datasets.dataset import Dataset
    from ins_hil.datasets.generic_csv import read_generic_csv, write_generic_csv
    from ins_hil.runtime.pipeline import Pipeline, PipelineConfig
    from ins_hil.sim import sensors as se
    from ins_hil.sim import trajectory as tr
    from ins_hil.types import ImuSample

    wind = np.array((5.0, -3.0))
    truth = tr.generate(
        tr.uav_profile(speed=20.0, turn_period=60.0), 150.0, 0.01, math.radians(47.0), math.radians(8.0), 600.0
    )
    rng = np.random.default_rng(seed)
    imu = se.corrupt_imu(truth, se.mems_gyro(rng), se.mems_accel(rng), seed=seed + 1).samples()
    fixes = se.gnss_fixes(truth, se.GnssModel(rate=5, std_ne=0.5, std_d=1.0, std_vel=0.1), seed=seed + 2)
    tas = [AirspeedSample(float(truth.t[i]), float(np.linalg.norm(truth.vel_ned[i] - np.r_[wind, 0.0]))
                          + rng.normal(0.0, 0.3), 0.3) for i in range(10, len(truth.t), 10)]  # fmt: skip
    write_generic_csv(tmp_path / "fw.csv", Dataset(imu, fixes, aids=tas))
    ds = read_generic_csv(tmp_path / "fw.csv")
    assert len(ds.aids) == len(tas)
    for on in (True, False) if seed == 1 else (True,):
        nav = {"filter": {"wind_states": True, "init_wind": 5.0, "wind_sigma_rw": 0.01}, "airspeed": {"enabled": on}}
        pipe = Pipeline(PipelineConfig(init="gnss", nav=nav))
        for s in sorted([*ds.imu, *ds.gnss, *ds.aids], key=lambda s: (s.t, s.kind != "imu")):
            if s.kind == "imu":
                pipe.imu(cast(ImuSample, s))
            else:
                pipe.aid(s)
        pipe.flush()
        core: Any = pipe.core
        iw = core.idx.wind
        sd = np.sqrt(core.kf.P.diagonal()[iw : iw + 2])
        if on:
            assert core.stats["airspeed"].accepted > 1200 and pipe.counts.get("excluded_GnssFix", 0) == 0
            assert np.all(sd < 0.1) and np.all(np.abs(core.wind - wind) < 2.0 * sd), (core.wind, sd)
        else:
            assert "airspeed" not in core.stats and np.all(sd > 4.0)
