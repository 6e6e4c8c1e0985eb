"""Messages of the ``fc`` role (the gateway as a flight controller's external navigation source):
ODOMETRY (external navigation, PX4 and ArduPilot), GPS_INPUT (ArduPilot GPS1_TYPE = 14) and
HIL_STATE_QUATERNION (PX4 HIL)."""

from __future__ import annotations

import math

from ins_hil.nav import earth
from ins_hil.nav.rotation import dcm_from_quat
from ins_hil.runtime.mavlink_msgs.common import MessageBase, _dop, _floats, _frame_of, _gps_week, _i16
from ins_hil.types import NavState


class FcMessages(MessageBase):
    """Builders of the flight-controller messages (``_send_<message>``, one state in, one message out)."""

    def _send_odometry(self, st: NavState) -> None:
        m = self._m
        d = self._home_ned(st)
        q = _floats(st.q_nb)
        wx, wy, wz = _floats(st.omega_b)
        # child frame body FRD (MAVLink ODOMETRY convention): v_b = (C_b^n)ᵀ v_n, C_b^n from rotation.dcm_from_quat
        c = dcm_from_quat(st.q_nb).tolist()
        vn, ve, vd = _floats(st.vel_ned)
        vbx = c[0][0] * vn + c[1][0] * ve + c[2][0] * vd
        vby = c[0][1] * vn + c[1][1] * ve + c[2][1] * vd
        vbz = c[0][2] * vn + c[1][2] * ve + c[2][2] * vd
        sp0, sp1, sp2 = _floats(st.std_pos)
        if (sp0 > 0.0 or sp1 > 0.0 or sp2 > 0.0) and not (math.isnan(sp0) or math.isnan(sp1) or math.isnan(sp2)):
            # (that is max(std_pos) > 0) upper-right triangle, row-major: diagonal at 0, 6, 11, 15, 18, 20
            sa0, sa1, sa2 = _floats(st.std_att)
            sv0, sv1, sv2 = _floats(st.std_vel)
            pc = [0.0] * 21
            pc[0], pc[6], pc[11], pc[15], pc[18], pc[20] = sp0**2, sp1**2, sp2**2, sa0**2, sa1**2, sa2**2
            vc = [0.0] * 21
            vc[0], vc[6], vc[11] = sv0**2, sv1**2, sv2**2
        else:  # unknown: NaN first element
            pc = [math.nan] + [0.0] * 20
            vc = list(pc)
        t_us = round(st.t * 1e6)
        quality = 100 if st.aligned else 0
        # estimator_type VIO: PX4 reads the covariances only when it is not NAIVE (an inertial + aided estimate)
        if self._fast:  # wire order: time, x, y, z, q, v, rates, covariances, frame ids, reset, estimator, quality
            self._emit(
                _frame_of("ODOMETRY"), t_us, *d, *q, vbx, vby, vbz, wx, wy, wz, *pc, *vc,
                self._odom_frame, m.MAV_FRAME_BODY_FRD, 0, m.MAV_ESTIMATOR_TYPE_VIO, quality,
            )  # fmt: skip
        else:
            self.mav.odometry_send(
                t_us, self._odom_frame, m.MAV_FRAME_BODY_FRD, *d, q, vbx, vby, vbz, wx, wy, wz, pc, vc,
                0, m.MAV_ESTIMATOR_TYPE_VIO, quality,
            )  # fmt: skip

    def _send_gps_input(self, st: NavState) -> None:
        """The fused state as a MAVLink GPS (ArduPilot GPS1_TYPE = 14). hdop/vdop from the last fix where its
        source gave them, else UINT16_MAX with GPS_INPUT_IGNORE_FLAG_HDOP|VDOP; time_week/time_week_ms: the
        GPS time of the last fix moved on to the state's time, or 0/0 (which ArduPilot takes as "no GPS
        time") while the source gives none; satellites from the last fix, 0 when the source gives none.
        alt: MSL (EGM96)."""
        m = self._m
        v, sp, sv = st.vel_ned, st.std_pos, st.std_vel
        g = self._gnss
        ignore = m.GPS_INPUT_IGNORE_FLAG_HDOP | m.GPS_INPUT_IGNORE_FLAG_VDOP
        hdop = vdop = 65535.0
        if g is not None and _dop(g, "hdop") != 0xFFFF:
            hdop, ignore = _dop(g, "hdop") * 0.01, ignore & ~m.GPS_INPUT_IGNORE_FLAG_HDOP
        if g is not None and _dop(g, "vdop") != 0xFFFF:
            vdop, ignore = _dop(g, "vdop") * 0.01, ignore & ~m.GPS_INPUT_IGNORE_FLAG_VDOP
        week, week_ms = _gps_week(g, st.t)
        self.mav.gps_input_send(
            round(st.t * 1e6),
            0,
            ignore,
            week_ms,
            week,
            3 if st.aligned else 1,
            round(math.degrees(st.lat) * 1e7),
            round(math.degrees(st.lon) * 1e7),
            float(self._msl(st.lat, st.lon, st.h)),
            hdop,
            vdop,
            float(v[0]),
            float(v[1]),
            float(v[2]),
            float(max(sv)),
            float(math.hypot(sp[0], sp[1])),
            float(sp[2]),
            min(254, g.num_sats) if g is not None else 0,
        )

    def _send_hil_state_quaternion(self, st: NavState) -> None:
        q, w, v = st.q_nb, st.omega_b, st.vel_ned
        a = st.accel_b / earth.G0 * 1000.0  # mG
        gs = math.hypot(v[0], v[1])
        self.mav.hil_state_quaternion_send(
            round(st.t * 1e6),
            [float(x) for x in q],
            float(w[0]),
            float(w[1]),
            float(w[2]),
            round(math.degrees(st.lat) * 1e7),
            round(math.degrees(st.lon) * 1e7),
            round(self._msl(st.lat, st.lon, st.h) * 1000),  # MSL, as PX4 reads it (AMSL)
            _i16(v[0] * 100),
            _i16(v[1] * 100),
            _i16(v[2] * 100),
            min(65535, round(gs * 100)),
            min(65535, round(gs * 100)),
            _i16(a[0]),
            _i16(a[1]),
            _i16(a[2]),
        )
