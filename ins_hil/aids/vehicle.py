"""Vehicle aids: ZUPT/ZARU at rest, the non-holonomic constraint (NHC) and the longitudinal-acceleration prior in motion
(ground vehicle); the rotor drag on the body specific force (multirotor). No sample of their own: they run after
every IMU time update (``[core.nav.aids]`` in :mod:`ins_hil.core_parts.config`; the models in
:mod:`ins_hil.fusion.measurements`)."""

from __future__ import annotations

import math
from typing import TYPE_CHECKING, Any, NamedTuple

import numpy as np

from ins_hil.core_parts.contract import Measurement
from ins_hil.nav.rotation import dcm_from_quat
from ins_hil.types import ImuSample, Vec

from . import Aid, AidSource

if TYPE_CHECKING:
    from ins_hil.core_parts.config import NavConfig
    from ins_hil.fusion.ekf import StateIndex
    from ins_hil.nav.mechanization import StrapdownNED


_new = tuple.__new__  # a NamedTuple without its generated __new__ (a snapshot per IMU step)


class AidsSnapshot(NamedTuple):
    """The aids' state at one step (:meth:`VehicleAids.snapshot`)."""

    nhc_next: float
    still_time: float
    ema_w: Vec
    ema_f: Vec
    w_lp: Vec
    drag_next: float
    ema_fb: Vec
    la: tuple[float, float, float, float]


class VehicleAids(Aid):
    """Rest detection and the ZUPT/ZARU/NHC measurements of a ground vehicle (``NavConfig.aids``: ``nhc``/``zupt``),
    and a multirotor's drag measurement (``drag``) while the rest detector does not see it standing.

    Rest detection on exponentially averaged (τ = ``zupt_tau``) rate and specific-force magnitudes, so engine
    vibration (tens of Hz, °/s-level on a car) does not hide a stop."""

    def __init__(self, cfg: NavConfig, idx: StateIndex) -> None:
        from ins_hil.fusion import measurements  # the models: not at import (see the registry)

        mm = measurements  # its functions (a NavCore is deep-copyable: no module in its state)
        self.drag_model, self.zero_velocity, self.zero_rate = mm.multirotor_drag, mm.zero_velocity, mm.zero_rate
        self.nhc, self.nhc_mounted = mm.nonholonomic, mm.nonholonomic_mounted
        self.long_accel = mm.longitudinal_accel
        self.cfg, self.idx = cfg, idx
        self.la_on = cfg.aids.long_accel_std > 0.0
        self.on = cfg.aids.nhc or cfg.aids.zupt or cfg.aids.drag or self.la_on
        # the longitudinal-acceleration prior's window: next fusion time (s), Σa_x, Σa_x² (m/s², (m/s²)²), samples
        self.la: tuple[float, float, float, float] = (0.0, 0.0, 0.0, 0.0)
        self.drag_next = 0.0  # s, the next drag-aid time (drag_rate)
        self.ema_fb = np.zeros(3)  # averaged compensated body specific force (m/s², drag_tau)
        self.nhc_next = 0.0  # s, the next aid time (nhc_rate)
        self.still_time = 0.0  # s at rest so far
        self.ema_w = np.zeros(3)  # averaged compensated body rate (rad/s)
        self.ema_f = np.array((0.0, 0.0, -9.80665))  # averaged specific force (NED, m/s²)
        self.w_lp = np.zeros(3)  # low-passed body rate for the NHC lever-arm term (nhc_omega_lp_hz)
        lever_on = bool(np.any(cfg.aids.nhc_lever_b != 0.0))
        self.lever_lp = cfg.aids.nhc_omega_lp_hz > 0.0 and lever_on
        self.mounted = idx.mnt is not None or lever_on or cfg.aids.nhc_pitch_per_accel != 0.0
        self.stateful = self.per_step = self.on
        self.core: Any = None

    def after_step(self, imu: ImuSample) -> None:
        """Apply the aids due after this IMU step (``NavCore._apply``)."""
        core = self.core
        for m in self.measurements(imu, core.ins, core.omega_b, core.q_mount, core.g_local, core.f_b, core.wind):
            core._apply(m, imu.t)

    def snapshot(self) -> AidsSnapshot:
        return _new(AidsSnapshot, (self.nhc_next, self.still_time, self.ema_w, self.ema_f, self.w_lp, self.drag_next,
                                   self.ema_fb, self.la))  # fmt: skip

    def restore(self, d: AidsSnapshot) -> None:
        self.nhc_next, self.still_time, self.ema_w, self.ema_f, self.w_lp, self.drag_next, self.ema_fb, self.la = d

    def measurements(
        self, imu: ImuSample, ins: StrapdownNED, omega_b: Vec, q_mount: Vec, g_local: float, f_b: Vec, wind: Vec
    ) -> tuple[Measurement, ...]:
        """The aids due after this IMU step, in update order (none between two ``nhc_rate`` / ``drag_rate`` ticks).

        omega_b / f_b: compensated body rate (rad/s) and specific force (m/s²); q_mount: residual IMU body →
        vehicle rotation; g_local: m/s²; wind: the estimated horizontal wind (NED north, east; m/s)."""
        c = self.cfg
        if not self.on:
            return ()
        ground = self._ground(imu, ins, omega_b, q_mount, g_local)
        if self.la_on:
            ground = (*ground, *self._long_accel(imu, ins, q_mount, g_local, f_b))
        if not c.aids.drag:
            return ground
        b = min(1.0, imu.dt / c.aids.drag_tau)
        self.ema_fb = self.ema_fb + b * (f_b - self.ema_fb)
        if imu.t < self.drag_next or self.still_time > 0.0:
            return ground
        self.drag_next = imu.t + 1.0 / c.aids.drag_rate
        s = ins.state
        z, H = self.drag_model(self.idx, dcm_from_quat(s.q_nb), s.vel_ned, wind, self.ema_fb, c.aids.drag_coef)
        return (*ground, Measurement("drag", z, H, np.full(2, c.aids.drag_std**2), c.aids.gate))

    def _long_accel(
        self, imu: ImuSample, ins: StrapdownNED, q_mount: Vec, g_local: float, f_b: Vec
    ) -> tuple[Measurement, ...]:
        """The longitudinal-acceleration prior (``long_accel_std``): the kinematic acceleration along the vehicle's
        forward axis, a_x = (R (f_b + Ĉ^T g))_x (R: IMU body → vehicle; g = (0, 0, g) NED; Coriolis left out),
        averaged over 1/``long_accel_rate`` s, is fused as 0 with the variance σ² + s²/(n − 1) (σ =
        ``long_accel_std``; s²: the window's variance of a_x over its n samples, the vibration left in the mean)."""
        c = self.cfg.aids
        C = dcm_from_quat(ins.state.q_nb)
        down_b = C[2].tolist()  # Ĉ^T e_D
        a_b = [float(f_b[i]) + g_local * down_b[i] for i in range(3)]
        R = dcm_from_quat(q_mount) if self.mounted else None
        if R is not None:
            r0 = R[0].tolist()
            ax = r0[0] * a_b[0] + r0[1] * a_b[1] + r0[2] * a_b[2]
        else:
            ax = a_b[0]
        t_next, sx, sxx, n = self.la
        sx, sxx, n = sx + ax, sxx + ax * ax, n + 1.0
        if imu.t < t_next:
            self.la = (t_next, sx, sxx, n)
            return ()
        self.la = (imu.t + 1.0 / c.long_accel_rate, 0.0, 0.0, 0.0)
        if n < 2.0:
            return ()
        mean = sx / n
        var = max(sxx / n - mean * mean, 0.0) / (n - 1.0)  # the mean's variance (samples independent)
        z, H = self.long_accel(self.idx, C, R if R is not None else np.eye(3), mean, g_local)
        return (Measurement("long_accel", z, H, np.array((c.long_accel_std**2 + var,)), c.gate),)

    def _ground(
        self, imu: ImuSample, ins: StrapdownNED, omega_b: Vec, q_mount: Vec, g_local: float
    ) -> tuple[Measurement, ...]:
        """ZUPT/ZARU and the NHC (and the rest detector the drag aid reads)."""
        c = self.cfg
        t = imu.t
        s = ins.state
        a = min(1.0, imu.dt / c.aids.zupt_tau)
        self.ema_w = self.ema_w + a * (omega_b - self.ema_w)
        # specific force in NED (not its body magnitude): a start from rest with 1 m/s² changes |f| by only
        # 0.05 m/s² (second order) but the horizontal specific force by 1 m/s², so the ZUPT stops in time
        self.ema_f = self.ema_f + a * (ins.f_ned - self.ema_f)
        w, f = self.ema_w, self.ema_f
        if self.lever_lp:
            b = 1.0 - math.exp(-2.0 * math.pi * c.aids.nhc_omega_lp_hz * imu.dt)  # first-order IIR, causal
            self.w_lp = self.w_lp + b * (omega_b - self.w_lp)
        wn = math.sqrt(float(w[0]) ** 2 + float(w[1]) ** 2 + float(w[2]) ** 2)
        fn = math.sqrt(float(f[0]) ** 2 + float(f[1]) ** 2 + (float(f[2]) + g_local) ** 2)  # |f − (0, 0, −g)|
        vn = s.vel_ned
        slow = float(vn[0]) ** 2 + float(vn[1]) ** 2 + float(vn[2]) ** 2 < c.aids.zupt_max_speed**2
        # constant-velocity driving looks like rest to the IMU: require a low estimated speed too
        still = slow and wn < c.aids.zupt_gyro and fn < c.aids.zupt_accel
        self.still_time = self.still_time + imu.dt if still else 0.0
        if t < self.nhc_next:
            return ()
        self.nhc_next = t + 1.0 / c.aids.nhc_rate
        idx = self.idx
        if c.aids.zupt and self.still_time >= c.aids.zupt_time:
            z, H = self.zero_velocity(idx, s.vel_ned)
            zupt = Measurement("zupt", z, H, np.full(3, c.aids.zupt_std**2), c.aids.gate)
            if not (c.aids.zaru and idx.bg is not None):
                return (zupt,)
            # zero angular rate: the averaged compensated rate is the residual gyro bias, z = 0 − ω̄ = −δb_g
            z, H = self.zero_rate(idx, w)
            self.ema_w = np.zeros(3)
            return zupt, Measurement("zupt", z, H, np.full(3, c.aids.zaru_std**2), c.aids.gate)
        if c.aids.nhc and float(np.linalg.norm(s.vel_ned)) > c.aids.nhc_min_speed:
            C = dcm_from_quat(s.q_nb)
            if self.mounted:
                R = dcm_from_quat(q_mount)
                if c.aids.nhc_pitch_per_accel != 0.0:
                    # suspension pitch (squat/dive): the body pitches nose-up by θ = k a_x relative to the road
                    # when accelerating forward, so the velocity has v_b,z = v θ; the constraint holds in the
                    # road frame u = R_y(θ) v_b (a_x: averaged kinematic acceleration, body x)
                    ax = float(C[0, 0] * f[0] + C[1, 0] * f[1] + C[2, 0] * (float(f[2]) + g_local))
                    th = c.aids.nhc_pitch_per_accel * ax
                    ct, st_ = math.cos(th), math.sin(th)
                    R = R @ np.array(((ct, 0.0, st_), (0.0, 1.0, 0.0), (-st_, 0.0, ct)))
                w_l = self.w_lp if self.lever_lp else omega_b
                z, H, _ = self.nhc_mounted(idx, C, s.vel_ned, R, w_l, c.aids.nhc_lever_b)
            else:
                z, H = self.nhc(idx, C, s.vel_ned)
            if c.aids.nhc_vertical:
                return (
                    Measurement("nhc", z, H, np.array((c.aids.nhc_std**2, c.aids.nhc_std_vertical**2)), c.aids.gate),
                )
            return (Measurement("nhc", z[:1], H[:1], np.array((c.aids.nhc_std**2,)), c.aids.gate),)
        return ()


class VehicleSource(AidSource):
    name = "vehicle"
    kinds = ("nhc", "zupt", "drag", "long_accel")

    def enabled(self, nav: Any) -> bool:
        return bool(nav.aids.nhc or nav.aids.zupt or nav.aids.drag or nav.aids.long_accel_std > 0.0)

    def stat_kinds(self, nav: Any) -> tuple[str, ...]:
        extra = ("drag",) if nav.aids.drag else ()
        return ("nhc", "zupt", *extra, *(("long_accel",) if nav.aids.long_accel_std > 0.0 else ()))

    def bind(self, core: Any) -> VehicleAids:
        a = VehicleAids(core.cfg, core.idx)
        a.core = core
        core.aids = a
        return a


SOURCE = VehicleSource()
