"""Fault injection on IMU sample streams (redundant sets and single triads).

Failure modes (``ins_hil.types.FaultMode``), applied to one sensor (one column
of increments) from ``t_start`` for ``duration`` seconds; ``size`` is in the
sensor's rate unit (rad/s for gyros, m/s² for accelerometers) unless noted:

* STEP_BIAS: constant bias ``size`` added.
* RAMP: drift growing at ``size`` per second (rad/s² or m/s³) from ``t_start``.
* STUCK: output frozen at its last value before ``t_start`` (size unused).
* DROPOUT: no output (NaN increments; the monitor treats NaN or a missing unit as dropout).
* NOISE_BURST: extra white noise of standard deviation ``size`` per sample.
* SATURATION: output clipped at ±``size`` (a sensor saturating far below its range).
* SCALE_FACTOR: output multiplied by (1 + ``size``) (dimensionless).

Deterministic for a given ``seed``. Increments are rate × dt, so a bias b adds b·dt.
"""

from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass

import numpy as np

from ins_hil.nav import earth
from ins_hil.sim.redundant import RedundantSeries
from ins_hil.sim.sensors import ImuSeries
from ins_hil.types import BaroSample, FaultMode, GnssFix, Vec


@dataclass(frozen=True)
class FaultSpec:
    """One injected fault: ``mode`` on row ``sensor`` of group ``"gyro"``/``"accel"`` (see module doc)."""

    mode: FaultMode
    sensor: int
    t_start: float
    size: float = 0.0
    group: str = "gyro"
    duration: float = math.inf

    def __post_init__(self) -> None:
        if self.group not in ("gyro", "accel"):
            raise ValueError(f"FaultSpec.group must be 'gyro' or 'accel', got {self.group!r}")
        if self.mode in (FaultMode.UNKNOWN, FaultMode.JUMP, FaultMode.DRIFT):
            raise ValueError(f"FaultSpec.mode {self.mode.name} is not an inertial-sensor fault to inject")
        if self.mode == FaultMode.SATURATION and self.size <= 0:
            raise ValueError(f"FaultSpec: SATURATION needs a positive clip level, got size={self.size}")
        if self.duration <= 0:
            raise ValueError(f"FaultSpec.duration must be positive, got {self.duration}")


def inject_column(inc: Vec, t: Vec, dt: float, spec: FaultSpec, seed: int = 0) -> Vec:
    """A copy of one sensor's increments (N,) with the fault applied; ``t`` are interval end times."""
    out = np.array(inc, dtype=np.float64, copy=True)
    t0 = t - dt  # interval start
    on = (t0 >= spec.t_start - 1e-12) & (t0 < spec.t_start + spec.duration - 1e-12)
    if not on.any():
        return out
    m = spec.mode
    if m == FaultMode.STEP_BIAS:
        out[on] += spec.size * dt
    elif m == FaultMode.RAMP:
        tm = t0[on] + 0.5 * dt - spec.t_start
        out[on] += spec.size * tm * dt
    elif m == FaultMode.STUCK:
        k0 = int(np.argmax(on))
        out[on] = out[k0 - 1] if k0 > 0 else 0.0
    elif m == FaultMode.DROPOUT:
        out[on] = np.nan
    elif m == FaultMode.NOISE_BURST:
        rng = np.random.default_rng(seed)
        out[on] += rng.normal(0.0, spec.size, int(on.sum())) * dt
    elif m == FaultMode.SATURATION:
        lim = spec.size * dt
        out[on] = np.clip(out[on], -lim, lim)
    elif m == FaultMode.SCALE_FACTOR:
        out[on] *= 1.0 + spec.size
    else:  # pragma: no cover - guarded in __post_init__
        raise ValueError(f"unsupported fault mode {m!r}")
    return out


def inject(series: RedundantSeries, spec: FaultSpec, seed: int = 0) -> RedundantSeries:
    """A copy of a redundant series with ``spec`` applied to one sensor row."""
    n = series.geometry.n
    if not 0 <= spec.sensor < n:
        raise ValueError(f"FaultSpec.sensor={spec.sensor} out of range for {series.geometry.name} ({n} rows)")
    out = series.copy()
    arr = out.gyro if spec.group == "gyro" else out.accel
    arr[:, spec.sensor] = inject_column(arr[:, spec.sensor], series.t, series.dt, spec, seed)
    return out


def inject_imu(series: ImuSeries, spec: FaultSpec, seed: int = 0) -> ImuSeries:
    """A copy of a single-triad :class:`ImuSeries` with ``spec`` applied to axis ``spec.sensor`` (0..2)."""
    if not 0 <= spec.sensor < 3:
        raise ValueError(f"FaultSpec.sensor={spec.sensor}: a triad has axes 0..2")
    arr = (series.dtheta if spec.group == "gyro" else series.dvel).copy()
    arr[:, spec.sensor] = inject_column(arr[:, spec.sensor], series.t, series.dt, spec, seed)
    if spec.group == "gyro":
        return ImuSeries(series.t, series.dt, arr, series.dvel, series.gyro_bias, series.accel_bias, series.flags)
    return ImuSeries(series.t, series.dt, series.dtheta, arr, series.gyro_bias, series.accel_bias, series.flags)


# --------------------------------------------------------------------------- aiding sensors
# GNSS / baro faults on measurement lists (``ins_hil.sim.sensors.gnss_fixes`` / ``baro_samples``).
# Offsets are NED metres (down positive) applied from ``t_start`` for ``duration`` seconds.


def _gnss_offset(f: GnssFix, d_ned: Vec, dv_ned: Vec | None) -> GnssFix:
    m, n = earth.radii(f.lat)
    vel = f.vel_ned
    if dv_ned is not None and vel is not None:
        vel = np.asarray(vel, dtype=np.float64) + dv_ned
    return dataclasses.replace(
        f,
        lat=f.lat + float(d_ned[0]) / (m + f.h),
        lon=f.lon + float(d_ned[1]) / ((n + f.h) * math.cos(f.lat)),
        h=f.h - float(d_ned[2]),
        vel_ned=vel,
    )


def gnss_jump(fixes: list[GnssFix], t_start: float, offset_ned: Vec, duration: float = math.inf) -> list[GnssFix]:
    """Copies of ``fixes`` with a constant position offset (m, NED) while t ∈ [t_start, t_start + duration)."""
    off = np.asarray(offset_ned, dtype=np.float64)
    return [_gnss_offset(f, off, None) if t_start <= f.t < t_start + duration else f for f in fixes]


def gnss_drift(
    fixes: list[GnssFix],
    t_start: float,
    rate_ned: Vec,
    match_velocity: bool = False,
    duration: float = math.inf,
) -> list[GnssFix]:
    """A slow drift / spoofing-like pull: position offset ``rate_ned``·(t − t_start) (m/s, NED).

    With ``match_velocity`` the reported velocity carries the same ``rate_ned`` (a consistent pull);
    otherwise only the position moves. After ``duration`` the fixes are healthy again."""
    r = np.asarray(rate_ned, dtype=np.float64)
    return [
        _gnss_offset(f, r * (f.t - t_start), r if match_velocity else None)
        if t_start <= f.t < t_start + duration
        else f
        for f in fixes
    ]


def baro_drift(samples: list[BaroSample], t_start: float, rate: float, duration: float = math.inf) -> list[BaroSample]:
    """Baro altitude drifting at ``rate`` (m/s, up positive) from ``t_start``; pressure recomputed (ISA)."""
    from ins_hil.nav.earth import pressure_from_altitude

    out = []
    for s in samples:
        if t_start <= s.t < t_start + duration:
            alt = s.altitude + rate * (s.t - t_start)
            s = dataclasses.replace(s, altitude=alt, pressure=pressure_from_altitude(alt))
        out.append(s)
    return out
