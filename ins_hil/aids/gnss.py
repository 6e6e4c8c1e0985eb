"""GNSS position and velocity aid (:class:`~ins_hil.types.GnssFix`, ``[core.nav.gnss]`` in
:mod:`ins_hil.core_parts.config`).

The models are :func:`ins_hil.core_parts.gnss.gnss_position` / ``gnss_velocity`` (lever arm, σ floors, the
v̂·Δt shift of a late fix); here: the reset of a filter that rejected the fixes too long (σ re-opened, or
the divergence recovery of ``NavCore._recover``), the baro datum's GNSS height, the split of a fix whose
velocity is valid earlier (``gnss.vel_delay``), the GNSS course before navigation (alignment, yaw GSF), the
validation boundary's GNSS checks and the ``.ihlog`` record (type 2).
"""

from __future__ import annotations

import math
from collections.abc import Iterator
from dataclasses import replace
from typing import Any

import numpy as np

from ins_hil.core_parts.contract import _vec3
from ins_hil.nav.rotation import dcm_from_quat
from ins_hil.types import FixType, GnssFix

from . import _INF, Aid, AidSource


class GnssAid(Aid):
    def __init__(self, core: Any) -> None:
        from ins_hil.core_parts import gnss  # the models (they load the filter: not at import, see the registry)

        self.core = core
        self.position, self.velocity = gnss.gnss_position, gnss.gnss_velocity

    def parts(self, meas: GnssFix) -> tuple[GnssFix, ...]:
        """Position at ``t`` and, with ``gnss.vel_delay``, the velocity at its own (earlier) time of validity."""
        d = self.core.cfg.gnss.vel_delay
        if d > 0 and meas.vel_ned is not None:
            return replace(meas, vel_ned=None), replace(meas, t=meas.t - d, lat=math.nan)
        return (meas,)

    def arrive(self, meas: GnssFix) -> None:
        self.core.yaw_reset.gnss(meas)  # the yaw bank runs from the first fix (core_parts/yaw_reset.py)

    def align(self, meas: GnssFix) -> None:
        core = self.core
        if core.yaw_gsf is not None and meas.vel_ned is not None:
            core.yaw_gsf.fuse_velocity(np.asarray(meas.vel_ned), meas.std_vel)
        core.align.meas(meas)

    def fuse(self, meas: GnssFix, assume_now: bool = False) -> Iterator[None]:
        """Position (with the reset after ``gnss.reset_after`` rejections), then velocity; yields between them."""
        core, gnss_position, gnss_velocity = self.core, self.position, self.velocity
        s = core.ins.state
        C = dcm_from_quat(s.q_nb)
        c = core.cfg
        if not math.isfinite(meas.lat):  # velocity-only (gnss.vel_delay)
            if c.gnss.use_vel and meas.vel_ned is not None:
                core._apply(gnss_velocity(meas, s, C, core.omega_b, core.idx, c), meas.t)
            return
        m = gnss_position(meas, s, C, core.idx, c, assume_now)
        st = core.stats["gnss_pos"]
        force = st.consecutive_rejects >= c.gnss.reset_after and core.gnss_reset.ok(
            meas, m, core.kf.P, s.vel_ned, core.kf.P.diagonal()[3:6]
        )
        if force and core.gnss_reset.diverged:
            core._recover(meas, core.gnss_reset.track_vel)
            m = gnss_position(meas, s, C, core.idx, c, assume_now)
        if force:
            # GNSS rejected for too long: the INS has drifted, re-initialise position/velocity σ
            core.kf.set_state_sigma("pos", np.sqrt(m.z * m.z + m.r))
            zv = np.zeros(3) if meas.vel_ned is None else np.asarray(meas.vel_ned) - s.vel_ned
            core.kf.set_state_sigma("vel", np.abs(zv) + 0.1)
            core.stats["gnss_vel"].consecutive_rejects = 0
            if not core.replaying:
                core.gnss_resets += 1
        accepted = core._apply(m, meas.t, force)
        if not core.replaying:
            core.gnss_reset.note(meas, accepted, st.last_ratio)
            if accepted and core.hold is not None:
                core.hold.gnss(meas.t, meas.lat, meas.lon, meas.h)
        if accepted:
            core.baro.gnss_height(meas, C, max(meas.std_d, c.gnss.min_std[1]) * c.gnss.std_scale)
        if c.gnss.use_vel and meas.vel_ned is not None:
            yield  # a real-time caller may run an IMU step here (the fix is then ≤ 1 step older)
            s = core.ins.state
            core._apply(gnss_velocity(meas, s, dcm_from_quat(s.q_nb), core.omega_b, core.idx, c), meas.t)
        if not core.replaying:
            core._yaw_check(meas)  # EKF2's emergency yaw reset when the velocity fails against the yaw bank


class GnssSource(AidSource):
    name = "gnss"
    sample = GnssFix
    record = 2
    # t, lat, lon, h, vel[3], std_ne, std_d, std_vel, t_arrival_ns, has_vel, fix_type, num_sats, source
    record_fmt = "10dqBBBB"
    reasons = ("gnss_fix_type", "gnss_nonfinite", "gnss_position", "gnss_height", "gnss_velocity", "gnss_std",
               "gnss_time")  # fmt: skip
    kinds = ("gnss_pos", "gnss_vel")
    drift_monitor = True
    split_check = True

    def enabled(self, nav: Any) -> bool:
        return True

    def check(self, meas: GnssFix) -> None:
        """A finite time; lat/lon/h finite (lat = NaN: a velocity-only record, lon and h unused); σ (``std_ne``,
        ``std_d``, ``std_vel``) finite numbers ≥ 0; the velocity (when given) 3 finite numbers."""
        super().check(meas)
        # lat = NaN: a velocity-only record (lon, h unused), as the core itself splits a fix (gnss.vel_delay)
        for k in () if math.isnan(meas.lat) else ("lat", "lon", "h"):
            v = getattr(meas, k)
            if not abs(v) < _INF:
                raise ValueError(f"NavCore.fuse: GnssFix.{k} = {v!r}: must be a finite number")
        for k in ("std_ne", "std_d", "std_vel"):
            v = getattr(meas, k)
            if not 0.0 <= v < _INF:
                raise ValueError(f"NavCore.fuse: GnssFix.{k} = {v!r}: must be a finite number >= 0")
        if meas.vel_ned is not None:
            _vec3(meas.vel_ned, "NavCore.fuse: GnssFix.vel_ned")

    def validate(self, v: Any, g: GnssFix) -> str | None:
        """Fix type ≥ ``gnss_min_fix_type``; lat/lon in range, height in [``gnss_h_min_m``, ``gnss_h_max_m``];
        the velocity finite below ``gnss_speed_max_mps``; σ finite, > 0 and below ``gnss_std_max_m`` /
        ``gnss_std_vel_max_mps``; the time strictly increasing per receiver (``source``)."""
        lim = v.limits
        if not g.fix_type >= lim.gnss_min_fix_type:
            return "gnss_fix_type"
        fin = math.isfinite
        if not (fin(g.t) and fin(g.lat) and fin(g.lon) and fin(g.h)):
            return "gnss_nonfinite"
        if not (-math.pi / 2 <= g.lat <= math.pi / 2 and -math.pi <= g.lon <= math.pi):
            return "gnss_position"
        if not lim.gnss_h_min_m <= g.h <= lim.gnss_h_max_m:
            return "gnss_height"
        vel = g.vel_ned
        if vel is not None:
            try:
                v0, v1, v2 = (float(x) for x in vel)
            except (TypeError, ValueError):
                return "gnss_velocity"
            if not v0 * v0 + v1 * v1 + v2 * v2 < lim.gnss_speed_max_mps**2:  # NaN/inf fail too
                return "gnss_velocity"
        smax = lim.gnss_std_max_m
        if not (0 < g.std_ne < smax and 0 < g.std_d < smax and 0 < g.std_vel < lim.gnss_std_vel_max_mps):
            return "gnss_std"
        last = v.last_time("gnss", g.source)
        if not g.t > last:
            return "gnss_time"
        v.set_time("gnss", g.source, g.t)
        return None

    def starts_core(self, s: GnssFix) -> bool:
        return s.fix_type >= FixType.FIX_3D

    def fields(self, s: GnssFix) -> tuple[Any, ...]:
        vel = s.vel_ned if s.vel_ned is not None else (0.0, 0.0, 0.0)
        return (s.t, s.lat, s.lon, s.h, float(vel[0]), float(vel[1]), float(vel[2]), s.std_ne, s.std_d, s.std_vel,
                s.t_arrival_ns, s.vel_ned is not None, int(s.fix_type), s.num_sats & 0xFF, s.source & 0xFF)  # fmt: skip

    def build(self, vals: tuple[Any, ...]) -> GnssFix:
        t, lat, lon, h, vn, ve, vd, sne, sd, sv, arr, hv, ft, ns, src = vals
        return GnssFix(t, lat, lon, h, np.array((vn, ve, vd)) if hv else None, sne, sd, sv, FixType(ft), ns, src, arr)

    def stat_kinds(self, nav: Any) -> tuple[str, ...]:
        return self.kinds

    def bind(self, core: Any) -> GnssAid:
        return GnssAid(core)


SOURCE = GnssSource()
