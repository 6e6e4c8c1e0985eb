"""The bytes a MAVLink endpoint puts on the wire, pinned by a digest.

3,000 pseudo-random states per case go through the endpoint as the gateway drives it (``offer``, the
task's texts/replies/heartbeat group, GNSS fixes, sensor health changes, ground-station requests), on a
fake monotonic clock, in both roles, unsigned (the precompiled framing) and signed (pymavlink's sender,
fixed signing timestamp). Every message type of ``ALL_MESSAGES`` is streamed. The digests were taken on
the endpoint before its message builders moved to :mod:`ins_hil.runtime.mavlink_msgs`, and re-taken
when both sides changed on purpose for issue 38: the flight-controller messages (ODOMETRY quality/reset
counter/covariance frames, GPS_INPUT DOP and fix, SET_GPS_GLOBAL_ORIGIN) and the ground-station side
(EXTENDED_SYS_STATE, BATTERY_STATUS and HOME_POSITION streamed, INT32 parameters bytewise, the home from a
converged solution, the drop rate in c%, GLOBAL_POSITION_INT's heading unknown before alignment); a change
of any byte of any message changes them.
"""

from __future__ import annotations

import hashlib
import math
import time
from collections import Counter

import numpy as np
import pytest
from ins_hil.drivers.mavlink_link import configure_signing
from pymavlink.dialects.v20 import ardupilotmega as mavlink2
from runtime_helpers import BufferSink

from ins_hil.nav.rotation import quat_normalize
from ins_hil.runtime.mavlink_out import ALL_MESSAGES, EndpointConfig, MavlinkEndpoint, fault_text
from ins_hil.runtime.metrics import RuntimeMetrics
from ins_hil.types import FaultEvent, FaultMode, GnssFix, NavState

KEY = bytes(range(32))
N_STATES = 3000
SIGN_T0 = 123_456_789_000  # signing timestamp (10 µs units) at the endpoint's start
EXPECTED = {
    ("gcs", False): "74d860e90ca4ebbb3d5f22eb0cbabcb6223b2b6adf6f4c89662f78b164c95359",
    ("gcs", True): "3a40b265e8feeea2e7ed59d2953f24b981b590428effc7d0aff2c63e31716172",
    ("fc", False): "c6e5552f391ddbf16be72655e15fc289b77a9ce9fe0bede5e761c87e9f8e7e2b",
    ("fc", True): "5df8d669c5cdb56287b4a017e3d07ebfa03ecb8189b1a84824dae8834c0d339a",
}


def _state(rng: np.random.Generator, t: float, k: int) -> NavState:
    st = NavState(
        t=t,
        q_nb=quat_normalize(rng.normal(size=4)),
        vel_ned=rng.normal(0.0, 20.0, 3),
        lat=0.6 + 1e-6 * k + rng.normal(0.0, 1e-4),
        lon=-1.2 + rng.normal(0.0, 1e-4),
        h=float(rng.uniform(-100.0, 3000.0)),
        std_pos=np.abs(rng.normal(0.0, 2.0, 3)),
        std_vel=np.abs(rng.normal(0.0, 0.2, 3)),
        std_att=np.abs(rng.normal(0.0, 0.02, 3)),
        omega_b=rng.normal(0.0, 1.0, 3),
        accel_b=rng.normal(0.0, 15.0, 3),
        aligned=k % 97 > 10,
        test_ratios={
            "gnss_vel": float(rng.uniform(0, 2)),
            "gnss_ne": float(rng.uniform(0, 2)),
            "baro_hgt": float(rng.uniform(0, 2)),
            "mag": float(rng.uniform(0, 2)),
        },
    )
    if k % 211 == 7:
        st.std_pos = np.zeros(3)
    elif k % 211 == 8:
        st.std_pos = np.array([0.0, math.nan, 1.0])
    return st


def _fix(rng: np.random.Generator, t: float, k: int) -> GnssFix:
    return GnssFix(
        t=t,
        lat=0.6 + rng.normal(0.0, 1e-4),
        lon=-1.2 + rng.normal(0.0, 1e-4),
        h=float(rng.uniform(0.0, 500.0)),
        vel_ned=None if k % 5 == 0 else rng.normal(0.0, 0.3 if k % 7 == 0 else 10.0, 3),
        num_sats=int(rng.integers(0, 40)),
        gps_week=0 if k % 4 == 0 else 2300,
        gps_tow=float(rng.uniform(0.0, 604_799.0)),
        hdop=math.nan if k % 3 == 0 else float(rng.uniform(0.5, 3.0)),
        vdop=math.nan if k % 2 == 0 else float(rng.uniform(0.5, 3.0)),
    )


def _requests(key: bytes | None) -> list[bytes]:
    """A ground station's requests to system 42 (one of them to another system)."""
    gcs = mavlink2.MAVLink(None, srcSystem=255, srcComponent=190)
    configure_signing(gcs, key)
    if key is not None:
        gcs.signing.timestamp = SIGN_T0 + 5
    m = mavlink2
    out = []
    for cmd, p1, p2 in (
        (m.MAV_CMD_REQUEST_MESSAGE, m.MAVLINK_MSG_ID_HOME_POSITION, 0),
        (m.MAV_CMD_REQUEST_MESSAGE, m.MAVLINK_MSG_ID_AUTOPILOT_VERSION, 0),
        (m.MAV_CMD_REQUEST_MESSAGE, m.MAVLINK_MSG_ID_SYSTEM_TIME, 0),
        (m.MAV_CMD_REQUEST_MESSAGE, m.MAVLINK_MSG_ID_GPS_RAW_INT, 0),
        (m.MAV_CMD_REQUEST_MESSAGE, m.MAVLINK_MSG_ID_VFR_HUD, 0),
        (m.MAV_CMD_REQUEST_MESSAGE, 9999, 0),
        (m.MAV_CMD_GET_MESSAGE_INTERVAL, m.MAVLINK_MSG_ID_ATTITUDE, 0),
        (m.MAV_CMD_GET_MESSAGE_INTERVAL, m.MAVLINK_MSG_ID_HIL_STATE_QUATERNION, 0),
        (m.MAV_CMD_SET_MESSAGE_INTERVAL, m.MAVLINK_MSG_ID_VFR_HUD, 20_000),
        (m.MAV_CMD_PREFLIGHT_STORAGE, 1, 0),
        (m.MAV_CMD_COMPONENT_ARM_DISARM, 1, 0),
        (m.MAV_CMD_REQUEST_AUTOPILOT_CAPABILITIES, 1, 0),
    ):
        out.append(gcs.command_long_encode(42, 1, cmd, 0, p1, p2, 0, 0, 0, 0, 0).pack(gcs))
    out.append(gcs.command_int_encode(42, 1, 0, m.MAV_CMD_REQUEST_MESSAGE, 0, 0, 24, 0, 0, 0, 0, 0, 0).pack(gcs))
    out.append(gcs.command_long_encode(7, 1, m.MAV_CMD_REQUEST_MESSAGE, 0, 30, 0, 0, 0, 0, 0, 0).pack(gcs))
    out.append(gcs.mission_request_list_encode(42, 1, 0).pack(gcs))
    out.append(gcs.file_transfer_protocol_encode(0, 42, 1, list(bytes((3, 0, 0, 5)).ljust(251, b"\x00"))).pack(gcs))
    out.append(gcs.param_request_list_encode(42, 1).pack(gcs))
    return out


def _record(role: str, signed: bool, monkeypatch: pytest.MonkeyPatch) -> tuple[list[bytes], Counter[str]]:
    clock = [1_000_000_000_000]
    monkeypatch.setattr(time, "monotonic_ns", lambda: clock[0])
    rates = dict.fromkeys(ALL_MESSAGES, 40.0) | {"HEARTBEAT": 2.0, "SYS_STATUS": 3.0, "GPS_RAW_INT": 60.0}
    cfg = EndpointConfig(role=role, signing_key=KEY.hex() if signed else "", rates=rates)
    metrics = RuntimeMetrics()
    ep = MavlinkEndpoint(cfg, metrics)
    ep.reset_counter = 0  # ODOMETRY's reset_counter starts at random
    sink = BufferSink()
    ep.tr = sink  # type: ignore[assignment]
    if signed:
        ep.mav.signing.timestamp = SIGN_T0
    rng = np.random.default_rng(2024 + (role == "fc") + 2 * signed)
    requests = _requests(KEY if signed else None)
    imu = metrics.sensors["imu"]
    clock[0] += 200_000_000
    ep._beat()  # no state yet: the heartbeat group from the task
    for k in range(N_STATES):
        t = 1.0 + 0.01 * k
        clock[0] += 7_000_000 + int(rng.integers(0, 6_000_000))
        imu.configured, imu.count, imu.healthy = True, k + 1, k % 500 < 450
        metrics.sensors["gnss"].count = k // 20
        metrics.sensors["gnss"].healthy = k % 300 < 200
        metrics.fdi_state = "ok" if k % 700 < 600 else "fault"
        if k % 9 == 0:
            ep.offer_gnss(_fix(rng, t - 0.05, k // 9))
        if k % 37 == 0:
            ev = FaultEvent(t=t, sensor=f"gyro[{k % 3}]", mode=FaultMode.STEP_BIAS, cleared=k % 74 == 0)
            ep.statustext(*fault_text(ev))
        ep.offer(_state(rng, t, k), clock[0] - 1_000_000, 0 if k % 3 else clock[0] - 500_000)
        if k % 150 == 75:
            ep._on_data(requests[(k // 150) % len(requests)])
        if k % 400 == 399:  # the IMU stops for 0.6 s: the task sends the heartbeat group alone
            clock[0] += 600_000_000
        ep._send_texts()
        ep._send_replies()
        ep._beat()
    mav = mavlink2.MAVLink(None)
    mav.robust_parsing = True
    types = Counter(m.get_type() for b in sink.bufs for m in mav.parse_buffer(b) or [])
    return sink.bufs, types


@pytest.mark.parametrize(("role", "signed"), list(EXPECTED))
def test_wire_bytes_are_unchanged(role: str, signed: bool, monkeypatch: pytest.MonkeyPatch) -> None:
    bufs, types = _record(role, signed, monkeypatch)
    streamed = {t for t in ALL_MESSAGES if role == "fc" or t not in ("ODOMETRY", "GPS_INPUT")}
    assert streamed <= set(types), sorted(streamed - set(types))
    digest = hashlib.sha256(b"".join(bufs)).hexdigest()
    assert digest == EXPECTED[(role, signed)], (len(bufs), dict(types))
