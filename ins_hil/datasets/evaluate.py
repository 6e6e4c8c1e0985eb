"""Offline evaluation of NavCore on recorded or simulated data (pure: no I/O, no plots).

``run_drive`` replays a recording with reference-grade GNSS (the car drive: ``ins_hil.datasets.study``) with
GNSS removed in outage windows and scores the antenna position against the fixes; ``run_truth`` replays a
simulated scenario against its truth. Both return time series for plots and a metrics dict.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field

import numpy as np

from ins_hil.core import NavConfig, NavCore
from ins_hil.nav import earth
from ins_hil.nav.rotation import dcm_from_quat, euler_from_quat, quat_conj, quat_mul, rotvec_from_quat
from ins_hil.types import BaroSample, GnssFix, ImuSample, MagSample, Vec

Progress = Callable[[int, int], None]


@dataclass
class Series:
    """Recorded output of a run (one row per record)."""

    t: list[float] = field(default_factory=list)
    pos_err: list[Vec] = field(default_factory=list)  # NED m
    vel_err: list[Vec] = field(default_factory=list)
    att_err: list[Vec] = field(default_factory=list)  # rad (roll, pitch, yaw)
    std_pos: list[Vec] = field(default_factory=list)
    std_vel: list[Vec] = field(default_factory=list)
    std_att: list[Vec] = field(default_factory=list)
    gyro_bias: list[Vec] = field(default_factory=list)
    accel_bias: list[Vec] = field(default_factory=list)
    ned: list[Vec] = field(default_factory=list)  # estimated position, NED m from the origin
    ref_ned: list[Vec] = field(default_factory=list)
    ratios: list[dict[str, float]] = field(default_factory=list)
    nees: list[float] = field(default_factory=list)  # 9-dof NEES of (δr, δv, μ) (simulations)

    def arrays(self) -> dict[str, Vec]:
        return {k: np.array(v) for k, v in self.__dict__.items() if k != "ratios"}


def antenna_ned(core: NavCore, lever: Vec, t: float, origin: tuple[float, float, float]) -> Vec:
    """The core's GNSS antenna position (NED m from ``origin`` = (lat rad, lon rad, h m)) at time ``t`` s:
    the state's position plus the body lever arm ``lever`` (m), moved on with its velocity to ``t``."""
    s = core.ins.state
    p = earth.ned_from_geodetic(s.lat, s.lon, s.h, *origin)
    return p + dcm_from_quat(s.q_nb) @ lever + s.vel_ned * (t - s.t)


def run_drive(
    imu: Sequence[ImuSample],
    gnss: Sequence[GnssFix],
    scored: Sequence[bool],
    cfg: NavConfig,
    outages: Sequence[tuple[float, float]],
    progress: Progress | None = None,
    aux: Sequence[BaroSample | MagSample] = (),
) -> tuple[dict[str, float], Series, NavCore]:
    """Replay with GNSS removed inside ``outages``; score the antenna position at every epoch whose ``scored``
    flag is set (e.g. the RTK-fixed ones): inside outages and, with GNSS present, the a-priori error
    (before that epoch is fused) and the a-posteriori one. ``aux`` (baro/magnetometer samples, sorted
    by ``t`` s) are fused after the IMU step that reaches their time, inside outages too."""
    core = NavCore(None, cfg)
    lever = cfg.gnss.lever_arm_b
    g0 = gnss[0]
    origin = (g0.lat, g0.lon, g0.h)
    ser = Series()
    out_err: list[Vec] = []
    prior_err: list[Vec] = []
    post_err: list[Vec] = []
    j = ja = 0
    n = len(imu)
    t_aligned = math.nan
    for k, s in enumerate(imu):
        core.step(s)
        while ja < len(aux) and aux[ja].t <= s.t:
            core.fuse(aux[ja])
            ja += 1
        while j < len(gnss) and gnss[j].t <= s.t:
            f = gnss[j]
            j += 1
            inside = any(a <= f.t < b for a, b in outages)
            if core.phase == "nav":
                ref = earth.ned_from_geodetic(f.lat, f.lon, f.h, *origin)
                e = antenna_ned(core, lever, f.t, origin) - ref
                if scored[j - 1]:
                    (out_err if inside else prior_err).append(e)
                ser.t.append(f.t)
                ser.pos_err.append(e)
                ser.ned.append(ref + e)
                ser.ref_ned.append(ref)
                st = core.state()
                ser.std_pos.append(st.std_pos)
                ser.std_vel.append(st.std_vel)
                ser.std_att.append(st.std_att)
                ser.gyro_bias.append(st.gyro_bias)
                ser.accel_bias.append(st.accel_bias)
                ser.vel_err.append(st.vel_ned - (f.vel_ned if f.vel_ned is not None else st.vel_ned))
                ser.att_err.append(np.zeros(3))
                ser.ratios.append(dict(st.test_ratios))
            if not inside:
                core.fuse(f)
                if core.phase == "nav" and scored[j - 1]:
                    ref = earth.ned_from_geodetic(f.lat, f.lon, f.h, *origin)
                    post_err.append(antenna_ned(core, lever, f.t, origin) - ref)
            if core.phase == "nav" and math.isnan(t_aligned):
                t_aligned = f.t
        if progress is not None and (k % 2000 == 0 or k == n - 1):
            progress(k + 1, n)
    oe = np.array(out_err) if out_err else np.zeros((0, 3))
    pe = np.array(prior_err) if prior_err else np.zeros((0, 3))
    qe = np.array(post_err) if post_err else np.zeros((0, 3))

    def hrms(a: Vec) -> float:
        return float(np.sqrt(np.mean(np.sum(a[:, :2] ** 2, axis=1)))) if len(a) else math.nan

    m = {
        "outage_h_rms_m": hrms(oe),
        "outage_h_max_m": float(np.max(np.linalg.norm(oe[:, :2], axis=1))) if len(oe) else math.nan,
        "outage_v_rms_m": float(np.sqrt(np.mean(oe[:, 2] ** 2))) if len(oe) else math.nan,
        "outage_epochs": len(oe),
        "gnss_h_rms_prior_m": hrms(pe),
        "gnss_h_rms_post_m": hrms(qe),
        "gnss_epochs": len(pe),
        "t_aligned_s": t_aligned - gnss[0].t,
        "gnss_rejected": core.stats["gnss_pos"].rejected,
        "nhc_updates": core.stats["nhc"].accepted,
        "zupt_updates": core.stats["zupt"].accepted,
    }
    return m, ser, core


def run_truth(
    core: NavCore,
    imu: Sequence[ImuSample],
    meas: Sequence,
    truth,
    record_every: int = 10,
    progress: Progress | None = None,
) -> Series:
    """Replay a simulated scenario (measurements fused in order of ``t_deliver`` = t + latency
    if the object has it, else t) and record errors against the truth."""
    order = sorted(meas, key=lambda m: getattr(m, "t_arrival_ns", 0) * 1e-9 or m.t)
    j = 0
    ser = Series()
    lat0, lon0, h0 = float(truth.lat[0]), float(truth.lon[0]), float(truth.h[0])
    n = len(imu)
    for k, s in enumerate(imu):
        st = core.step(s)
        while j < len(order) and (getattr(order[j], "t_arrival_ns", 0) * 1e-9 or order[j].t) <= s.t + 1e-9:
            core.fuse(order[j])
            j += 1
        if k % record_every == record_every - 1:
            st = core.state()
            i = k + 1
            dp = earth.ned_delta_small(st.lat - truth.lat[i], st.lon - truth.lon[i], st.h - truth.h[i],
                                       truth.lat[i], truth.h[i])  # fmt: skip
            d = euler_from_quat(st.q_nb) - truth.euler[i]
            # NEES in the filter's conventions: δr, δv = true − computed; Ĉ = (I + [μ×]) C
            mu = rotvec_from_quat(quat_mul(st.q_nb, quat_conj(truth.q_nb[i])))
            e = np.concatenate([-dp, truth.vel_ned[i] - st.vel_ned, mu])
            P9 = core.kf.P[:9, :9]
            ser.nees.append(float(e @ np.linalg.solve(P9, e)))
            ser.t.append(s.t)
            ser.pos_err.append(dp)
            ser.vel_err.append(st.vel_ned - truth.vel_ned[i])
            ser.att_err.append((d + np.pi) % (2 * np.pi) - np.pi)
            ser.std_pos.append(st.std_pos)
            ser.std_vel.append(st.std_vel)
            ser.std_att.append(st.std_att)
            ser.gyro_bias.append(st.gyro_bias)
            ser.accel_bias.append(st.accel_bias)
            ser.ned.append(earth.ned_from_geodetic(st.lat, st.lon, st.h, lat0, lon0, h0))
            ser.ref_ned.append(earth.ned_from_geodetic(truth.lat[i], truth.lon[i], truth.h[i], lat0, lon0, h0))
            ser.ratios.append(dict(st.test_ratios))
        if progress is not None and (k % 5000 == 0 or k == n - 1):
            progress(k + 1, n)
    return ser
