"""GNSS aiding: the position and velocity measurements (lever arm, time alignment to the IMU step) and the
reset after a run of rejected fixes, let through only when the rejected fixes agree with each other, and — when
they are far beyond the gate — only when the INS's own velocity has left the fixes' track (a diverged filter, not a
GNSS jump: EKF2 resets to GNSS after ``EKF2_GPS_TOUT`` of failed checks)."""

from __future__ import annotations

import itertools
import math
from collections import deque

import numpy as np

from ins_hil.fusion import measurements as mm
from ins_hil.fusion.ekf import StateIndex
from ins_hil.fusion.innovation import test_ratio
from ins_hil.nav import earth
from ins_hil.nav.mechanization import StrapdownState
from ins_hil.types import GnssFix, Vec

from .config import NavConfig
from .contract import Measurement

#: a GNSS reset needs every rejected fix within this many gates of the INS (GnssReset.ok)
RESET_GATE_FACTOR = 20.0


def gnss_position(
    meas: GnssFix, s: StrapdownState, C: Vec, idx: StateIndex, c: NavConfig, assume_now: bool
) -> Measurement:
    """The antenna position update (C = C_b^n). Unless ``assume_now``, the fix is shifted by v̂·(t_step − t)
    to the step time (interpolation between IMU samples); σ floored at ``gnss.min_std``, scaled."""
    std_ne = max(meas.std_ne, c.gnss.min_std[0]) * c.gnss.std_scale
    std_d = max(meas.std_d, c.gnss.min_std[1]) * c.gnss.std_scale
    shift = None if assume_now else s.vel_ned * (s.t - meas.t)  # time alignment to the step
    z, H = mm.gnss_position(idx, C, s.lat, s.lon, s.h, meas.lat, meas.lon, meas.h, c.gnss.lever_arm_b, shift)
    return Measurement("gnss_pos", z, H, np.array((std_ne**2, std_ne**2, std_d**2)), c.gnss.gate)


def gnss_velocity(meas: GnssFix, s: StrapdownState, C: Vec, omega_b: Vec, idx: StateIndex, c: NavConfig) -> Measurement:
    """The antenna velocity update (lever-arm rate ω × l with the compensated body rate ``omega_b``, rad/s)."""
    assert meas.vel_ned is not None
    std_v = max(meas.std_vel, c.gnss.min_std[2]) * c.gnss.std_scale
    z, H = mm.gnss_velocity(idx, C, s.vel_ned, omega_b, np.asarray(meas.vel_ned), c.gnss.lever_arm_b)
    return Measurement("gnss_vel", z, H, np.full(3, std_v**2), c.gnss.gate)


class GnssReset:
    """The consecutive rejected GNSS positions with their test ratios, for the reset after ``gnss.reset_after``."""

    def __init__(self, c: NavConfig) -> None:
        self.cfg = c
        self.rejected: deque[tuple[GnssFix, float]] = deque(maxlen=max(1, c.gnss.reset_after))
        self.accepted = False  # a GNSS position has been accepted since the start
        self.diverged = ""  # why the last reset allowed by ok() was a divergence ("" for a drift inside the bound)
        self.track_vel = np.zeros(3)  # the rejected fixes' track velocity (NED m/s) of that divergence

    def note(self, meas: GnssFix, accepted: bool, ratio: float) -> None:
        """Count a fused fix (not during a replay): an accepted one clears the run of rejections."""
        if accepted:
            self.rejected.clear()
            self.accepted = True
        else:
            self.rejected.append((meas, ratio))

    def ok(self, meas: GnssFix, m: Measurement, P: Vec, vel_ins: Vec, var_vel_ins: Vec) -> bool:
        """May a GNSS position rejected ``gnss.reset_after`` times in a row reset the filter (be accepted over
        its gate, position/velocity σ re-initialised)? Only when the rejected fixes pass a consistency test
        of their own, so that junk cannot trigger a reset:

        1. the last ``gnss.reset_after`` rejected fixes and this one agree with each other
           (:func:`gnss_fixes_agree`);
        2. each of them is within ``RESET_GATE_FACTOR`` × the gate of the INS (test ratio ≤ factor²): an
           INS whose position has drifted beyond the gate — unless no GNSS position has been accepted yet (a
           wrong configured start), or the filter has diverged: the INS velocity ``vel_ins`` (NED m/s, variance
           ``var_vel_ins``) is off the fixes' own track (:func:`ins_off_track`). A GNSS jump (or an injected
           offset) moves the fixes but not their track's velocity, so it stays gated.

        Sets :attr:`diverged` to the reason whenever the INS velocity is off the track (a reset of a diverged
        filter, inside the bound or beyond it), "" for a position drift alone.
        """
        c = self.cfg
        self.diverged = ""
        fixes = [(f, q) for f, q in self.rejected if f.t < meas.t]
        if len(fixes) < c.gnss.reset_after:
            return False
        S = m.H @ P @ m.H.T + np.diag(m.r)
        ratio, _ = test_ratio(m.z, S, c.gnss.gate)
        fixes.append((meas, ratio))
        fx = [f for f, _ in fixes]
        if not gnss_fixes_agree(fx, c):
            return False
        off = ins_off_track(fx, vel_ins, var_vel_ins, c)
        if off is None and self.accepted and max(q for _, q in fixes) > RESET_GATE_FACTOR**2:
            return False
        if off is not None:
            self.track_vel = off[1]
            self.diverged = f"the INS velocity is {off[0]:.1f} m/s off the GNSS track"
        return True


def ins_off_track(fixes: list[GnssFix], vel_ins: Vec, var_vel_ins: Vec, c: NavConfig) -> tuple[float, Vec] | None:
    """How far (m/s) the INS velocity (NED m/s, variance m²/s²) is off the velocity of the fixes' own track, when
    beyond ``gnss.gate`` σ of both (χ² over the three axes), with that track velocity (NED m/s); None when it
    agrees. The track's velocity: the last fix's receiver velocity, or without one the last fix's velocity of a
    least-squares quadratic through the positions (a turning track is no straight line)."""
    sc, mn = c.gnss.std_scale, c.gnss.min_std
    last = fixes[-1]
    if last.vel_ned is not None:
        v = np.asarray(last.vel_ned, dtype=float)
        var = np.full(3, (max(last.std_vel, mn[2]) * sc) ** 2)
    else:
        # the velocity at the last fix of a least-squares quadratic p(τ) = a + b τ + c τ², τ = t − t_last: b
        t = np.array([f.t for f in fixes]) - last.t
        if len(fixes) < 4 or float(np.ptp(t)) <= 0.0:
            return None
        A = np.stack([np.ones_like(t), t, t * t], axis=1)
        p = np.array([earth.ned_from_geodetic(f.lat, f.lon, f.h, last.lat, last.lon, last.h) for f in fixes])
        coef, *_ = np.linalg.lstsq(A, p, rcond=None)
        v = coef[1]
        s_ne = max(max(f.std_ne, mn[0]) for f in fixes) * sc
        s_d = max(max(f.std_d, mn[1]) for f in fixes) * sc
        var = np.array((s_ne**2, s_ne**2, s_d**2)) * float(np.linalg.pinv(A.T @ A)[1, 1])
    e = np.asarray(vel_ins, dtype=float) - v
    q = float(np.sum(e * e / (var + np.asarray(var_vel_ins, dtype=float))))
    return (float(np.linalg.norm(e)), v) if q > c.gnss.gate**2 * 3 else None


def gnss_fixes_agree(fixes: list[GnssFix], c: NavConfig) -> bool:
    """Do consecutive GNSS fixes (time order) agree with each other? Each position follows the previous one
    by their mean velocity × Δt (or, without velocities, lies on the straight line through its neighbours),
    within ``gnss.gate`` σ of their own σ (NE, D; m): the consistency test a GNSS reset needs
    (:meth:`GnssReset.ok`, and ``ins_hil.cref.CNavCore`` for the C core), so junk cannot trigger one."""
    g2 = c.gnss.gate**2
    sc = c.gnss.std_scale
    mn = c.gnss.min_std

    def sig(f: GnssFix) -> tuple[float, float, float]:
        return max(f.std_ne, mn[0]) * sc, max(f.std_d, mn[1]) * sc, max(f.std_vel, mn[2]) * sc

    meas = fixes[-1]
    m, n = earth.radii(meas.lat)

    def ned(f: GnssFix) -> tuple[float, float, float]:
        return ((f.lat - meas.lat) * (m + meas.h), (f.lon - meas.lon) * (n + meas.h) * math.cos(meas.lat),
                meas.h - f.h)  # fmt: skip

    pts = [(f.t, ned(f), sig(f), None if f.vel_ned is None else np.asarray(f.vel_ned, dtype=float))
           for f in fixes]  # fmt: skip
    if all(p[3] is not None for p in pts):
        for (t0, p0, s0, v0), (t1, p1, s1, v1) in itertools.pairwise(pts):
            dt = t1 - t0
            assert v0 is not None and v1 is not None
            for k in range(3):
                e = p1[k] - p0[k] - 0.5 * (float(v0[k]) + float(v1[k])) * dt
                sp = s0[0 if k < 2 else 1] ** 2 + s1[0 if k < 2 else 1] ** 2
                if not e * e <= g2 * (sp + 0.25 * (s0[2] ** 2 + s1[2] ** 2) * dt * dt):
                    return False
        return True
    if len(pts) < 3:
        return False
    for (t0, p0, s0, _), (t1, p1, s1, _), (t2, p2, s2, _) in zip(pts, pts[1:], pts[2:], strict=False):
        w = (t1 - t0) / (t2 - t0)
        for k in range(3):
            e = p1[k] - (p0[k] + w * (p2[k] - p0[k]))
            j = 0 if k < 2 else 1
            if not e * e <= g2 * (s0[j] ** 2 + s1[j] ** 2 + s2[j] ** 2):
                return False
    return True
