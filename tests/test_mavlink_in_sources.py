"""MAVLink GNSS input held to the spec and to a real flight controller's set-up (issue 38 items 2, 3, 4, 8):
heights on the WGS84 datum (``alt`` is MSL in common.xml), GNSS only from the configured source and never
our own output echoed back, our HEARTBEAT not a ground station's, one fix per GNSS time (issue 39), the
FC's GNSS lag removed."""

from __future__ import annotations

import asyncio
import logging
import math
import socket
import time
from typing import Any

import pytest
from ins_hil.drivers.factory import make_driver
from ins_hil.drivers.mavlink_in import MavlinkDriver
from pymavlink.dialects.v20 import ardupilotmega as mavlink

from ins_hil import config
from ins_hil.config import REPO_CONFIGS, ConfigError
from ins_hil.geoid import undulation
from ins_hil.sim.fc import SimFlightController
from ins_hil.types import GnssFix, gps_from_unix

LAT, LON = 50.45, 30.52  # Kyiv: EGM96 undulation ≈ 25.4 m
MSL = 154.61  # m: a fix here at this MSL altitude is at h ≈ 180.0 m above the WGS84 ellipsoid
NOW = 50 * 10**9


def _collect(drv: MavlinkDriver) -> list[Any]:
    got: list[Any] = []
    drv._sink = got.append
    return got


class _Fc:
    """Packs messages as one MAVLink source (system, component) and feeds them to a driver."""

    def __init__(self, drv: MavlinkDriver, sysid: int = 1, compid: int = 1) -> None:
        self.drv = drv
        self.mav = mavlink.MAVLink(None, srcSystem=sysid, srcComponent=compid)

    def send(self, m: Any, now_ns: int = NOW, sysid: int | None = None, compid: int | None = None) -> None:
        if sysid is not None:
            self.mav.srcSystem = sysid
        if compid is not None:
            self.mav.srcComponent = compid
        self.drv.feed(m.pack(self.mav), now_ns=now_ns)
        self.mav.seq = (self.mav.seq + 1) % 256


def _gps_raw(mav: Any, t_us: int, alt_mm: int, alt_ellipsoid_mm: int = 0) -> Any:
    return mav.gps_raw_int_encode(t_us, 3, round(LAT * 1e7), round(LON * 1e7), alt_mm, 80, 120, 0, 0, 12,
                                  alt_ellipsoid_mm, 1500, 2500, 200, 0)  # fmt: skip


def _gps_input(mav: Any, t_us: int, alt_m: float, week: int = 0, week_ms: int = 0) -> Any:
    return mav.gps_input_encode(t_us, 0, 0, week_ms, week, 3, round(LAT * 1e7), round(LON * 1e7), alt_m, 0.8, 1.2,
                                0.0, 0.0, 0.0, 0.2, 0.9, 1.4, 14)  # fmt: skip


def _hil_gps(mav: Any, t_us: int, alt_mm: int) -> Any:
    return mav.hil_gps_encode(t_us, 3, round(LAT * 1e7), round(LON * 1e7), alt_mm, 90, 130, 0, 0, 0, 0, 0, 10)


# ---------------------------------------------------------------------------------------------- datum
@pytest.mark.parametrize(
    "kind",
    ["GPS_INPUT", "HIL_GPS", "GPS_RAW_INT", "GPS_RAW_INT+alt_ellipsoid", "GPS2_RAW"],
)
def test_a_fix_at_msl_enters_on_the_wgs84_datum(kind: str) -> None:
    """A fix at MSL 154.61 m at 50.45 N 30.52 E is h = 180.0 ± 1 m (EGM96 N ≈ 25.4 m) whatever message carries
    it; with ``alt_ellipsoid`` filled, that WGS84 height is taken as it is."""
    drv = MavlinkDriver("udpin:127.0.0.1:0")
    got = _collect(drv)
    fc = _Fc(drv)
    m = fc.mav
    msg = {
        "GPS_INPUT": lambda: _gps_input(m, 1_000_000, MSL),
        "HIL_GPS": lambda: _hil_gps(m, 1_000_000, round(MSL * 1e3)),
        "GPS_RAW_INT": lambda: _gps_raw(m, 1_000_000, round(MSL * 1e3)),
        "GPS_RAW_INT+alt_ellipsoid": lambda: _gps_raw(m, 1_000_000, round(MSL * 1e3), 180_000),
        "GPS2_RAW": lambda: m.gps2_raw_encode(1_000_000, 3, round(LAT * 1e7), round(LON * 1e7), round(MSL * 1e3),
                                              80, 120, 0, 0, 9, 0, 0, 0, 0, 0, 0, 0, 0),
    }[kind]()  # fmt: skip
    fc.send(msg)
    (fix,) = [s for s in got if isinstance(s, GnssFix)]
    assert fix.h == pytest.approx(180.0, abs=1.0), f"{kind}: h = {fix.h:.2f} m"


def test_simulated_fc_writes_msl_and_round_trips() -> None:
    """The simulated flight controller writes GPS_RAW_INT ``alt`` as MSL (its ``h_m`` less the undulation) and
    ``alt_ellipsoid`` as WGS84: the driver gets ``h_m`` back either way, and ``alt`` alone is no longer h."""
    for ell in (True, False):
        sim = SimFlightController(target=("127.0.0.1", 9), alt_ellipsoid=ell)
        m = sim._gps(time.monotonic())
        assert m.alt == pytest.approx((sim.h_m - undulation(math.radians(LAT), math.radians(LON))) * 1e3, abs=1)
        assert m.alt_ellipsoid == (round(sim.h_m * 1e3) if ell else 0)
        drv = MavlinkDriver("udpin:127.0.0.1:0")
        got = _collect(drv)
        drv.feed(m.pack(mavlink.MAVLink(None, srcSystem=1, srcComponent=1)), now_ns=NOW)
        assert [s.h for s in got] == [pytest.approx(sim.h_m, abs=0.01)]


def test_simulated_gnss_device_sends_msl() -> None:
    """The simulated GNSS device's GPS_INPUT ``alt`` is MSL: the driver's h is the truth's WGS84 height."""
    from ins_hil.sim.devices import _send_gnss

    sent: list[Any] = []

    class _Mav:
        def gps_input_send(self, *a: Any) -> None:
            sent.append(a)

    f = GnssFix(t=1.0, lat=math.radians(LAT), lon=math.radians(LON), h=180.0, vel_ned=[0.0, 0.0, 0.0], std_ne=1.0,
                std_d=1.5, std_vel=0.2, num_sats=12)  # fmt: skip
    _send_gnss(_Mav(), f)
    assert sent[0][8] == pytest.approx(MSL, abs=0.1)  # alt


# ---------------------------------------------------------------------------------------------- sources
def _gateway_input(path: str = "default.toml", **over: Any) -> MavlinkDriver:
    cfg = config.load(REPO_CONFIGS / path)
    ic = next(i for i in cfg.inputs if i.type == "mavlink")
    for k, v in over.items():
        setattr(ic, k, v)
    return make_driver(ic.driver_table(cfg))


def test_gateway_takes_gnss_only_from_the_configured_system() -> None:
    """The default configuration takes GNSS only from system 1 (ArduPilot's and PX4's default): a GPS_INPUT
    from system 200 is refused and counted."""
    drv = _gateway_input()
    got = _collect(drv)
    fc = _Fc(drv)
    fc.send(_gps_input(fc.mav, 1_000_000, MSL), sysid=200)
    fc.send(_gps_input(fc.mav, 1_100_000, MSL), sysid=1, compid=220)
    assert len(got) == 1 and drv.health.errors == {"unknown_system": 1}


def test_gnss_from_our_own_output_identity_is_refused_and_said_once(caplog: pytest.LogCaptureFixture) -> None:
    """flight_controller.toml's fc output is 1/197 (the autopilot's system): our own GPS_INPUT routed back from
    it is refused (``own_message``), said once however often it comes, and the FC's own GNSS still passes."""
    drv = _gateway_input("flight_controller.toml", compid=0)
    assert (1, 197) in drv.own_ids and (42, 1) in drv.own_ids
    got = _collect(drv)
    fc = _Fc(drv)
    with caplog.at_level(logging.WARNING, logger="ins_hil"):
        for k in range(3):
            fc.send(_gps_input(fc.mav, 1_000_000 + k * 100_000, MSL), compid=197)
    fc.send(_gps_raw(fc.mav, 2_000_000, round(MSL * 1e3)), compid=1)
    assert len(got) == 1 and drv.health.errors == {"own_message": 3}
    said = [r.getMessage() for r in caplog.records if "an identity the gateway's outputs send as" in r.getMessage()]
    assert len(said) == 1 and "1/197" in said[0]


def test_gnss_only_from_the_configured_component_and_types() -> None:
    warned: list[str] = []
    drv = MavlinkDriver("udpin:127.0.0.1:0", system_id=1, component_id=1, gnss_messages=["GPS2_RAW"],
                        on_warn=warned.append)  # fmt: skip
    got = _collect(drv)
    fc = _Fc(drv)
    fc.send(_gps_raw(fc.mav, 1_000_000, 180_000))  # a type not taken
    fc.send(_gps_raw(fc.mav, 1_200_000, 180_000))
    fc.send(fc.mav.gps2_raw_encode(1_300_000, 3, 504500000, 305200000, 180000, 80, 120, 0, 0, 9, 0, 0, 0, 0, 0, 0,
                                   0, 0), compid=220)  # another component  # fmt: skip
    fc.send(fc.mav.gps2_raw_encode(1_400_000, 3, 504500000, 305200000, 180000, 80, 120, 0, 0, 9, 0, 0, 0, 0, 0, 0,
                                   0, 0), compid=1)  # fmt: skip
    assert len(got) == 1 and drv.health.errors == {"gnss_refused": 3}
    assert len(warned) == 2 and "GPS_RAW_INT" in warned[0] and "component 220" in warned[1]


def test_the_gps_input_echo_loop_is_a_one_line_config_error() -> None:
    """ArduPilot with GPS1_TYPE = 14 sends our GPS_INPUT back as its GPS_RAW_INT: an fc output sending GPS_INPUT
    to system 1 while an input takes GPS_RAW_INT from it is refused at load (and so as a parameter change)."""
    cfg = config.load(REPO_CONFIGS / "flight_controller.toml")
    doc = cfg.document()
    doc["outputs"][0].setdefault("rates", {})["GPS_INPUT"] = 5.0
    with pytest.raises(ConfigError) as e:
        cfg.revalidate(doc)
    msg = str(e.value)
    assert "\n" not in msg and "inputs[1]" in msg and "GPS_RAW_INT" in msg and "GPS_INPUT" in msg
    doc["inputs"][1]["gnss_messages"] = ["GPS2_RAW"]  # the documented way out: the FC's second receiver only
    assert cfg.revalidate(doc).inputs[1].gnss_messages == ["GPS2_RAW"]
    doc["inputs"][1]["gnss_messages"] = ["GPS3_RAW"]
    with pytest.raises(ConfigError, match="gnss_messages"):
        cfg.revalidate(doc)


def test_gps_raw_int_echo_refused_by_default_when_we_send_gps_input() -> None:
    """``gnss_messages`` left empty: with an fc output sending GPS_INPUT to system 1 (its default 5 Hz), the input
    refuses GPS_RAW_INT from system 1 (our fix echoed by GPS1_TYPE = 14), says why once, takes GPS2_RAW."""
    cfg = config.load(REPO_CONFIGS / "default.toml")
    doc = cfg.document()
    doc["outputs"].append({"name": "fc", "type": "mavlink", "url": "udpout:127.0.0.1:14555", "role": "fc",
                           "sysid": 1, "compid": 197})  # fmt: skip
    cfg = cfg.revalidate(doc)
    warned: list[str] = []
    drv = make_driver(cfg.inputs[1].driver_table(cfg))
    drv.on_warn = warned.append
    got = _collect(drv)
    fc = _Fc(drv)
    fc.send(_gps_raw(fc.mav, 1_000_000, 180_000))
    fc.send(_gps_raw(fc.mav, 1_200_000, 180_000))
    fc.send(fc.mav.gps2_raw_encode(1_300_000, 3, 504500000, 305200000, 180000, 80, 120, 0, 0, 9, 0, 0, 0, 0, 0, 0,
                                   0, 0))  # fmt: skip
    assert len(got) == 1 and drv.health.errors == {"gnss_refused": 2}
    assert len(warned) == 1 and "outputs[1] sends GPS_INPUT to system 1" in warned[0]
    # without that output, GPS_RAW_INT is taken
    plain = make_driver(config.load(REPO_CONFIGS / "default.toml").inputs[1].driver_table(cfg=None))
    assert "GPS_RAW_INT" in plain.gnss_messages


def test_an_input_that_would_refuse_the_simulated_gnss_is_a_config_error() -> None:
    cfg = config.load(REPO_CONFIGS / "default.toml")
    doc = cfg.document()
    doc["inputs"][1]["sysid"] = 7
    with pytest.raises(ConfigError, match=r"would refuse the simulated GNSS"):
        cfg.revalidate(doc)


# ---------------------------------------------------------------------------------------------- heartbeat
def test_our_heartbeat_is_not_a_ground_stations() -> None:
    """ArduPilot (GCS_Common.cpp handle_heartbeat) takes any heartbeat from a GCS system id (MAV_GCS_SYSID,
    default 255) as its ground station's, PX4 one of type MAV_TYPE_GCS: ours comes from the FC's system with
    an onboard computer's component and type, so a lost real ground station still trips FS_GCS."""

    async def main() -> list[Any]:
        fc_sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        fc_sock.bind(("127.0.0.1", 0))
        fc_sock.setblocking(False)
        drv = MavlinkDriver(f"udpout:127.0.0.1:{fc_sock.getsockname()[1]}", system_id=1, timesync_s=0.2)
        task = asyncio.create_task(drv.run(lambda s: None))
        loop = asyncio.get_running_loop()
        parser = mavlink.MAVLink(None)
        hbs: list[Any] = []
        try:
            while not hbs:
                data, _ = await asyncio.wait_for(loop.sock_recvfrom(fc_sock, 4096), 10.0)
                hbs += [m for m in parser.parse_buffer(data) or [] if m.get_type() == "HEARTBEAT"]
        finally:
            task.cancel()
            await asyncio.gather(task, return_exceptions=True)
            fc_sock.close()
        return hbs

    hb = asyncio.run(main())[0]
    assert hb.get_srcSystem() == 1 and hb.get_srcSystem() != 255
    assert hb.get_srcComponent() == mavlink.MAV_COMP_ID_ONBOARD_COMPUTER
    assert hb.type == mavlink.MAV_TYPE_ONBOARD_CONTROLLER and hb.type != mavlink.MAV_TYPE_GCS
    with pytest.raises(ValueError, match="ground station"):
        MavlinkDriver("udpin:127.0.0.1:0", source_system=255)


# ---------------------------------------------------------------------------------------------- time
@pytest.mark.parametrize("kind", ["GPS_RAW_INT", "GPS_INPUT", "HIL_GPS"])
def test_repeated_or_backwards_gnss_times_are_not_delivered(kind: str) -> None:
    """A flight controller streaming GPS_RAW_INT faster than its receiver repeats the last fix with the same
    time: fused once. Times [1.0, 1.0, 0.5, 1.2] s deliver 1.0 and 1.2 only (issue 39: [0, 0, −1] was
    delivered whole); an FC reboot (time more than 5 s back) restarts the stream."""
    drv = MavlinkDriver("udpin:127.0.0.1:0")
    got = _collect(drv)
    fc = _Fc(drv)
    make = {"GPS_RAW_INT": lambda us: _gps_raw(fc.mav, us, 180_000), "GPS_INPUT": lambda us: _gps_input(
        fc.mav, us, MSL), "HIL_GPS": lambda us: _hil_gps(fc.mav, us, 180_000)}[kind]  # fmt: skip
    for k, t in enumerate([100.0, 100.0, 99.5, 100.2]):
        fc.send(make(round(t * 1e6)), now_ns=NOW + k * 100_000_000)
    assert [round(s.t - got[0].t, 6) for s in got] == [0.0, 0.2]
    assert drv.health.errors == {"duplicate": 1, "time_backwards": 1}
    fc.send(make(round(3.0 * 1e6)), now_ns=NOW + 10**9)  # rebooted: its clock restarts
    assert drv.health.errors.get("gnss_restart") == 1


def test_the_fc_gnss_lag_is_removed_from_gps_raw_int() -> None:
    """GPS_RAW_INT's time is the FC's arrival stamp of the fix: with ``fc_gnss_lag_s`` the fix is placed that
    much earlier (its time of validity); GPS_INPUT's own time is left alone."""
    ts = {}
    for lag in (0.0, 0.12):
        drv = MavlinkDriver("udpin:127.0.0.1:0", fc_gnss_lag_s=lag)
        got = _collect(drv)
        fc = _Fc(drv)
        fc.send(fc.mav.heartbeat_encode(2, 3, 0, 0, 0))
        fc.send(fc.mav.scaled_pressure_encode(1000, 1000.0, 0.0, 2000))  # anchors FC time 1.0 s at NOW
        fc.send(_gps_raw(fc.mav, 1_500_000, 180_000), now_ns=NOW + 600_000_000)
        fc.send(_gps_input(fc.mav, 1_600_000, MSL), now_ns=NOW + 700_000_000)
        ts[lag] = [s.t for s in got if isinstance(s, GnssFix)]
    assert ts[0.0][0] - ts[0.12][0] == pytest.approx(0.12, abs=1e-6)
    assert ts[0.0][1] == pytest.approx(ts[0.12][1], abs=1e-9)


def test_gps_input_without_a_sender_clock_is_timed_by_its_gps_time() -> None:
    """GPS_INPUT with time_usec = 0 but a GPS week time: stamped at that time of validity (through the host's
    clock), not at its arrival; consecutive fixes with the same GPS time are one fix."""
    drv = MavlinkDriver("udpin:127.0.0.1:0")
    got = _collect(drv)
    fc = _Fc(drv)
    now = time.monotonic_ns()
    week, tow = gps_from_unix(time.time() - 2.0)  # a fix valid 2 s ago
    ms = round(tow * 1000)
    fc.send(_gps_input(fc.mav, 0, MSL, week, ms), now_ns=now)
    fc.send(_gps_input(fc.mav, 0, MSL, week, ms), now_ns=now)
    assert len(got) == 1
    assert now * 1e-9 - got[0].t == pytest.approx(2.0, abs=0.5)


def test_gnss_without_any_time_is_timed_by_its_arrival_once() -> None:
    """Neither a sender time nor a GPS time: stamped at arrival, and two arriving at the same instant are one."""
    drv = MavlinkDriver("udpin:127.0.0.1:0")
    got = _collect(drv)
    fc = _Fc(drv)
    for now in (NOW, NOW, NOW - 1000, NOW + 200_000_000):
        fc.send(_gps_input(fc.mav, 0, MSL), now_ns=now)
    assert [s.t for s in got] == [NOW * 1e-9, (NOW + 200_000_000) * 1e-9]
    assert drv.health.errors == {"duplicate": 1, "time_backwards": 1}


# ---------------------------------------------------------------------------------------------- gateway
@pytest.mark.slow
def test_gateway_refuses_its_own_gps_input_and_the_echo_and_says_so_once() -> None:
    """A running gateway with an fc output (1/197, GPS_INPUT at its default 5 Hz): our own GPS_INPUT routed back
    and the flight controller's GPS_RAW_INT (its echo with GPS1_TYPE = 14) are refused, counted in the input's
    drops, each said once as a warning under the input's config path; the FC's GPS2_RAW is taken."""
    from runtime_helpers import free_port, sim_config_dict

    from ins_hil.config import from_dict
    from ins_hil.runtime.loop import Gateway

    cfg = from_dict(sim_config_dict(
        sim={"enabled": False},
        inputs=[{"name": "imu0", "type": "serial_imu", "port": "/dev/ins-hil-no-such-tty"},
                {"name": "fc", "type": "mavlink", "url": "udpin:127.0.0.1:0"}],
        outputs=[{"name": "fc", "url": f"udpout:127.0.0.1:{free_port()}", "role": "fc", "sysid": 1, "compid": 197}],
        recorder={"enabled": False},
    ), "test")  # fmt: skip
    gw = Gateway(cfg)

    async def go() -> None:
        run = asyncio.create_task(gw.run(duration=None, signals=False))
        drv = None
        while drv is None or drv.local_address is None:
            await asyncio.sleep(0.02)
            drv = next((d for d in gw.drivers if d.name == "fc"), None)
        tx = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        own = mavlink.MAVLink(None, srcSystem=1, srcComponent=197)
        fc = mavlink.MAVLink(None, srcSystem=1, srcComponent=1)
        for k in range(3):
            tx.sendto(_gps_input(own, 1_000_000 + k * 200_000, MSL).pack(own), drv.local_address)
            tx.sendto(_gps_raw(fc, 1_000_000 + k * 200_000, round(MSL * 1e3)).pack(fc), drv.local_address)
            fc.seq += 1
            tx.sendto(fc.gps2_raw_encode(1_000_000 + k * 200_000, 3, 504500000, 305200000, round(MSL * 1e3), 80,
                                         120, 0, 0, 9, 0, 0, 0, 0, 0, 0, 0, 0).pack(fc), drv.local_address)  # fmt: skip
            own.seq += 1
            fc.seq += 1
            await asyncio.sleep(0.05)
        tx.close()
        drops = gw.metrics.source("fc").dropped
        end = time.monotonic() + 30.0  # until the 6 refusals are counted and said (a hang guard, not a window)
        while time.monotonic() < end and not (
            drops.get("driver_own_message") == 3 and drops.get("driver_gnss_refused") == 3
            and sum(w.startswith("inputs[1] (fc): refused") for w in gw.metrics.warnings) >= 2
        ):  # fmt: skip
            await asyncio.sleep(0.02)
        gw.request_stop("test")
        await run

    asyncio.run(go())
    drops = gw.metrics.source("fc").dropped
    assert drops.get("driver_own_message") == 3 and drops.get("driver_gnss_refused") == 3, drops
    said = [w for w in gw.metrics.warnings if w.startswith("inputs[1] (fc): refused")]
    assert len(said) == 2, said
    assert any("1/197" in w for w in said) and any("outputs[0] sends GPS_INPUT to system 1" in w for w in said)
