"""Interoperability with a client nobody here wrote: MAVSDK (PyPI ``mavsdk``, its native library
``libcmavsdk`` in-process; no mock) against a default ``ins-hil run`` (configs/default.toml: simulated
sensors, MAVLink to a free UDP port, recorder and MQTT off).

MAVSDK listens where the gateway sends (``udpin://``) and reads, as an application would: telemetry
(position, attitude, heading, velocity, GPS info, health, home, in-air/landed state, battery, status
text), the parameter plugin (all parameters; set and read back an INT32 and a REAL32; a refused INT32),
info, an (empty) mission download and a refused arm — every answer within generous timeouts and the values
consistent with each other and with the simulation (start at 50.45 N 30.52 E, 180 m WGS84).
"""

from __future__ import annotations

import math
import subprocess
import sys
import threading
import time
from pathlib import Path
from typing import Any

import pytest
from runtime_helpers import free_port

from ins_hil.config import default_path
from ins_hil.runtime.geoid import undulation

pytestmark = pytest.mark.integration  # still in the default run (pytest -m "not vcan"); mavsdk: the dev extras

LAT0, LON0, H0 = 50.45, 30.52, 180.0  # configs/default.toml [sim]
TIMEOUT_S = 90.0  # alignment needs the vehicle's first turn (~15 s of simulation); generous under load


def _config(tmp: Path, port: int) -> Path:
    """configs/default.toml with the ground-station output on ``port`` and the recorder off."""
    text = Path(default_path()).read_text()
    for old, new in (
        ('url = "udpout:127.0.0.1:14550"', f'url = "udpout:127.0.0.1:{port}"'),
        ("[recorder]\nenabled = true", "[recorder]\nenabled = false"),
    ):
        assert old in text, old
        text = text.replace(old, new)
    p = tmp / "default.toml"
    p.write_text(text)
    return p


class Latest:
    """The newest value and the count of every subscribed telemetry stream (MAVSDK calls back on its threads)."""

    def __init__(self) -> None:
        self.lock = threading.Lock()
        self.values: dict[str, Any] = {}
        self.counts: dict[str, int] = {}
        self.texts: list[str] = []

    def callback(self, name: str) -> Any:
        def cb(value: Any, _user: Any) -> None:
            with self.lock:
                self.values[name] = value
                self.counts[name] = self.counts.get(name, 0) + 1
                if name == "status_text":
                    self.texts.append(value.text)

        return cb

    def get(self, name: str) -> Any:
        with self.lock:
            return self.values.get(name)


def _wait(cond: Any, what: str, timeout: float = TIMEOUT_S) -> None:
    end = time.monotonic() + timeout
    while time.monotonic() < end:
        if cond():
            return
        time.sleep(0.1)
    raise AssertionError(f"MAVSDK: no {what} within {timeout:.0f} s")


STREAMS = (
    "position", "attitude_euler", "heading", "velocity_ned", "gps_info", "raw_gps", "health", "health_all_ok",
    "home", "in_air", "landed_state", "battery", "status_text",
)  # fmt: skip


def test_mavsdk_reads_a_default_gateway(tmp_path: Path) -> None:
    from mavsdk import ComponentType, Configuration, Mavsdk
    from mavsdk.plugins.action import Action, ActionError, ActionResult
    from mavsdk.plugins.info import Info
    from mavsdk.plugins.mission import Mission
    from mavsdk.plugins.param import Param, ParamError
    from mavsdk.plugins.telemetry import FixType, LandedState, Telemetry

    from ins_hil import __version__

    port = free_port()
    cfg = _config(tmp_path, port)
    gw = subprocess.Popen(
        [sys.executable, "-m", "ins_hil", "run", "--config", str(cfg), "--no-status", "--no-mqtt", "--duration", "300"],
        cwd=tmp_path, stdin=subprocess.DEVNULL, stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True,
    )  # fmt: skip
    sdk = Mavsdk(Configuration.create_with_component_type(ComponentType.GROUND_STATION))
    try:
        assert int(sdk.add_any_connection(f"udpin://127.0.0.1:{port}")) == 0  # ConnectionResult.SUCCESS
        system = sdk.first_autopilot(60.0)
        assert system is not None, "MAVSDK discovered no autopilot"
        tel = Telemetry(system)
        seen = Latest()
        for name in STREAMS:
            getattr(tel, "subscribe_" + name)(seen.callback(name))

        # parameters: all of them, INT32 decoded as integers (bytewise), set and read back
        param = Param(system)
        allp = param.get_all_params()
        ints = {p.name: p.value for p in allp.int_params}
        floats = {p.name: p.value for p in allp.float_params}
        assert ints["NAV_DELAY_COMP"] == 1 and ints["FLT_COV_EVERY"] == 10 and ints["NAV_ADAPTIVE"] == 0, ints
        assert floats["SR_ATTITUDE"] == 50.0 and math.isclose(floats["NAV_GATE_GNSS"], 5.0), floats
        assert param.get_param_int("NAV_DELAY_COMP") == 1
        param.set_param_int("NAV_DELAY_COMP", 1)  # an INT32 set (the value in force: accepted)
        assert param.get_param_int("NAV_DELAY_COMP") == 1
        with pytest.raises(ParamError):  # a filter-shaping INT32 is refused at run time (needs a restart)
            param.set_param_int("FLT_COV_EVERY", 5)
        assert param.get_param_int("FLT_COV_EVERY") == 10
        param.set_param_float("NAV_GATE_GNSS", 4.5)  # a REAL32 applied to the running core
        assert math.isclose(param.get_param_float("NAV_GATE_GNSS"), 4.5)

        # info, mission, arm
        ver = Info(system).get_version()
        major, minor = (int(x) for x in __version__.split(".")[:2])
        assert (ver.flight_sw_major, ver.flight_sw_minor) == (major, minor)
        assert list(Mission(system).download_mission().mission_items) == []
        with pytest.raises(ActionError) as exc:
            Action(system).arm()
        assert exc.value.result == ActionResult.COMMAND_DENIED

        # telemetry: every stream answers; the heading once aligned (unknown before), the home once taken
        _wait(lambda: all(seen.get(n) is not None for n in STREAMS), "telemetry on every stream")
        _wait(lambda: math.isfinite(seen.get("heading").heading_deg), "heading (the solution aligned)")
        _wait(lambda: "INS aligned" in seen.texts, "STATUSTEXT 'INS aligned'")
        time.sleep(1.0)  # one more round of the 1 Hz messages after the alignment
        with seen.lock:
            v = dict(seen.values)
    finally:
        sdk.destroy()
        gw.terminate()
        try:
            out, _ = gw.communicate(timeout=20)
        except subprocess.TimeoutExpired:
            gw.kill()
            out, _ = gw.communicate()
    assert gw.returncode == 0, out

    n0 = undulation(math.radians(LAT0), math.radians(LON0))
    home, pos = v["home"], v["position"]
    # the home: where the simulation starts, its altitude MSL from a converged solution (not the first fix)
    north = (home.latitude_deg - LAT0) * 111_250.0
    east = (home.longitude_deg - LON0) * 111_250.0 * math.cos(math.radians(LAT0))
    assert math.hypot(north, east) < 3.0 and abs(home.absolute_altitude_m - (H0 - n0)) < 1.0, home
    # the position: relative altitude = absolute − home's, on the same datum
    assert abs(pos.absolute_altitude_m - pos.relative_altitude_m - home.absolute_altitude_m) < 0.01, (pos, home)
    assert abs(pos.latitude_deg - LAT0) < 0.05 and abs(pos.longitude_deg - LON0) < 0.05
    raw = v["raw_gps"]
    assert abs(raw.absolute_altitude_m - (raw.altitude_ellipsoid_m - n0)) < 0.05  # GPS_RAW_INT: MSL + ellipsoid
    assert v["gps_info"].fix_type == FixType.FIX_3D and v["gps_info"].num_satellites >= 4
    # heading (GLOBAL_POSITION_INT.hdg) = attitude yaw, in 0..360
    yaw = v["attitude_euler"].yaw_deg % 360.0
    d = (v["heading"].heading_deg - yaw + 180.0) % 360.0 - 180.0
    assert abs(d) < 5.0, (v["heading"], v["attitude_euler"])
    # the INS speed and the receiver's agree (the vehicle flies at up to 20 m/s)
    vel = v["velocity_ned"]
    assert abs(math.hypot(vel.north_m_s, vel.east_m_s) - raw.velocity_m_s) < 2.0, (vel, raw)
    # health: the configured sensors (IMU, GNSS, baro) and the positions are good; no magnetometer is
    # configured, so none is reported present, and MAVSDK's health_all_ok (which requires a calibrated
    # magnetometer) follows its parts; nothing to arm
    h = v["health"]
    assert h.is_gyrometer_calibration_ok and h.is_accelerometer_calibration_ok
    assert h.is_local_position_ok and h.is_global_position_ok and h.is_home_position_ok and not h.is_armable
    parts = (h.is_gyrometer_calibration_ok, h.is_accelerometer_calibration_ok, h.is_magnetometer_calibration_ok,
             h.is_local_position_ok, h.is_global_position_ok, h.is_home_position_ok)  # fmt: skip
    assert v["health_all_ok"] == all(parts)
    # ground contact is unknown to a navigation gateway: landed state UNKNOWN (in_air stays False)
    assert v["landed_state"] == LandedState.UNKNOWN and not v["in_air"]
    # no battery monitor: no voltage made up from UINT16_MAX (65.535 V), remaining unknown
    b = v["battery"]
    assert not (b.voltage_v > 60.0) and not (b.remaining_percent >= 0.0), b
