"""Named, seeded simulation scenarios: truth + corrupted IMU + aiding measurements.

``build(name, seed, duration=None)`` returns a :class:`Scenario` with the truth, the
IMU samples, the measurement list (GNSS, baro, magnetometer; time of validity ``t``,
delivery time in ``t_arrival_ns`` when a latency is simulated), the initial state for
the core (with the scenario's initial errors) and the filter settings that suit it as plain data
(``nav``: a ``[core.nav]`` table; ``ins_hil.runtime.pipeline.nav_config(sc.nav)`` is its NavConfig),
so the simulator does not import the core.

Scenarios:
* ``static``: 120 s at rest, MEMS IMU, GNSS 5 Hz, baro, magnetometer (alignment check).
* ``example32``: the book's Example 3.2 (DIGEST_000 §3.8): circle T = 300 s, V = 60 m/s,
  roll oscillation; INS at 20 Hz, σ_ω = 3 arcmin/s, σ_a = 1e−2 m/s² (white, gaussian
  with the book's σ; the book's uniform noise is unspecified, §10 item 19); GNSS 0.1 m/s,
  50 m (the book's values) at one correction per 2 s; magnetometer σ_m = 0.0524 (unit
  vector components) and altimeter σ = 1 m; initial attitude error ≈ 0.1 rad per axis,
  1 % position/velocity errors. Schedule as the book (500 s): [0, 60] free INS, [60, 180]
  GNSS + mag + alt, [180, 420] mag + alt only, [420, 500] all.
* ``example32_gnss``: the same motion and IMU with a modern GNSS (0.5 m, 0.02 m/s at 5 Hz)
  all the time after 60 s, for the steady-state accuracy check (9 states as the book).
* ``coning``: 60 s of coning at rest (2 Hz, 0.05 rad, IMU 200 Hz), GNSS + baro + magnetometer.
* ``uav``: the mission profile (take-off, climb, turns, cruise, descent), MEMS IMU at
  100 Hz, GNSS 5 Hz with 200 ms latency, a 20 s outage and multipath outliers, baro, mag.
* ``uav_modelled``: the same with only the IMU errors the 15-state filter models (biases,
  Gauss–Markov drift, white noise; no scale-factor/misalignment) and no outliers: the
  filter-consistency (NEES/NIS) check.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from ins_hil.nav.mechanization import StrapdownState
from ins_hil.nav.rotation import quat_from_rotvec, quat_mul
from ins_hil.sim import sensors as se
from ins_hil.sim import trajectory as tr
from ins_hil.types import ImuSample

ARCMIN = math.pi / 180.0 / 60.0
NAMES = ("static", "example32", "example32_gnss", "coning", "uav", "uav_modelled")


@dataclass
class Scenario:
    """A ready-to-run simulated scenario."""

    name: str
    truth: tr.TruthSeries
    imu: list[ImuSample]
    meas: list[Any]
    initial: StrapdownState
    nav: dict[str, Any]  # the [core.nav] table (NavConfig sections: "gnss", "mag", ..., "filter")
    info: dict[str, Any] = field(default_factory=dict)


def _initial(truth: tr.TruthSeries, datt: tuple[float, float, float], eps_v: float = 0.0, dpos_m: float = 0.0):
    q = quat_mul(quat_from_rotvec(np.asarray(datt)), truth.q_nb[0])
    v = truth.vel_ned[0] * (1.0 + eps_v)
    lat = truth.lat[0] + dpos_m / 6.37e6
    return StrapdownState(q, v, float(lat), float(truth.lon[0]), float(truth.h[0]), float(truth.t[0]))


def _deliver(meas: list[Any], latency: float) -> list[Any]:
    for m in meas:
        m.t_arrival_ns = round((m.t + latency) * 1e9)
    return meas


def build(name: str, seed: int = 0, duration: float | None = None) -> Scenario:
    """Build scenario ``name`` (one of NAMES) with random seed ``seed``."""
    if name not in NAMES:
        raise ValueError(f"unknown scenario {name!r}; choose one of {', '.join(NAMES)}")
    rng = np.random.default_rng(seed)
    lat0, lon0, h0 = math.radians(45.0), math.radians(30.0), 200.0
    ref = se.earth_field_ned()
    if name == "static":
        T = duration or 120.0
        truth = tr.generate(tr.static_profile(0.02, -0.03, 0.8), T, 0.01, lat0, lon0, h0)
        ser = se.corrupt_imu(truth, se.mems_gyro(rng), se.mems_accel(rng), seed=rng)
        imu = ser.samples()
        meas: list[Any] = se.gnss_fixes(truth, se.GnssModel(rate=5), seed=rng)
        meas += se.baro_samples(truth, seed=rng)
        meas += se.mag_samples(truth, field_ned=ref, rate=10, seed=rng)
        cfg: dict[str, Any] = {
            "alignment": {"mode": "static", "level_only": True},
            "mag": {"ref_ned": ref, "std": 0.01},
        }
        init = StrapdownState(np.array([1.0, 0, 0, 0]), np.zeros(3), lat0, lon0, h0)
        return Scenario(
            name, truth, imu, meas, init, cfg, {"accel_bias": ser.accel_bias[0], "gyro_bias": ser.gyro_bias[0]}
        )
    if name in ("example32", "example32_gnss"):
        T = duration or 500.0
        dt = 0.05  # 20 Hz (book)
        truth = tr.generate(tr.circle_profile(), T, dt, lat0, lon0, h0)
        g = se.ImuErrorModel(noise_density=3 * ARCMIN * math.sqrt(dt))  # σ_ω per sample = 3 arcmin/s
        a = se.ImuErrorModel(noise_density=1e-2 * math.sqrt(dt))  # σ_a = 1e-2 m/s²
        imu = se.corrupt_imu(truth, g, a, seed=rng).samples()
        fcfg = {"gyro_bias": False, "accel_bias": False, "gyro_arw": 3 * ARCMIN * math.sqrt(dt),
                "accel_vrw": 1e-2 * math.sqrt(dt), "init_pos": 57.3, "init_vel": 1.2, "init_att": 0.1,
                "init_yaw": 0.1, "earth_terms": True}  # fmt: skip
        if name == "example32":
            gm = se.GnssModel(rate=0.5, std_ne=50.0, std_d=50.0, std_vel=0.1, outages=[(0, 60), (180, 420)])
            cfg = {"filter": fcfg, "mag": {"ref_ned": ref, "std": 0.0524}, "baro": {"std": 1.0, "offset": 0.0}}
        else:
            gm = se.GnssModel(rate=5.0, std_ne=0.5, std_d=1.0, std_vel=0.02, outages=[(0, 60)])
            cfg = {"filter": fcfg, "mag": {"ref_ned": ref, "std": 0.0524}, "baro": {"std": 1.0, "offset": 0.0}}
        meas = list(se.gnss_fixes(truth, gm, seed=rng))
        mag = se.mag_samples(truth, field_ned=ref, rate=0.5 if name == "example32" else 5.0, std=0.0524 * 50e-6 / 1.0,
                             seed=rng)  # fmt: skip
        meas += [m for m in mag if m.t >= 60.0]
        meas += [b for b in se.baro_samples(truth, rate=0.5 if name == "example32" else 5.0, std=1.0, seed=rng)
                 if b.t >= 60.0]  # fmt: skip
        # book initial errors: attitude ≈ 0.1 rad per axis (quaternion [1, .05, −.05, .05]), 1 % in r and v
        init = _initial(truth, (0.1, -0.1, 0.1), eps_v=0.01, dpos_m=0.01 * 2864.79)
        cfg["gnss"] = {"gate": 10.0}
        cfg["mag"] = {**cfg["mag"], "gate": 10.0}
        return Scenario(name, truth, imu, meas, init, cfg, {"steady_from": 120.0 if name == "example32" else 250.0})
    if name == "coning":
        T = duration or 60.0
        truth = tr.generate(tr.coning_profile(), T, 0.005, lat0, lon0, h0)
        imu = se.corrupt_imu(truth, se.mems_gyro(rng), se.mems_accel(rng), seed=rng).samples()
        meas = [*se.gnss_fixes(truth, se.GnssModel(rate=5), seed=rng), *se.baro_samples(truth, seed=rng)]
        meas += se.mag_samples(truth, field_ned=ref, rate=10, seed=rng)
        init = _initial(truth, (0.01, -0.01, 0.02))
        return Scenario(name, truth, imu, meas, init, {"mag": {"ref_ned": ref, "std": 0.01}, "baro": {"offset": 0.0}})
    # uav, uav_modelled
    T = duration or 240.0
    truth = tr.generate(tr.mission_profile(), T, 0.01, lat0, lon0, h0)
    gyro, accel = se.mems_gyro(rng), se.mems_accel(rng)
    if name == "uav_modelled":  # only the errors the 15-state filter models: biases (GM) and white noise
        gyro.scale_factor = accel.scale_factor = np.zeros(3)
        gyro.misalignment = accel.misalignment = np.zeros((3, 3))
    imu = se.corrupt_imu(truth, gyro, accel, seed=rng).samples()
    gm = se.GnssModel(rate=5, std_ne=1.0, std_d=2.0, std_vel=0.1, outages=[(150.0, 170.0)],
                      outlier_prob=0.01 if name == "uav" else 0.0, outlier_size=20.0, latency=0.2)  # fmt: skip
    meas = [*_deliver(list(se.gnss_fixes(truth, gm, seed=rng)), gm.latency), *se.baro_samples(truth, seed=rng)]
    meas += se.mag_samples(truth, field_ned=ref, rate=10, seed=rng)
    init = _initial(truth, (0.01, -0.01, 0.05))
    # σ_m = 0.2 µT / 50 µT = 0.004 per unit-vector component (the simulated sensor); datum known (QNH-like)
    cfg = {"mag": {"ref_ned": ref, "std": 0.004}, "baro": {"offset": 0.0}}
    return Scenario(name, truth, imu, meas, init, cfg, {"steady_from": 60.0})


@dataclass
class CarRun:
    """The simulated car of the odometer study (:func:`odometer_car`): the truth, the consumer-grade IMU, the GNSS
    fixes without outages, the odometer readings (t s, speed along body x m/s: (1 + ``scale``) × the true speed plus
    noise) and the initial state (yaw 0.02 rad off)."""

    truth: tr.TruthSeries
    imu: list[Any]
    fixes: list[Any]
    odometer: list[tuple[float, float]]
    initial: StrapdownState
    scale: float


def odometer_car(seed: int = 1, duration: float = 100.0, scale: float = 0.03) -> CarRun:
    """The car of the odometer study (docs/accuracy.md): ``car_profile`` at 12 m/s, weaving, at 45° N; a
    consumer-grade IMU (the MEMS models with 100 °/h gyro and 5 mg accelerometer bias instability, τ 60 s: worse
    than the filter's tuning assumes); GNSS 5 Hz (σ 0.1 m, 0.05 m/s); an odometer at 10 Hz (σ 0.05 m/s) reading
    ``scale`` (3 %) fast."""
    from ins_hil.nav import earth
    from ins_hil.nav.rotation import dcm_from_quat, quat_from_euler

    truth = tr.generate(tr.car_profile(speed=12.0, t_start=2.0, t_stop=110.0), duration, 0.01,
                        math.radians(45.0), 0.5, 100.0)  # fmt: skip
    rng = np.random.default_rng(seed)
    g, a = se.mems_gyro(rng), se.mems_accel(rng)
    g.bias_instability, g.bias_tau = math.radians(100.0) / 3600.0, 60.0
    a.bias_instability, a.bias_tau = 5e-3 * earth.G0, 60.0
    imu = se.corrupt_imu(truth, g, a, seed=seed + 1).samples()
    fixes = se.gnss_fixes(truth, se.GnssModel(rate=5, std_ne=0.1, std_d=0.2, std_vel=0.05), seed=seed + 2)
    orng = np.random.default_rng(seed + 3)
    odo = []
    for i in range(10, len(truth.t), 10):
        vb = dcm_from_quat(truth.q_nb[i]).T @ truth.vel_ned[i]
        odo.append((float(truth.t[i]), (1.0 + scale) * float(vb[0]) + float(orng.normal(0.0, 0.05))))
    e = truth.euler[0]
    init = StrapdownState(quat_from_euler(e[0], e[1], e[2] + 0.02), truth.vel_ned[0].copy(), truth.lat[0],
                          truth.lon[0], truth.h[0], truth.t[0])  # fmt: skip
    return CarRun(truth, imu, fixes, odo, init, scale)
