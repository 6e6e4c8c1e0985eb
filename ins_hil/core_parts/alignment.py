"""The two-phase alignment before navigation (``NavConfig.alignment.mode = "static"``): coarse levelling from the mean
specific force over ``alignment.time`` s at rest (book §4.1.1), then yaw from the magnetometer (refined alignment,
§4.1.2, Example 4.1) or from the GNSS course: a receiver's velocity once its speed exceeds ``gnss_yaw_speed``, or for a
position-only receiver a robust straight-line fit over several seconds of fixes (never one pair of fixes: one GNSS
jump between two close fixes is a "speed" of metres per second in any direction)."""

from __future__ import annotations

import math
from collections import deque
from typing import Protocol

import numpy as np

from ins_hil.fusion.ekf import ErrorStateEKF, StateIndex
from ins_hil.fusion.yaw_gsf import YawGsf
from ins_hil.nav import alignment, earth
from ins_hil.nav.mechanization import StrapdownNED
from ins_hil.nav.rotation import dcm_from_euler, dcm_from_quat, euler_from_quat, quat_from_euler
from ins_hil.types import BaroSample, GnssFix, ImuSample, MagSample, Vec

from .baro_datum import BaroDatum, baro_altitude
from .config import NavConfig

#: s: the longest interval between two position-only fixes whose difference is taken as a velocity
MAX_DIFF_S = 2.0

#: s: the longest span of position-only fixes fitted for the in-motion course (:meth:`Alignment._track_course`)
COURSE_SPAN_S = 5.0

#: the fewest position-only fixes the course fit takes
COURSE_MIN_FIXES = 5

#: rad: the most the gyros may turn the vehicle over the fitted span (the fit is of a straight track)
COURSE_MAX_TURN = 10.0 * math.pi / 180.0

#: the 2-D residual (in σ) beyond which a fix is an outlier of the fit: √χ²₂(99.9 %) = 3.72
COURSE_OUTLIER_SIGMA = 3.72

#: the largest share of fixes the fit may reject as outliers before it calls the track inconsistent
COURSE_MAX_REJECTED = 0.3

#: s the window stays frozen after the IMU saw motion while the levelling waits for a position (then it slides again)
MAX_FROZEN_S = 30.0


class Alignable(Protocol):
    """What the alignment sets in the core (:class:`ins_hil.core.NavCore`): the nominal state, the filter's
    attitude/bias σ, the gyro bias, the phase (``level`` → ``heading`` → ``nav``) and the local gravity."""

    cfg: NavConfig
    ins: StrapdownNED
    kf: ErrorStateEKF
    idx: StateIndex
    baro: BaroDatum
    bg: Vec
    ba: Vec
    omega_b: Vec
    phase: str
    g_local: float
    yaw_gsf: YawGsf | None


class Alignment:
    """The levelling window and the alignment state of a core that starts without an attitude."""

    def __init__(self, core: Alignable) -> None:
        self.core, self.cfg = core, core.cfg
        self.buf: deque[tuple[float, Vec, Vec]] = deque()  # the window: (dt s, Δv m/s, Δθ rad)
        self.f_sum = np.zeros(3)  # Σ Δv over the window (m/s, body)
        self.w_sum = np.zeros(3)  # Σ Δθ over the window (rad, body)
        self.t_win = 0.0  # the window's length (s)
        self.moving = False  # motion seen: a GNSS speed above still_speed, or the IMU's motion test
        self.imu_moving = False  # the IMU's motion test has fired (the window is then frozen)
        self.dev_w = 0.0  # smoothed squared departure of the rate from the window's mean ((rad/s)²)
        self.dev_f = 0.0  # the same for the specific force ((m/s²)²)
        self.pending: deque[ImuSample] = deque()  # samples not yet in the window (still_delay)
        self.fb: Vec | None = None  # mean specific force of the levelling window (body, m/s²; its length t_win)
        self.C = np.eye(3)  # the levelled attitude C_b^n, its yaw as the filter holds it (level_tilt_prior)
        self.t_end = 0.0  # the time of its last sample
        self.have_pos = self.cfg.alignment.mode == "given"
        self.last_mag: Vec | None = None  # the last magnetometer field (body, any unit)
        self.last_speed: float | None = None  # the last GNSS horizontal speed seen (m/s)
        self.prev_fix: GnssFix | None = None  # the fix before (a position-only receiver's velocity by difference)
        self.gyrocompass_std: float | None = None  # σ_ψ (rad) the gyrocompass would give (alignment.gyrocompass)
        # the heading phase's position-only track: (t s, lat rad, lon rad, h m, σ_NE m, gyro-held yaw rad)
        self.track: deque[tuple[float, float, float, float, float, float]] = deque()
        self.track_note = ""  # why the track gives no course yet (waiting_for)

    def step(self, imu: ImuSample) -> None:
        """One IMU sample before navigation: into the levelling window, or the gyro-only attitude (heading)."""
        core = self.core
        core.ins.state.t = imu.t
        c = self.cfg
        if core.phase == "level":
            # the IMU's motion test: each sample against the window's mean (a take-off into a hover, with its
            # GNSS speed below still_speed, must not slide into the window; engine vibration at rest averages
            # to the window's mean and only counts by its RMS)
            if self.t_win >= 0.5 and not self.imu_moving:
                a = imu.dt / (c.alignment.still_tau + imu.dt)
                dw = imu.dtheta / imu.dt - self.w_sum / self.t_win
                df = imu.dvel / imu.dt - self.f_sum / self.t_win
                # |dw|², |df|² as plain products in a fixed order (not ``dw @ dw``: BLAS's rounding is the host's
                # kernel's, e.g. with or without FMA), so the C core's levelling (align.c) gives the same bits anywhere
                wx, wy, wz = dw.tolist()
                fx, fy, fz = df.tolist()
                self.dev_w += a * ((wx * wx + wy * wy + wz * wz) - self.dev_w)
                self.dev_f += a * ((fx * fx + fy * fy + fz * fz) - self.dev_f)
                if self.dev_w > c.alignment.still_gyro**2 or self.dev_f > c.alignment.still_accel**2:
                    self.imu_moving = self.moving = True
            # samples enter the levelling window only ``still_delay`` s later, so the window cannot hold
            # the first moments of a motion that the GNSS speed test detects late; once the IMU has seen
            # motion the window is frozen (the pending samples bring the attitude forward at levelling)
            self.pending.append(imu)
            while self.pending and imu.t - self.pending[0].t > (
                MAX_FROZEN_S if self.imu_moving else c.alignment.still_delay
            ):
                old = self.pending.popleft()
                self.buf.append((old.dt, old.dvel, old.dtheta))
                self.t_win += old.dt
                self.f_sum = self.f_sum + old.dvel
                self.w_sum = self.w_sum + old.dtheta
            while self.buf and self.t_win - self.buf[0][0] >= c.alignment.time:
                dt0, dv0, dth0 = self.buf.popleft()
                self.t_win -= dt0
                self.f_sum = self.f_sum - dv0
                self.w_sum = self.w_sum - dth0
            full = self.t_win >= c.alignment.time - 0.5 * imu.dt
            if self.have_pos and (full or (self.moving and self.t_win >= 0.5)):
                mag_ok = c.mag.ref_ned is not None and self.last_mag is not None
                if self.moving or mag_ok or c.alignment.level_only or c.alignment.gyrocompass:
                    self._level()
        elif core.phase == "heading":
            # attitude from the (bias-compensated) gyros alone, velocity held at zero, until a GNSS course
            dth = imu.dtheta - core.bg * imu.dt
            core.ins.step(dth, imu.dvel - core.ba * imu.dt, imu.dt)
            core.ins.state.t = imu.t
            core.ins.state.vel_ned = np.zeros(3)
            core.omega_b = dth / imu.dt

    def _level(self) -> None:
        """Coarse levelling (book §4.1.1) and gyro bias from the static window; refined
        alignment with the magnetometer (§4.1.2) when a field reference is configured."""
        core = self.core
        c = self.cfg
        s = core.ins.state
        f = self.f_sum / self.t_win
        roll, pitch = alignment.coarse_level(f)
        yaw = 0.0
        # gyro bias = mean rate − Earth rate; only the vertical Earth-rate component is known before yaw
        w = self.w_sum / self.t_win
        C0 = dcm_from_quat(quat_from_euler(roll, pitch, 0.0))
        core.bg = w - C0.T @ np.array((0.0, 0.0, -earth.OMEGA_E * math.sin(s.lat)))
        have_yaw = False
        yaw_std = c.alignment.mag_yaw_std
        if c.alignment.gyrocompass:
            # book eq. 4.2 on the levelled mean rate: Earth rate's horizontal part points north; usable only when
            # the gyro bias is well below Ω cos φ (≈ 10.6 °/h at 45°): σ_ψ ≈ σ_bias / (Ω cos φ)
            ohm = earth.OMEGA_E * math.cos(s.lat)
            f_c = c.filter
            sig = math.hypot(f_c.init_gyro_bias, f_c.gyro_arw / math.sqrt(self.t_win)) / max(ohm, 1e-12)
            if sig <= c.alignment.gyrocompass_max_std:
                yaw = alignment.gyrocompass_yaw(C0 @ w)
                C = dcm_from_quat(quat_from_euler(roll, pitch, yaw))
                core.bg = w - C.T @ earth.earth_rate_ned(s.lat)
                have_yaw, yaw_std = True, sig
            self.gyrocompass_std = sig
        if not have_yaw and c.mag.ref_ned is not None and self.last_mag is not None:
            # tilt from the accelerometer alone, yaw from the tilt-compensated field direction: unit-free, and an
            # error in the reference's dip or magnitude moves no tilt (the book's two-vector A of §4.1.2 weighs
            # both vectors equally and takes their magnitudes as given)
            try:
                yaw = alignment.mag_heading(roll, pitch, self.last_mag, c.mag.ref_ned)
                have_yaw = True
            except ValueError:
                have_yaw = False
        s.q_nb = quat_from_euler(roll, pitch, yaw)
        s.vel_ned = np.zeros(3)
        core.ins.reset_history()
        self.fb, self.C = f, dcm_from_quat(s.q_nb)
        self.t_end = self.pending[0].t - self.pending[0].dt if self.pending else s.t
        # bring the attitude from the end of the window to now with the delayed samples
        t_now = s.t
        self._bring_forward()
        self.pending.clear()
        s = core.ins.state
        s.t = t_now
        if core.idx.bg is not None:
            core.kf.set_state_sigma("bg", c.alignment.gyro_bias_std)
        if have_yaw:
            self.enter_nav(yaw_std=yaw_std)
        else:
            core.phase = "heading"

    def _bring_forward(self) -> None:
        """The levelled attitude through the held-back samples (:attr:`pending`), from the end of the window to
        now: the gyros with the levelled bias removed, the velocity held at zero."""
        core = self.core
        for old in self.pending:
            core.ins.step(old.dtheta - core.bg * old.dt, old.dvel, old.dt)
            core.ins.state.vel_ned = np.zeros(3)

    def meas(self, meas: GnssFix | BaroSample | MagSample) -> None:
        """An aiding sample before navigation: the position, the motion test, the GNSS course yaw; the baro datum
        starts learning."""
        core = self.core
        s = core.ins.state
        if meas.kind == "mag":
            self.last_mag = np.asarray(meas.field_b)
            return
        if meas.kind == "baro":
            # learn the datum before navigation starts, so that the baro holds the height from the first step
            core.baro.learn(meas.t, baro_altitude(meas))
            return
        if meas.kind != "gnss":
            return
        if math.isfinite(meas.h):
            core.baro.gnss_height(
                meas, dcm_from_quat(s.q_nb), max(meas.std_d, self.cfg.gnss.min_std[1]) * self.cfg.gnss.std_scale
            )
        vel, std_vel = self._velocity(meas)
        if core.phase == "level":
            s.lat, s.lon, s.h = meas.lat, meas.lon, meas.h
            self.have_pos = True
            if vel is not None:
                self.moving = self.moving or math.hypot(float(vel[0]), float(vel[1])) > self.cfg.alignment.still_speed
        if core.phase != "heading":
            return
        gsf = core.yaw_gsf
        a = self.cfg.alignment
        if gsf is None and meas.vel_ned is None:
            # a position-only receiver: the course of a robust fit over several seconds of fixes
            fit = self._track_course(meas)
            if fit is None:
                return
            v, sig_course, d_ne = fit
            sp = math.hypot(float(v[0]), float(v[1]))
            self.last_speed = sp
            yaw_std = math.hypot(a.gnss_yaw_std, sig_course)
            if sp < a.still_speed or yaw_std > a.aligned_yaw_std:
                self.track_note = (f"course σ {math.degrees(sig_course):.1f}° over {len(self.track)} fixes at "
                                   f"{sp:.2f} m/s")  # fmt: skip
                return
            self._take_course(meas, alignment.yaw_from_course(v), yaw_std, v, d_ne)
            return
        if vel is None:
            return
        v = vel
        sp = math.hypot(float(v[0]), float(v[1]))
        self.last_speed = sp
        if (gsf is not None and gsf.converged()) or (gsf is None and sp >= a.gnss_yaw_speed):
            if gsf is not None:  # the yaw bank weighted by the GNSS velocity (fusion/yaw_gsf.py)
                yaw, yaw_std = gsf.yaw, math.sqrt(gsf.yaw_var)
            else:  # in-motion yaw = GNSS course (no sideslip)
                yaw = alignment.yaw_from_course(v)
                # 1-σ of course − heading (gnss_yaw_std: sideslip, lag) and of the course itself (σ_v / V)
                yaw_std = math.hypot(a.gnss_yaw_std, max(std_vel, a.gnss_yaw_vel_floor) / sp)
            self._take_course(meas, yaw, yaw_std, v, np.zeros(2))

    def _take_course(self, meas: GnssFix, yaw: float, yaw_std: float, v: Vec, d_ne: Vec) -> None:
        """Enter navigation with ``yaw`` (rad, σ ``yaw_std``), the velocity ``v`` (NED m/s) and the antenna at
        ``meas`` moved by ``d_ne`` (m north, east: the fitted track's position at the fix's time)."""
        core = self.core
        s = core.ins.state
        roll, pitch, yaw_was = euler_from_quat(s.q_nb)
        s.q_nb = quat_from_euler(roll, pitch, yaw)
        # the yaw reset turns the computed frame about down: the levelled tilt (fixed in NED) turns with it
        self.C = dcm_from_euler(0.0, 0.0, yaw - yaw_was) @ self.C
        s.vel_ned = np.asarray(v, dtype=np.float64).copy()
        C = dcm_from_quat(s.q_nb)
        d = C @ self.cfg.gnss.lever_arm_b
        m, n = earth.radii(meas.lat)
        s.lat = meas.lat + (float(d_ne[0]) - d[0]) / (m + meas.h)
        s.lon = meas.lon + (float(d_ne[1]) - d[1]) / ((n + meas.h) * math.cos(meas.lat))
        s.h = meas.h + d[2]
        core.ins.state.t = max(s.t, meas.t)
        self.enter_nav(yaw_std=yaw_std)

    def _track_course(self, meas: GnssFix) -> tuple[Vec, float, Vec] | None:
        """The course of a position-only receiver from the fixes of the last :data:`COURSE_SPAN_S` s over which
        the gyros turned the vehicle by at most :data:`COURSE_MAX_TURN`: a least-squares straight line
        p(t) = p₀ + v (t − t_k) north and east, refitted without the fixes whose 2-D residual exceeds
        :data:`COURSE_OUTLIER_SIGMA` σ, with σ from the residuals themselves (their median, a jump cannot inflate
        it) floored at a tenth of the receiver's σ_NE. Returns the velocity at the fix (NED m/s: the fitted mean
        velocity turned by the gyros' yaw change since the fit's mean time), the course's 1-σ (rad, σ_v / V) and the
        fitted position's offset from the fix (m north, east); None while too few fixes agree."""
        yaw_now = euler_from_quat(self.core.ins.state.q_nb)[2]
        tr = self.track
        if tr and not 0.0 < meas.t - tr[-1][0] <= MAX_DIFF_S:
            tr.clear()
        tr.append((meas.t, meas.lat, meas.lon, meas.h, meas.std_ne, yaw_now))
        while tr and (meas.t - tr[0][0] > COURSE_SPAN_S or abs(math.remainder(tr[0][5] - yaw_now, math.tau))
                      > COURSE_MAX_TURN):  # fmt: skip
            tr.popleft()
        if len(tr) < COURSE_MIN_FIXES:
            self.track_note = f"{len(tr)} of {COURSE_MIN_FIXES} position fixes on a straight track"
            return None
        arr = np.array(tr)
        tau = arr[:, 0] - meas.t
        p = np.array([earth.ned_from_geodetic(r[1], r[2], r[3], meas.lat, meas.lon, meas.h)[:2] for r in tr])
        floor = 0.1 * float(np.median(arr[:, 4]))
        keep = np.ones(len(tr), dtype=bool)
        A = np.stack([np.ones_like(tau), tau], axis=1)
        for _ in range(4):
            coef, *_ = np.linalg.lstsq(A[keep], p[keep], rcond=None)
            r = np.linalg.norm(p - A @ coef, axis=1)
            # the median 2-D residual norm of N(0, σ²I₂) is σ √(2 ln 2)
            sig = max(float(np.median(r[keep])) / math.sqrt(2.0 * math.log(2.0)), floor, 1e-4)
            new = r <= COURSE_OUTLIER_SIGMA * sig
            if np.array_equal(new, keep) or new.sum() < COURSE_MIN_FIXES:
                break
            keep = new
        if keep.sum() < COURSE_MIN_FIXES or 1.0 - keep.mean() > COURSE_MAX_REJECTED:
            self.track_note = f"the track's fixes disagree ({int((~keep).sum())} of {len(tr)} off the line)"
            return None
        cov = np.linalg.inv(A[keep].T @ A[keep])
        v_ne = coef[1]
        sp = float(np.hypot(v_ne[0], v_ne[1]))
        if sp <= 0.0:
            return None
        sig_course = sig * math.sqrt(float(cov[1, 1])) / sp
        dyaw = math.remainder(yaw_now - float(np.mean(arr[keep, 5])), math.tau)
        c, sn = math.cos(dyaw), math.sin(dyaw)
        v = np.array((c * v_ne[0] - sn * v_ne[1], sn * v_ne[0] + c * v_ne[1], 0.0))
        return v, sig_course, np.asarray(coef[0], dtype=np.float64)

    def _velocity(self, meas: GnssFix) -> tuple[Vec | None, float]:
        """The fix's velocity (NED m/s) and its σ; for a position-only receiver the difference of this fix and the
        one before, when they are at most :data:`MAX_DIFF_S` apart (σ = √2 σ_NE / Δt); (None, 0) otherwise."""
        prev, self.prev_fix = self.prev_fix, meas
        if meas.vel_ned is not None:
            return np.asarray(meas.vel_ned), meas.std_vel
        if prev is None or not 0.0 < meas.t - prev.t <= MAX_DIFF_S:
            return None, 0.0
        dt = meas.t - prev.t
        d = earth.ned_from_geodetic(meas.lat, meas.lon, meas.h, prev.lat, prev.lon, prev.h)
        return np.asarray(d) / dt, math.sqrt(2.0) * max(meas.std_ne, prev.std_ne) / dt

    def waiting_for(self) -> str:
        """Why the core is not navigating yet, in one line for a user ("" once it navigates)."""
        c = self.cfg
        phase = self.core.phase
        if phase == "level":
            if not self.have_pos:
                return "levelling: waiting for a position (a GNSS fix)"
            if self.t_win < c.alignment.time - 1e-9:
                return f"levelling: {self.t_win:.1f} of {c.alignment.time:g} s at rest"
            return (
                "levelled at rest: waiting for motion (GNSS speed above "
                f"{c.alignment.still_speed:g} m/s or the IMU's motion test) to take the yaw from the GNSS course, "
                "or set a magnetometer reference (mag.ref_ned), alignment.gyrocompass or alignment.level_only"
            )
        if phase == "heading":
            gc = ""
            if self.gyrocompass_std is not None:
                gc = (f"gyrocompass refused (σ_ψ {math.degrees(self.gyrocompass_std):.0f}° > "
                      f"{math.degrees(c.alignment.gyrocompass_max_std):.0f}°: "
                      "gyro bias too large for Earth rate); ")  # fmt: skip
            if c.mag.ref_ned is not None and self.last_mag is None:
                return gc + "yaw: waiting for a magnetometer sample"
            gsf = self.core.yaw_gsf
            if gsf is not None:
                sd = "no GNSS velocity yet" if not gsf.started else f"σ {math.degrees(math.sqrt(gsf.yaw_var)):.0f}°"
                lim = math.degrees(gsf.cfg.converged_std)
                return gc + f"yaw: waiting for the GNSS-velocity yaw estimator ({sd} > {lim:.0f}°; needs accelerations)"
            last = (
                "no GNSS velocity yet (nor two position fixes within 2 s)"
                if self.last_speed is None
                else f"last {self.last_speed:.2f} m/s"
            )
            if self.prev_fix is not None and self.prev_fix.vel_ned is None:
                return gc + f"yaw: waiting for a straight GNSS track for the course ({self.track_note or last})"
            return gc + f"yaw: waiting for a GNSS speed of {c.alignment.gnss_yaw_speed:g} m/s for the course ({last})"
        return ""

    def enter_nav(self, yaw_std: float | None = None) -> None:
        """Start navigating; with ``yaw_std`` (rad) the attitude σ (and the levelled tilt's correlated prior)."""
        core = self.core
        core.phase = "nav"
        s = core.ins.state
        core.g_local = earth.normal_gravity(s.lat, s.h)
        if yaw_std is not None:
            c = self.cfg.filter
            core.kf.set_state_sigma("att", np.array((c.init_att, c.init_att, yaw_std)))
            if self.cfg.alignment.level_tilt_prior and self.fb is not None:
                # the levelled tilt holds the horizontal accelerometer error (book §4.1.1): correlated prior;
                # what the levelling leaves: the window's accelerometer noise and the gyro drift since the window
                since = max(0.0, s.t - self.t_end)
                sig = math.hypot(c.accel_vrw / math.sqrt(max(self.t_win, 1e-3)) / core.g_local,
                                 self.cfg.alignment.gyro_bias_std * since)  # fmt: skip
                core.kf.level_tilt(self.C, self.fb, sig)
