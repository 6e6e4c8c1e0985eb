"""Sensor error models applied to the ideal outputs of :mod:`ins_hil.sim.trajectory`.

IMU (per axis, body FRD): constant bias (turn-on), bias instability as a
first-order Gauss–Markov process, white noise as angle/velocity random walk,
scale factor and misalignment (one 3×3 matrix ``I + S + M``), quantization
of the increments, and saturation of the rate / specific force.
GNSS: position/velocity noise, latency, outages, multipath-like outliers.
Baro: altitude with noise and a slowly drifting bias. Magnetometer: the Earth
field rotated into body plus hard/soft iron and noise.

Deterministic: every model takes a ``numpy.random.Generator`` (or a seed).
Units: rad, rad/s, m/s, m/s², s, m, T.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from ins_hil.nav import earth
from ins_hil.nav.rotation import dcm_from_quat
from ins_hil.sim.trajectory import TruthSeries
from ins_hil.types import BaroSample, FixType, GnssFix, ImuSample, MagSample, Vec

DEG = math.pi / 180.0
DPH = DEG / 3600.0  # deg/h in rad/s
MG = 1e-3 * earth.G0  # milli-g in m/s^2


@dataclass
class ImuErrorModel:
    """Error parameters of one triad (gyro or accelerometer).

    bias: constant turn-on bias (rad/s or m/s²), per axis.
    bias_instability: 1-σ of the Gauss–Markov bias drift (same unit), with
    correlation time ``bias_tau`` (s).
    noise_density: white-noise density (rad/s/√Hz = ARW, or m/s²/√Hz = VRW).
    scale_factor: per-axis scale-factor error (dimensionless).
    misalignment: 3×3 off-diagonal cross-coupling (rad); diagonal ignored.
    quantization: increment LSB (rad or m/s); 0 = none.
    saturation: |rate| or |specific force| limit; 0 = none.
    """

    bias: Vec = field(default_factory=lambda: np.zeros(3))
    bias_instability: float = 0.0
    bias_tau: float = 300.0
    noise_density: float = 0.0
    scale_factor: Vec = field(default_factory=lambda: np.zeros(3))
    misalignment: Vec = field(default_factory=lambda: np.zeros((3, 3)))
    quantization: float = 0.0
    saturation: float = 0.0

    def matrix(self) -> Vec:
        """Scale-factor/misalignment matrix I + diag(sf) + offdiag(M)."""
        m = np.array(self.misalignment, dtype=np.float64).copy()
        np.fill_diagonal(m, 0.0)
        return np.eye(3) + np.diag(self.scale_factor) + m


def mems_gyro(rng: np.random.Generator | None = None) -> ImuErrorModel:
    """A typical MEMS gyro (UAV-grade): 0.2 °/s turn-on bias, 10 °/h instability,
    0.15 °/√h ARW, 500 ppm scale factor, 1 mrad misalignment, ±2000 °/s range.

    With ``rng`` the bias/scale/misalignment are drawn at those 1-σ levels;
    without, zeros (only the stochastic parts remain).
    """
    m = ImuErrorModel(
        bias_instability=10 * DPH,
        noise_density=0.15 * DEG / 60.0,
        quantization=0.0,
        saturation=2000 * DEG,
    )
    if rng is not None:
        m.bias = rng.normal(0, 0.2 * DEG, 3)
        m.scale_factor = rng.normal(0, 500e-6, 3)
        m.misalignment = rng.normal(0, 1e-3, (3, 3))
    return m


def mems_accel(rng: np.random.Generator | None = None) -> ImuErrorModel:
    """A typical MEMS accelerometer: 20 mg turn-on bias, 0.1 mg instability,
    70 µg/√Hz VRW, 1000 ppm scale factor, 1 mrad misalignment, ±16 g range."""
    m = ImuErrorModel(
        bias_instability=0.1 * MG,
        noise_density=70e-6 * earth.G0,
        saturation=16 * earth.G0,
    )
    if rng is not None:
        m.bias = rng.normal(0, 20 * MG, 3)
        m.scale_factor = rng.normal(0, 1000e-6, 3)
        m.misalignment = rng.normal(0, 1e-3, (3, 3))
    return m


@dataclass
class ImuSeries:
    """Corrupted IMU increments and the error terms that went in (for tests)."""

    t: Vec  # (N,) end time of each interval
    dt: float
    dtheta: Vec  # (N, 3)
    dvel: Vec  # (N, 3)
    gyro_bias: Vec  # (N, 3) total bias (constant + drift), rad/s
    accel_bias: Vec  # (N, 3) m/s^2
    flags: Vec  # (N,) ImuFlags bits

    def samples(self, imu_id: int = 0, seq0: int = 0) -> list[ImuSample]:
        """The series as ImuSample objects."""
        return [
            ImuSample(
                t=float(self.t[k]),
                dt=self.dt,
                dtheta=self.dtheta[k],
                dvel=self.dvel[k],
                imu_id=imu_id,
                seq=(seq0 + k) & 0xFFFF,
                flags=int(self.flags[k]),
            )
            for k in range(len(self.t))
        ]


def _gauss_markov(n: int, dt: float, sigma: float, tau: float, rng: np.random.Generator) -> Vec:
    """(n, 3) first-order Gauss–Markov sequence with stationary 1-σ ``sigma``."""
    out = np.zeros((n, 3))
    if sigma <= 0.0 or n == 0:
        return out
    phi = math.exp(-dt / tau)
    q = sigma * math.sqrt(1.0 - phi * phi)
    w = rng.normal(0.0, q, (n, 3))
    x = rng.normal(0.0, sigma, 3)
    for k in range(n):
        x = phi * x + w[k]
        out[k] = x
    return out


def _corrupt(ideal_inc: Vec, dt: float, m: ImuErrorModel, rng: np.random.Generator) -> tuple[Vec, Vec, Vec]:
    """Apply one triad's errors to increments (N, 3); returns (increments, total bias, saturated mask)."""
    n = len(ideal_inc)
    bias = m.bias[None, :] + _gauss_markov(n, dt, m.bias_instability, m.bias_tau, rng)
    rate = ideal_inc / dt
    sat = np.zeros(n, dtype=bool)
    meas = rate @ m.matrix().T + bias
    if m.noise_density > 0.0:
        # white noise of density N: per-interval mean has σ = N / √dt
        meas = meas + rng.normal(0.0, m.noise_density / math.sqrt(dt), (n, 3))
    if m.saturation > 0.0:
        over = np.abs(meas) > m.saturation
        sat = over.any(axis=1)
        meas = np.clip(meas, -m.saturation, m.saturation)
    inc = meas * dt
    if m.quantization > 0.0:
        # quantize the running sum so no increment is lost (as a real IMU's accumulator)
        cum = np.cumsum(inc, axis=0)
        qcum = np.round(cum / m.quantization) * m.quantization
        inc = np.diff(np.vstack([np.zeros(3), qcum]), axis=0)
    return inc, bias, sat


def corrupt_imu(
    truth: TruthSeries,
    gyro: ImuErrorModel,
    accel: ImuErrorModel,
    seed: int | np.random.Generator = 0,
) -> ImuSeries:
    """Apply gyro and accelerometer error models to the ideal increments of ``truth``."""
    rng = seed if isinstance(seed, np.random.Generator) else np.random.default_rng(seed)
    dth, gb, gsat = _corrupt(truth.dtheta, truth.dt, gyro, rng)
    dv, ab, asat = _corrupt(truth.dvel, truth.dt, accel, rng)
    flags = gsat.astype(np.int64) * 1 + asat.astype(np.int64) * 2
    return ImuSeries(truth.t[1:].copy(), truth.dt, dth, dv, gb, ab, flags)


@dataclass
class GnssModel:
    """GNSS receiver model: rate (Hz), 1-σ noise (m, m/s), latency (s),
    outages as (start, end) sensor-time intervals, and an outlier probability
    with its size (m) for multipath-like jumps."""

    rate: float = 5.0
    std_ne: float = 1.0
    std_d: float = 2.0
    std_vel: float = 0.1
    latency: float = 0.0
    outages: list[tuple[float, float]] = field(default_factory=list)
    outlier_prob: float = 0.0
    outlier_size: float = 20.0
    lever_arm_b: Vec = field(default_factory=lambda: np.zeros(3))


def gnss_fixes(truth: TruthSeries, model: GnssModel, seed: int | np.random.Generator = 1) -> list[GnssFix]:
    """GNSS fixes at ``model.rate`` from the truth (valid at their epoch ``t``).

    The latency is not applied to ``t`` (which is the time of validity);
    a consumer that simulates delivery delays adds ``model.latency`` to the
    arrival time. Lever arm: antenna position = IMU position + C_b^n l_b.
    """
    rng = seed if isinstance(seed, np.random.Generator) else np.random.default_rng(seed)
    step = max(1, round(1.0 / (model.rate * truth.dt)))
    out: list[GnssFix] = []
    for k in range(0, len(truth.t), step):
        t = float(truth.t[k])
        if any(a <= t < b for a, b in model.outages):
            continue
        lat, lon, h = float(truth.lat[k]), float(truth.lon[k]), float(truth.h[k])
        C = dcm_from_quat(truth.q_nb[k])
        d_ned = C @ model.lever_arm_b
        d_ned = d_ned + np.array([rng.normal(0, model.std_ne), rng.normal(0, model.std_ne), rng.normal(0, model.std_d)])
        if model.outlier_prob > 0 and rng.random() < model.outlier_prob:
            d_ned = d_ned + rng.normal(0, model.outlier_size, 3)
        m, n = earth.radii(lat)
        out.append(
            GnssFix(
                t=t,
                lat=lat + d_ned[0] / (m + h),
                lon=lon + d_ned[1] / ((n + h) * math.cos(lat)),
                h=h - d_ned[2],
                vel_ned=truth.vel_ned[k] + rng.normal(0, model.std_vel, 3),
                std_ne=model.std_ne,
                std_d=model.std_d,
                std_vel=model.std_vel,
                fix_type=FixType.FIX_3D,
                num_sats=12,
            )
        )
    return out


def baro_samples(
    truth: TruthSeries,
    rate: float = 25.0,
    std: float = 0.5,
    bias: float = 0.0,
    drift_sigma: float = 0.0,
    drift_tau: float = 600.0,
    seed: int | np.random.Generator = 2,
) -> list[BaroSample]:
    """Barometric altitude samples (altitude above the ellipsoid + bias + noise), with ISA pressure."""
    rng = seed if isinstance(seed, np.random.Generator) else np.random.default_rng(seed)
    step = max(1, round(1.0 / (rate * truth.dt)))
    idx = range(0, len(truth.t), step)
    drift = _gauss_markov(len(idx), step * truth.dt, drift_sigma, drift_tau, rng)[:, 0]
    out = []
    for j, k in enumerate(idx):
        alt = float(truth.h[k]) + bias + float(drift[j]) + rng.normal(0, std)
        out.append(BaroSample(t=float(truth.t[k]), pressure=earth.pressure_from_altitude(alt), altitude=alt))
    return out


def earth_field_ned(declination: float = 0.15, inclination: float = 1.15, intensity: float = 50e-6) -> Vec:
    """Earth magnetic field in NED (T) from declination, inclination (rad) and intensity."""
    h = intensity * math.cos(inclination)
    return np.array([h * math.cos(declination), h * math.sin(declination), intensity * math.sin(inclination)])


def mag_samples(
    truth: TruthSeries,
    field_ned: Vec | None = None,
    rate: float = 50.0,
    std: float = 0.2e-6,
    hard_iron: Vec | None = None,
    soft_iron: Vec | None = None,
    seed: int | np.random.Generator = 3,
) -> list[MagSample]:
    """Magnetometer samples: m_b = S C_n^b m_n + b_hard + noise (T)."""
    rng = seed if isinstance(seed, np.random.Generator) else np.random.default_rng(seed)
    f = earth_field_ned() if field_ned is None else np.asarray(field_ned, dtype=np.float64)
    S = np.eye(3) if soft_iron is None else np.asarray(soft_iron, dtype=np.float64)
    b = np.zeros(3) if hard_iron is None else np.asarray(hard_iron, dtype=np.float64)
    step = max(1, round(1.0 / (rate * truth.dt)))
    out = []
    for k in range(0, len(truth.t), step):
        C = dcm_from_quat(truth.q_nb[k])
        mb = S @ (C.T @ f) + b + rng.normal(0, std, 3)
        out.append(MagSample(t=float(truth.t[k]), field_b=mb))
    return out
