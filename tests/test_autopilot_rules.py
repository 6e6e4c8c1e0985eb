"""What ArduPilot and PX4 do with each message the gateway sends them (role ``fc``), rule by rule, and the
gateway's own output held against those rules at start-up, before alignment, after alignment, across a
re-initialisation and a restart, and across an IMU gap.

Each rule is a small function that says what the consumer does with a decoded message, with the consumer's
file and function in a comment. Read from ArduPilot 4.6 (Copter-4.6 branch) and PX4 v1.15 (main of 2025 for
the EKF2 aid sources). The output is the real encoder path: a :class:`MavlinkEndpoint` driven the way the
loop drives it (``offer``, the heartbeat task, sensor health), and a short live ``ins-hil`` gateway run with
the simulator, an ``fc`` output and a 0.8-s IMU stop (SIGSTOP of the simulator process).
"""

from __future__ import annotations

import asyncio
import itertools
import math
import os
import re
import signal
import socket
import time
from pathlib import Path
from typing import Any

import numpy as np
import pytest
from pymavlink.dialects.v20 import ardupilotmega as mav
from runtime_helpers import BufferSink, free_port, sim_config_dict, sim_gateway

from ins_hil.nav import earth
from ins_hil.nav.rotation import dcm_from_quat, euler_from_quat, quat_from_euler, quat_from_rotvec, quat_mul
from ins_hil.runtime.geoid import undulation
from ins_hil.runtime.mavlink_out import EndpointConfig, MavlinkEndpoint
from ins_hil.runtime.metrics import RuntimeMetrics
from ins_hil.types import FixType, GnssFix, NavState

DOCS = Path(__file__).resolve().parents[1] / "docs" / "flight_controller.md"
LAT0, LON0, H0 = math.radians(50.45), math.radians(30.52), 180.0

# ============================================================================ the rules
# ---- ODOMETRY (331) -----------------------------------------------------------------


def ap_odometry_taken(o: Any) -> bool:
    """ArduPilot libraries/GCS_MAVLink/GCS_Common.cpp, GCS_MAVLINK::handle_odometry: returns at once unless
    frame_id == MAV_FRAME_LOCAL_FRD and child_frame_id == MAV_FRAME_BODY_FRD; the velocity is then rotated
    by the message's quaternion (body → earth) before AP_VisualOdom::handle_vision_speed_estimate."""
    return bool(o.frame_id == mav.MAV_FRAME_LOCAL_FRD and o.child_frame_id == mav.MAV_FRAME_BODY_FRD)


def ap_visodom_consumes(o: Any, viso_qual_min: int = 0) -> bool:
    """ArduPilot libraries/AP_VisualOdom/AP_VisualOdom_MAV.cpp, AP_VisualOdom_MAV::handle_pose_estimate and
    handle_vision_speed_estimate: ``consume = (_quality >= _frontend.get_quality_min())``; VISO_QUAL_MIN
    (AP_VisualOdom.cpp var_info ``_QUAL_MIN``) defaults to 0: "0 to send if good or unknown"; −1 = failed."""
    return bool(o.quality >= viso_qual_min)


def px4_ev_fuses(o: Any, ekf2_ev_qmin: int = 0) -> bool:
    """PX4 src/modules/ekf2/EKF/aid_sources/external_vision/ev_control.cpp, Ekf::controlExternalVisionFusion:
    ``quality_sufficient = (_params.ev_quality_minimum <= 0) || (ev_sample.quality >= ev_quality_minimum)``;
    EKF2_EV_QMIN defaults to 0, so with the default every ODOMETRY is fused, whatever its quality
    (mavlink_receiver.cpp handle_message_odometry copies ``quality`` into vehicle_odometry)."""
    return ekf2_ev_qmin <= 0 or o.quality >= ekf2_ev_qmin


def px4_velocity_variance(o: Any) -> tuple[float, float, float]:
    """PX4 src/modules/mavlink/mavlink_receiver.cpp, MavlinkReceiver::handle_message_odometry: with
    child_frame_id MAV_FRAME_BODY_FRD the velocity is VELOCITY_FRAME_BODY_FRD and, for an estimator_type other
    than NAIVE, velocity_variance = velocity_covariance[0], [6], [11]: variances along the BODY axes."""
    assert o.child_frame_id == mav.MAV_FRAME_BODY_FRD and o.estimator_type != mav.MAV_ESTIMATOR_TYPE_NAIVE
    return o.velocity_covariance[0], o.velocity_covariance[6], o.velocity_covariance[11]


def px4_orientation_variance(o: Any) -> tuple[float, float, float]:
    """Same function: orientation_variance = pose_covariance[15], [18], [20]: roll, pitch, yaw (the 6×6's
    states are x, y, z, roll, pitch, yaw)."""
    return o.pose_covariance[15], o.pose_covariance[18], o.pose_covariance[20]


def fc_resets_to_new_position(prev: Any, cur: Any) -> bool:
    """A changed reset_counter makes both flight controllers reset their position to the new one instead of
    fusing (or rejecting) a step: ArduPilot libraries/AP_VisualOdom/AP_VisualOdom_Backend.cpp,
    AP_VisualOdom_Backend::get_reset_timestamp_ms (a new counter → a new reset time handed to
    AP_AHRS::writeExtNavData, EKF3 resets position to ExternalNav); PX4 ev_control.cpp,
    Ekf::controlExternalVisionFusion: ``ev_reset = (ev_sample.reset_counter != _ev_sample_prev.reset_counter)``."""
    return bool(prev.reset_counter != cur.reset_counter)


# ---- SET_GPS_GLOBAL_ORIGIN (48) -----------------------------------------------------------


def px4_origin_taken(s: Any, fc_sysid: int) -> bool:
    """PX4 src/modules/mavlink/mavlink_receiver.cpp, handle_message_set_gps_global_origin: only when
    ``target_system == _mavlink->get_system_id()``; lat/lon degE7, altitude mm (AMSL) →
    VEHICLE_CMD_SET_GPS_GLOBAL_ORIGIN."""
    return bool(s.target_system == fc_sysid)


def ap_origin(s: Any) -> tuple[float, float, float]:
    """ArduPilot GCS_Common.cpp, GCS_MAVLINK::handle_set_gps_global_origin: check_latlng, then
    ``ekf_origin.alt = packet.altitude / 10`` (mm → cm, AMSL) → AP_AHRS::set_origin. (lat °, lon °, MSL m)."""
    assert abs(s.latitude) <= 900_000_000 and abs(s.longitude) <= 1_800_000_000
    return s.latitude * 1e-7, s.longitude * 1e-7, (s.altitude // 10) * 0.01


# ---- GPS_INPUT (232) --------------------------------------------------------------------------

GPS_UNKNOWN_DOP = 9999  # libraries/AP_GPS/AP_GPS.h
GPS_HDOP_GOOD_DEFAULT = 140  # ArduCopter/config.h, parameter GPS_HDOP_GOOD (range 100–900)


def ap_gps_hdop(g: Any, previous: int = GPS_UNKNOWN_DOP) -> int:
    """ArduPilot libraries/AP_GPS/AP_GPS_MAV.cpp, AP_GPS_MAV::handle_msg: ``have_hdop = (ignore_flags &
    GPS_INPUT_IGNORE_FLAG_HDOP) == 0``; then ``state.hdop = packet.hdop * 100`` (uint16), else the state keeps
    its value (GPS_UNKNOWN_DOP = 9999 from the start)."""
    if g.ignore_flags & mav.GPS_INPUT_IGNORE_FLAG_HDOP:
        return previous
    return int(g.hdop * 100) & 0xFFFF


def copter_hdop_prearm_ok(hdop: int, gps_hdop_good: int = GPS_HDOP_GOOD_DEFAULT) -> bool:
    """ArduPilot ArduCopter/AP_Arming.cpp, AP_Arming_Copter::gps_checks: ``copter.gps.get_hdop() >
    copter.g.gps_hdop_good`` → "High GPS HDOP" and no arming in a mode that needs a position."""
    return hdop <= gps_hdop_good


def ap_gps_fix_used(g: Any) -> bool:
    """AP_GPS_MAV::handle_msg: ``state.status = packet.fix_type``; EKF3 takes a GPS measurement only at
    status ≥ GPS_OK_FIX_3D (libraries/AP_NavEKF3/AP_NavEKF3_Measurements.cpp, NavEKF3_core::readGpsData)."""
    return bool(g.fix_type >= 3)


def ap_gps_lag_s(gps_delay_ms: int) -> float:
    """ArduPilot libraries/AP_GPS/AP_GPS.cpp, AP_GPS::get_lag: GPSn_DELAY_MS > 0 → that value; 0 → the
    backend's get_lag, which AP_GPS_MAV inherits from libraries/AP_GPS/GPS_Backend.h: 0.2 s."""
    return gps_delay_ms * 1e-3 if gps_delay_ms > 0 else 0.2


def ap_gps_time_ok(g: Any) -> bool:
    """AP_GPS_MAV::handle_msg: time_week/time_week_ms become the GPS time; with fix ≥ 3 and week > 0 the
    timestamp ``(time_week − first_week) · AP_MSEC_PER_WEEK + time_week_ms`` feeds the jitter correction: a
    ms of week must be < AP_MSEC_PER_WEEK (604 800 000), a whole week is the next week's 0."""
    return bool(0 <= g.time_week_ms < 604_800_000)


def ap_gps_fields_used(g: Any) -> int:
    """AP_GPS_MAV::handle_msg: each GPS_INPUT_IGNORE_FLAG_* bit drops that field; the gateway provides them
    all (altitude MSL m, NED velocity m/s, accuracies m and m/s, DOP)."""
    return int(g.ignore_flags)


# ---- HEARTBEAT ------------------------------------------------------------------------------------

MAV_GCS_SYSID_DEFAULT = 255  # ArduPilot SYSID_MYGCS / MAV_GCS_SYSID default


def heartbeat_counts_as_gcs(hb: Any) -> bool:
    """ArduPilot GCS_Common.cpp, GCS_MAVLINK::handle_heartbeat: a heartbeat from system id SYSID_MYGCS (255)
    marks the ground station seen (resets the FS_GCS timer); PX4 mavlink_receiver.cpp handle_message_heartbeat:
    type MAV_TYPE_GCS → telemetry_status.heartbeat_type_gcs (the data-link-loss failsafe's input)."""
    return bool(hb.get_srcSystem() == MAV_GCS_SYSID_DEFAULT or hb.type == mav.MAV_TYPE_GCS)


# ============================================================================ the gateway's output


def _state(t: float, aligned: bool = True, pos_ned: tuple[float, float, float] = (0.0, 0.0, 0.0),
           resets: int = 0, yaw_deg: float = 120.0) -> NavState:  # fmt: skip
    """A state at ``pos_ned`` (m) from (LAT0, LON0, H0), moving 3 m/s north-east-up-ish, rolled and pitched."""
    lat, lon, h = earth.geodetic_from_ned(np.array(pos_ned), LAT0, LON0, H0)
    return NavState(
        t=t,
        q_nb=quat_from_euler(math.radians(10), math.radians(-5), math.radians(yaw_deg)),
        vel_ned=np.array([3.0, -4.0, 0.5]),
        lat=float(lat),
        lon=float(lon),
        h=float(h),
        std_pos=np.array([0.5, 0.6, 1.2]) if aligned else np.array([7.0, 7.0, 5.0]),
        std_vel=np.array([0.05, 0.08, 0.1]),
        std_att=np.radians([0.5, 0.7, 2.0]),
        omega_b=np.array([0.01, -0.02, 0.03]),
        accel_b=np.array([0.1, 0.2, -9.8]),
        aligned=aligned,
        resets=resets,
    )


class _Run:
    """An fc endpoint on a fake monotonic clock, fed like the loop feeds it; every message it writes, with
    the phase it was written in."""

    def __init__(self, monkeypatch: pytest.MonkeyPatch, frame: str = "LOCAL_FRD") -> None:
        self.clock = [1_000_000_000_000]
        monkeypatch.setattr(time, "monotonic_ns", lambda: self.clock[0])
        rates = {"HEARTBEAT": 1.0, "ODOMETRY": 30.0, "GPS_INPUT": 5.0, "HIL_STATE_QUATERNION": 10.0}
        cfg = EndpointConfig(role="fc", sysid=1, compid=197, odometry_frame=frame, rates=rates)
        self.metrics = RuntimeMetrics()
        self.ep = MavlinkEndpoint(cfg, self.metrics)
        self.sink = BufferSink()
        self.ep.tr = self.sink  # type: ignore[assignment]
        self.parser = mav.MAVLink(None)
        self.msgs: list[tuple[str, Any]] = []
        imu, gnss = self.metrics.sensors["imu"], self.metrics.sensors["gnss"]
        imu.configured = gnss.configured = True

    def _collect(self, phase: str) -> None:
        for b in self.sink.bufs:
            for m in self.parser.parse_buffer(b) or []:
                self.msgs.append((phase, m))
        self.sink.bufs.clear()

    def idle(self, seconds: float, phase: str) -> None:
        """No states (start-up, IMU stopped): the endpoint's task sends what it sends alone."""
        for _ in range(round(seconds / 0.05)):
            self.clock[0] += 50_000_000
            self.ep._beat()
        self._collect(phase)

    def states(self, t0: float, seconds: float, phase: str, **kw: Any) -> float:
        """States at 100 Hz from sensor time t0 (the position moving with the velocity), IMU and GNSS healthy."""
        imu, gnss = self.metrics.sensors["imu"], self.metrics.sensors["gnss"]
        offset = kw.pop("offset", (0.0, 0.0, 0.0))
        n = round(seconds * 100)
        for k in range(n):
            t = t0 + 0.01 * k
            self.clock[0] += 10_000_000
            imu.count += 10
            imu.healthy = gnss.healthy = True
            gnss.count += 1
            if k % 20 == 0:
                self.ep.offer_gnss(GnssFix(t, LAT0, LON0, H0, np.zeros(3), fix_type=FixType.FIX_3D, num_sats=12,
                                           gps_week=2345, gps_tow=604_799.0 + t))  # fmt: skip
            p = (3.0 * t + offset[0], -4.0 * t + offset[1], 0.5 * t + offset[2])
            self.ep.offer(_state(t, pos_ned=p, **kw), self.clock[0] - 1_000_000, self.clock[0])
            self.ep._beat()
        self._collect(phase)
        return t0 + 0.01 * n

    def imu_lost(self, seconds: float) -> None:
        imu = self.metrics.sensors["imu"]
        imu.healthy = False
        self.idle(seconds, "imu_gap")

    def of(self, typ: str, *phases: str) -> list[Any]:
        return [m for p, m in self.msgs if m.get_type() == typ and (not phases or p in phases)]


def _drive(monkeypatch: pytest.MonkeyPatch, frame: str = "LOCAL_FRD") -> _Run:
    """start-up (no state) → 2 s unaligned → 3 s aligned → a re-initialisation (NavState.resets + 1, the
    position steps 5 m north) → 2 s → the IMU stops for 0.6 s → 2 s after it came back."""
    r = _Run(monkeypatch, frame)
    r.idle(1.5, "startup")
    t = r.states(1.0, 2.0, "unaligned", aligned=False)
    t = r.states(t, 3.0, "aligned")
    t = r.states(t, 2.0, "reinit", resets=1, offset=(5.0, 0.0, 0.0))
    r.imu_lost(0.6)
    r.states(t + 0.6, 2.0, "after_gap", resets=1, offset=(5.0, 0.0, 0.0))
    return r


# ---------------------------------------------------------------------------- item 1: an unusable solution


@pytest.mark.parametrize("frame", ["LOCAL_FRD", "LOCAL_NED"])
def test_no_flight_controller_fuses_an_unaligned_or_lost_solution(monkeypatch: pytest.MonkeyPatch,
                                                                   frame: str) -> None:  # fmt: skip
    r = _drive(monkeypatch, frame)
    for phase in ("startup", "unaligned", "imu_gap"):
        for o in r.of("ODOMETRY", phase):
            # with the autopilots' defaults (VISO_QUAL_MIN = 0, EKF2_EV_QMIN = 0) nothing unusable may be fused
            assert not ap_visodom_consumes(o), (phase, o.quality)
            assert not px4_ev_fuses(o), (phase, o.quality)
        for g in r.of("GPS_INPUT", phase):
            assert not ap_gps_fix_used(g), (phase, g.fix_type)
        assert not r.of("HIL_STATE_QUATERNION", phase), phase  # no validity field: not sent at all
    # and once aligned the solution is taken by both
    odo = r.of("ODOMETRY", "aligned")
    assert len(odo) > 60 and all(ap_visodom_consumes(o, 1) and px4_ev_fuses(o, 1) for o in odo)
    assert all(ap_gps_fix_used(g) for g in r.of("GPS_INPUT", "aligned"))
    assert r.of("HIL_STATE_QUATERNION", "aligned")


def test_gps_input_has_no_fix_while_dead_reckoning(monkeypatch: pytest.MonkeyPatch) -> None:
    """The GNSS input lost after alignment: the state is an inertial dead-reckoning; AP's EKF must not take
    it as a 3-D fix (it then runs its own dead-reckoning and failsafes)."""
    r = _Run(monkeypatch)
    t = r.states(1.0, 2.0, "aligned")
    gnss = r.metrics.sensors["gnss"]
    imu = r.metrics.sensors["imu"]
    for k in range(200):
        r.clock[0] += 10_000_000
        imu.count += 10
        gnss.healthy = False
        r.ep.offer(_state(t + 0.01 * k, pos_ned=(3.0 * (t + 0.01 * k), 0.0, 0.0)), r.clock[0], r.clock[0])
    r._collect("dead_reckoning")
    dr = r.of("GPS_INPUT", "dead_reckoning")
    assert dr and not any(ap_gps_fix_used(g) for g in dr)
    assert all(ap_gps_fix_used(g) for g in r.of("GPS_INPUT", "aligned"))


# ---------------------------------------------------------------------------- item 5: ArduPilot's GPS lag


def _doc_param(name: str) -> int:
    m = re.search(rf"^\| `{name}` \| (\d+)", DOCS.read_text(), re.MULTILINE)  # its row in a parameter table
    assert m, f"docs/flight_controller.md sets no {name}"
    return int(m.group(1))


def test_the_documented_delays_replace_ardupilots_200_ms_gps_lag() -> None:
    """GPS_INPUT carries the current state (time_usec = the state's time): the lag ArduPilot assumes must be
    the gateway + link latency (a few ms), not the MAVLink GPS backend's 0.2 s (≈ 3 m along-track at 15 m/s)."""
    gps = _doc_param("GPS1_DELAY_MS")
    viso = _doc_param("VISO_DELAY_MS")
    assert 0.001 <= ap_gps_lag_s(gps) <= 0.05 and 1 <= viso <= 50
    assert ap_gps_lag_s(0) == 0.2  # left at 0 the backend's lag applies


# ---------------------------------------------------------------------------- item 6: Copter's HDOP pre-arm


def test_copter_can_arm_on_the_gateways_gps_input(monkeypatch: pytest.MonkeyPatch) -> None:
    r = _drive(monkeypatch)
    gi = r.of("GPS_INPUT", "aligned")
    assert gi and all(ap_gps_fields_used(g) == 0 for g in gi)  # nothing ignored, HDOP/VDOP included
    hdop = GPS_UNKNOWN_DOP
    for g in gi:
        hdop = ap_gps_hdop(g, hdop)
    # σ = (0.5, 0.6) m horizontal: HDOP 0.78 with the documented 1 m range error: the pre-arm passes
    assert copter_hdop_prearm_ok(hdop), hdop
    assert math.isclose(gi[-1].hdop, math.hypot(0.5, 0.6), rel_tol=1e-5) and math.isclose(
        gi[-1].vdop, 1.2, rel_tol=1e-5
    )
    # unaligned (σh ≈ 9.9 m): a high HDOP, the pre-arm refuses (also at the parameter's top, 900: 9.9 m > 9 m)
    un = r.of("GPS_INPUT", "unaligned")
    assert un and not copter_hdop_prearm_ok(ap_gps_hdop(un[-1]), 900)


def test_gps_input_ms_of_week_never_reaches_a_whole_week() -> None:
    """GPS time 0.9996 ms before the end of week 2345: rounds to week 2346, 0 ms (item 8)."""
    ep = MavlinkEndpoint(EndpointConfig(role="fc", sysid=1, compid=197), RuntimeMetrics())
    sink = BufferSink()
    ep.tr = sink  # type: ignore[assignment]
    ep.offer_gnss(GnssFix(2.0, LAT0, LON0, H0, gps_week=2345, gps_tow=604_799.9996, fix_type=FixType.FIX_3D))
    ep._send_gps_input(_state(2.0))
    (g,) = [m for b in sink.bufs for m in mav.MAVLink(None).parse_buffer(b) or []]
    assert ap_gps_time_ok(g), g.time_week_ms
    assert (g.time_week, g.time_week_ms) == (2346, 0)


# ---------------------------------------------------------------------------- item 7: resets and the origin


def _jump(a: Any, b: Any) -> float:
    """The position step between two ODOMETRY messages beyond what their velocity explains (m)."""
    dt = (b.time_usec - a.time_usec) * 1e-6
    va = dcm_from_quat(np.array(a.q)) @ [a.vx, a.vy, a.vz]
    vb = dcm_from_quat(np.array(b.q)) @ [b.vx, b.vy, b.vz]
    pred = np.array([a.x, a.y, a.z]) + 0.5 * (va + vb) * dt
    return float(np.linalg.norm(np.array([b.x, b.y, b.z]) - pred))


def test_position_steps_and_restarts_are_signalled(monkeypatch: pytest.MonkeyPatch) -> None:
    r = _drive(monkeypatch)
    odo = [m for p, m in r.msgs if m.get_type() == "ODOMETRY"]
    phase = [p for p, m in r.msgs if m.get_type() == "ODOMETRY"]
    jumps = 0
    for (pa, a), (pb, b) in zip(zip(phase, odo, strict=True), zip(phase[1:], odo[1:], strict=True), strict=False):
        if _jump(a, b) > 0.5 or (pa != pb and "reinit" in (pa, pb)):
            jumps += 1
            assert fc_resets_to_new_position(a, b), (pa, pb, _jump(a, b))
        elif pa == pb:
            assert not fc_resets_to_new_position(a, b), pa  # a counter change makes the FC drop its estimate
    assert jumps >= 1
    # the IMU gap: the first ODOMETRY after it resets too (the INS ran blind for 0.6 s)
    last_before = r.of("ODOMETRY", "reinit")[-1]
    first_after = r.of("ODOMETRY", "after_gap")[0]
    assert fc_resets_to_new_position(last_before, first_after)


def test_a_restarted_gateway_changes_the_counter_the_fc_saw(monkeypatch: pytest.MonkeyPatch) -> None:
    """A gateway restart re-takes the home: the first ODOMETRY of the new process must carry another counter
    than the last of the old one, or the FC fuses the new frame's positions as a step. The counter starts at
    random per process (a repeat has a 1/256 chance); here two starts with different draws."""
    import secrets

    draws = iter([17, 200])
    monkeypatch.setattr(secrets, "randbelow", lambda n: next(draws))
    a = _Run(monkeypatch)
    a.states(1.0, 2.0, "aligned")
    b = _Run(monkeypatch)
    b.states(1.0, 2.0, "aligned", offset=(40.0, 0.0, 0.0))  # the new home 40 m away
    last_old, first_new = a.of("ODOMETRY")[-1], b.of("ODOMETRY")[0]
    assert (first_new.x, first_new.y) == (0.0, 0.0) and last_old.x > 5.0  # the frames differ
    assert fc_resets_to_new_position(last_old, first_new)
    monkeypatch.undo()
    starts = set()
    for _ in range(64):
        r = _Run.__new__(_Run)
        ep = MavlinkEndpoint(EndpointConfig(role="fc", sysid=1, compid=197), RuntimeMetrics())
        sink = BufferSink()
        ep.tr = sink  # type: ignore[assignment]
        ep._send_odometry(_state(1.0))
        r.msgs = [("x", m) for b in sink.bufs for m in mav.MAVLink(None).parse_buffer(b) or []]
        starts.add(r.of("ODOMETRY")[0].reset_counter)
    assert len(starts) > 16  # random per start (a fixed start repeats the value the FC saw)


def test_the_fc_learns_our_local_origin(monkeypatch: pytest.MonkeyPatch) -> None:
    r = _drive(monkeypatch)
    org = r.of("SET_GPS_GLOBAL_ORIGIN")
    assert org, "no SET_GPS_GLOBAL_ORIGIN"
    assert not r.of("SET_GPS_GLOBAL_ORIGIN", "startup", "unaligned")  # no origin before there is a home
    o0 = r.of("ODOMETRY", "aligned")[-1]
    t = o0.time_usec * 1e-6
    st = _state(t, pos_ned=(3.0 * t, -4.0 * t, 0.5 * t))
    for s in org:
        assert px4_origin_taken(s, fc_sysid=1)
        lat, lon, alt = ap_origin(s)
        # the origin is the point ODOMETRY's local frame starts from: origin + NED offset = the state
        n, e, d = earth.ned_from_geodetic(st.lat, st.lon, st.h, math.radians(lat), math.radians(lon),
                                          alt + undulation(math.radians(lat), math.radians(lon)))  # fmt: skip
        assert abs(n - o0.x) < 0.02 and abs(e - o0.y) < 0.02 and abs(d - o0.z) < 0.02


# ---------------------------------------------------------------------------- item 8: frames of the covariances


def test_px4_reads_the_velocity_and_attitude_variances_in_their_frames(monkeypatch: pytest.MonkeyPatch) -> None:
    r = _drive(monkeypatch, "LOCAL_NED")
    o = r.of("ODOMETRY", "aligned")[-1]
    st = _state(o.time_usec * 1e-6)
    c = dcm_from_quat(st.q_nb)
    body = np.diag(c.T @ np.diag(np.asarray(st.std_vel) ** 2) @ c)
    assert np.allclose(px4_velocity_variance(o), body, rtol=1e-5)
    # roll/pitch/yaw variances: small rotations about the NED axes carried to Euler angles numerically
    e0 = euler_from_quat(st.q_nb)
    jac = np.zeros((3, 3))
    for k in range(3):
        d = np.zeros(3)
        d[k] = 1e-6
        jac[:, k] = (euler_from_quat(quat_mul(quat_from_rotvec(d), st.q_nb)) - e0) / 1e-6
    euler = np.diag(jac @ np.diag(np.asarray(st.std_att) ** 2) @ jac.T)
    assert np.allclose(px4_orientation_variance(o), euler, rtol=1e-4)
    assert ap_odometry_taken(r.of("ODOMETRY", "aligned")[0]) is False  # LOCAL_NED is PX4's; AP needs LOCAL_FRD
    assert all(ap_odometry_taken(o) for o in _drive(monkeypatch, "LOCAL_FRD").of("ODOMETRY"))


# ---------------------------------------------------------------------------- heartbeats


def test_our_fc_link_heartbeat_is_no_ground_station(monkeypatch: pytest.MonkeyPatch) -> None:
    r = _drive(monkeypatch)
    hbs = r.of("HEARTBEAT")
    assert r.of("HEARTBEAT", "startup") and len(hbs) >= 8  # 1 Hz from the start, also with no state
    for hb in hbs:
        assert not heartbeat_counts_as_gcs(hb)
        assert (hb.get_srcSystem(), hb.get_srcComponent()) == (1, 197)
        assert hb.type == mav.MAV_TYPE_ONBOARD_CONTROLLER and hb.autopilot == mav.MAV_AUTOPILOT_INVALID


# ---------------------------------------------------------------------------- a live gateway run


def _hdop_ok(gi: list[Any]) -> bool:
    """ArduPilot's HDOP (its last fused GPS_INPUT's, as its driver keeps it) passes the copter pre-arm check."""
    used = [g for g in gi if ap_gps_fix_used(g)]
    hdop = GPS_UNKNOWN_DOP
    for g in used:
        hdop = ap_gps_hdop(g, hdop)
    return bool(used) and copter_hdop_prearm_ok(hdop)


def _live(port: int, deadline: float = 120.0) -> tuple[list[tuple[float, Any]], Any, tuple[float, float]]:
    """``ins-hil run`` with the simulator and an fc output (ArduPilot's frames, every fc message) to a UDP
    listener; once it navigates (40 ODOMETRY, and the GPS_INPUT ArduPilot uses pass its HDOP pre-arm check), the
    simulator process is stopped (SIGSTOP) for 0.8 s: the IMU gap; the run ends 20 ODOMETRY after it. Counts, not
    times: a busy machine starts the gateway slowly; ``deadline`` (s) only guards against a hang. Returns (arrival
    s, message) in arrival order, the gateway and the (SIGSTOP, SIGCONT) times on the arrival clock."""
    d = sim_config_dict(
        outputs=[{"name": "fc", "url": f"udpout:127.0.0.1:{port}", "role": "fc", "sysid": 1, "compid": 197,
                  "odometry_frame": "LOCAL_FRD",
                  "rates": {"ODOMETRY": 30.0, "GPS_INPUT": 5.0, "HIL_STATE_QUATERNION": 10.0}}],
        recorder={"enabled": False},
    )  # fmt: skip
    d["core"].setdefault("nav", {}).setdefault("alignment", {})["aligned_yaw_std"] = 3.14  # aligned at init
    from ins_hil.config import from_dict

    gw = sim_gateway(from_dict(d, "test"))
    rx = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    rx.bind(("127.0.0.1", port))
    rx.setblocking(False)
    parser = mav.MAVLink(None)
    got: list[tuple[float, Any]] = []
    marks: list[float] = []

    def n_odo() -> int:
        return sum(m.get_type() == "ODOMETRY" for _, m in got)

    async def until(cond: Any) -> None:
        end = time.monotonic() + deadline
        while not cond() and time.monotonic() < end:
            await asyncio.sleep(0.02)

    async def go() -> None:
        t0 = time.monotonic()

        async def pump() -> None:
            while True:
                try:
                    data = rx.recv(65536)
                except BlockingIOError:
                    await asyncio.sleep(0.01)
                    continue
                for m in parser.parse_buffer(data) or []:
                    got.append((time.monotonic() - t0, m))

        async def gap() -> None:
            await until(lambda: n_odo() >= 40 and _hdop_ok([m for _, m in got if m.get_type() == "GPS_INPUT"]))
            pid = gw.sim.proc.pid
            os.kill(pid, signal.SIGSTOP)
            marks.append(time.monotonic() - t0)
            try:
                await asyncio.sleep(0.8)
            finally:
                os.kill(pid, signal.SIGCONT)
                marks.append(time.monotonic() - t0)
            n = n_odo()
            await until(lambda: n_odo() >= n + 20)
            gw.request_stop("test")

        p = asyncio.create_task(pump())
        g = asyncio.create_task(gap())
        await gw.run(duration=deadline * 3, signals=False)
        await asyncio.sleep(0.1)
        p.cancel()
        g.cancel()

    asyncio.run(go())
    rx.close()
    assert len(marks) == 2, "the gateway never navigated"
    return got, gw, (marks[0], marks[1])


@pytest.mark.slow
def test_a_live_gateway_run_keeps_the_rules() -> None:
    got, gw, (t_stop, t_cont) = _live(free_port())
    types = [m.get_type() for _, m in got]
    assert "HEARTBEAT" in types and types.index("HEARTBEAT") < types.index("ODOMETRY")  # start-up: beats first
    odo = [(t, m) for t, m in got if m.get_type() == "ODOMETRY"]
    assert len(odo) > 30
    assert all(ap_odometry_taken(m) and ap_visodom_consumes(m, 1) and px4_ev_fuses(m, 1) for _, m in odo)
    gi = [m for _, m in got if m.get_type() == "GPS_INPUT"]
    assert all(ap_gps_fields_used(g) == 0 and ap_gps_time_ok(g) for g in gi)
    assert _hdop_ok(gi)  # the fused σh is ≤ 1.4 m within seconds
    # the IMU gap: ODOMETRY stops, and the first one after it tells the FC to reset
    # the pause across the IMU stop, not the longest one (a busy host may pause the loop elsewhere too): the last
    # ODOMETRY that came before the SIGCONT and the first after it
    k = max(i for i in range(len(odo) - 1) if odo[i][0] < t_cont)
    assert odo[k + 1][0] - odo[k][0] >= 0.8, (t_stop, t_cont, [round(t, 2) for t, _ in odo])
    assert fc_resets_to_new_position(odo[k][1], odo[k + 1][1])
    for (_, a), (_, b) in itertools.pairwise(odo):
        if _jump(a, b) > 1.0:
            assert fc_resets_to_new_position(a, b), _jump(a, b)
    org = [m for _, m in got if m.get_type() == "SET_GPS_GLOBAL_ORIGIN"]
    assert org and all(px4_origin_taken(s, 1) for s in org)
    assert not any(heartbeat_counts_as_gcs(m) for _, m in got if m.get_type() == "HEARTBEAT")
    # the gateway's own latency (IMU arrival → first message of that state sent), even on a loaded test host,
    # is far from the 0.2 s ArduPilot assumes for a MAVLink GPS left at GPS1_DELAY_MS = 0
    lat = gw.metrics.snapshot()["latency"]["arrival_to_sent"]
    assert lat["count"] > 30 and lat["p50_us"] * 1e-6 < 0.25 * ap_gps_lag_s(0)


# ---------------------------------------------------------------------------- the core's reset signal


def test_navstate_resets_counts_new_cores_and_gnss_position_resets() -> None:
    """NavState.resets (what ODOMETRY's reset_counter follows) changes when the pipeline restarts the core
    after a fault, when it re-aligns, and when the core resets its position on consistent GNSS fixes."""
    from test_core_guard import LAT, LON, WIDE, H, Run, _core_at, _drive_core

    r = Run("python", **WIDE)
    r.run(2.0)
    first = r.states[-1].resets
    r.imu(dtheta=(1e30, 0.0, 0.0))  # a core failure: restarted from the last good state
    r.run(0.5)
    assert r.counts["core_restart"] == 1 and r.states[-1].resets == first + 1
    r.imu(dtheta=(1e30, 0.0, 0.0))  # again before the first cleared: re-aligned from the next fix
    r.run(1.0)
    assert r.counts["core_realign"] == 1 and r.states[-1].resets > first + 1
    core = _core_at(LAT, "python")  # 200 m of consistent GNSS disagreement: the position is reset
    lat = math.radians(LAT)
    fixes = [GnssFix(t=0.2 * (k + 1), lat=lat + 200.0 / 6.37e6, lon=math.radians(LON), h=H,
                     vel_ned=np.zeros(3), std_ne=1.0, std_d=2.0, std_vel=0.1) for k in range(12)]  # fmt: skip
    _drive_core(core, fixes, 0.0)
    assert core.gnss_resets >= 1
