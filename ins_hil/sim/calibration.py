"""Simulated calibration runs with known sensor errors (for tests and demos).

* :func:`accel_static_run`: the book's multi-position static test (§4.2.1, 16
  positions, 45° steps about X then Y) with smooth transits between positions.
* :func:`rate_table_run`: the book's rate-table gyro test (§4.2.2, Table 4.1
  tilts, ±ω at each, several rates), the table spinning about the vertical.
* :func:`mag_rotation_run`: a tumbling rotation sequence for the ellipsoid fit.
* :func:`static_noise_record`: a long static rate record with white noise,
  flicker (bias-instability) noise and rate random walk of known sizes, for the
  Allan variance. (The Gauss–Markov drift of :mod:`ins_hil.sim.sensors` has an
  Allan *hump*, not the flat floor that defines B, so it is not used there.)

The motion is a piecewise attitude profile run through
:func:`ins_hil.sim.trajectory.generate` (exact increments incl. Earth rate and
normal gravity) and corrupted by :func:`ins_hil.sim.sensors.corrupt_imu`.
Deterministic for a given seed.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from ins_hil.nav import earth
from ins_hil.nav.calibration import BOOK_ACCEL_POSITIONS, TABLE_4_1_TILTS, accel_references, gyro_references
from ins_hil.sim.sensors import ImuErrorModel, ImuSeries, corrupt_imu, earth_field_ned, mag_samples
from ins_hil.sim.trajectory import Kinematics, Profile, generate
from ins_hil.types import Vec


@dataclass
class Segment:
    """One piece of a table schedule: roll/pitch go smoothly from (r0, p0) to (r1, p1), the
    yaw rate from w0 to w1 (rad/s), over ``duration`` s; ``label`` ≥ 0 marks a measurement step."""

    duration: float
    roll0: float
    pitch0: float
    roll1: float
    pitch1: float
    w0: float
    w1: float
    label: int = -1


def schedule_profile(segments: Sequence[Segment], yaw0: float = 0.0) -> tuple[Profile, Vec]:
    """A trajectory profile (fixed position, attitude only) for a list of segments.

    Returns the profile and the segment start times (len + 1, last = end).
    Transitions use the quintic smoothstep s(u) (C², so the increments are smooth).
    """
    t0 = np.concatenate([[0.0], np.cumsum([s.duration for s in segments])])
    yaw_start = [yaw0]
    for s in segments:  # ∫ yaw rate over a segment = T (w0 + (w1 − w0)/2), since ∫₀¹ s(u) du = 1/2
        yaw_start.append(yaw_start[-1] + s.duration * 0.5 * (s.w0 + s.w1))
    arr = {
        k: np.array([getattr(s, k) for s in segments])
        for k in ("duration", "roll0", "pitch0", "roll1", "pitch1", "w0", "w1")
    }
    ys = np.array(yaw_start[:-1])

    def prof(t: Vec) -> Kinematics:
        t = np.atleast_1d(np.asarray(t, dtype=np.float64))
        i = np.clip(np.searchsorted(t0, t, side="right") - 1, 0, len(segments) - 1)
        T = arr["duration"][i]
        u = np.clip((t - t0[i]) / T, 0.0, 1.0)
        s = u**3 * (10 - 15 * u + 6 * u * u)
        ds = 30 * u * u * (1 - u) ** 2 / T
        big_s = 2.5 * u**4 - 3 * u**5 + u**6  # ∫₀ᵘ s
        dr = arr["roll1"][i] - arr["roll0"][i]
        dp = arr["pitch1"][i] - arr["pitch0"][i]
        dw = arr["w1"][i] - arr["w0"][i]
        e = np.column_stack(
            [arr["roll0"][i] + dr * s, arr["pitch0"][i] + dp * s, ys[i] + T * (arr["w0"][i] * u + dw * big_s)]
        )
        er = np.column_stack([dr * ds, dp * ds, arr["w0"][i] + dw * s])
        z = np.zeros_like(e)
        return Kinematics(e, er, z, z.copy())

    return prof, t0


@dataclass
class CalibrationRun:
    """A simulated calibration log: IMU increments, step labels (−1 = transit) and the truth."""

    imu: ImuSeries
    labels: Vec  # (N,) int
    references: Vec  # (M, 3) reference of step 0..M−1 (m/s² or rad/s, body FRD)
    gyro_model: ImuErrorModel
    accel_model: ImuErrorModel
    lat: float

    @property
    def gyro(self) -> Vec:
        return self.imu.dtheta / self.imu.dt

    @property
    def accel(self) -> Vec:
        return self.imu.dvel / self.imu.dt


def _labels(t_end: Vec, dt: float, t0: Vec, segments: Sequence[Segment]) -> Vec:
    """Label of each interval (ending at t_end) that lies wholly inside a labelled segment."""
    start = t_end - dt
    i = np.clip(np.searchsorted(t0, start + 1e-9, side="right") - 1, 0, len(segments) - 1)
    lab = np.array([s.label for s in segments])[i]
    inside = t_end <= t0[i + 1] + 1e-9
    return np.where(inside, lab, -1)


def _run(
    segments: list[Segment], dt: float, lat: float, gyro: ImuErrorModel, accel: ImuErrorModel, seed: int
) -> tuple[ImuSeries, Vec]:
    prof, t0 = schedule_profile(segments)
    truth = generate(prof, float(t0[-1]), dt, lat, 0.5, 100.0)
    imu = corrupt_imu(truth, gyro, accel, seed)
    return imu, _labels(imu.t, dt, t0, segments)


def accel_static_run(
    gyro: ImuErrorModel,
    accel: ImuErrorModel,
    positions: Sequence[tuple[float, float]] | None = None,
    step_time: float = 20.0,
    transit_time: float = 3.0,
    dt: float = 0.01,
    lat: float = math.radians(50.45),
    seed: int = 0,
) -> CalibrationRun:
    """Multi-position static test: hold each (φ1, φ2) tilt (rad; default the book's 16) for step_time s.

    References: the exact specific force f = C_x(φ1) C_y(φ2) [0, 0, −g(lat, h)] of each step.
    """
    pos = list(BOOK_ACCEL_POSITIONS if positions is None else positions)
    segs: list[Segment] = []
    prev = (0.0, 0.0)
    for k, (p1, p2) in enumerate(pos):
        segs.append(Segment(transit_time, prev[0], prev[1], p1, p2, 0.0, 0.0))
        segs.append(Segment(step_time, p1, p2, p1, p2, 0.0, 0.0, label=k))
        prev = (p1, p2)
    imu, labels = _run(segs, dt, lat, gyro, accel, seed)
    g = earth.normal_gravity(lat, 100.0)
    return CalibrationRun(imu, labels, accel_references(pos, g), gyro, accel, lat)


def rate_table_run(
    gyro: ImuErrorModel,
    accel: ImuErrorModel,
    rates: Sequence[float] = (math.radians(3.0), math.radians(9.0)),
    tilts: Sequence[tuple[float, float]] | None = None,
    step_time: float = 60.0,
    transit_time: float = 4.0,
    dt: float = 0.01,
    lat: float = math.radians(50.45),
    seed: int = 0,
) -> CalibrationRun:
    """Rate-table test (book §4.2.2): at each Table 4.1 tilt spin at +ω then −ω for step_time s.

    Step order and references as :func:`ins_hil.nav.calibration.gyro_references` with the
    latitude (the horizontal Earth rate averages out only over whole revolutions: choose
    step_time as a multiple of 2π/ω).
    """
    tl = list(TABLE_4_1_TILTS if tilts is None else tilts)
    segs: list[Segment] = []
    prev = (0.0, 0.0, 0.0)
    k = 0
    for w in rates:
        for p1, p2 in tl:
            for sgn in (1.0, -1.0):
                segs.append(Segment(transit_time, prev[0], prev[1], p1, p2, prev[2], sgn * w))
                segs.append(Segment(step_time, p1, p2, p1, p2, sgn * w, sgn * w, label=k))
                prev = (p1, p2, sgn * w)
                k += 1
    imu, labels = _run(segs, dt, lat, gyro, accel, seed)
    return CalibrationRun(imu, labels, gyro_references(tl, rates, lat), gyro, accel, lat)


def mag_rotation_run(
    duration: float = 120.0,
    rate: float = 20.0,
    hard_iron: Vec | None = None,
    soft_iron: Vec | None = None,
    std: float = 0.1e-6,
    field_ned: Vec | None = None,
    full_sphere: bool = True,
    seed: int = 3,
) -> tuple[Vec, Vec]:
    """Magnetometer samples (N, 3) in T while tumbling; returns (times, raw field).

    ``full_sphere`` False rotates about the vertical only (a circle: insufficient data).
    """
    dt = 1.0 / rate

    def prof(t: Vec) -> Kinematics:
        t = np.atleast_1d(np.asarray(t, dtype=np.float64))
        if full_sphere:
            w = 2 * math.pi / duration
            e = np.column_stack([3 * w * t, 1.3 * np.sin(2 * w * t), 5 * w * t])
            er = np.column_stack([np.full_like(t, 3 * w), 2.6 * w * np.cos(2 * w * t), np.full_like(t, 5 * w)])
        else:
            w = 2 * math.pi / duration
            e = np.column_stack([np.zeros_like(t), np.zeros_like(t), 2 * w * t])
            er = np.column_stack([np.zeros_like(t), np.zeros_like(t), np.full_like(t, 2 * w)])
        z = np.zeros_like(e)
        return Kinematics(e, er, z, z.copy())

    truth = generate(prof, duration, dt, math.radians(50.45), 0.5, 100.0)
    f = earth_field_ned() if field_ned is None else field_ned
    ms = mag_samples(truth, f, rate, std, hard_iron, soft_iron, seed)
    return np.array([m.t for m in ms]), np.array([m.field_b for m in ms])


def flicker_noise(n: int, dt: float, b: float, rng: np.random.Generator, axes: int = 3) -> Vec:
    """(n, axes) rate noise with two-sided PSD B²/(2π f) (bias instability B), via FFT shaping.

    Its Allan deviation is flat at B·√(2 ln2/π) for dt ≪ τ ≪ n·dt (IEEE 952 C.1.3).
    """
    w = rng.standard_normal((n, axes))
    f = np.fft.rfftfreq(n, dt)
    h = np.zeros_like(f)
    h[1:] = b / np.sqrt(2 * math.pi * f[1:] * dt)  # unit white noise has two-sided PSD dt
    return np.fft.irfft(np.fft.rfft(w, axis=0) * h[:, None], n=n, axis=0)


def static_noise_record(
    duration: float,
    dt: float,
    random_walk: float,
    bias_instability: float = 0.0,
    rate_random_walk: float = 0.0,
    bias: Vec | None = None,
    seed: int = 7,
) -> Vec:
    """Increments (N, 3) of a static sensor: bias + white (N) + flicker (B) + rate random walk (K).

    Units: N in ·/√Hz, B in the rate unit, K in ·/√s (rate unit rad/s or m/s²); output
    increments rate·dt. Fully vectorised, so records of 10⁶ samples take well under a second.
    """
    rng = np.random.default_rng(seed)
    n = round(duration / dt)
    rate = random_walk / math.sqrt(dt) * rng.standard_normal((n, 3))
    if bias_instability > 0:
        rate += flicker_noise(n, dt, bias_instability, rng)
    if rate_random_walk > 0:
        rate += np.cumsum(rate_random_walk * math.sqrt(dt) * rng.standard_normal((n, 3)), axis=0)
    if bias is not None:
        rate += np.asarray(bias)[None, :]
    return rate * dt
