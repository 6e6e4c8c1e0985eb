"""Messages of the ``gcs`` role (a ground station sees the gateway as its own vehicle): SYS_STATUS,
ATTITUDE, ATTITUDE_QUATERNION, GLOBAL_POSITION_INT, LOCAL_POSITION_NED, GPS_RAW_INT (pass-through of the
last GNSS fix), VFR_HUD, ESTIMATOR_STATUS, EXTENDED_SYS_STATE, BATTERY_STATUS (HOME_POSITION is with the
requests, :mod:`.requests`)."""

from __future__ import annotations

import math
import time

from ins_hil.runtime.mavlink_msgs.common import MessageBase, _dop, _floats, _frame_of, _i16, _u32, mavlink_module
from ins_hil.types import NavState


class GcsMessages(MessageBase):
    """Builders of the ground-station messages (``_send_<message>``, one state in, one message out)."""

    def _drop_rate(self) -> tuple[int, int]:
        """(drop_rate_comm in c%, errors_comm): the inputs' dropped samples ÷ (received + dropped) over the
        last window of at least 1 s (the rate of the previous window until the next one closes), and the
        cumulative drop count (saturated at UINT16_MAX − 1)."""
        m = self.metrics
        dropped = m.dropped_total()
        received = sum(s.received for s in m.sources.values())
        now = time.monotonic_ns()
        t0, d0, r0 = self._drop_ref
        if t0 == 0 or now - t0 >= 1_000_000_000:
            d, r = dropped - d0, received - r0
            self._drop_cpct = min(10000, round(1e4 * d / (r + d))) if d > 0 else 0
            self._drop_ref = (now, dropped, received)
        return self._drop_cpct, min(0xFFFE, dropped)

    def _send_sys_status(self, st: NavState | None) -> None:
        present, enabled, health, _, _ = self._vehicle_status()
        drops, errors = self._drop_rate()
        # battery unknown (the spec's values): voltage UINT16_MAX, current −1, remaining −1 (BATTERY_STATUS too)
        if self._fast:  # wire order: present, enabled, health, load, voltage, current, drop_rate, errors ×5,
            # battery_remaining, then the three *_extended fields
            self._emit(
                _frame_of("SYS_STATUS"), present, enabled, health, 0, 0xFFFF, -1, drops, errors, 0, 0, 0, 0, -1, 0, 0, 0
            )
        else:
            self.mav.sys_status_send(present, enabled, health, 0, 0xFFFF, -1, -1, drops, errors, 0, 0, 0, 0)

    def _send_extended_sys_state(self, st: NavState | None) -> None:
        """EXTENDED_SYS_STATE: landed state and VTOL state UNDEFINED — a navigation gateway cannot tell ground
        contact, and the vehicle is no VTOL (MAVSDK's in_air()/landed_state() then report False/UNKNOWN)."""
        m = self._m
        self.mav.extended_sys_state_send(m.MAV_VTOL_STATE_UNDEFINED, m.MAV_LANDED_STATE_UNDEFINED)

    def _send_battery_status(self, st: NavState | None) -> None:
        """BATTERY_STATUS of a gateway without a battery monitor: every field "unknown" as the spec gives it
        (cell voltages UINT16_MAX, current −1, consumed −1, remaining −1, temperature INT16_MAX). A client
        that reads SYS_STATUS's battery while no BATTERY_STATUS came (MAVSDK) would show its UINT16_MAX
        voltage as 65.535 V; with this one MAVSDK reports 0 V, remaining −1 %."""
        m = self._m
        self.mav.battery_status_send(
            0, m.MAV_BATTERY_FUNCTION_UNKNOWN, m.MAV_BATTERY_TYPE_UNKNOWN, 0x7FFF, [0xFFFF] * 10, -1, -1, -1, -1,
            0, m.MAV_BATTERY_CHARGE_STATE_UNDEFINED, [0, 0, 0, 0], 0, 0,
        )  # fmt: skip

    def _send_attitude(self, st: NavState) -> None:
        r, p, y = self._euler(st)
        wx, wy, wz = _floats(st.omega_b)
        if self._fast:
            self._emit(_frame_of("ATTITUDE"), self._tboot_ms(st), r, p, y, wx, wy, wz)
        else:
            self.mav.attitude_send(self._tboot_ms(st), r, p, y, wx, wy, wz)

    def _send_attitude_quaternion(self, st: NavState) -> None:
        q, w = _floats(st.q_nb), _floats(st.omega_b)
        if self._fast:  # repr_offset_q (extension) = zeros, as pymavlink's default
            self._emit(_frame_of("ATTITUDE_QUATERNION"), self._tboot_ms(st), *q, *w, 0.0, 0.0, 0.0, 0.0)
        else:
            self.mav.attitude_quaternion_send(self._tboot_ms(st), *q, *w)

    def _send_global_position_int(self, st: NavState) -> None:
        """relative_alt: above the home (0 until the home is taken, MessageBase._track_home); hdg: the yaw,
        UINT16_MAX (unknown) before alignment."""
        vn, ve, vd = _floats(st.vel_ned)
        self._track_home(st)
        rel = st.h - self._home[2] if self._home is not None else 0.0
        hdg = round((math.degrees(self._euler(st)[2]) % 360.0) * 100) % 36000 if st.aligned else 0xFFFF
        vals = (
            self._tboot_ms(st),
            round(math.degrees(st.lat) * 1e7),
            round(math.degrees(st.lon) * 1e7),
            round(self._msl(st.lat, st.lon, st.h) * 1000),  # MSL (EGM96); relative_alt: above the home
            round(rel * 1000),
            _i16(vn * 100),
            _i16(ve * 100),
            _i16(vd * 100),
            hdg,
        )
        if self._fast:  # wire order = argument order
            self._emit(_frame_of("GLOBAL_POSITION_INT"), *vals)
        else:
            self.mav.global_position_int_send(*vals)

    def _send_local_position_ned(self, st: NavState) -> bool:
        """NED position (m) from the home, which is the local origin; not sent (False) before the home is
        taken (MessageBase._track_home)."""
        self._track_home(st)
        if self._home is None:
            return False
        d = self._home_ned(st)
        v = _floats(st.vel_ned)
        if self._fast:
            self._emit(_frame_of("LOCAL_POSITION_NED"), self._tboot_ms(st), *d, *v)
        else:
            self.mav.local_position_ned_send(self._tboot_ms(st), *d, *v)
        return True

    def _send_gps_raw_int(self, st: NavState) -> None:
        g = self._gnss
        self._gnss_new = False
        if g is None:
            return
        if g.vel_ned is not None:
            v = g.vel_ned
            gs = math.hypot(v[0], v[1])
            vel = min(65534, round(gs * 100))
            cog = round((math.degrees(math.atan2(v[1], v[0])) % 360.0) * 100) % 36000 if gs > 0.2 else 0xFFFF
        else:
            vel = cog = 0xFFFF  # unknown
        # eph/epv are HDOP/VDOP × 100 where the source gave them, else UINT16_MAX (unknown); the accuracies go
        # to h_acc/v_acc (mm) and vel_acc (mm/s). alt is MSL (EGM96), alt_ellipsoid the WGS84 height.
        hdop, vdop = _dop(g, "hdop"), _dop(g, "vdop")
        sats = g.num_sats if g.num_sats > 0 else 255  # 0 with a fix: not reported by the source
        self.mav.gps_raw_int_send(
            round(g.t * 1e6),
            int(g.fix_type),
            round(math.degrees(g.lat) * 1e7),
            round(math.degrees(g.lon) * 1e7),
            round(self._msl(g.lat, g.lon, g.h) * 1000),
            hdop,
            vdop,
            vel,
            cog,
            sats,
            round(g.h * 1000),
            _u32(g.std_ne * 1000),
            _u32(g.std_d * 1000),
            _u32(g.std_vel * 1000),
            0,
        )

    def _send_vfr_hud(self, st: NavState) -> None:
        v = st.vel_ned
        gs = math.hypot(v[0], v[1])
        hdg = round(math.degrees(self._euler(st)[2])) % 360
        self.mav.vfr_hud_send(gs, gs, hdg, 0, self._msl(st.lat, st.lon, st.h), -float(v[2]))  # alt: MSL

    def _send_estimator_status(self, st: NavState | None) -> None:
        """Flags only while the solution is valid (aligned, fresh: IMU not lost); without a state
        (sent by the 1 Hz task) every flag is clear, the ratios and accuracies 0."""
        m = mavlink_module()
        if st is None or not self._solution_valid():
            t_us = round((time.monotonic_ns() - self._t0_ns) * 1e-3)  # no state: time since the endpoint started
            self.mav.estimator_status_send(t_us, 0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0)
            return
        tr = st.test_ratios
        flags = 0
        if st.aligned:
            flags = (
                m.ESTIMATOR_ATTITUDE
                | m.ESTIMATOR_VELOCITY_HORIZ
                | m.ESTIMATOR_VELOCITY_VERT
                | m.ESTIMATOR_POS_HORIZ_ABS
                | m.ESTIMATOR_POS_VERT_ABS
            )
        else:
            flags = m.ESTIMATOR_CONST_POS_MODE

        def ratio(*keys: str) -> float:
            vals = [float(v) for k, v in tr.items() if any(s in k.lower() for s in keys)]
            return max(vals) if vals else 0.0

        sp = st.std_pos
        self.mav.estimator_status_send(
            round(st.t * 1e6),
            flags,
            ratio("vel"),
            ratio("pos", "gnss_ne", "horiz"),
            ratio("baro", "hgt", "height", "vert", "_d"),
            ratio("mag"),
            0.0,
            0.0,
            float(math.hypot(sp[0], sp[1])),
            float(sp[2]),
        )
