"""The GCS protocols a vehicle answers, with pymavlink as the ground station over real UDP.

The gateway side is a real MavlinkEndpoint with its ParamStore (and a real Pipeline for the
navigation values) on an asyncio loop in a thread, offered aligned states at 100 Hz; the ground
station is ``mavutil.mavlink_connection('udpin:…')`` where the endpoint sends.
"""

from __future__ import annotations

import asyncio
import math
import struct
import threading
import time
from pathlib import Path
from typing import Any

import numpy as np
import pytest
from pymavlink import mavutil
from runtime_helpers import free_port, sim_config
from test_runtime_mavlink import _state

from ins_hil.config import ConfigError
from ins_hil.runtime.mavlink_out import MavlinkEndpoint
from ins_hil.runtime.mavlink_params import NAV_PARAMS, RATE_PARAM, ParamStore
from ins_hil.runtime.metrics import RuntimeMetrics
from ins_hil.runtime.pipeline import Pipeline
from ins_hil.types import FixType, GnssFix

SYSID = 42
M = mavutil.mavlink


class Vehicle:
    """A gcs endpoint + ParamStore (+ Pipeline) served on a background asyncio loop."""

    def __init__(self, tmp: Path, states: bool = True, param_encoding: str = "bytewise", **cfg_over: Any) -> None:
        self.port = free_port()
        out = {"name": "gcs", "url": f"udpout:127.0.0.1:{self.port}", "role": "gcs", "sysid": SYSID,
               "param_encoding": param_encoding}  # fmt: skip
        over: dict[str, Any] = {
            "outputs": [out],
            "recorder": {"enabled": False},
            "core": {"init": "config", "init_lat_deg": 50.45, "init_lon_deg": 30.52, "init_h": 181.5},
        }
        over.update(cfg_over)
        self.cfg = sim_config(**over)
        self.params = ParamStore(self.cfg, tmp / "params.toml")
        self.metrics = RuntimeMetrics()
        self.pipeline = Pipeline(self.params.cfg.pipeline)
        self.ep = MavlinkEndpoint(self.params.cfg.outputs[0], self.metrics)
        self.params.attach([self.ep], self.pipeline)
        self.states = states
        self._stop = threading.Event()
        self._ready = threading.Event()
        self._th = threading.Thread(target=lambda: asyncio.run(self._main()), daemon=True)

    async def _main(self) -> None:
        await self.ep.start()
        self._ready.set()
        k = 0
        while not self._stop.is_set():
            if self.states:
                if k == 0:
                    lat, lon = math.radians(50.45), math.radians(30.52)
                    v = np.array([3.0, -4.0, 0.5])
                    self.ep.offer_gnss(GnssFix(1.0, lat, lon, 181.0, v, fix_type=FixType.FIX_3D, num_sats=9))
                self.ep.offer(_state(1.0 + 0.01 * k), 0, 0)
                k += 1
            await asyncio.sleep(0.01)
        await self.ep.close()

    def __enter__(self) -> Vehicle:
        # the ground station listens where the endpoint sends (MAVProxy's --master=udpin:…)
        url = f"udpin:127.0.0.1:{self.port}"
        self.gcs = mavutil.mavlink_connection(url, source_system=255, dialect="ardupilotmega")
        self.start()
        self.wait("HEARTBEAT")  # the endpoint's address is known to the GCS from its first datagram
        return self

    def __exit__(self, *exc: object) -> None:
        self.stop()
        self.gcs.close()

    def start(self) -> None:
        """Start the vehicle's event-loop thread and wait (5 s at most) until its endpoint is up."""
        self._th.start()
        assert self._ready.wait(5)

    def stop(self) -> None:
        """Stop the event loop and join its thread (5 s at most)."""
        self._stop.set()
        self._th.join(5)

    def wait(self, typ: str | list[str], timeout: float = 20.0, cond: Any = None) -> Any:  # returns when it came
        end = time.monotonic() + timeout
        while time.monotonic() < end:
            m = self.gcs.recv_match(type=typ, blocking=True, timeout=0.2)
            if m is not None and m.get_srcSystem() == SYSID and (cond is None or cond(m)):
                return m
        return None

    def collect(self, typ: str, seconds: float) -> list[Any]:
        out = []
        end = time.monotonic() + seconds
        while time.monotonic() < end:
            m = self.gcs.recv_match(type=typ, blocking=True, timeout=0.1)
            if m is not None and m.get_srcSystem() == SYSID:
                out.append(m)
        return out

    def collect_at_least(self, typ: str, n: int, seconds: float, deadline: float = 30.0) -> tuple[list[Any], float]:
        """``typ`` messages for ``seconds`` s and until ``n`` came (``deadline`` s at most: a hang guard; a busy
        machine sends late, never early): (the messages, the seconds it took)."""
        out = []
        t0 = time.monotonic()
        while (time.monotonic() - t0 < seconds or len(out) < n) and time.monotonic() - t0 < deadline:
            m = self.gcs.recv_match(type=typ, blocking=True, timeout=0.1)
            if m is not None and m.get_srcSystem() == SYSID:
                out.append(m)
        return out, time.monotonic() - t0

    def command(self, cmd: int, *p: float, target: int = SYSID) -> Any:
        params = [*p, *([0.0] * (7 - len(p)))]
        self.gcs.mav.command_long_send(target, 1, cmd, 0, *params)
        return self.wait("COMMAND_ACK", cond=lambda a: a.command == cmd)


def _param_set(v: Vehicle, name: str, value: float, ptype: int = M.MAV_PARAM_TYPE_REAL32) -> Any:
    v.gcs.mav.param_set_send(SYSID, 1, name.encode(), value, ptype)
    return v.wait("PARAM_VALUE", cond=lambda m: m.param_id == name)


def _bytewise(i: int) -> float:
    """The PARAM_* float that carries the int32 ``i`` bytewise (MAV_PROTOCOL_CAPABILITY_PARAM_ENCODE_BYTEWISE)."""
    return float(struct.unpack("<f", struct.pack("<i", i))[0])


def _value(m: Any) -> float:
    """A PARAM_VALUE's value as the ground station reads it: REAL32 as is, INT32 from the float's bytes."""
    if m.param_type == M.MAV_PARAM_TYPE_INT32:
        return float(struct.unpack("<i", struct.pack("<f", m.param_value))[0])
    return float(m.param_value)


def test_param_request_list_returns_every_index_with_the_count(tmp_path: Path) -> None:
    with Vehicle(tmp_path) as v:
        v.gcs.mav.param_request_list_send(SYSID, 1)
        got: dict[int, Any] = {}
        n = len(NAV_PARAMS) + len(RATE_PARAM)
        end = time.monotonic() + 60  # until every index came (a pause of a busy machine is no end of the list)
        while time.monotonic() < end and len(got) < n:
            m = v.gcs.recv_match(type="PARAM_VALUE", blocking=True, timeout=0.3)
            if m is not None:
                got[m.param_index] = m
        extra = v.collect("PARAM_VALUE", 0.5)  # nothing beyond the count follows
    assert sorted(got) == list(range(n)) and all(m.param_index in got for m in extra), extra
    assert {m.param_count for m in got.values()} == {n}
    names = {m.param_id: m for m in got.values()}
    assert all(len(k) <= 16 for k in names)
    assert math.isclose(names["SR_ATTITUDE"].param_value, 50.0) and names["SR_ATTITUDE"].param_type == 9
    assert math.isclose(names["NAV_GATE_GNSS"].param_value, 5.0)
    dc = names["NAV_DELAY_COMP"]  # INT32, bytewise: the float's bytes are the int32 1
    assert dc.param_type == M.MAV_PARAM_TYPE_INT32 and _value(dc) == 1 and dc.param_value == _bytewise(1)
    assert _value(names["FLT_COV_EVERY"]) == 10


def test_param_read_set_good_bad_and_other_system(tmp_path: Path) -> None:
    with Vehicle(tmp_path) as v:
        v.gcs.mav.param_request_read_send(SYSID, 1, b"NAV_GATE_BARO", -1)
        r = v.wait("PARAM_VALUE", cond=lambda m: m.param_id == "NAV_GATE_BARO")
        assert r is not None and math.isclose(r.param_value, 5.0) and r.param_count == len(NAV_PARAMS) + len(RATE_PARAM)

        # a good value: applied to the running core at once, echoed
        ok = _param_set(v, "NAV_GATE_GNSS", 4.0)
        assert ok is not None and math.isclose(ok.param_value, 4.0)
        assert v.pipeline.core is not None and v.pipeline.core.cfg.gnss.gate == 4.0
        assert v.pipeline.cfg.nav.gnss.gate == 4.0
        # a rate: applied to the stream
        r = _param_set(v, "SR_VFR_HUD", 2.0)
        assert r is not None and math.isclose(r.param_value, 2.0) and v.ep.rates["VFR_HUD"] == 2.0

        # bad values: refused, the old value echoed, a STATUSTEXT says why
        for name, value, ptype, old in (
            ("SR_ATTITUDE", -3.0, 9, 50.0),  # negative rate
            ("NAV_USE_GNSS_V", 0.5, M.MAV_PARAM_TYPE_REAL32, 1.0),  # not an integer
            ("NAV_USE_GNSS_V", _bytewise(2), M.MAV_PARAM_TYPE_INT32, 1.0),  # 2 (bytewise) is no 0/1
            ("NAV_GATE_GNSS", 3.0, M.MAV_PARAM_TYPE_INT32, 4.0),  # wrong type for a REAL32 parameter
            ("NAV_USE_GNSS_V", 0.0, M.MAV_PARAM_TYPE_REAL32, 1.0),  # right type (C cast), but needs a restart
            ("FLT_GYRO_ARW", 1e-3, 9, _default_arw()),  # shapes the filter at start: refused live
        ):
            r = _param_set(v, name, value, ptype)
            assert r is not None and math.isclose(_value(r), old, rel_tol=1e-6), (name, r)
        assert v.ep.rates["ATTITUDE"] == 50.0 and v.pipeline.core.cfg.gnss.use_vel is True
        t = v.wait("STATUSTEXT", cond=lambda m: "FLT_GYRO_ARW" in m.text)
        assert t is not None and "restart" in t.text

        # addressed to another system: ignored (no PARAM_VALUE), counted
        v.gcs.mav.param_set_send(7, 1, b"SR_ATTITUDE", 5.0, 9)
        assert v.wait("PARAM_VALUE", timeout=1.0) is None
        assert v.ep.rates["ATTITUDE"] == 50.0 and v.ep.rx_ignored >= 1


def _default_arw() -> float:
    from ins_hil.fusion.ekf import FilterConfig

    return float(np.float32(FilterConfig().gyro_arw))


def test_commands_are_acknowledged(tmp_path: Path) -> None:
    with Vehicle(tmp_path) as v:
        a = v.command(M.MAV_CMD_DO_SET_SERVO, 1, 1500)  # not handled
        assert a is not None and a.result == M.MAV_RESULT_UNSUPPORTED and a.target_system == 255
        a = v.command(M.MAV_CMD_COMPONENT_ARM_DISARM, 1)
        assert a is not None and a.result == M.MAV_RESULT_DENIED
        # COMMAND_INT too
        v.gcs.mav.command_int_send(SYSID, 1, 0, M.MAV_CMD_DO_SET_HOME, 0, 0, 0, 0, 0, 0, 0, 0, 0)
        a = v.wait("COMMAND_ACK", cond=lambda m: m.command == M.MAV_CMD_DO_SET_HOME)
        assert a is not None and a.result == M.MAV_RESULT_UNSUPPORTED

        a = v.command(M.MAV_CMD_REQUEST_MESSAGE, M.MAVLINK_MSG_ID_AUTOPILOT_VERSION)
        av = v.wait("AUTOPILOT_VERSION")
        assert a.result == M.MAV_RESULT_ACCEPTED and av is not None
        caps = M.MAV_PROTOCOL_CAPABILITY_MAVLINK2 | M.MAV_PROTOCOL_CAPABILITY_PARAM_FLOAT
        assert av.capabilities & caps == caps and av.capabilities & M.MAV_PROTOCOL_CAPABILITY_COMMAND_INT
        assert not av.capabilities & M.MAV_PROTOCOL_CAPABILITY_FTP

        a = v.command(M.MAV_CMD_REQUEST_MESSAGE, M.MAVLINK_MSG_ID_HOME_POSITION)
        hp = v.wait("HOME_POSITION")
        assert a.result == M.MAV_RESULT_ACCEPTED and hp is not None
        assert hp.latitude == 504500000 and hp.longitude == 305200000
        assert abs(hp.altitude * 1e-3 - (181.5 - 25.25)) < 0.3  # MSL: EGM96 undulation 25.25 m there

        a = v.command(M.MAV_CMD_REQUEST_MESSAGE, M.MAVLINK_MSG_ID_GPS_RAW_INT)  # a streamed message, once
        g = v.wait("GPS_RAW_INT")
        assert a.result == M.MAV_RESULT_ACCEPTED and g is not None and g.satellites_visible == 9

        a = v.command(M.MAV_CMD_GET_MESSAGE_INTERVAL, M.MAVLINK_MSG_ID_ATTITUDE)
        mi = v.wait("MESSAGE_INTERVAL")
        assert a.result == M.MAV_RESULT_ACCEPTED and mi.message_id == M.MAVLINK_MSG_ID_ATTITUDE
        assert mi.interval_us == 20000

        # another system's command: no ACK at all. The endpoint answers in the order it receives, so a command to
        # us sent right after it is the next one acknowledged (no 20-s wait for an ACK that must never come)
        v.gcs.mav.command_long_send(9, 1, M.MAV_CMD_DO_SET_RELAY, 0, 1, 1, 0, 0, 0, 0, 0)
        v.gcs.mav.command_long_send(SYSID, 1, M.MAV_CMD_COMPONENT_ARM_DISARM, 0, 1, 0, 0, 0, 0, 0, 0)
        acked: list[int] = []
        a = v.wait("COMMAND_ACK", cond=lambda m: acked.append(m.command) or m.command == M.MAV_CMD_COMPONENT_ARM_DISARM)
        assert a is not None and acked == [M.MAV_CMD_COMPONENT_ARM_DISARM], acked


def test_set_message_interval_changes_the_measured_rate(tmp_path: Path) -> None:
    with Vehicle(tmp_path) as v:
        before, _ = v.collect_at_least("ATTITUDE", 10, 1.0)
        a = v.command(M.MAV_CMD_SET_MESSAGE_INTERVAL, M.MAVLINK_MSG_ID_ATTITUDE, 200000)  # 5 Hz
        assert a is not None and a.result == M.MAV_RESULT_ACCEPTED
        v.collect("ATTITUDE", 0.3)
        after, took = v.collect_at_least("ATTITUDE", 4, 1.0)
        # the state times (time_boot_ms) of consecutive messages: 20 ms at 50 Hz, 200 ms at 5 Hz (a busy host only
        # lengthens them: the 50-Hz bound is loose, 100 ms; the 5-Hz one bounds the rate from above)
        gaps_before = np.diff([m.time_boot_ms for m in before])
        gaps_after = np.diff([m.time_boot_ms for m in after])
        assert np.median(gaps_before) <= 100 and np.median(gaps_after) >= 150, (gaps_before, gaps_after)
        assert len(after) <= 5.0 * took + 2, (len(after), took)  # at most 5 Hz over the time it took
        # the rate parameter follows
        v.gcs.mav.param_request_read_send(SYSID, 1, b"SR_ATTITUDE", -1)
        r = v.wait("PARAM_VALUE", cond=lambda m: m.param_id == "SR_ATTITUDE")
        assert r is not None and math.isclose(r.param_value, 5.0)
        a = v.command(M.MAV_CMD_SET_MESSAGE_INTERVAL, M.MAVLINK_MSG_ID_ATTITUDE, -1)  # off
        assert a.result == M.MAV_RESULT_ACCEPTED and "ATTITUDE" not in v.ep.rates


def test_mission_and_ftp_get_final_answers(tmp_path: Path) -> None:
    with Vehicle(tmp_path) as v:
        v.gcs.mav.mission_request_list_send(SYSID, 1, M.MAV_MISSION_TYPE_FENCE)
        mc = v.wait("MISSION_COUNT")
        assert mc is not None and mc.count == 0 and mc.mission_type == M.MAV_MISSION_TYPE_FENCE
        assert mc.target_system == 255
        # FTP ListDirectory (opcode 3), seq 17: NAK (129) of that opcode, error UnknownCommand (7), seq 18
        req = bytes([17, 0, 0, 3, 1, 0, 0, 0, 0, 0, 0, 0]) + b"/"
        v.gcs.mav.file_transfer_protocol_send(0, SYSID, 1, list(req.ljust(251, b"\x00")))
        f = v.wait("FILE_TRANSFER_PROTOCOL")
        assert f is not None
        p = bytes(f.payload)
        assert int.from_bytes(p[0:2], "little") == 18 and p[3] == 129 and p[4] == 1 and p[5] == 3 and p[12] == 7


def test_parameters_saved_and_loaded_at_start(tmp_path: Path) -> None:
    with Vehicle(tmp_path) as v:
        assert _param_set(v, "SR_GLOBAL_POS", 3.0) is not None
        assert _param_set(v, "NAV_BARO_STD", 0.8) is not None
        a = v.command(M.MAV_CMD_PREFLIGHT_STORAGE, 1)
        assert a is not None and a.result == M.MAV_RESULT_ACCEPTED
        a = v.command(M.MAV_CMD_PREFLIGHT_STORAGE, 2)  # reset to defaults: not offered
        assert a is not None and a.result == M.MAV_RESULT_UNSUPPORTED
    text = (tmp_path / "params.toml").read_text()
    assert "NAV_BARO_STD = 0.8" in text and "[params.gcs]" in text and "SR_GLOBAL_POS = 3.0" in text
    # a new start with the file: the values are in the configuration it runs
    store = ParamStore(sim_config(**_outputs(v.port)), tmp_path / "params.toml")
    assert store.cfg.pipeline.nav.baro.std == 0.8
    assert store.cfg.outputs[0].effective_rates()["GLOBAL_POSITION_INT"] == 3.0
    # a bad file is a config error naming the file and the parameter (the config's own validation)
    (tmp_path / "bad.toml").write_text("[params]\nFLT_COV_EVERY = 0\n")
    with pytest.raises(ConfigError, match=r"bad\.toml.*cov_every"):
        ParamStore(sim_config(**_outputs(v.port)), tmp_path / "bad.toml")
    (tmp_path / "bad2.toml").write_text("[params]\nNO_SUCH = 1\n")
    with pytest.raises(ConfigError, match="NO_SUCH"):
        ParamStore(sim_config(**_outputs(v.port)), tmp_path / "bad2.toml")


def _outputs(port: int) -> dict[str, Any]:
    return {"outputs": [{"name": "gcs", "url": f"udpout:127.0.0.1:{port}", "role": "gcs", "sysid": SYSID}]}


@pytest.mark.parametrize("name", ["default.toml", "flight_controller.toml", "hil_px4.toml", "dronecan_imu.toml"])
def test_shipped_configs_round_trip_through_their_document(name: str) -> None:
    """PARAM_SET validates the whole document: every shipped config must come back unchanged."""
    from ins_hil.config import REPO_CONFIGS, load

    store = ParamStore(load(REPO_CONFIGS / name), path=None)
    assert store.writable, store.why_readonly


def _mavproxy() -> list[str]:
    import shutil
    import sys

    exe = shutil.which("mavproxy.py", path=str(Path(sys.executable).parent)) or shutil.which("mavproxy.py")
    if exe is None:
        raise RuntimeError("mavproxy.py not found: MAVProxy is in the dev extras (pip install -e .[dev])")
    return [sys.executable, exe]


@pytest.mark.slow
def test_mavproxy_param_fetch_and_set(tmp_path: Path) -> None:
    """MAVProxy (interactive, commands on stdin): ``param fetch`` lists every parameter, ``param set``
    of a good value is applied, of a non-integer to an INT32 parameter refused (MAVProxy reports the
    failure with the value we echoed; the output's ``param_encoding = "c_cast"``: MAVProxy decodes INT32
    bytewise for PX4 only), and the refusal's STATUSTEXT is shown; ``wp list`` gets an
    empty mission, ``arm throttle`` a DENIED and an unknown command an UNSUPPORTED COMMAND_ACK."""
    import re
    import subprocess

    v = Vehicle(tmp_path, param_encoding="c_cast")  # the INT32 values as MAVProxy decodes a non-PX4 vehicle's
    mp = subprocess.Popen(
        [*_mavproxy(), f"--master=udpin:127.0.0.1:{v.port}", f"--state-basedir={tmp_path}",
         "--default-modules=param,wp,arm,cmdlong", "--mav20"],
        cwd=tmp_path, stdin=subprocess.PIPE, stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True,
    )  # fmt: skip
    lines: list[str] = []
    out = mp.stdout
    assert out is not None
    threading.Thread(target=lambda: lines.extend(iter(out.readline, "")), daemon=True).start()

    def wait_for(pattern: str, timeout: float = 10.0) -> re.Match[str] | None:
        end = time.monotonic() + timeout
        while time.monotonic() < end:
            for ln in list(lines):
                if (m := re.search(pattern, ln)) is not None:
                    return m
            time.sleep(0.1)
        return None

    def cmd(c: str) -> None:
        assert mp.stdin is not None
        mp.stdin.write(c + "\n")
        mp.stdin.flush()

    n = len(NAV_PARAMS) + len(RATE_PARAM)
    try:
        time.sleep(1.0)  # MAVProxy binds its UDP port
        v.start()
        assert wait_for(r"Detected vehicle 42:1") is not None, "".join(lines)
        lines.clear()
        cmd("param fetch")
        got = wait_for(r"Received (\d+) parameters")
        assert got is not None and int(got.group(1)) == n, "".join(lines)
        cmd("param set SR_VFR_HUD 2")
        cmd("param set NAV_USE_GNSS_V 0.5")
        # refused, the unchanged 1 echoed (c_cast: MAVProxy decodes bytewise for PX4 autopilots only,
        # MAVProxy/modules/mavproxy_param.py handle_px4_param_value; with the default bytewise it shows 1.4e-45)
        assert wait_for(r"Failed to set NAV_USE_GNSS_V to 0.5 \(invalid returned value 1.0\)") is not None, lines
        cmd("param set NAV_DELAY_COMP 1")  # an INT32 set (the value in force): confirmed by the echo
        cmd("param show NAV_DELAY_COMP")
        assert wait_for(r"NAV_DELAY_COMP\s+1(\.0)?\s*$") is not None, "".join(lines)
        assert wait_for(r"NAV_USE_GNSS_V: wrong type") is not None  # our STATUSTEXT, shown by MAVProxy
        cmd("param set FLT_GYRO_ARW 0.001")  # refused with a 51-character text: sent in two chunks, shown whole
        assert wait_for(r"FLT_GYRO_ARW: needs a restart \(set it in the config\)") is not None, "".join(lines)
        cmd("param show SR_VFR_HUD")
        assert wait_for(r"SR_VFR_HUD\s+2\.0") is not None, "".join(lines)
        cmd("wp list")
        assert wait_for(r"Requesting 0 waypoints") is not None, "".join(lines)
        cmd("arm throttle")
        assert wait_for(r"COMMAND_ACK: COMPONENT_ARM_DISARM: DENIED") is not None, "".join(lines)
        cmd("long DO_SET_SERVO 1 1500")
        assert wait_for(r"COMMAND_ACK: DO_SET_SERVO: UNSUPPORTED") is not None, "".join(lines)
    finally:
        mp.terminate()
        try:
            mp.wait(5)
        except subprocess.TimeoutExpired:
            mp.kill()
            mp.wait()
        v.stop()
    assert v.ep.rates["VFR_HUD"] == 2.0 and v.pipeline.core.cfg.gnss.use_vel is True
    saved = (tmp_path / "mav_42_1.parm").read_text().split("\n")
    assert len([s for s in saved if s.strip()]) == n  # MAVProxy's own copy of the parameter list


def test_int32_parameters_are_bytewise_both_ways(tmp_path: Path) -> None:
    """INT32 parameters travel bytewise (as AUTOPILOT_VERSION advertises: MAVSDK and QGroundControl decode a
    non-ArduPilot vehicle's integers that way): PARAM_VALUE carries the int's bytes, a bytewise PARAM_SET is
    read as the integer it holds, a C-cast one (MAVProxy's REAL32 of the integer) still as its value."""
    with Vehicle(tmp_path) as v:
        a = v.command(M.MAV_CMD_REQUEST_MESSAGE, M.MAVLINK_MSG_ID_AUTOPILOT_VERSION)
        av = v.wait("AUTOPILOT_VERSION")
        assert a is not None and a.result == M.MAV_RESULT_ACCEPTED and av is not None
        assert av.capabilities & M.MAV_PROTOCOL_CAPABILITY_PARAM_ENCODE_BYTEWISE
        assert not av.capabilities & M.MAV_PROTOCOL_CAPABILITY_PARAM_ENCODE_C_CAST
        assert av.capabilities & M.MAV_PROTOCOL_CAPABILITY_MISSION_INT  # MAVSDK's mission download needs it
        v.gcs.mav.param_request_read_send(SYSID, 1, b"FLT_COV_EVERY", -1)
        r = v.wait("PARAM_VALUE", cond=lambda m: m.param_id == "FLT_COV_EVERY")
        assert r is not None and r.param_type == M.MAV_PARAM_TYPE_INT32 and r.param_value == _bytewise(10)

        # the value in force (1), bytewise: accepted, echoed bytewise
        r = _param_set(v, "NAV_DELAY_COMP", _bytewise(1), M.MAV_PARAM_TYPE_INT32)
        assert r is not None and r.param_type == M.MAV_PARAM_TYPE_INT32 and r.param_value == _bytewise(1)
        # C cast (REAL32 1.0, as MAVProxy sends an integer): the same value
        r = _param_set(v, "NAV_DELAY_COMP", 1.0, M.MAV_PARAM_TYPE_REAL32)
        assert r is not None and _value(r) == 1
        # bytewise 0 is read as 0, and refused for its real reason (shapes the filter at start), not as a type
        r = _param_set(v, "NAV_DELAY_COMP", _bytewise(0), M.MAV_PARAM_TYPE_INT32)
        assert r is not None and _value(r) == 1
        t = v.wait("STATUSTEXT", cond=lambda m: "NAV_DELAY_COMP" in m.text)
        assert t is not None and "restart" in t.text, t
        r = _param_set(v, "FLT_COV_EVERY", _bytewise(5), M.MAV_PARAM_TYPE_INT32)
        assert r is not None and _value(r) == 10
        t = v.wait("STATUSTEXT", cond=lambda m: "FLT_COV_EVERY" in m.text)
        assert t is not None and "restart" in t.text and "type" not in t.text, t


def test_home_state_and_battery_answered_before_and_after_the_home(tmp_path: Path) -> None:
    """HOME_POSITION requested before there is any position: accepted, and sent once the home is taken;
    its interval can be set (it is streamed); EXTENDED_SYS_STATE and BATTERY_STATUS are streamed without
    a state and answer REQUEST_MESSAGE, with the spec's "unknown" values."""
    with Vehicle(tmp_path, states=False) as v:
        a = v.command(M.MAV_CMD_REQUEST_MESSAGE, M.MAVLINK_MSG_ID_HOME_POSITION)
        assert a is not None and a.result == M.MAV_RESULT_ACCEPTED
        assert v.wait("HOME_POSITION", timeout=0.5) is None  # no position: nothing yet
        a = v.command(M.MAV_CMD_SET_MESSAGE_INTERVAL, M.MAVLINK_MSG_ID_HOME_POSITION, 1_000_000)
        assert a is not None and a.result == M.MAV_RESULT_ACCEPTED
        es = v.wait("EXTENDED_SYS_STATE")
        assert es is not None and es.landed_state == M.MAV_LANDED_STATE_UNDEFINED
        assert es.vtol_state == M.MAV_VTOL_STATE_UNDEFINED
        a = v.command(M.MAV_CMD_REQUEST_MESSAGE, M.MAVLINK_MSG_ID_EXTENDED_SYS_STATE)
        assert a is not None and a.result == M.MAV_RESULT_ACCEPTED
        b = v.wait("BATTERY_STATUS")
        assert b is not None and list(b.voltages) == [0xFFFF] * 10 and b.current_battery == -1
        assert b.battery_remaining == -1 and b.temperature == 0x7FFF
        v.states = True  # positions arrive: the home is taken (σ_d 1.2 m, aligned) and sent unasked
        hp = v.wait("HOME_POSITION")
        assert hp is not None and hp.latitude == 504500000
        # streamed at the 1 Hz set above (at most 1 Hz over the time it took, a busy host only sends fewer); the
        # same home (it moves)
        homes, took = v.collect_at_least("HOME_POSITION", 2, 2.5)
        assert 2 <= len(homes) <= took + 2, (len(homes), took)
        assert {(m.latitude, m.altitude) for m in homes} == {(hp.latitude, hp.altitude)}


def _gcs_endpoint(**rates: float) -> tuple[MavlinkEndpoint, list[bytes]]:
    from runtime_helpers import BufferSink

    from ins_hil.runtime.mavlink_out import EndpointConfig

    ep = MavlinkEndpoint(EndpointConfig(rates=rates), RuntimeMetrics())
    sink = BufferSink()
    ep.tr = sink  # type: ignore[assignment]
    return ep, sink.bufs


def _parse(bufs: list[bytes]) -> list[Any]:
    from pymavlink.dialects.v20 import ardupilotmega

    mav = ardupilotmega.MAVLink(None)
    return [m for b in bufs for m in mav.parse_buffer(b) or []]


def test_home_is_taken_from_a_converged_solution_at_rest(monkeypatch: pytest.MonkeyPatch) -> None:
    """Parked at 181.5 m: the first states are 3 m high with σ_d 3 m (the first GNSS fix), then the
    solution converges. The home is taken at σ_d ≤ 1 m (not from the first state), re-taken at rest as σ_d
    falls to 0.7 of its σ (HOME_POSITION each time), and kept once the vehicle drove off."""
    clock = [10**12]
    monkeypatch.setattr(time, "monotonic_ns", lambda: clock[0])
    ep, bufs = _gcs_endpoint(HOME_POSITION=0.0)  # not streamed: every HOME_POSITION here is a (re-)take
    t = [1.0]

    def feed(h: float, sd: float, v: tuple[float, float, float] = (0.0, 0.0, 0.0), n: int = 10) -> list[Any]:
        bufs.clear()
        for _ in range(n):
            st = _state(t[0])
            st.h, st.std_pos, st.vel_ned, st.aligned = h, np.array([0.5, 0.5, sd]), np.array(v), False
            clock[0] += 100_000_000  # 10 Hz: every GLOBAL_POSITION_INT/LOCAL_POSITION_NED is due
            t[0] += 0.1
            ep.offer(st, 0, 0)
            ep._send_replies()
        return _parse(bufs)

    first = feed(184.5, 3.0)
    gp = [m for m in first if m.get_type() == "GLOBAL_POSITION_INT"]
    assert gp and all(m.relative_alt == 0 for m in gp) and all(m.hdg == 0xFFFF for m in gp)  # unaligned: unknown
    assert not [m for m in first if m.get_type() in ("HOME_POSITION", "LOCAL_POSITION_NED")]
    assert ep._home is None
    conv = feed(182.3, 0.9)
    assert ep._home is not None and ep._home[2] == 182.3
    assert [m.get_type() for m in conv].count("HOME_POSITION") == 1
    assert [m for m in conv if m.get_type() == "LOCAL_POSITION_NED"]
    better = feed(181.6, 0.6)  # 0.6 ≤ 0.7 × 0.9: re-taken, sent again
    assert ep._home[2] == 181.6 and [m.get_type() for m in better].count("HOME_POSITION") == 1
    assert feed(181.55, 0.5, n=3) and ep._home[2] == 181.6  # 0.5 > 0.7 × 0.6: kept
    feed(181.5, 0.4, v=(5.0, 0.0, 0.0))  # drives off
    feed(181.5, 0.2)  # parked somewhere, converged further: the home stays where it was taken
    assert ep._home[2] == 181.6
    gp = [m for m in feed(181.5, 0.2, n=2) if m.get_type() == "GLOBAL_POSITION_INT"]
    assert gp and gp[-1].relative_alt == -100  # mm: 0.1 m below the home


def test_drop_rate_is_a_rate_in_centi_percent(monkeypatch: pytest.MonkeyPatch) -> None:
    """SYS_STATUS drop_rate_comm: the share (c%) of the inputs' samples dropped in the last window of
    ≥ 1 s; errors_comm the cumulative count."""
    clock = [10**12]
    monkeypatch.setattr(time, "monotonic_ns", lambda: clock[0])
    ep, bufs = _gcs_endpoint()
    src = ep.metrics.source("imu0")

    def second(received: int, dropped: int) -> Any:
        src.received += received
        src.drop("queue_full", dropped)
        clock[0] += 1_000_000_000
        bufs.clear()
        ep._send_sys_status(None)
        return _parse(bufs)[0]

    second(0, 0)  # the first window starts
    s = second(990, 10)
    assert s.drop_rate_comm == 100 and s.errors_comm == 10  # 10 of 1000: 1 %
    s = second(1000, 0)
    assert s.drop_rate_comm == 0 and s.errors_comm == 10  # no drops in this second
    s = second(500, 500)
    assert s.drop_rate_comm == 5000 and s.errors_comm == 510


def test_statustext_long_texts_in_chunks_and_repeats_once(monkeypatch: pytest.MonkeyPatch) -> None:
    """A text over 50 characters goes out in chunks with one id (MAVLink 2's reassembly; a text of exactly
    100 characters ends with an empty chunk), a short one as a single message (id 0); the same text again
    within 2 s is not sent again."""
    clock = [10**12]
    monkeypatch.setattr(time, "monotonic_ns", lambda: clock[0])
    ep, bufs = _gcs_endpoint()
    long_text = "params not saved: [Errno 13] Permission denied: '/etc/ins-hil/default.params.toml'"
    for text in (long_text, "x" * 100, "INS aligned", "INS aligned"):
        ep.statustext(6, text)
    ep._send_texts()
    st = [m for m in _parse(bufs) if m.get_type() == "STATUSTEXT"]
    by_id: dict[int, list[Any]] = {}
    for m in st:
        by_id.setdefault(m.id, []).append(m)
    single = by_id.pop(0)
    assert [m.text for m in single] == ["INS aligned"]  # once
    texts = sorted("".join(m.text for m in sorted(ms, key=lambda m: m.chunk_seq)) for ms in by_id.values())
    assert texts == sorted([long_text, "x" * 100])
    assert max(len(ms) for ms in by_id.values()) == 3  # 50 + 50 + the empty end
    clock[0] += 2_100_000_000
    bufs.clear()
    ep.statustext(6, "INS aligned")
    ep._send_texts()
    assert [m.text for m in _parse(bufs)] == ["INS aligned"]


@pytest.mark.slow
def test_imu_pauses_give_one_lost_and_one_back_text_each() -> None:
    """Five 0.6-s pauses of the sensors (the simulator process stopped, then catching up its backlog) while
    aligned: at most one "lost" and one "back" STATUSTEXT about the IMU/INS per pause."""
    import os
    import signal

    from runtime_helpers import sim_config_dict, sim_gateway
    from test_runtime_mavlink import _drain, _listen

    from ins_hil.config import from_dict

    port = free_port()
    d = sim_config_dict(
        sim={"imu_errors": "none"},
        core={
            "init": "config",
            "init_lat_deg": 50.45,
            "init_lon_deg": 30.52,
            "init_h": 180.0,
            "nav": {"alignment": {"aligned_yaw_std": 0.5}},
        },  # aligned at once (yaw σ 10° < 0.5 rad)
        outputs=[{"name": "gcs", "url": f"udpout:127.0.0.1:{port}", "role": "gcs", "sysid": SYSID}],
        recorder={"enabled": False},
    )
    rx = _listen(port)
    from pymavlink.dialects.v20 import ardupilotmega

    mav = ardupilotmega.MAVLink(None)
    got: list[Any] = []
    gw = sim_gateway(from_dict(d, "test"))

    async def go() -> None:
        async def pump() -> None:
            while True:
                _drain(rx, mav, got)
                await asyncio.sleep(0.02)

        async def pauses() -> None:
            end = time.monotonic() + 120.0  # until aligned (about 1 s idle; a busy host starts slowly): a hang guard
            while time.monotonic() < end and not any(
                m.get_type() == "STATUSTEXT" and m.text == "INS aligned" for _, m in got
            ):
                await asyncio.sleep(0.05)
            await asyncio.sleep(1.0)
            for _ in range(5):
                os.kill(gw.sim.proc.pid, signal.SIGSTOP)
                await asyncio.sleep(0.6)
                os.kill(gw.sim.proc.pid, signal.SIGCONT)
                await asyncio.sleep(2.0)
            gw.request_stop("test")

        tasks = [asyncio.create_task(pump()), asyncio.create_task(pauses())]
        await gw.run(duration=300.0, signals=False)
        await asyncio.sleep(0.1)
        _drain(rx, mav, got)
        for t in tasks:
            t.cancel()

    asyncio.run(go())
    rx.close()
    texts = [m.text for _, m in got if m.get_type() == "STATUSTEXT"]
    assert texts.count("INS aligned") >= 1  # aligned before the pauses
    first = texts.index("INS aligned") + 1
    about = [x for x in texts[first:] if x.startswith(("IMU", "INS"))]
    lost = [x for x in about if "lost" in x]
    back = [x for x in about if "lost" not in x and ("back" in x or "aligned" in x)]
    assert 1 <= len(lost) <= 5 and len(back) <= 5, texts


def test_fc_endpoint_keeps_its_first_position_as_origin() -> None:
    """The converged home is the ground station's: an ``fc`` endpoint's origin (ODOMETRY, and any
    GLOBAL_POSITION_INT it streams) stays its first position, whatever the σ does later."""
    from runtime_helpers import BufferSink

    from ins_hil.runtime.mavlink_out import EndpointConfig

    ep = MavlinkEndpoint(EndpointConfig(role="fc", rates={"GLOBAL_POSITION_INT": 10.0}), RuntimeMetrics())
    ep.tr = BufferSink()  # type: ignore[assignment]
    for k, (h, sd) in enumerate(((184.5, 3.0), (182.3, 0.9), (181.6, 0.5), (181.5, 0.2))):
        st = _state(1.0 + k)
        st.h, st.std_pos, st.vel_ned = h, np.array([0.5, 0.5, sd]), np.zeros(3)
        ep.offer(st, 0, 0)
        time.sleep(0.11)
    assert ep._home is not None and ep._home[2] == 184.5


def test_c_cast_output_sends_integers_as_their_value(tmp_path: Path) -> None:
    """``param_encoding = "c_cast"`` (for MAVProxy, Mission Planner): INT32 values as their float, C_CAST
    advertised; a set is read either way."""
    with Vehicle(tmp_path, param_encoding="c_cast") as v:
        a = v.command(M.MAV_CMD_REQUEST_MESSAGE, M.MAVLINK_MSG_ID_AUTOPILOT_VERSION)
        av = v.wait("AUTOPILOT_VERSION")
        assert a is not None and av is not None
        assert av.capabilities & M.MAV_PROTOCOL_CAPABILITY_PARAM_ENCODE_C_CAST
        assert not av.capabilities & M.MAV_PROTOCOL_CAPABILITY_PARAM_ENCODE_BYTEWISE
        v.gcs.mav.param_request_read_send(SYSID, 1, b"FLT_COV_EVERY", -1)
        r = v.wait("PARAM_VALUE", cond=lambda m: m.param_id == "FLT_COV_EVERY")
        assert r is not None and r.param_type == M.MAV_PARAM_TYPE_INT32 and r.param_value == 10.0
        r = _param_set(v, "NAV_DELAY_COMP", _bytewise(1), M.MAV_PARAM_TYPE_INT32)
        assert r is not None and r.param_value == 1.0
