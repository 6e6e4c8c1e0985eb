"""MAVLink output builders: every GCS and flight-controller message decodes with pymavlink to the state sent."""

from __future__ import annotations

import asyncio
import math
import socket
import time
from collections.abc import Callable

import numpy as np
import pytest
from conftest import machine_alone
from pymavlink.dialects.v20 import ardupilotmega as mavlink2
from runtime_helpers import free_port, sim_gateway

from ins_hil.nav.rotation import dcm_from_quat, quat_from_euler
from ins_hil.runtime.mavlink_out import EndpointConfig, MavlinkEndpoint
from ins_hil.runtime.metrics import RuntimeMetrics
from ins_hil.types import FixType, GnssFix, NavState

KYIV_N = 25.25  # EGM96 geoid undulation (m) at 50.45° N 30.52° E, the egm96 package's full 5' grid node


def _state(t: float) -> NavState:
    return NavState(
        t=t,
        q_nb=quat_from_euler(math.radians(10), math.radians(-5), math.radians(120)),
        vel_ned=np.array([3.0, -4.0, 0.5]),
        lat=math.radians(50.45),
        lon=math.radians(30.52),
        h=181.5,
        std_pos=np.array([0.5, 0.6, 1.2]),
        std_vel=np.array([0.05, 0.05, 0.1]),
        std_att=np.radians([0.5, 0.5, 2.0]),
        omega_b=np.array([0.01, -0.02, 0.03]),
        accel_b=np.array([0.1, 0.2, -9.8]),
        aligned=True,
        test_ratios={"gnss_pos": 0.4, "gnss_vel": 0.2, "baro": 0.1},
    )


def _collect(role: str, rates: dict[str, float]) -> dict[str, list]:
    port = free_port()
    rx = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    rx.bind(("127.0.0.1", port))
    rx.setblocking(False)
    metrics = RuntimeMetrics()

    async def go() -> None:
        ep = MavlinkEndpoint(EndpointConfig(name=role, url=f"udpout:127.0.0.1:{port}", role=role, rates=rates), metrics)
        await ep.start()
        ep.offer_gnss(GnssFix(1.0, math.radians(50.45), math.radians(30.52), 181.0, np.array([3.0, -4.0, 0.5]),
                              fix_type=FixType.FIX_3D, num_sats=14))  # fmt: skip
        ep.statustext(4, "INS fault gyro[1] step_bias")
        for k in range(30):
            ep.offer(_state(1.0 + 0.01 * k), 0, 0)
            await asyncio.sleep(0.01)
        await ep.close()

    asyncio.run(go())
    mav = mavlink2.MAVLink(None)
    out: dict[str, list] = {}
    while True:
        try:
            data = rx.recv(65536)
        except BlockingIOError:
            break
        for m in mav.parse_buffer(data) or []:
            out.setdefault(m.get_type(), []).append(m)
    rx.close()
    assert metrics.outputs[role]["bytes"] > 0
    return out


def test_gcs_messages_decode_to_the_state() -> None:
    out = _collect("gcs", {"ATTITUDE": 100.0, "GLOBAL_POSITION_INT": 100.0, "ESTIMATOR_STATUS": 100.0})
    for typ in ("HEARTBEAT", "SYS_STATUS", "ATTITUDE", "ATTITUDE_QUATERNION", "GLOBAL_POSITION_INT",
                "LOCAL_POSITION_NED", "GPS_RAW_INT", "VFR_HUD", "ESTIMATOR_STATUS", "STATUSTEXT"):  # fmt: skip
        assert typ in out, typ
    hb = out["HEARTBEAT"][0]
    assert hb.get_srcSystem() == 42 and hb.type == mavlink2.MAV_TYPE_QUADROTOR
    assert hb.system_status == mavlink2.MAV_STATE_ACTIVE
    a = out["ATTITUDE"][0]
    assert math.isclose(math.degrees(a.roll), 10, abs_tol=1e-4) and math.isclose(
        math.degrees(a.pitch), -5, abs_tol=1e-4
    )
    assert math.isclose(math.degrees(a.yaw), 120, abs_tol=1e-4) and math.isclose(a.yawspeed, 0.03, rel_tol=1e-6)
    assert a.time_boot_ms == 1000
    g = out["GLOBAL_POSITION_INT"][0]
    assert g.lat == 504500000 and g.lon == 305200000
    # MSL: the ellipsoidal 181.5 m less the EGM96 undulation at 50.45° N 30.52° E (25.25 m on the 5' grid)
    assert abs(g.alt * 1e-3 - (181.5 - KYIV_N)) < 0.3 and g.relative_alt == 0
    assert (g.vx, g.vy, g.vz) == (300, -400, 50) and g.hdg == 12000
    assert len(out["GPS_RAW_INT"]) == 1 and out["GPS_RAW_INT"][0].satellites_visible == 14  # one fix, passed once
    es = out["ESTIMATOR_STATUS"][0]
    assert math.isclose(es.pos_horiz_ratio, 0.4, rel_tol=1e-6) and math.isclose(es.vel_ratio, 0.2, rel_tol=1e-6)
    assert math.isclose(es.pos_horiz_accuracy, math.hypot(0.5, 0.6), rel_tol=1e-6)
    assert out["STATUSTEXT"][0].text.startswith("INS fault gyro[1]")
    q = out["ATTITUDE_QUATERNION"][0]
    assert np.allclose([q.q1, q.q2, q.q3, q.q4], _state(1.0).q_nb, atol=1e-7)


def test_flight_controller_messages_decode_to_the_state() -> None:
    out = _collect("fc", {"ODOMETRY": 100.0, "GPS_INPUT": 100.0, "HIL_STATE_QUATERNION": 100.0})
    st = _state(1.0)
    o = out["ODOMETRY"][0]
    assert o.frame_id == mavlink2.MAV_FRAME_LOCAL_NED and o.child_frame_id == mavlink2.MAV_FRAME_BODY_FRD
    assert np.allclose(o.q, st.q_nb, atol=1e-7) and (o.x, o.y, o.z) == (0.0, 0.0, 0.0)  # first state = home
    v_b = dcm_from_quat(st.q_nb).T @ st.vel_ned
    assert np.allclose([o.vx, o.vy, o.vz], v_b, atol=1e-5)
    assert math.isclose(o.pose_covariance[0], 0.25, rel_tol=1e-6) and math.isclose(
        o.pose_covariance[11], 1.44, rel_tol=1e-6
    )
    gi = out["GPS_INPUT"][0]
    assert gi.lat == 504500000 and gi.fix_type == 3 and math.isclose(gi.vn, 3.0)
    assert abs(gi.alt - (181.5 - KYIV_N)) < 0.3  # MSL
    hil = out["HIL_STATE_QUATERNION"][0]
    assert np.allclose(hil.attitude_quaternion, st.q_nb, atol=1e-7) and hil.vx == 300
    assert abs(hil.alt * 1e-3 - (181.5 - KYIV_N)) < 0.3  # PX4 reads it as AMSL
    assert out["HEARTBEAT"][0].type == mavlink2.MAV_TYPE_ONBOARD_CONTROLLER


def _stream_out(url: str, read: object) -> list[str]:
    """Run a gcs endpoint on ``url`` for a moment; ``read()`` returns what the peer got."""
    metrics = RuntimeMetrics()

    async def go() -> None:
        ep = MavlinkEndpoint(EndpointConfig(name="s", url=url, rates={"ATTITUDE": 100.0}), metrics)
        await ep.start()
        for k in range(60):
            ep.offer(_state(1.0 + 0.01 * k), 0, 0)
            await asyncio.sleep(0.01)
        await ep.close()

    asyncio.run(go())
    mav = mavlink2.MAVLink(None)
    return [m.get_type() for m in mav.parse_buffer(read()) or []]  # type: ignore[operator]


def test_tcp_endpoint_connects_and_streams() -> None:
    srv = socket.socket(socket.AF_INET, socket.SOCK_STREAM)
    srv.bind(("127.0.0.1", 0))
    srv.listen(1)
    srv.settimeout(10)
    port = srv.getsockname()[1]
    conns: list[socket.socket] = []

    def read() -> bytes:
        c = conns[0]
        c.setblocking(False)
        buf = b""
        while True:
            try:
                d = c.recv(65536)
            except BlockingIOError:
                return buf
            if not d:
                return buf
            buf += d

    import threading

    th = threading.Thread(target=lambda: conns.append(srv.accept()[0]))
    th.start()
    types = _stream_out(f"tcp:127.0.0.1:{port}", read=lambda: (th.join(), read())[1])
    srv.close()
    assert "HEARTBEAT" in types and types.count("ATTITUDE") > 10


def test_serial_endpoint_writes_to_a_tty() -> None:
    import os
    import tty

    master, slave = os.openpty()
    tty.setraw(slave)
    os.set_blocking(master, False)

    def read() -> bytes:
        buf = b""
        while True:
            try:
                d = os.read(master, 65536)
            except BlockingIOError:
                return buf
            if not d:
                return buf
            buf += d

    types = _stream_out(f"serial:{os.ttyname(slave)}:115200", read=read)
    os.close(master)
    os.close(slave)
    assert "HEARTBEAT" in types and types.count("ATTITUDE") > 10


def _listen(port: int) -> socket.socket:
    rx = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    rx.bind(("127.0.0.1", port))
    rx.setblocking(False)
    return rx


def _drain(rx: socket.socket, mav: object, out: list) -> None:
    while True:
        try:
            data = rx.recv(65536)
        except BlockingIOError:
            return
        for m in mav.parse_buffer(data) or []:  # type: ignore[attr-defined]
            out.append((time.monotonic(), m))


def _run_gateway(
    cfg_dict: dict,
    seconds: float,
    port: int,
    kill_when: Callable[[list], bool] | None = None,
    until: Callable[[list], bool] | None = None,
) -> tuple[list, object]:
    """Run a Gateway for ``seconds`` while a UDP listener on ``port`` collects (arrival time, message), in arrival
    order. ``kill_when(got)``: the simulator process is killed (SIGKILL) once it holds for the messages received so
    far; ``until(got)``: the gateway stops once it holds (after the kill, if any), ``seconds`` then being a deadline
    that only a failure reaches (conditions, not wall-time windows: the test holds on a loaded machine)."""
    from ins_hil.config import from_dict

    rx = _listen(port)
    mav = mavlink2.MAVLink(None)
    got: list = []
    gw = sim_gateway(from_dict(cfg_dict, "test"))

    async def go() -> None:
        async def pump() -> None:
            killed = kill_when is None
            k = 0
            while True:
                _drain(rx, mav, got)
                k += 1
                if k % 5 == 0:  # the conditions every 0.1 s
                    if not killed and kill_when is not None and kill_when(got):
                        if gw.sim is not None and gw.sim.proc is not None:
                            gw.sim.proc.kill()
                        killed = True
                    elif killed and until is not None and until(got):
                        gw.request_stop("test condition met")
                await asyncio.sleep(0.02)

        t = asyncio.create_task(pump())
        await gw.run(duration=seconds, signals=False)
        await asyncio.sleep(0.1)
        _drain(rx, mav, got)
        t.cancel()

    asyncio.run(go())
    rx.close()
    return got, gw


@pytest.mark.slow
def test_heartbeat_at_1hz_without_any_sensor() -> None:
    """flight_controller.toml without hardware: no IMU, no state — the vehicle is still there (STANDBY),
    its SYS_STATUS says the IMU and GNSS are configured but not healthy, the battery unknown."""
    from runtime_helpers import sim_config_dict

    port = free_port()
    d = sim_config_dict(
        sim={"enabled": False},
        inputs=[{"name": "imu0", "type": "serial_imu", "port": "/dev/ins-hil-no-such-tty"},
                {"name": "fc", "type": "mavlink", "url": "udpin:127.0.0.1:0"}],
        outputs=[{"name": "gcs", "url": f"udpout:127.0.0.1:{port}", "role": "gcs", "sysid": 42}],
        recorder={"enabled": False},
    )  # fmt: skip

    def seen(got: list) -> bool:  # 3 heartbeats, a SYS_STATUS and an ESTIMATOR_STATUS (a deadline, not a window)
        kinds = [m.get_type() for _, m in got]
        return kinds.count("HEARTBEAT") >= 3 and "SYS_STATUS" in kinds and "ESTIMATOR_STATUS" in kinds

    t0 = time.monotonic()
    got, _ = _run_gateway(d, 30.0, port, until=seen)
    ran_s = time.monotonic() - t0
    hb = [m for _, m in got if m.get_type() == "HEARTBEAT"]
    assert len(hb) >= 3 and {m.system_status for m in hb} == {mavlink2.MAV_STATE_STANDBY}
    # 1 Hz, never faster: the early one of the start-up (before the core is loaded) and one a second from the
    # first state-less beat (advance_due: no catch-up burst), so n beats take more than n - 2 s; a starved host
    # only makes them fewer (a beat at 10 Hz fails this)
    assert len(hb) <= ran_s + 2
    ss = [m for _, m in got if m.get_type() == "SYS_STATUS"][-1]
    imu = mavlink2.MAV_SYS_STATUS_SENSOR_3D_GYRO | mavlink2.MAV_SYS_STATUS_SENSOR_3D_ACCEL
    gps = mavlink2.MAV_SYS_STATUS_SENSOR_GPS
    assert ss.onboard_control_sensors_present & imu == imu and ss.onboard_control_sensors_present & gps
    assert ss.onboard_control_sensors_health & (imu | gps | mavlink2.MAV_SYS_STATUS_AHRS) == 0
    assert ss.voltage_battery == 65535 and ss.current_battery == -1 and ss.battery_remaining == -1
    es = [m for _, m in got if m.get_type() == "ESTIMATOR_STATUS"]
    assert es and all(m.flags == 0 for m in es)


_IMU = mavlink2.MAV_SYS_STATUS_SENSOR_3D_GYRO | mavlink2.MAV_SYS_STATUS_SENSOR_3D_ACCEL
_GPS = mavlink2.MAV_SYS_STATUS_SENSOR_GPS


def _navigating(got: list) -> bool:
    """More than 50 ATTITUDE and a SYS_STATUS with the IMU and the GNSS healthy."""
    att = sum(1 for _, m in got if m.get_type() == "ATTITUDE")
    ok = _IMU | _GPS
    return att > 50 and any(
        m.get_type() == "SYS_STATUS" and m.onboard_control_sensors_health & ok == ok for _, m in got
    )


def _after_imu_lost(got: list) -> list:
    """The messages received after the last "IMU lost: no data" STATUSTEXT (arrival order; none before it): the
    last, since a gateway starved for 2 s by a loaded machine before the kill says it too (then "IMU back")."""
    for i in range(len(got) - 1, -1, -1):
        m = got[i][1]
        if m.get_type() == "STATUSTEXT" and m.text == "IMU lost: no data":
            return [m for _, m in got[i + 1 :]]
    return []


def _status_followed(got: list) -> None:
    """After the IMU was lost: 3 HEARTBEATs, the last CRITICAL; no state (ATTITUDE); the last SYS_STATUS with the
    IMU and GNSS present and unhealthy; GNSS lost said too; every ESTIMATOR_STATUS with its flags clear."""
    after = _after_imu_lost(got)
    texts = [m.text for _, m in got if m.get_type() == "STATUSTEXT"]
    assert "IMU lost: no data" in texts and "GNSS lost: no data" in texts, texts
    assert not [m for m in after if m.get_type() == "ATTITUDE"], "a state after the IMU was lost"
    hb = [m for m in after if m.get_type() == "HEARTBEAT"]
    assert len(hb) >= 3, f"{len(hb)} HEARTBEAT after the IMU was lost"
    assert hb[-1].system_status == mavlink2.MAV_STATE_CRITICAL
    ss = [m for _, m in got if m.get_type() == "SYS_STATUS"][-1]
    assert ss.onboard_control_sensors_present & _IMU == _IMU and ss.onboard_control_sensors_health & _IMU == 0
    assert ss.onboard_control_sensors_health & _GPS == 0
    es = [m for m in after if m.get_type() == "ESTIMATOR_STATUS"]
    assert es and all(m.flags == 0 for m in es)


def _holds(check: Callable[[list], None], got: list) -> bool:
    try:
        check(got)
    except AssertionError:
        return False
    return True


@pytest.mark.slow
def test_imu_stopped_heartbeat_goes_on_and_the_status_follows() -> None:
    """The simulator is killed once the gateway navigates: the heartbeat goes on at 1 Hz, the IMU/GNSS/baro health
    bits drop, STATUSTEXT says they are lost, system_status turns CRITICAL, ESTIMATOR_STATUS flags clear. Waits for
    that (3 heartbeats after the IMU was lost) up to 30 s, which only a gateway that stops beating reaches."""
    from runtime_helpers import sim_config_dict

    port = free_port()
    d = sim_config_dict(
        sim={"imu_errors": "none"},
        outputs=[{"name": "gcs", "url": f"udpout:127.0.0.1:{port}", "role": "gcs", "sysid": 42}],
        recorder={"enabled": False},
    )
    with machine_alone():  # the 2-s IMU watchdog is real time: not beside another worker's real-time test
        got, gw = _run_gateway(d, 30.0, port, kill_when=_navigating, until=lambda g: _holds(_status_followed, g))
    assert _navigating(got), "the gateway navigated with the IMU and GNSS healthy before the simulator was killed"
    _status_followed(got)
    assert gw.stopped_reason == "test condition met"
    assert gw.metrics.aligned is False and gw.metrics.snapshot()["sensors"]["imu"]["healthy"] is False


def test_sensor_health_lost_and_back_events_follow_the_arrivals() -> None:
    """RuntimeMetrics' per-sensor health on its own clock: a 1 kHz IMU and a 5 Hz GNSS arrive, stop
    (lost after 0.5 s and 1 s: 5 periods), come back ("back" after a full second at their rate, once),
    and an IMU trickling at a fifth of its rate is lost once, without flapping."""
    m = RuntimeMetrics()
    m.expect_inputs([("imu0", "serial_imu"), ("fc", "mavlink")])
    imu = m.source("imu0")
    fix = GnssFix(0.0, 0.9, 0.5, 100.0)
    t = 1_000_000_000
    step = 50_000_000  # the housekeeping period

    def run(seconds: float, imu_per_step: int, gnss_on: bool) -> list[tuple[int, str]]:
        nonlocal t
        for k in range(round(seconds * 1e9 / step)):
            imu.received += imu_per_step
            if gnss_on and k % 4 == 0:
                m.aid_seen(fix)
            t += step
            m.tick(t)
        return m.drain_sensor_events()

    assert run(3.0, 50, True) == []
    assert m.sensors["imu"].healthy and m.sensors["gnss"].healthy and not m.sensors["mag"].present
    assert m.sensors["baro"].present and not m.sensors["baro"].healthy  # configured (mavlink input), never seen
    assert run(0.45, 0, True) == [] and m.sensors["imu"].healthy
    assert run(0.2, 0, True) == [(3, "IMU lost: no data")] and not m.sensors["imu"].healthy
    assert run(1.2, 50, False) == [(3, "GNSS lost: no data")]
    assert run(2.5, 50, True) == [(5, "IMU back"), (5, "GNSS back")]
    assert run(3.0, 50, True) == []
    assert run(6.0, 10, True) == [(3, "IMU lost: no data")]  # 200 Hz of 1 kHz
    snap = m.snapshot()["sensors"]
    assert not snap["imu"]["healthy"] and round(snap["imu"]["expected_hz"]) == 1000
