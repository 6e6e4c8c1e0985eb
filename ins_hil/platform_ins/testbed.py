"""Simulated test bed for the seed-004 platform-INS corrections (DIGEST_001_004 §4.6).

The seed's laboratory run (a Ts-060K platform INS on a three-axis test bed with the
harmonic moments of eq. 22) publishes no data or parameters, so this is a simulation with
parameters of our own (:class:`TestbedConfig`, all stated):

* truth: the nonlinear error model eq. (1) (corrected reading) with first-order
  Gauss–Markov drifts ω_E^dr, ω_N^dr, a constant ω_up^dr, accelerometer offsets B_E, B_N and
  an initial velocity error, integrated by RK4 together with δφ̇ = δv_N/R and Φ̇_up = ω_up^dr
  (the seed gives no equations for these two); the test bed's harmonic moments eq. (22)
  M_i = M_i0 sin ωt deflect the platform by Φ_osc,i = (M_i0 / k_s) sin ωt (k_s: our
  stabilisation-loop stiffness), added to the deviation-angle rates;
* flight: constant velocity, optionally with manoeuvres (horizontal acceleration pulses);
* sensors: the three gyros' precession angles from eq. (2) (M = 0) plus white noise; the
  platform accelerometers a^p = C(Φ) f + B + noise (rows of eq. 1's C(Φ));
* corrections, all on the north channel x = (δv_N, Φ_E, ω_E^dr) of eq. (13) at step T:
  the classical one (accelerometer measurement z2 = Φ_E g + δa_y of eqs. 8–10, a
  conventional KF, measurements skipped while the INS indicates horizontal acceleration),
  and the reduced-measurement one (Φ from the precession angles by eq. 5 → moving average
  → S⁻¹z* of eq. 21 → the adaptive KF), also run non-adaptively for comparison.

Metric: RMS over the run after ``settle`` s of the output error (true error − estimate;
the uncorrected output's error is the true error itself), improvement = 1 − RMS_corr / RMS_uncorr.
The reduced-measurement estimate of epoch k is available at k + 2 (it needs z_{k+2}) and the
centred smoothing windows look half a window ahead: the comparison is of delayed estimates.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from ins_hil.types import Vec

from . import model as pi
from .adaptive import AdaptiveKF


@dataclass(frozen=True)
class TestbedConfig:
    """Parameters of the simulated run (ours: the seed gives none)."""

    duration: float = 7200.0  # s
    dt: float = 0.1  # s, simulation and sensor sampling step
    T: float = 30.0  # s, filter step of eq. (13)
    lat0: float = math.radians(55.75)  # rad
    v0: tuple[float, float] = (0.0, 200.0)  # (v_E, v_N) m/s
    manoeuvres: bool = True
    # pulses (t_start s, duration s, a_E m/s², a_N m/s²); each is followed by its opposite
    pulses: tuple[tuple[float, float, float, float], ...] = (
        (600.0, 40.0, 0.0, 1.0),
        (1500.0, 60.0, 1.5, 0.0),
        (2400.0, 40.0, 0.0, -1.0),
        (3300.0, 60.0, -1.5, 0.5),
        (4200.0, 40.0, 0.5, 1.0),
        (5100.0, 60.0, 1.0, -0.5),
        (6000.0, 40.0, -1.0, 0.0),
    )
    drift_rms: float = math.radians(0.05) / 3600.0  # A, rad/s
    beta: float = 1.0 / 3600.0  # 1/s
    drift_up: float = math.radians(0.05) / 3600.0  # rad/s
    bias: tuple[float, float] = (2e-4, -2e-4)  # B_E, B_N m/s²
    dv0: tuple[float, float] = (0.3, 0.3)  # δv_E, δv_N at t = 0, m/s
    J: float = 2e-3  # kg m²
    H: float = 1.0  # N m s
    h: float = 1e-2  # N m s
    osc_amp: tuple[float, float, float] = (5e-5, 5e-5, 5e-5)  # M_i0 / k_s, rad
    osc_freq: float = 2.0 * math.pi / 5.0  # ω of eq. (22), rad/s
    sigma_precession: float = 1e-5  # rad, precession-angle sensor noise per sample
    sigma_accel: float = 5e-4  # m/s², accelerometer noise per sample
    pre_window: int = 3  # samples, moving average on the precession angles
    accel_gate: float = 0.05  # m/s², classical correction skipped above this indicated acceleration
    # nominal noises of the filters (the true ones are "unknown", DIGEST §4.4)
    sigma_z_nom: float = 1e-7  # rad, reduced-measurement angle noise
    drift_rms_nom: float = math.radians(0.01) / 3600.0  # rad/s
    sigma_input_nom: float = 2e-5  # m/s², B_N treated as input noise
    settle: float = 600.0  # s excluded from the metric
    seed: int = 4


def _accel_profile(cfg: TestbedConfig, t: Vec) -> Vec:
    a = np.zeros((len(t), 2))
    if cfg.manoeuvres:
        for t0, d, ae, an in cfg.pulses:
            on = (t >= t0) & (t < t0 + d)
            back = (t >= t0 + d) & (t < t0 + 2 * d)
            a[on] += (ae, an)
            a[back] -= (ae, an)
    return a


@dataclass
class TestbedResult:
    cfg: TestbedConfig
    t: Vec  # s, fine time
    truth: Vec  # (n, 6): δv_E, δv_N, Φ_E, Φ_N, Φ_up, δφ (total platform angles)
    drift: Vec  # (n, 2): ω_E^dr, ω_N^dr
    osc: Vec  # (n, 3): Φ_osc
    phi_first: Vec  # (n, 3): eq. (4) reconstruction
    phi_second: Vec  # (n, 3): eq. (5) reconstruction
    t_k: Vec  # s, filter epochs
    x_true: Vec  # (m, 3): (δv_N, Φ_E − Φ_osc,E, ω_E^dr) at the epochs
    est: dict[str, Vec] = field(default_factory=dict)  # (m, 3) per correction
    cond_S: float = 0.0
    s_inv: Vec = field(default_factory=lambda: np.zeros((3, 3)))
    scales: dict[str, tuple[Vec, Vec]] = field(default_factory=dict)  # (s_Q, s_R) per component at the end
    # per epoch, reduced-measurement filters: Sage–Husa scales (s_Q (m, 3), s_R (m, 3)); NaN before the first update
    scale_hist: dict[str, tuple[Vec, Vec]] = field(default_factory=dict)
    reduced: Vec = field(default_factory=lambda: np.zeros((0, 3)))  # (m − 2, 3): y_k = S⁻¹z*_k of eq. 21
    z_phi: Vec = field(default_factory=lambda: np.zeros(0))  # (m,): smoothed Φ_E (eq. 5) at the epochs, rad
    z_acc: Vec = field(default_factory=lambda: np.zeros(0))  # (m,): smoothed a_y^p (eq. 8), m/s²
    gated: Vec = field(default_factory=lambda: np.zeros(0, dtype=bool))  # (m,): level-flight measurement skipped


def simulate(cfg: TestbedConfig = TestbedConfig()) -> TestbedResult:
    """Run the test bed: truth, sensors, the classical and the reduced-measurement corrections."""
    rng = np.random.default_rng(cfg.seed)
    dt = cfg.dt
    n = round(cfg.duration / dt) + 1
    t = dt * np.arange(n)
    acc = _accel_profile(cfg, t)
    vel = np.empty((n, 2))
    vel[0] = cfg.v0
    vel[1:] = cfg.v0 + np.cumsum(acc[:-1], axis=0) * dt
    lat = cfg.lat0 + np.concatenate([[0.0], np.cumsum(vel[:-1, 1]) * dt]) / pi.R_EARTH
    amp = np.asarray(cfg.osc_amp)
    w = cfg.osc_freq
    osc = np.outer(np.sin(w * t), amp)
    J, H, h = cfg.J, cfg.H, cfg.h
    ebt = math.exp(-cfg.beta * dt)
    q_gm = cfg.drift_rms * math.sqrt(1.0 - ebt * ebt)
    drift = np.empty((n, 2))
    drift[0] = cfg.drift_rms * rng.standard_normal(2)
    for k in range(1, n):
        drift[k] = ebt * drift[k - 1] + q_gm * rng.standard_normal(2)

    # state: δv_E, δv_N, Φ_E, Φ_N, Φ_up, δφ, δ, λ, ϑ, δ̇, λ̇, ϑ̇
    def rhs(tt: float, s: Vec, k: int) -> Vec:
        f = (acc[k, 0], acc[k, 1], pi.G)
        v = (vel[k, 0], vel[k, 1], 0.0)
        dr = (drift[k, 0], drift[k, 1], cfg.drift_up)
        err = pi.error_rates(s[:5], f, v, lat[k], dr, cfg.bias, dlat=s[5])
        osc_dot = amp * w * math.cos(w * tt)
        phi_dot = np.array([err[2] + osc_dot[0], err[3] + osc_dot[1], cfg.drift_up + osc_dot[2]])
        gy = pi.precession_accel(s[6:9], s[9:12], s[2:5], phi_dot, J, H, h)
        return np.concatenate([err[:2], phi_dot, [s[1] / pi.R_EARTH], s[9:12], gy])

    s = np.zeros(12)
    s[0], s[1] = cfg.dv0
    out = np.empty((n, 12))
    out[0] = s
    for k in range(n - 1):
        tk = t[k]
        k1 = rhs(tk, s, k)
        k2 = rhs(tk + 0.5 * dt, s + 0.5 * dt * k1, k)
        k3 = rhs(tk + 0.5 * dt, s + 0.5 * dt * k2, k)
        k4 = rhs(tk + dt, s + dt * k3, k)
        s = s + dt / 6.0 * (k1 + 2 * k2 + 2 * k3 + k4)
        out[k + 1] = s

    prec = out[:, 6:9] + cfg.sigma_precession * rng.standard_normal((n, 3))
    phi1 = pi.reconstruct_angles(prec, dt, J, H, h, order=1, window=cfg.pre_window)
    phi2 = pi.reconstruct_angles(prec, dt, J, H, h, order=2, window=cfg.pre_window)
    # platform accelerometer y: row 2 of C(Φ) f + B_N + noise (the classical measurement)
    pe, pu = out[:, 2], out[:, 4]
    ay = -np.cos(pe) * np.sin(pu) * acc[:, 0] + np.cos(pe) * np.cos(pu) * acc[:, 1] + np.sin(pe) * pi.G
    ay = ay + cfg.bias[1] + cfg.sigma_accel * rng.standard_normal(n)

    step = round(cfg.T / dt)
    idx = np.arange(0, n, step)
    win = step  # post-smoothing over one filter step (Fig. 6); removes the 5 s oscillation
    z_phi = pi.moving_average(phi2[:, 0], win)[idx]
    z_acc = pi.moving_average(ay, win)[idx]
    a_ind = pi.moving_average(np.abs(acc[:, 0]) + np.abs(acc[:, 1]), win)[idx]
    x_true = np.column_stack([out[idx, 1], out[idx, 2] - osc[idx, 0], drift[idx, 0]])

    T = cfg.T
    F = pi.north_channel_F(T, beta=cfg.beta)
    S = pi.observability_matrix(F)
    Si = pi.s_inverse(T, beta=cfg.beta)
    q_nom = np.array(
        [(T * cfg.sigma_input_nom) ** 2, (T * 1e-9) ** 2, cfg.drift_rms_nom**2 * (1 - math.exp(-2 * cfg.beta * T))]
    )
    P0 = np.diag([0.5**2, 1e-4**2, (3 * cfg.drift_rms_nom) ** 2])
    est: dict[str, Vec] = {}
    scales: dict[str, tuple[Vec, Vec]] = {}
    scale_hist: dict[str, tuple[Vec, Vec]] = {}

    # classical: z = a_y^p = Φ_E g + δa_y, level unaccelerated flight only (eqs. 8–10)
    for name, gated in (("classical", True), ("classical, ungated", False)):
        kf = AdaptiveKF(
            F, np.array([[0.0, pi.G, 0.0]]), q_nom, [(cfg.sigma_accel**2 / win)], np.zeros(3), P0.copy(), adapt=False
        )
        xs = np.empty((len(idx), 3))
        xs[0] = kf.x
        for k in range(1, len(idx)):
            if a_ind[k] < cfg.accel_gate or not gated:
                xs[k] = kf.step(np.array([z_acc[k]]))
            else:  # manoeuvre: the level-flight measurement is invalid, predict only
                xs[k] = kf.predict()
        est[name] = xs

    # reduced measurements: y_k = S⁻¹ (z_k, z_{k+1}, z_{k+2}) ≈ x_k, H = I
    y = pi.reduced_measurements(z_phi, T, beta=cfg.beta)
    r_nom = Si @ (cfg.sigma_z_nom**2 * np.eye(3)) @ Si.T
    for name, adapt in (("reduced adaptive", True), ("reduced non-adaptive", False)):
        kf = AdaptiveKF(F, np.eye(3), q_nom, r_nom, np.zeros(3), P0.copy(), adapt=adapt)
        xs = np.full((len(idx), 3), np.nan)
        hq, hr = np.full((len(idx), 3), np.nan), np.full((len(idx), 3), np.nan)
        xs[0] = kf.x
        for k in range(1, len(y)):
            xs[k] = kf.step(y[k])
            hq[k], hr[k] = kf.q_scales, kf.r_scales
        est[name] = xs
        scales[name] = (kf.q_scales, kf.r_scales)
        scale_hist[name] = (hq, hr)
    return TestbedResult(
        cfg,
        t,
        out[:, :6],
        drift,
        osc,
        phi1,
        phi2,
        t[idx],
        x_true,
        est,
        float(np.linalg.cond(S)),
        Si,
        scales,
        scale_hist,
        y,
        z_phi,
        z_acc,
        a_ind >= cfg.accel_gate,
    )


STATE_NAMES = ("velocity δv_N", "deviation angle Φ_E", "drift ω_E^dr")


def improvements(res: TestbedResult) -> dict[str, tuple[float, float, float]]:
    """Per correction: improvement (%) of velocity, deviation angle and drift, 100 (1 − RMS_corr / RMS_uncorr)."""
    keep = res.t_k >= res.cfg.settle
    out: dict[str, tuple[float, float, float]] = {}
    for name, xs in res.est.items():
        ok = keep & np.all(np.isfinite(xs), axis=1)
        e = res.x_true[ok] - xs[ok]
        u = res.x_true[ok]
        rc = np.sqrt(np.mean(e * e, axis=0))
        ru = np.sqrt(np.mean(u * u, axis=0))
        out[name] = tuple(float(100.0 * (1.0 - a / b)) for a, b in zip(rc, ru, strict=True))  # type: ignore[assignment]
    return out
