"""The learnt baro datum: the offset from barometric altitude to ellipsoidal height, calibrated against GNSS."""

from __future__ import annotations

import math
from typing import NamedTuple

import numpy as np

from ins_hil.fusion import measurements as mm
from ins_hil.fusion.ekf import ErrorStateEKF
from ins_hil.nav import earth
from ins_hil.nav.mechanization import StrapdownNED
from ins_hil.types import BaroSample, GnssFix, Vec

from .contract import Measurement


def baro_altitude(meas: BaroSample) -> float:
    """Barometric altitude (m above the baro datum): the sample's, else from its static pressure (Pa)."""
    if math.isfinite(meas.altitude):
        return meas.altitude
    return earth.altitude_from_pressure(meas.pressure)


_new = tuple.__new__  # a NamedTuple without its generated __new__ (a snapshot per IMU step)


class BaroSnapshot(NamedTuple):
    """The datum's state at one step (:meth:`BaroDatum.snapshot`)."""

    offset: float | None
    offset_var: float
    t_baro: float
    baro_dt: float
    t_gnss_ok: float
    h_gnss: float
    gnss_var_d: float
    gnss_dt: float


class BaroDatum:
    """Baro datum offset (baro altitude → ellipsoidal height, m) and the GNSS height it learns from.

    std: baro noise σ (m); tau: learning time constant (s; 0 = no learning); fixed: a configured offset (m;
    None = from the first sample, then learnt); lever_b: IMU → GNSS antenna (m, body FRD).
    """

    def __init__(self, std: float, tau: float, fixed: float | None, lever_b: Vec) -> None:
        self.std, self.tau, self.fixed, self.lever_b = std, tau, fixed, lever_b
        self.offset: float | None = None
        self.offset_var = 0.0  # m²
        self.t_baro = 0.0  # s, the last baro sample
        self.baro_dt = 0.04  # s between baro samples (the last interval seen)
        self.t_gnss_ok = -math.inf  # s, the last healthy GNSS height
        self.h_gnss = 0.0  # m, the IMU height of that fix
        self.gnss_var_d = 1.0  # m², its variance
        self.gnss_dt = 1.0  # s between GNSS heights (the last interval seen, ≤ 1 s)

    def snapshot(self) -> BaroSnapshot:
        return _new(BaroSnapshot, (self.offset, self.offset_var, self.t_baro, self.baro_dt, self.t_gnss_ok,
                                   self.h_gnss, self.gnss_var_d, self.gnss_dt))  # fmt: skip

    def restore(self, d: BaroSnapshot) -> None:
        (self.offset, self.offset_var, self.t_baro, self.baro_dt, self.t_gnss_ok, self.h_gnss, self.gnss_var_d,
         self.gnss_dt) = d  # fmt: skip

    def gnss_height(self, meas: GnssFix, C: Vec, std_d: float) -> None:
        """Note a healthy GNSS height: the IMU height (m, antenna height + lever arm turned by ``C`` = C_b^n),
        its time and variance (``std_d`` m, the fused σ)."""
        if meas.t > self.t_gnss_ok:
            self.gnss_dt = min(meas.t - self.t_gnss_ok, 1.0)  # the GNSS interval (s; ≤ 1 s)
        self.t_gnss_ok = meas.t
        self.h_gnss = meas.h + float((C @ self.lever_b)[2])
        self.gnss_var_d = std_d * std_d

    def learn(self, t: float, alt: float) -> None:
        """While GNSS is healthy (fused, or received within 0.5 s before navigation), learn the datum against the
        GNSS height: a first-order filter, τ = ``tau``; against GNSS, not the filter height, which the baro itself
        drives. Before navigation the first sample with a GNSS height starts it, so that the baro holds the height
        from the first navigation step."""
        if self.fixed is None and self.tau > 0 and abs(t - self.t_gnss_ok) < 0.5:
            if self.offset is None:
                self.offset, self.offset_var = self.h_gnss - alt, self.gnss_var_d
            else:
                dt = max(0.0, t - self.t_baro)
                a = min(1.0, dt / self.tau)
                self.offset += a * (self.h_gnss - alt - self.offset)
                # each GNSS height is used by the k baro samples until the next one: its error enters k times
                # coherently, (k a)² σ_g² per k samples; the baro noise once per sample
                k = max(1.0, self.gnss_dt / dt) if dt > 0.0 else 1.0
                var_in = self.std**2 + k * self.gnss_var_d
                self.offset_var = (1 - a) ** 2 * self.offset_var + a * a * var_in
                if dt > 0.0:
                    self.baro_dt = dt
        self.t_baro = t

    def measurement(self, meas: BaroSample, ins: StrapdownNED, kf: ErrorStateEKF, gate: float) -> Measurement:
        """The baro height update (datum started or learnt first)."""
        s = ins.state
        alt = baro_altitude(meas)
        if self.offset is None:
            # no datum learnt during the alignment: configured, or from the first sample
            self.offset = self.fixed if self.fixed is not None else s.h - alt
            self.offset_var = float(kf.P[2, 2])
            self.t_baro = meas.t
        else:
            self.learn(meas.t, alt)
        z, H = mm.baro_height(kf.idx, s.h, alt + self.offset)
        # a learnt datum's error is common to the samples within its correlation time (≈ tau, the learning's
        # time constant): fused as white noise it enters R with the variance it has over the 2τ/Δt samples it
        # spans (the equivalent information of correlated noise), not once per sample
        r_b = self.std**2
        if self.fixed is None:
            r_b += self.offset_var * max(1.0, 2.0 * self.tau / max(self.baro_dt, 1e-3))
        return Measurement("baro", z, H, np.array((r_b,)), gate)
