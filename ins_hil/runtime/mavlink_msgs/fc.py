"""Messages of the ``fc`` role (the gateway as a flight controller's external navigation source):
ODOMETRY (external navigation, PX4 and ArduPilot), GPS_INPUT (ArduPilot GPS1_TYPE = 14) and
HIL_STATE_QUATERNION (PX4 HIL)."""

from __future__ import annotations

import math

from ins_hil.nav import earth
from ins_hil.nav.rotation import dcm_rows
from ins_hil.runtime.mavlink_msgs.common import (
    JUMP_M,
    MessageBase,
    _floats,
    _frame_of,
    _gps_week,
    _i16,
    _live_lib,
)
from ins_hil.types import NavState

#: GPS_INPUT's DOP is the filter's σ over this range error (m): hdop = hypot(σN, σE) / DOP_RANGE_M
DOP_RANGE_M = 1.0
DOP_MAX = 99.99  # ArduPilot stores hdop × 100 in a uint16 and calls 9999 unknown (GPS_UNKNOWN_DOP)


_ZEROS9 = (0.0,) * 9
#: ODOMETRY's covariance while unknown (σ not yet positive and finite): NaN first element
_UNKNOWN_COV = (math.nan,) + (0.0,) * 20


def _body_cov(c: list[list[float]], s: list[float]) -> tuple[float, float, float, float, float, float]:
    """(xx, xy, xz, yy, yz, zz) of Cᵀ diag(s²) C: NED variances (σ ``s``) in body FRD axes, C = C_b^n."""
    a, b, d = s[0] * s[0], s[1] * s[1], s[2] * s[2]
    r0, r1, r2 = c
    return (
        a * r0[0] * r0[0] + b * r1[0] * r1[0] + d * r2[0] * r2[0],
        a * r0[0] * r0[1] + b * r1[0] * r1[1] + d * r2[0] * r2[1],
        a * r0[0] * r0[2] + b * r1[0] * r1[2] + d * r2[0] * r2[2],
        a * r0[1] * r0[1] + b * r1[1] * r1[1] + d * r2[1] * r2[1],
        a * r0[1] * r0[2] + b * r1[1] * r1[2] + d * r2[1] * r2[2],
        a * r0[2] * r0[2] + b * r1[2] * r1[2] + d * r2[2] * r2[2],
    )


def _euler_cov(c: list[list[float]], s: list[float]) -> tuple[float, float, float, float, float, float]:
    """(rr, rp, ry, pp, py, yy): the covariance of (roll, pitch, yaw) from attitude errors ψ about the NED axes
    with σ ``s`` (rad). δe = W⁻¹ Cᵀ ψ: Cᵀψ is the error in body axes, W⁻¹ maps body rates to the ZYX Euler
    rates (roll' = p + (q sinφ + r cosφ) tanθ, pitch' = q cosφ − r sinφ, yaw' = (q sinφ + r cosφ)/cosθ);
    cosθ is held ≥ 1e-3 at the pitch singularity. Straight-line floats (the per-message path)."""
    r0, r1, r2 = c
    sth = max(-1.0, min(1.0, -r2[0]))
    cth = max(math.sqrt(1.0 - sth * sth), 1e-3)
    n = math.hypot(r2[1], r2[2]) or 1.0
    sph, cph = r2[1] / n, r2[2] / n
    tth = sth / cth
    # ψ along NED axis k: body error (p, q, r) = row k of C, then its Euler error (a_k, b_k, g_k)
    u = r0[1] * sph + r0[2] * cph
    a0, b0, g0 = r0[0] + u * tth, r0[1] * cph - r0[2] * sph, u / cth
    u = r1[1] * sph + r1[2] * cph
    a1, b1, g1 = r1[0] + u * tth, r1[1] * cph - r1[2] * sph, u / cth
    u = r2[1] * sph + r2[2] * cph
    a2, b2, g2 = r2[0] + u * tth, r2[1] * cph - r2[2] * sph, u / cth
    v0, v1, v2 = s[0] * s[0], s[1] * s[1], s[2] * s[2]
    return (
        v0 * a0 * a0 + v1 * a1 * a1 + v2 * a2 * a2,
        v0 * a0 * b0 + v1 * a1 * b1 + v2 * a2 * b2,
        v0 * a0 * g0 + v1 * a1 * g1 + v2 * a2 * g2,
        v0 * b0 * b0 + v1 * b1 * b1 + v2 * b2 * b2,
        v0 * b0 * g0 + v1 * b1 * g1 + v2 * b2 * g2,
        v0 * g0 * g0 + v1 * g1 * g1 + v2 * g2 * g2,
    )


class FcMessages(MessageBase):
    """Builders of the flight-controller messages (``_send_<message>``, one state in, one message out)."""

    def _send_odometry(self, st: NavState) -> bool:
        """ODOMETRY: quality 100 for a usable state (:meth:`_usable`), −1 (MAVLink: invalid) otherwise; role
        ``fc`` sends nothing (False) for an unusable state, as PX4 fuses any quality while ``EKF2_EV_QMIN``
        ≤ 0 (its default). reset_counter: :meth:`_note_usable`; covariances in the message's frames (pose:
        NED position, roll/pitch/yaw; velocity: body FRD)."""
        usable = self._usable(st)
        reset = self._note_usable(st, usable)
        fc = self.cfg.role == "fc"
        if fc and not usable:
            return False
        quality = 100 if usable else -1
        m = self._m
        lv = self._live
        if self._fast and lv is not None:
            if self._odometry_c(st, reset, quality):
                if reset and fc:
                    self._send_origin()
                return True
            # a NaN in the state: the Python builder below, from the C path's last message (and back to it)
            self._fc_prev = tuple(lv.prev[1:8]) if lv.prev[0] else None
        d = self._home_ned(st)
        vn, ve, vd = _floats(st.vel_ned)
        prev, t = self._fc_prev, st.t
        if prev is not None and not reset:  # a step of the position beyond what the velocity explains
            h = 0.5 * (t - prev[0])
            dn = d[0] - prev[1] - h * (vn + prev[4])
            de = d[1] - prev[2] - h * (ve + prev[5])
            dd = d[2] - prev[3] - h * (vd + prev[6])
            if dn * dn + de * de + dd * dd > JUMP_M * JUMP_M:
                self.reset_counter = (self.reset_counter + 1) & 0xFF
        self._fc_prev = (t, d[0], d[1], d[2], vn, ve, vd)
        if lv is not None:
            lv.prev[0:8] = [1.0, *self._fc_prev]
        q = _floats(st.q_nb)
        wx, wy, wz = _floats(st.omega_b)
        # child frame body FRD (MAVLink ODOMETRY convention): v_b = (C_b^n)ᵀ v_n, C_b^n = rotation.dcm_rows (floats)
        c = dcm_rows(q[0], q[1], q[2], q[3])
        r0, r1, r2 = c
        vbx = r0[0] * vn + r1[0] * ve + r2[0] * vd
        vby = r0[1] * vn + r1[1] * ve + r2[1] * vd
        vbz = r0[2] * vn + r1[2] * ve + r2[2] * vd
        sp0, sp1, sp2 = _floats(st.std_pos)
        pc: tuple[float, ...]
        vc: tuple[float, ...]
        if (sp0 > 0.0 or sp1 > 0.0 or sp2 > 0.0) and not (math.isnan(sp0) or math.isnan(sp1) or math.isnan(sp2)):
            # (that is max(std_pos) > 0) upper-right triangle of the 6×6, row-major: (r, c) at 6r − r(r−1)/2 + c − r
            pc = (sp0**2, 0.0, 0.0, 0.0, 0.0, 0.0, sp1**2, 0.0, 0.0, 0.0, 0.0, sp2**2, 0.0, 0.0, 0.0,
                  *_euler_cov(c, _floats(st.std_att)))  # fmt: skip
            xx, xy, xz, yy, yz, zz = _body_cov(c, _floats(st.std_vel))
            vc = (xx, xy, xz, 0.0, 0.0, 0.0, yy, yz, 0.0, 0.0, 0.0, zz, *_ZEROS9)
        else:  # unknown: NaN first element
            pc = vc = _UNKNOWN_COV
        t_us = round(st.t * 1e6)
        rc = self.reset_counter
        # estimator_type VIO: PX4 reads the covariances only when it is not NAIVE (an inertial + aided estimate)
        if self._fast:  # wire order: time, x, y, z, q, v, rates, covariances, frame ids, reset, estimator, quality
            self._emit(
                _frame_of("ODOMETRY"), t_us, *d, *q, vbx, vby, vbz, wx, wy, wz, *pc, *vc,
                self._odom_frame, m.MAV_FRAME_BODY_FRD, rc, m.MAV_ESTIMATOR_TYPE_VIO, quality,
            )  # fmt: skip
        else:
            self.mav.odometry_send(
                t_us, self._odom_frame, m.MAV_FRAME_BODY_FRD, *d, q, vbx, vby, vbz, wx, wy, wz, list(pc), list(vc),
                rc, m.MAV_ESTIMATOR_TYPE_VIO, quality,
            )  # fmt: skip
        if reset and fc:
            self._send_origin()  # the local origin, at once after the first ODOMETRY of a (re)start
        return True

    def _odometry_c(self, st: NavState, reset: bool, quality: int) -> bool:
        """The ODOMETRY of the Python path below, its numbers and framing in C (``live_odometry``,
        firmware_ref/src/live.c: the same operations in the same order, the same bytes). False: nothing sent, a
        NaN in the state (its sign through the arithmetic is not CPython's): the caller's Python path sends it."""
        lv = self._live
        assert lv is not None and _live_lib is not None
        if self._home is None:
            self._set_home(st)
        try:  # (ndarray.tolist: the floats of _floats, without its call)
            lv.st[0:23] = [st.t, st.lat, st.lon, st.h, *st.q_nb.tolist(), *st.vel_ned.tolist(), *st.omega_b.tolist(),
                           *st.std_pos.tolist(), *st.std_vel.tolist(), *st.std_att.tolist()]  # fmt: skip
        except AttributeError:  # not arrays
            lv.st[0:23] = [st.t, st.lat, st.lon, st.h, *_floats(st.q_nb), *_floats(st.vel_ned), *_floats(st.omega_b),
                           *_floats(st.std_pos), *_floats(st.std_vel), *_floats(st.std_att)]  # fmt: skip
        mav, ids = self.mav, lv.ids
        ids[0] = self._odom_frame
        ids[2] = self.reset_counter
        ids[4] = quality
        ids[5] = mav.seq
        ids[6] = mav.srcSystem
        ids[7] = mav.srcComponent
        r = _live_lib.live_odometry(lv.out, lv.st, lv.home, lv.prev, 1 if reset else 0, ids)
        if r == -3:
            return False
        if r >= 0x10000 or r == -2:  # the position stepped beyond what the velocity explains
            self.reset_counter = (self.reset_counter + 1) & 0xFF
        if r < 0:  # as struct.pack: a value the message cannot carry
            raise OverflowError("ODOMETRY: a value beyond the message's range")
        self._emit_bytes(lv.buf[: r & 0xFFFF])
        return True

    def _send_gps_input(self, st: NavState) -> None:
        """The fused state as a MAVLink GPS (ArduPilot GPS1_TYPE = 14). fix_type 3 while the state is usable
        and GNSS-aided, 1 (no fix) before alignment, with the IMU lost, or while dead reckoning (a GNSS input
        is present and lost). hdop = hypot(σN, σE) / 1 m, vdop = σD / 1 m (a DOP with a 1 m range error:
        ArduPilot's GPS_HDOP_GOOD = 140 then means σh ≤ 1.4 m), at most 99.99; flagged ignored only when σ
        is not finite. time_week/time_week_ms: the GPS time of the last fix moved on to the state's time, or
        0/0 (which ArduPilot takes as "no GPS time") while the source gives none; satellites from the last
        fix, 0 when the source gives none. alt: MSL (EGM96)."""
        m = self._m
        v, sp, sv = st.vel_ned, _floats(st.std_pos), st.std_vel
        g = self._gnss
        ignore = 0
        hdop, vdop = math.hypot(sp[0], sp[1]) / DOP_RANGE_M, sp[2] / DOP_RANGE_M
        if not math.isfinite(hdop):
            hdop, ignore = 65535.0, ignore | m.GPS_INPUT_IGNORE_FLAG_HDOP
        if not math.isfinite(vdop):
            vdop, ignore = 65535.0, ignore | m.GPS_INPUT_IGNORE_FLAG_VDOP
        hdop, vdop = min(hdop, DOP_MAX), min(vdop, DOP_MAX)
        gnss = self.metrics.sensors["gnss"]
        dead_reckoning = gnss.present and gnss.count > 0 and not gnss.healthy
        fix = 3 if self._usable(st) and not dead_reckoning else 1
        week, week_ms = _gps_week(g, st.t)
        self.mav.gps_input_send(
            round(st.t * 1e6),
            0,
            ignore,
            week_ms,
            week,
            fix,
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

    def _send_hil_state_quaternion(self, st: NavState) -> bool:
        """HIL_STATE_QUATERNION of a usable state (:meth:`_usable`); nothing (False) otherwise: the message
        has no validity field, and PX4 in HIL takes it as the truth."""
        if not self._usable(st):
            return False
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
        return True
