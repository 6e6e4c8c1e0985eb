"""The messages docs/flight_controller.md says a flight controller reads, decoded with pymavlink, checked
field by field against what PX4 (mavlink_receiver.cpp) and ArduPilot (GCS_Common handle_odometry,
AP_GPS_MAV) take from them: units, frames, flags, covariance layout."""

from __future__ import annotations

import math
from typing import Any

import numpy as np
from pymavlink.dialects.v20 import ardupilotmega as mav
from runtime_helpers import BufferSink
from test_runtime_mavlink import KYIV_N, _state

from ins_hil.nav.rotation import dcm_from_quat
from ins_hil.runtime.mavlink_out import EndpointConfig, MavlinkEndpoint
from ins_hil.runtime.metrics import RuntimeMetrics
from ins_hil.types import FixType, GnssFix, gps_from_unix


def _send(typ: str, st: Any = None, gnss: GnssFix | None = None, **cfg: Any) -> Any:
    """One message of type ``typ`` built by an fc endpoint (unsigned: the fast framing where it exists)."""
    ep = MavlinkEndpoint(EndpointConfig(role="fc", sysid=1, compid=197, **cfg), RuntimeMetrics())
    sink = BufferSink()
    ep.tr = sink  # type: ignore[assignment]
    if gnss is not None:
        ep.offer_gnss(gnss)
    getattr(ep, "_send_" + typ.lower())(st if st is not None else _state(2.0))
    msgs = [m for b in sink.bufs for m in mav.MAVLink(None).parse_buffer(b) or []]
    if typ == "ODOMETRY" and msgs:  # the first ODOMETRY is followed by the local origin
        assert [m.get_type() for m in msgs] == [typ, "SET_GPS_GLOBAL_ORIGIN"]
        msgs = msgs[:1]
    assert [m.get_type() for m in msgs] == [typ]
    m = msgs[0]
    assert m.get_srcSystem() == 1 and m.get_srcComponent() == 197
    return m


def _fix(**kw: Any) -> GnssFix:
    base = {"vel_ned": np.array([3.0, -4.0, 0.5]), "fix_type": FixType.FIX_3D, "num_sats": 11,
            "std_ne": 0.8, "std_d": 1.6, "std_vel": 0.12}  # fmt: skip
    base.update(kw)
    return GnssFix(2.0, math.radians(50.45), math.radians(30.52), 181.0, **base)


def test_odometry_frames_covariance_and_body_velocity() -> None:
    st = _state(2.0)
    o = _send("ODOMETRY", st)
    # PX4: frame_id LOCAL_NED (pose in NED), child BODY_FRD (velocity in the body frame)
    assert o.frame_id == mav.MAV_FRAME_LOCAL_NED and o.child_frame_id == mav.MAV_FRAME_BODY_FRD
    # PX4 ignores the covariances of a MAV_ESTIMATOR_TYPE_NAIVE estimate and accepts VISION/VIO
    assert o.estimator_type == mav.MAV_ESTIMATOR_TYPE_VIO
    assert o.time_usec == 2_000_000 and o.quality == 100
    assert np.allclose(o.q, st.q_nb, atol=1e-7)  # body → local (Hamilton, w first)
    assert np.allclose([o.vx, o.vy, o.vz], dcm_from_quat(st.q_nb).T @ st.vel_ned, atol=1e-5)
    assert np.allclose([o.rollspeed, o.pitchspeed, o.yawspeed], st.omega_b, atol=1e-7)
    # pose_covariance: the upper-right triangle of the 6×6 (x, y, z, roll, pitch, yaw), row-major, 21 floats:
    # NED position variances at 0, 6, 11; the roll/pitch/yaw block (15–20) is the NED attitude σ carried to
    # Euler angles (tests/test_autopilot_rules.py checks it against a numerical Jacobian); nothing else
    pc = np.array(o.pose_covariance)
    assert pc.shape == (21,)
    diag = {0: 0.5**2, 6: 0.6**2, 11: 1.2**2}
    for i in (*range(15),):
        assert math.isclose(pc[i], diag.get(i, 0.0), rel_tol=1e-6, abs_tol=0.0), i
    ea = np.array([[pc[15], pc[16], pc[17]], [pc[16], pc[18], pc[19]], [pc[17], pc[19], pc[20]]])
    assert np.all(np.linalg.eigvalsh(ea) > 0)  # a covariance
    assert math.isclose(np.trace(ea), np.sum(np.radians([0.5, 0.5, 2.0]) ** 2), rel_tol=0.05)  # ~level: ≈ trace
    # velocity_covariance: body FRD like the velocity (C^T Σ_NED C), the rate block unknown (0)
    vc = np.array(o.velocity_covariance)
    c = dcm_from_quat(st.q_nb)
    sb = c.T @ np.diag([0.05**2, 0.05**2, 0.1**2]) @ c
    assert np.allclose(vc[[0, 1, 2, 6, 7, 11]], sb[np.triu_indices(3)], rtol=1e-5, atol=1e-9)
    assert np.count_nonzero(vc[[3, 4, 5, 8, 9, 10, *range(12, 21)]]) == 0
    # the triangle index of (row, col): 6 r − r(r−1)/2 + (c − r), so (1, 1) → 6, (5, 5) → 20
    assert [6 * r - r * (r - 1) // 2 for r in range(6)] == [0, 6, 11, 15, 18, 20]


def test_odometry_unknown_covariance_and_the_ardupilot_frame() -> None:
    st = _state(2.0)
    st.std_pos = np.zeros(3)  # no covariance yet
    o = _send("ODOMETRY", st)
    assert math.isnan(o.pose_covariance[0]) and math.isnan(o.velocity_covariance[0])  # NaN first = unknown
    assert o.quality == 100
    # ArduPilot's handle_odometry takes frame_id LOCAL_FRD (and child BODY_FRD) only: the same NED values
    a = _send("ODOMETRY", _state(2.0), odometry_frame="LOCAL_FRD")
    assert a.frame_id == mav.MAV_FRAME_LOCAL_FRD and a.child_frame_id == mav.MAV_FRAME_BODY_FRD
    b = _send("ODOMETRY", _state(2.0))
    assert (a.x, a.y, a.z, list(a.q), a.vx) == (b.x, b.y, b.z, list(b.q), b.vx)


def test_gps_input_fields_as_ardupilot_reads_them() -> None:
    st = _state(2.0)
    g = _send("GPS_INPUT", st, gnss=_fix())
    # DOP from the filter σ over a 1 m range error: hdop = hypot(σN, σE), vdop = σD; nothing ignored
    assert g.ignore_flags == 0
    assert math.isclose(g.hdop, math.hypot(0.5, 0.6), rel_tol=1e-6) and math.isclose(g.vdop, 1.2, rel_tol=1e-6)
    # GPS time unknown: week 0 (AP_GPS_MAV uses the week's time only when time_week > 0)
    assert g.time_week == 0 and g.time_week_ms == 0
    assert g.time_usec == 2_000_000 and g.gps_id == 0 and g.fix_type == 3 and g.satellites_visible == 11
    assert (g.lat, g.lon) == (504500000, 305200000)
    assert abs(g.alt - (181.5 - KYIV_N)) < 0.3  # MSL (m), as both autopilots take it
    assert np.allclose([g.vn, g.ve, g.vd], st.vel_ned, atol=1e-6)  # NED m/s
    assert math.isclose(g.horiz_accuracy, math.hypot(0.5, 0.6), rel_tol=1e-6)
    assert math.isclose(g.vert_accuracy, 1.2, rel_tol=1e-6) and math.isclose(g.speed_accuracy, 0.1, rel_tol=1e-6)
    assert g.yaw == 0  # not available
    st.aligned = False
    assert _send("GPS_INPUT", st).fix_type == 1  # no fix before alignment


def test_gps_raw_int_msl_altitude_and_accuracies() -> None:
    g = _send("GPS_RAW_INT", gnss=_fix())
    assert g.eph == 65535 and g.epv == 65535  # HDOP/VDOP × 100: the source gives none → unknown
    assert g.alt_ellipsoid == 181000 and abs(g.alt * 1e-3 - (181.0 - KYIV_N)) < 0.3
    assert (g.h_acc, g.v_acc, g.vel_acc) == (800, 1600, 120)  # mm, mm, mm/s
    assert g.vel == 500 and g.cog == round(math.degrees(math.atan2(-4.0, 3.0)) % 360 * 100)
    assert g.satellites_visible == 11 and g.fix_type == 3 and g.time_usec == 2_000_000
    u = _send("GPS_RAW_INT", gnss=_fix(vel_ned=None, num_sats=0))
    assert u.vel == 65535 and u.cog == 65535 and u.satellites_visible == 255  # unknown


def test_hil_state_quaternion_units_as_px4_reads_them() -> None:
    st = _state(2.0)
    h = _send("HIL_STATE_QUATERNION", st)
    assert np.allclose(h.attitude_quaternion, st.q_nb, atol=1e-7)
    assert np.allclose([h.rollspeed, h.pitchspeed, h.yawspeed], st.omega_b, atol=1e-7)
    assert (h.lat, h.lon) == (504500000, 305200000) and abs(h.alt * 1e-3 - (181.5 - KYIV_N)) < 0.3
    assert (h.vx, h.vy, h.vz) == (300, -400, 50)  # cm/s NED
    assert h.true_airspeed == 500 and h.time_usec == 2_000_000
    assert (h.xacc, h.yacc, h.zacc) == tuple(round(a / 9.80665 * 1000) for a in st.accel_b)  # mG


def test_fc_heartbeat_is_an_onboard_controller_in_standby_without_a_solution() -> None:
    hb = _send("HEARTBEAT")  # built without any state offered to the endpoint: no solution yet
    assert hb.type == mav.MAV_TYPE_ONBOARD_CONTROLLER and hb.autopilot == mav.MAV_AUTOPILOT_INVALID
    assert hb.mavlink_version == 3 and hb.system_status == mav.MAV_STATE_STANDBY


def test_gps_time_and_dop_are_passed_where_the_source_gives_them() -> None:
    g = GnssFix(2.0, math.radians(50.45), math.radians(30.52), 181.0, np.array([3.0, -4.0, 0.5]), num_sats=8,
                gps_week=2345, gps_tow=123456.789, hdop=0.9, vdop=1.4)  # fmt: skip
    gi = _send("GPS_INPUT", gnss=g)  # the state at the fix's time
    assert gi.time_week == 2345 and gi.time_week_ms == 123456789 and gi.ignore_flags == 0
    gi = _send("GPS_INPUT", _state(2.5), gnss=g)  # 0.5 s later: the fix's GPS time moved on to the state's
    assert gi.time_week == 2345 and gi.time_week_ms == 123457289
    # GPS_INPUT's DOP is the fused state's (σ), not the receiver's
    assert math.isclose(gi.hdop, math.hypot(0.5, 0.6), rel_tol=1e-6) and math.isclose(gi.vdop, 1.2, rel_tol=1e-6)
    raw = _send("GPS_RAW_INT", gnss=g)
    assert (raw.eph, raw.epv) == (90, 140)  # HDOP/VDOP × 100


def test_system_time_with_the_heartbeat_once_gps_time_is_known() -> None:
    """SYSTEM_TIME (UNIX µs, from the fix's GPS time moved on to the state's time; GPS − UTC = 18 s) goes out
    with the 1 Hz HEARTBEAT once the GNSS gives GPS time, and not before."""
    ep = MavlinkEndpoint(EndpointConfig(role="gcs", sysid=42), RuntimeMetrics())
    sink = BufferSink()
    ep.tr = sink  # type: ignore[assignment]
    ep._send_heartbeat(_state(2.0))
    assert [m.get_type() for b in sink.bufs for m in mav.MAVLink(None).parse_buffer(b) or []] == ["HEARTBEAT"]
    week, tow = gps_from_unix(1_700_000_000.0)  # 2023-11-14 22:13:20 UTC
    assert (week, tow) == (2288, 252818.0)  # GPS week 2288 began on 2023-11-12
    ep.offer_gnss(GnssFix(1.5, 0.88, 0.53, 181.0, gps_week=week, gps_tow=tow))
    sink.bufs.clear()
    ep._send_heartbeat(_state(2.0))
    msgs = [m for b in sink.bufs for m in mav.MAVLink(None).parse_buffer(b) or []]
    assert [m.get_type() for m in msgs] == ["HEARTBEAT", "SYSTEM_TIME"]
    assert msgs[1].time_unix_usec == 1_700_000_000_500_000 and msgs[1].time_boot_ms == 2000


def test_mavlink_driver_reads_gps_time_and_dop() -> None:
    """GPS_INPUT's week and ms of week and its DOP (unless ignored), GPS_RAW_INT's UNIX time and eph/epv (DOP ×
    100) reach the fix; a week of 0 or an unknown DOP stays unknown."""
    from ins_hil.drivers.mavlink_in import MavlinkDriver

    out: list[Any] = []
    drv = MavlinkDriver("udpin:127.0.0.1:0", name="fc", emit={"gnss"})
    drv._sink = out.append
    m = mav.MAVLink(None, srcSystem=1, srcComponent=1)
    m.robust_parsing = True
    import time as _time

    t_us = round(_time.time() * 1e6)  # GPS_RAW_INT with UNIX time: the driver maps it by the wall clock
    msgs = [
        m.gps_input_encode(5_000_000, 0, 0, 252818_250, 2288, 3, 504500000, 305200000, 180.0, 0.9, 1.3, 0, 0, 0,
                           0.1, 0.8, 1.5, 12),
        m.gps_input_encode(5_200_000, 0, 2 | 4, 0, 0, 3, 504500000, 305200000, 180.0, 0.9, 1.3, 0, 0, 0,
                           0.1, 0.8, 1.5, 12),
        m.gps_raw_int_encode(t_us, 3, 504500000, 305200000, 180000, 120, 65535, 0, 0, 12),
    ]  # fmt: skip
    now = _time.monotonic_ns()
    for msg in msgs:
        drv.feed(msg.pack(m), now)
        m.seq = (m.seq + 1) % 256
    fixes = [f for f in out if isinstance(f, GnssFix)]
    assert len(fixes) == 3, drv.health.errors
    a, b, c = fixes
    assert a.gps_week == 2288 and a.gps_tow == 252818.25
    assert math.isclose(a.hdop, 0.9, rel_tol=1e-6) and math.isclose(a.vdop, 1.3, rel_tol=1e-6)
    assert b.gps_week == 0 and math.isnan(b.gps_tow) and math.isnan(b.hdop) and math.isnan(b.vdop)
    assert (c.gps_week, c.gps_tow) == gps_from_unix(t_us * 1e-6)
    assert math.isclose(c.hdop, 1.2) and math.isnan(c.vdop)
