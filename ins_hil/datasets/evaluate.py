"""Offline evaluation on recorded or simulated data (pure: no I/O, no plots), on the one replay loop
(:func:`ins_hil.datasets.run.replay`: the gateway's pipeline) with scoring observers.

``run_drive`` replays a recording with reference-grade GNSS (the car drive: ``ins_hil.datasets.study``) with
GNSS withheld in outage windows and scores the antenna position against the fixes (:class:`GnssScore`);
``run_truth`` replays a simulated scenario against its truth (:class:`TruthScore`). Both return time series
for plots.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from ins_hil.core import NavConfig
from ins_hil.datasets.run import GnssScore, Progress, navigating, offline_config, replay
from ins_hil.nav import earth
from ins_hil.nav.mechanization import StrapdownState
from ins_hil.nav.rotation import euler_from_quat, quat_conj, quat_mul, rotvec_from_quat
from ins_hil.runtime.pipeline import Observer, Pipeline
from ins_hil.types import BaroSample, GnssFix, ImuSample, MagSample, NavState, Vec


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


class _FirstNav(Observer):
    """The time of the first GNSS fix handled while the core navigates (fused, or withheld and scored)."""

    def __init__(self) -> None:
        self.t = math.nan

    def after_fuse(self, pipe: Pipeline, m: Any, fused: bool) -> None:
        if math.isnan(self.t) and m.kind == "gnss" and navigating(pipe):
            self.t = m.t


def run_drive(
    imu: Sequence[ImuSample],
    gnss: Sequence[GnssFix],
    scored: Sequence[bool],
    cfg: NavConfig,
    outages: Sequence[tuple[float, float]],
    progress: Progress | None = None,
    aux: Sequence[BaroSample | MagSample] = (),
    aiding_fdi: bool = True,
) -> tuple[dict[str, float], Series, Any]:
    """Replay (:func:`ins_hil.datasets.run.replay`, the gateway's pipeline) with GNSS withheld inside
    ``outages``; score the antenna position at every epoch whose ``scored`` flag is set (e.g. the RTK-fixed
    ones): inside outages and, with GNSS present, the a-priori error (before that epoch is fused) and the
    a-posteriori one. ``aux`` (baro/magnetometer samples) are fused at their time, inside outages too.
    (metrics, the series at the fixes, the core)."""
    g0 = gnss[0]
    origin = (g0.lat, g0.lon, g0.h)
    ok = {id(f) for f, s in zip(gnss, scored, strict=True) if s}
    inside = [any(a <= f.t < b for a, b in outages) for f in gnss]
    score = GnssScore(cfg.gnss.lever_arm_b, origin, [f for f, i in zip(gnss, inside, strict=True) if i])
    first = _FirstNav()
    aids: list[Any] = sorted([*aux, *(f for f, i in zip(gnss, inside, strict=True) if not i)],
                             key=lambda m: (m.t, 1 if m.kind == "gnss" else 0))  # fmt: skip
    pipe, _ = replay(imu, aids, cfg, [score, first], pipeline=offline_config(aiding_fdi), progress=progress,
                     source="drive")  # fmt: skip
    core: Any = pipe.core
    ser = Series()
    out_err: list[Vec] = []
    prior_err: list[Vec] = []
    post_err: list[Vec] = []
    rows = score.sorted_rows()
    for r in rows:
        st, f = r.state, r.fix
        if id(f) in ok:
            (out_err if r.inside else prior_err).append(r.prior)
            if r.fused:
                post_err.append(r.post)
        ser.t.append(f.t)
        ser.pos_err.append(r.prior)
        ser.ned.append(r.ref + r.prior)
        ser.ref_ned.append(r.ref)
        ser.std_pos.append(st.std_pos)
        ser.std_vel.append(st.std_vel)
        ser.std_att.append(st.std_att)
        ser.gyro_bias.append(st.gyro_bias)
        ser.accel_bias.append(st.accel_bias)
        ser.vel_err.append(st.vel_ned - (f.vel_ned if f.vel_ned is not None else st.vel_ned))
        ser.att_err.append(np.zeros(3))
        ser.ratios.append(dict(st.test_ratios))
    t_withheld = min((r.fix.t for r in rows if r.inside), default=math.nan)
    t_aligned = min(first.t, t_withheld) if math.isfinite(t_withheld) else first.t
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
        "gnss_excluded": pipe.counts.get("excluded_GnssFix", 0),
    }
    return m, ser, core


class TruthScore(Observer):
    """A simulated run's errors against its truth at every ``every``-th IMU epoch (the truth row at the
    epoch's time): position, velocity, attitude, σ, biases and the 9-dof NEES of (δr, δv, μ) with the
    core's covariance."""

    def __init__(self, truth: Any, every: int) -> None:
        self.truth, self.every, self.n = truth, every, 0
        self.ser = Series()
        self.lat0, self.lon0, self.h0 = float(truth.lat[0]), float(truth.lon[0]), float(truth.h[0])

    def epoch(self, pipe: Pipeline, st: NavState) -> None:
        self.n += 1
        if self.n % self.every:
            return
        tr, ser = self.truth, self.ser
        i = min(int(np.searchsorted(tr.t, st.t - 1e-9)), len(tr.t) - 1)
        dp = earth.ned_delta_small(st.lat - tr.lat[i], st.lon - tr.lon[i], st.h - tr.h[i], tr.lat[i], tr.h[i])
        d = euler_from_quat(st.q_nb) - tr.euler[i]
        # NEES in the filter's conventions: δr, δv = true − computed; Ĉ = (I + [μ×]) C
        mu = rotvec_from_quat(quat_mul(st.q_nb, quat_conj(tr.q_nb[i])))
        e = np.concatenate([-dp, tr.vel_ned[i] - st.vel_ned, mu])
        kf = getattr(pipe.core, "kf", None)
        ser.nees.append(float(e @ np.linalg.solve(kf.P[:9, :9], e)) if kf is not None else math.nan)
        ser.t.append(st.t)
        ser.pos_err.append(dp)
        ser.vel_err.append(st.vel_ned - tr.vel_ned[i])
        ser.att_err.append((d + np.pi) % (2 * np.pi) - np.pi)
        ser.std_pos.append(st.std_pos)
        ser.std_vel.append(st.std_vel)
        ser.std_att.append(st.std_att)
        ser.gyro_bias.append(st.gyro_bias)
        ser.accel_bias.append(st.accel_bias)
        ser.ned.append(earth.ned_from_geodetic(st.lat, st.lon, st.h, self.lat0, self.lon0, self.h0))
        ser.ref_ned.append(earth.ned_from_geodetic(tr.lat[i], tr.lon[i], tr.h[i], self.lat0, self.lon0, self.h0))
        ser.ratios.append(dict(st.test_ratios))


def run_truth(
    nav: NavConfig,
    initial: StrapdownState | None,
    imu: Sequence[ImuSample],
    meas: Sequence[Any],
    truth: Any,
    record_every: int = 10,
    progress: Progress | None = None,
    setup: Callable[[Pipeline], None] | None = None,
    aiding_fdi: bool = True,
) -> tuple[Series, Any]:
    """Replay a simulated scenario (:func:`ins_hil.datasets.run.replay`) from ``initial``, each measurement
    handed over when the IMU time reaches its arrival (``t_arrival_ns``, else its ``t``), and record the errors
    against the truth (:class:`TruthScore`). (series, the core)."""

    def arrival(m: Any) -> float:
        return getattr(m, "t_arrival_ns", 0) * 1e-9 or m.t

    order = sorted(meas, key=arrival)
    obs = TruthScore(truth, record_every)
    pipe, _ = replay(imu, order, nav, [obs], initial=initial, hand_at=[arrival(m) - 1e-9 for m in order],
                     pipeline=offline_config(aiding_fdi), progress=progress, source="scenario",
                     setup=setup)  # fmt: skip
    return obs.ser, pipe.core
