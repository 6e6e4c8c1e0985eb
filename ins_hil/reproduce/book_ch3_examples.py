"""Book Examples 3.1–3.3 (DIGEST_000 §3.6, §3.8, §3.10, §8 case 27) and the §6.1, §6.5 analogues (case 28).

One closed loop, :func:`run`, configured per example (:class:`Setup`): a circle of period T at speed V in
the xy plane, attitude from the classic z-x-z angles ψ = 2πt/T, ϑ, φ = 0.3 sin 10ψ (quaternion
q_z(ψ) ⊗ q_x(ϑ) ⊗ q_z(φ), body rates eq. 2.55 — the λ₂ sign of eq. 2.2 corrected, DIGEST_000 §10 item 1),
flat Earth, Earth rate and Coriolis neglected (as in eq. 3.1 and the examples).

* Sensors: rate samples ω(t_i) and specific-force samples f_b(t_i) at Δt, each plus zero-mean uniform noise of
  standard deviation σ (the book's "variance σ" read as a standard deviation, §10 item 19), plus the constant
  gyro bias n_c of Ex 3.3.
* Mechanization as the examples state: λ_m³ (eq. 2.27) on ∇θ from the quadratic spline (eq. 2.19),
  renormalised each step (the book normalises "only at the end", §10 item 7; λ_m³ grows the norm by
  ‖∇θ‖²/24 per step), and eqs. 2.20–2.21 on ã = Ĉ_b^n f + g.
* Filter: x = [μ; δv; δr (; δc)], Φ of eq. 3.2 / 3.41 every step, M by eq. 3.7, corrections by eqs. 3.6–3.8
  (Joseph form) every ``every`` seconds with the rows of H (eq. 3.3 / 3.30 / 3.43) of the sensors available.
  Sign convention of DIGEST_000 §9: Ĉ_b^n = (I + [μ×]) C_b^n, δv, δr = true − computed, δc = measured − true;
  the magnetometer enters at the level of its H row (z = [μ₂, μ₃] + noise), as in :mod:`ins_hil.fdi.bias`.
* ``feedback``: Γ = D = I (Ex 3.1, 3.3): the INS is corrected by x̂ and the estimate reset (§10 item 23), the
  bias fed back to the gyro input (eq. 3.45). Without it (Γ = D = 0, Ex 3.2) the estimate is propagated by Φ
  and the output is the INS corrected by x̂.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, replace
from functools import cache, lru_cache

import numpy as np

from ins_hil.nav.attitude import make_attitude
from ins_hil.nav.quadrature import SplineTranslational
from ins_hil.nav.rotation import dcm_from_quat, quat_from_rotvec, quat_mul, quat_normalize, skew
from ins_hil.types import Vec

from . import Row

ARCSEC = math.pi / (180.0 * 3600.0)
ARCMIN = 60.0 * ARCSEC
I3 = np.eye(3)


@dataclass(frozen=True)
class Setup:
    """One example's data (units: s, m, m/s, rad, rad/s; noise parameters are standard deviations)."""

    name: str
    duration: float
    theta: float = 0.0  # classic nutation ϑ
    period: float = 300.0  # T; math.inf: no rotation
    speed: float = 60.0  # V
    roll_amp: float = 0.3  # φ = roll_amp sin 10ψ
    g_down: float = -9.81  # z component of gravity: −g (z up, Ex 3.2/3.3) or +g (NED, Ex 3.1)
    dt: float = 0.05
    every: float = 2.0  # correction interval
    sig_w: float = 0.0
    sig_a: float = 0.0
    bias: tuple[float, float, float] = (0.0, 0.0, 0.0)  # n_c, rad/s (body)
    lam0: tuple[float, float, float, float] = (1.0, 0.0, 0.0, 0.0)  # non-normalised initial error quaternion
    eps: float = 0.0  # ε_r = ε_v
    qbar: tuple[float, ...] = ()  # Cholesky factor of Q per block (3 or 4 blocks)
    m0: tuple[float, ...] = ()  # Cholesky factor of M₀ per block
    eta_gps: tuple[float, float] = (0.1, 50.0)  # GPS velocity, position
    gps_bias: tuple[float, float] = (0.0, 0.0)  # GPS mean errors: velocity (m/s), position (m; along the nav x axis)
    eta_mag: float = 0.0524
    eta_baro: float = 1.0
    # (t0, t1, gps, mag + baro): sensors available for corrections at t in (t0, t1]
    schedule: tuple[tuple[float, float, bool, bool], ...] = ((0.0, math.inf, True, False),)
    feedback: bool = True
    seed: int = 0
    filter_on: bool = True


@dataclass
class Run:
    """1-Hz history: time, errors of the output (rad, m/s, m; nav axes), σ of μ, δv, δr from P (9), δĉ (rad/s)."""

    t: Vec
    att: Vec
    vel: Vec
    pos: Vec
    sig: Vec
    dc: Vec
    bias: Vec

    def at(self, t: float) -> int:
        return int(np.argmin(np.abs(self.t - t)))


def _uniform(rng: np.random.Generator, std: float, size: int) -> Vec:
    h = std * math.sqrt(3.0)
    return rng.uniform(-h, h, size)


def _mu(C_hat: Vec, C: Vec) -> Vec:
    """Small turn μ of Ĉ_b^n relative to C_b^n: Ĉ Cᵀ ≈ I + [μ×] (DIGEST_000 §9)."""
    D = C_hat @ C.T
    return 0.5 * np.array([D[2, 1] - D[1, 2], D[0, 2] - D[2, 0], D[1, 0] - D[0, 1]])


def run(s: Setup) -> Run:
    """Simulate one example; see the module docstring for the model."""
    rng = np.random.default_rng(s.seed)
    dt = s.dt
    wpsi = 0.0 if math.isinf(s.period) else 2.0 * math.pi / s.period
    R0 = 0.0 if wpsi == 0.0 else s.speed / wpsi
    qx = quat_from_rotvec(np.array([s.theta, 0.0, 0.0]))
    gvec = np.array([0.0, 0.0, s.g_down])
    nc = np.array(s.bias)
    nb = len(s.qbar)
    n = 3 * nb

    def truth(t: float) -> tuple[Vec, Vec, Vec, Vec, Vec]:
        psi = wpsi * t
        phi = s.roll_amp * math.sin(10.0 * psi)
        dpsi, dphi = wpsi, s.roll_amp * 10.0 * wpsi * math.cos(10.0 * psi)
        q = quat_mul(quat_mul(quat_from_rotvec(np.array([0.0, 0.0, psi])), qx), quat_from_rotvec(np.array([0, 0, phi])))
        st, ct = math.sin(s.theta), math.cos(s.theta)
        w = np.array([dpsi * st * math.sin(phi), dpsi * st * math.cos(phi), dpsi * ct + dphi])  # eq. 2.55, ϑ̇ = 0
        r = R0 * np.array([-math.sin(psi), math.cos(psi), 0.0])
        v = s.speed * np.array([-math.cos(psi), -math.sin(psi), 0.0])
        a = s.speed * wpsi * np.array([math.sin(psi), -math.cos(psi), 0.0])
        return q, w, r, v, a

    def sensors(t: float) -> tuple[Vec, Vec]:
        q, w, _, _, a = truth(t)
        f = dcm_from_quat(q).T @ (a - gvec)
        return w + nc + _uniform(rng, s.sig_w, 3), f + _uniform(rng, s.sig_a, 3)

    q_t, _, r_t, v_t, _ = truth(0.0)
    q = quat_normalize(quat_mul(quat_normalize(np.array(s.lam0)), q_t))
    att = make_attitude("dl3m")
    w0, f0 = sensors(0.0)
    att.prime_rate(w0)
    Ch = dcm_from_quat(q)
    trans = SplineTranslational(r_t * (1 + s.eps), v_t * (1 + s.eps), Ch @ f0 + gvec, dt)
    dc_hat = np.zeros(3)
    x = np.zeros(n)
    if s.filter_on:
        Q = np.diag(np.repeat(np.array(s.qbar) ** 2, 3))
        P = np.diag(np.repeat(np.array(s.m0) ** 2, 3))
        H_all = np.zeros((9, n))  # eq. 3.43 rows: μ₂, μ₃ | δv | δr | δr_z (baro)
        H_all[0:8, 1:9] = np.eye(8)
        H_all[8, 8] = 1.0
        eta_all = np.array([s.eta_mag] * 2 + [s.eta_gps[0]] * 3 + [s.eta_gps[1]] * 3 + [s.eta_baro])
    Phi = np.eye(n)
    steps = round(s.duration / dt)
    every = round(s.every / dt)
    per_s = round(1.0 / dt)
    out: dict[str, list[Vec]] = {k: [] for k in ("t", "att", "vel", "pos", "sig", "dc")}
    for k in range(1, steps + 1):
        t = k * dt
        w_m, f_m = sensors(t)
        q = quat_normalize(att.step_rate(q, w_m - dc_hat, dt))  # eqs. 2.19, 2.27, 3.45
        Ch = dcm_from_quat(q)
        f_n = Ch @ f_m
        r, v = trans.step(f_n + gvec)  # eqs. 2.20–2.21
        if s.filter_on:
            C = skew(f_n)  # eq. 3.1
            Phi[3:6, 0:3] = C * dt  # eq. 3.2 / 3.41
            Phi[6:9, 0:3] = C * (dt * dt / 2)
            Phi[6:9, 3:6] = I3 * dt
            if nb == 4:
                Phi[0:3, 9:12] = Ch * dt
                Phi[3:6, 9:12] = C @ Ch * (dt * dt / 2)
            P = Phi @ P @ Phi.T + Q  # eq. 3.7
            if not s.feedback:
                x = Phi @ x
        q_t, _, r_t, v_t, _ = truth(t)
        C_t = dcm_from_quat(q_t)
        if s.filter_on and k % every == 0:
            sel = [False] * 9
            for t0, t1, gps, mb in s.schedule:
                if t0 < t <= t1:
                    sel = [mb, mb] + [gps] * 6 + [mb]
            rows_ = np.flatnonzero(sel)
            if rows_.size:
                mu = _mu(Ch, C_t)
                dr = r_t - r
                z_all = np.concatenate([mu[1:3], v_t - v, dr, dr[2:3]]) + _uniform(rng, 1.0, 9) * eta_all
                z_all[[2, 5]] += s.gps_bias  # a GPS mean error is not noise: it stays in the solution
                H, z, Rm = H_all[rows_], z_all[rows_], np.diag(eta_all[rows_] ** 2)
                S = H @ P @ H.T + Rm
                K = np.linalg.solve(S, H @ P).T  # eq. 3.6
                x = x + K @ (z - H @ x)  # eq. 3.5
                IKH = np.eye(n) - K @ H
                P = IKH @ P @ IKH.T + K @ Rm @ K.T  # eq. 3.8 in Joseph form (3.16)
                if s.feedback:
                    q = quat_normalize(quat_mul(quat_from_rotvec(-x[0:3]), q))
                    trans.v = trans.v + x[3:6]
                    trans.r = trans.r + x[6:9]
                    if nb == 4:
                        dc_hat = dc_hat + x[9:12]
                    x = np.zeros(n)
                    Ch = dcm_from_quat(q)
                    r, v = trans.r, trans.v
        if k % per_s == 0:
            out["t"].append(np.array(t))
            out["att"].append(_mu(Ch, C_t) - x[0:3])
            out["vel"].append(v_t - (v + x[3:6]))
            out["pos"].append(r_t - (r + x[6:9]))
            out["sig"].append(np.sqrt(np.diag(P)[0:9]) if s.filter_on else np.zeros(9))
            out["dc"].append(dc_hat + (x[9:12] if nb == 4 else 0.0))
    o = {k: np.array(v) for k, v in out.items()}
    return Run(o["t"], o["att"], o["vel"], o["pos"], o["sig"], o["dc"], nc)


# The examples' data (DIGEST_000 §3.6, §3.8, §3.10); q̄ is 1e-3·{α, β, γ(, δ)} (eqs. 3.39, 3.46).
EX31 = Setup(
    "Ex 3.1",
    duration=900.0,  # not stated by the book (outage 300–600 s): 300 s after the outage
    theta=math.pi / 2,
    g_down=9.81,
    sig_w=1.0 * ARCMIN,
    sig_a=1e-2,
    lam0=(1.0, 5e-3, -5e-3, 5e-3),
    qbar=(0.0073e-3, 0.25e-3, 0.0063e-3),
    m0=(2e-2, 0.0, 0.0),
    schedule=((0.0, 300.0, True, False), (600.0, math.inf, True, False)),
)
EX31_NOISE_FREE = replace(EX31, duration=300.0, sig_w=0.0, sig_a=0.0, lam0=(1.0, 0.0, 0.0, 0.0), filter_on=False)
EX32 = Setup(
    "Ex 3.2",
    duration=500.0,
    sig_w=3.0 * ARCMIN,
    sig_a=1e-2,
    lam0=(1.0, 0.05, -0.05, 0.05),
    eps=0.01,
    qbar=(0.0218e-3, 0.25e-3, 0.0063e-3),
    m0=(0.02, 1.2, 57.3),
    schedule=((60.0, 180.0, True, True), (180.0, 420.0, False, True), (420.0, 500.0, True, True)),
    feedback=False,
)
EX33 = Setup(
    "Ex 3.3",
    duration=250.0,
    sig_w=3.0 * ARCMIN,
    sig_a=1e-2,
    bias=(94 * ARCSEC, -56 * ARCSEC, 22 * ARCSEC),
    lam0=(1.0, 0.05, -0.05, 0.05),
    eps=0.01,
    qbar=(0.0218e-3, 0.25e-3, 0.0063e-3, 5e-5 * 1e-3),
    m0=(0.04, 0.6, 28.65, 0.4),
    schedule=((0.0, math.inf, True, True),),
)
# Figs 3.17/3.19/3.21: the same run with the 9-state filter that disregards the bias (Larin & Tunik 2010b)
EX33_NO_BIAS = replace(EX33, qbar=EX33.qbar[:3], m0=EX33.m0[:3])

# §6.1 static laboratory test analogue (DIGEST_000 §6.1): ADIS16362 at 100 Hz, gyro RMS 0.1 °/s, accelerometer
# RMS 0.5 m/s², GPS every 1 s in [60, 180] s (RMS 0.1 m, 0.03 m/s; mean errors ≈ 0.3 m and 1e-3 m/s, put along
# north: the book gives no direction), level, NED, no Earth rate, white noise only. q̄ by the rule that reproduces
# the examples' factors (DIGEST_000 §3.6: σ_ω Δt/2, σ_a Δt/2, σ_a Δt²/4); m₀ for a 1° levelling error.
LAB_DT = 0.01
LAB = Setup(
    "§6.1 lab analogue",
    duration=300.0,
    period=math.inf,
    speed=0.0,
    roll_amp=0.0,
    g_down=9.81,
    dt=LAB_DT,
    every=1.0,
    sig_w=math.radians(0.1),
    sig_a=0.5,
    lam0=(1.0, 0.5 * math.radians(0.5), -0.5 * math.radians(0.5), 0.5 * math.radians(0.5)),
    qbar=(math.radians(0.1) * LAB_DT / 2, 0.5 * LAB_DT / 2, 0.5 * LAB_DT**2 / 4),
    m0=(math.radians(1.0), 0.1, 0.1),
    eta_gps=(0.03, 0.1),
    gps_bias=(1e-3, 0.3),
    schedule=((60.0, 180.0, True, False),),
)


# §6.5 flight Exp. 1 analogue: a 20-s GPS outage in flight (the book's 60 m/s circle, yaw-only motion, NED) with the
# §6.1 sensor grades; GPS every 1 s except in [120, 140] s.
FLIGHT_OUTAGE = (120.0, 140.0)
FLIGHT = replace(
    LAB,
    name="§6.5 flight outage analogue",
    duration=160.0,
    period=300.0,
    speed=60.0,
    roll_amp=0.3,
    schedule=((0.0, FLIGHT_OUTAGE[0], True, False), (FLIGHT_OUTAGE[1], math.inf, True, False)),
    gps_bias=(0.0, 0.0),
)
BOOK_OUTAGE_POS = (61.3043, 131.8389, 9.8646)  # m, N/E/D maxima in the 20-s outage (book §6.5 Exp. 1)
BOOK_OUTAGE_VEL = (10.3377, 16.2613, 3.7761)  # m/s
# Our measured values (documented so that a code change that moves them fails; see Row.expect)
FLIGHT_EXPECT_POS = (3.439, 8.088, 2.779)  # m, seed 0
FLIGHT_EXPECT_VEL = (0.3396, 0.7741, 0.2892)  # m/s
LAB_EXPECT = {"tilt": 0.0412, "vh": 0.0168, "vv": 0.0260, "pos": 0.367, "sig_yaw_ratio": 0.901}  # 5-seed medians

RUNS = {"EX31": EX31, "EX31_NOISE_FREE": EX31_NOISE_FREE, "EX32": EX32, "EX32_FEEDBACK": replace(EX32, feedback=True)}
RUNS |= {"EX33": EX33, "EX33_NO_BIAS": EX33_NO_BIAS, "LAB": LAB, "FLIGHT": FLIGHT}


SEEDS = (0, 1, 2, 3, 4)  # the book's noise draws are not given: the cheap runs' figures are medians over these
MULTI = ("EX32", "EX32_FEEDBACK", "EX33", "EX33_NO_BIAS", "LAB")


@cache
def result(name: str, seed: int = 0) -> Run:
    """The cached run of one setup of :data:`RUNS` with noise seed ``seed``."""
    return run(replace(RUNS[name], seed=seed))


def _norm(a: Vec) -> float:
    return float(np.linalg.norm(a))


def _rms(a: Vec) -> float:
    return float(np.sqrt(np.mean(np.sum(a * a, axis=-1))))


def _bound(
    g: str,
    case: str,
    published: float | None,
    ours: float,
    ref: float,
    check: str,
    note: str,
    why: str = "",
    changed: str = "",
    expect: float | None = None,
    expect_tol: float = 0.15,
) -> Row:
    """A bound from the book's text: a row that must hold, or (with ``why`` or ``changed``) a discrepancy.

    The choice is made here, in the source, not from the outcome: a bound that holds today and is broken
    by a code change fails. ``why`` says why the book's bound is not met, ``changed`` names a setting we
    changed from the book's; a discrepancy documents ``expect`` (our measured value) within ``expect_tol``
    (relative; the 5-seed medians are deterministic, the band absorbs cross-host rounding).
    """
    reason = "; ".join(x for x in (changed, why) if x)
    return Row(g, case, published, ours, 0.0, check, ref, note, discrepancy=reason,
               expect=expect if reason else None, expect_tol=expect_tol)  # fmt: skip


def _t_below_0(t: Vec, logs: Vec) -> float:
    """First time from which ``logs`` stays below 0 (0 if always, inf if it never settles there)."""
    above = np.flatnonzero(logs >= 0)
    if above.size == 0:
        return 0.0
    return float(t[above[-1] + 1]) if above[-1] + 1 < t.size else math.inf


def _figures(name: str, seed: int) -> dict[str, float]:
    """One run's figures: errors of the output at the instants the rows and the comparison use (°, m/s, m)."""
    a = result(name, seed)
    if name == "LAB":
        i, i0 = a.at(180), a.at(60)
        return {
            "tilt": math.degrees(_norm(a.att[i, 0:2])),
            "vh": _norm(a.vel[i, 0:2]),
            "vv": abs(float(a.vel[i, 2])),
            "pos": _norm(a.pos[i]),
            "sig_yaw_ratio": float(a.sig[i, 2] / a.sig[i0, 2]),
            "sig_tilt_ratio": float(_norm(a.sig[i, 0:2]) / _norm(a.sig[i0, 0:2])),
        }
    if name == "FLIGHT":
        w = (a.t > FLIGHT_OUTAGE[0]) & (a.t <= FLIGHT_OUTAGE[1])
        f = {f"pos_{i}": float(np.max(np.abs(a.pos[w, i]))) for i in range(3)}
        return f | {f"vel_{i}": float(np.max(np.abs(a.vel[w, i]))) for i in range(3)}
    t_gps = {"EX31": 300.0, "EX32": 180.0, "EX32_FEEDBACK": 180.0}.get(name, a.t[-1])
    t_out = {"EX31": 600.0, "EX32": 420.0, "EX32_FEEDBACK": 420.0}.get(name, math.nan)
    f = {
        "att_gps": math.degrees(_norm(a.att[a.at(t_gps)])),
        "vel_gps": _norm(a.vel[a.at(t_gps)]),
        "pos_gps": _norm(a.pos[a.at(t_gps)]),
        "sig_att_gps": math.degrees(_norm(a.sig[a.at(t_gps), 0:3])),
        "sig_pos_gps": _norm(a.sig[a.at(t_gps), 6:9]),
        "att_end": math.degrees(_norm(a.att[-1])),
        "vel_end": _norm(a.vel[-1]),
        "pos_end": _norm(a.pos[-1]),
        "sig_att_end": math.degrees(_norm(a.sig[-1, 0:3])),
    }
    if not math.isnan(t_out):
        j = a.at(t_out)
        f |= {
            "att_out": math.degrees(_norm(a.att[j])),
            "pos_out": _norm(a.pos[j]),
            "sig_att_out": math.degrees(_norm(a.sig[j, 0:3])),
        }
    if name == "EX31":
        nf = result("EX31_NOISE_FREE", seed)
        f["noise_free_arcsec"] = float(np.max(np.linalg.norm(nf.att, axis=1))) / ARCSEC
    if name in ("EX33", "EX33_NO_BIAS"):
        f["att_rms_tail"] = math.degrees(_rms(a.att[a.t > 150]))
    if name == "EX33":
        logs = np.log10(np.linalg.norm(a.bias - a.dc, axis=1) / _norm(a.bias))
        f |= {
            "log_6": float(logs[a.at(6)]),
            "log_end": float(logs[-1]),
            "t_log_below_0": _t_below_0(a.t, logs),
        }
    return f


@lru_cache(maxsize=1)
def figures() -> dict[str, dict[str, float]]:
    """Per run: Ex 3.1 and the flight outage from seed 0, the others (:data:`MULTI`) the median over :data:`SEEDS`."""
    out = {name: _figures(name, 0) for name in ("EX31", "FLIGHT")}
    for name in MULTI:
        per = [_figures(name, s) for s in SEEDS]
        out[name] = {k: float(np.median([p[k] for p in per])) for k in per[0]}
    return out


def equivalent_accel(pos_max: float, duration: float = 20.0) -> float:
    """Constant acceleration error (m/s²) that drifts the position by ``pos_max`` in ``duration``: 2Δr/t²."""
    return 2.0 * pos_max / duration**2


@lru_cache(maxsize=1)
def rows() -> list[Row]:
    f = figures()
    a, b, bf, c, cn, e = (f[k] for k in ("EX31", "EX32", "EX32_FEEDBACK", "EX33", "EX33_NO_BIAS", "LAB"))
    g = "Ex 3.1 (NED, ϑ = π/2, 9 states, GPS every 2 s, none in 300–600 s, 900 s, feedback Γ = D = I; seed 0)"
    out = [
        Row(
            g,
            "noise-free INS (λ³_m, eq. 2.19), max |μ| over 300 s, arcsec",
            1e-3,
            a["noise_free_arcsec"],
            0.0,
            "le",
            1e-2,
            "Fig. 3.2: 'of order 10⁻³ arcsec'; checked as < 10⁻²",
        ),
        Row(
            g,
            "|μ| at 300 s (GPS on), °, ≤ 3σ of M",
            None,
            a["att_gps"],
            0.0,
            "le",
            3 * a["sig_att_gps"],
            "Figs 3.5, 3.8",
        ),
        Row(
            g,
            "σ(μ) at 600 s / σ(μ) at 300 s (outage)",
            None,
            a["sig_att_out"] / a["sig_att_gps"],
            0.0,
            "ge",
            1.0,
            "Fig. 3.8: σ grows without correction",
        ),
        Row(
            g,
            "|μ| at 900 s (300 s after GPS returns), °, ≤ 3σ",
            None,
            a["att_end"],
            0.0,
            "le",
            3 * a["sig_att_end"],
            "Fig. 3.5",
        ),
    ]
    g = "Ex 3.2 (z up, ϑ = 0, 9 states, GPS + mag + baro, schedule 0/60/180/420/500 s; 5-seed median)"
    FB = "setting changed: feedback Γ = D = I (printed: Γ = D = 0)"
    lit = "Γ = D = 0 as printed (open loop) with 0.1-rad initial errors: "
    out += [
        _bound(
            g,
            "Γ = D = 0: |μ| at 180 s, °",
            1.0,
            b["att_gps"],
            1.0,
            "le",
            "'shares of a degree'",
        ),
        _bound(
            g,
            "Γ = D = 0: |δv| at 180 s, m/s",
            0.2,
            b["vel_gps"],
            0.2,
            "le",
            "'about 0.2 m/s'",
            lit + "g·μ²/2 ≈ 0.05 m/s² is unmodelled",
            expect=5.19,
        ),
        _bound(
            g,
            "Γ = D = 0: |δr| at 180 s, m",
            1.0,
            b["pos_gps"],
            1.0,
            "le",
            "'< 1 m'",
            lit + "the unmodelled acceleration integrates into position",
            expect=86.8,
        ),
        _bound(
            g,
            "feedback (our reading): |μ| at 180 s, °",
            1.0,
            bf["att_gps"],
            1.0,
            "le",
            "'shares of a degree'",
            "the initial 0.1-rad error is 5 α_m (P₀ optimistic, DIGEST_000 §10 item 21): the error is ≫ the "
            f"filter's own σ(μ) = {bf['sig_att_gps']:.2f}°",
            changed=FB,
            expect=1.085,
        ),
        _bound(
            g,
            "feedback (our reading): |δv| at 180 s, m/s",
            0.2,
            bf["vel_gps"],
            0.2,
            "le",
            "'about 0.2 m/s'",
            changed=FB,
            expect=0.0944,
        ),
        _bound(
            g,
            "feedback (our reading): |δr| at 180 s, m",
            1.0,
            bf["pos_gps"],
            1.0,
            "le",
            "'< 1 m'",
            f"60 fixes of σ = 50 m average to 50/√60 = 6.5 m (1σ); the filter's own σ(δr) is {bf['sig_pos_gps']:.1f} m",
            changed=FB,
            expect=5.86,
        ),
    ]
    g = "Ex 3.3 (Ex 3.2's motion, 12 states with the gyro bias, all sensors every 2 s, 250 s; 5-seed median)"
    out += [
        _bound(
            g,
            "log₁₀(‖n_c − δĉ‖/‖n_c‖) after 3 corrections (6 s)",
            None,
            c["log_6"],
            0.0,
            "le",
            "'2–3 steps of GPS correction' transient (Fig. 3.22)",
            f"below 0 only from {c['t_log_below_0']:.0f} s: the 0.1-rad initial attitude error (2.5 α_m) "
            "is first taken as bias (δ_m = 0.4)",
            expect=1.71,
        ),
        Row(
            g,
            "log₁₀(‖n_c − δĉ‖/‖n_c‖) at 250 s",
            None,
            c["log_end"],
            0.0,
            "le",
            0.0,
            "Fig. 3.22; the INS corrected and the estimate reset at each correction, δĉ fed to the gyros (eq. 3.45)",
        ),
        Row(
            g,
            "RMS |μ| 150–250 s with bias states, °, ≤ without (Figs 3.16/3.17)",
            None,
            c["att_rms_tail"],
            0.0,
            "le",
            cn["att_rms_tail"],
            "'expedient to compensate the systematic RG error'",
        ),
    ]
    g = (
        "Book §6.1 static lab test, simulated analogue (white-noise gyro 0.1 °/s, accel 0.5 m/s², 100 Hz, no Earth "
        "rate; GPS 1 Hz with its 0.3 m mean error; 5-seed median)"
    )
    ana = (
        "analogue, not a reproduction: white-noise sensors and no Earth rate, so the book's bound on a real "
        "ADIS16362 run is no test of it; ours is held at its measured value"
    )
    out += [
        _bound(
            g,
            "roll/pitch error at 180 s, °",
            0.1,
            e["tilt"],
            0.1,
            "le",
            "book: ≤ 0.1° (real ADIS16362)",
            ana,
            expect=LAB_EXPECT["tilt"],
        ),
        _bound(
            g,
            "horizontal velocity error at 180 s, m/s",
            0.05,
            e["vh"],
            0.05,
            "le",
            "book: < 0.05 m/s",
            ana,
            expect=LAB_EXPECT["vh"],
        ),
        _bound(
            g,
            "vertical velocity error at 180 s, m/s",
            0.15,
            e["vv"],
            0.15,
            "le",
            "book: ≈ 0.15 m/s",
            ana,
            expect=LAB_EXPECT["vv"],
        ),
        _bound(
            g,
            "position error at 180 s (against the truth), m",
            0.25,
            e["pos"],
            0.25,
            "le",
            "book: ≤ 0.25 m",
            "the GPS's stated mean error ≈ 0.3 m stays in the solution and alone exceeds the book's 0.25 m "
            "against the truth (the book's errors are presumably relative to its GPS)",
            expect=LAB_EXPECT["pos"],
        ),
        _bound(
            g,
            "σ(yaw) at 180 s / at 60 s (GPS does not improve heading)",
            None,
            e["sig_yaw_ratio"],
            1.0,
            "ge",
            "book: heading not improved by GPS (its gyro drift exceeds Earth rate; no Earth rate here)",
            f"σ(yaw) falls by {100 * (1 - e['sig_yaw_ratio']):.0f} % (tilt: {100 * (1 - e['sig_tilt_ratio']):.0f} %): "
            "Φ uses the measured specific force, whose 0.5 m/s² noise lends the heading a spurious observability",
            expect=LAB_EXPECT["sig_yaw_ratio"],
            expect_tol=0.03,
        ),
        Row(
            g,
            "σ(tilt) at 180 s / at 60 s",
            None,
            e["sig_tilt_ratio"],
            0.5,
            "rel",
            0.027,
            "levelling is observable (book: tilt improved by GPS); reference: our measured ratio",
        ),
    ]
    g = "Book §6.5 flight Exp. 1, 20-s GPS outage: simulated analogue (60 m/s circle, §6.1 sensor grades, 100 Hz)"
    fl = f["FLIGHT"]
    why = (
        "analogue, not a reproduction: white-noise sensors of the §6.1 grade only; the book's maximum implies an "
        "uncompensated acceleration error of 2Δr/t² = {a:.2f} m/s² (bias, vibration, scale factor of a real UAV)"
    )
    for i, ax in enumerate("NED"):
        out.append(
            Row(
                g,
                f"max |δr_{ax}| in the outage, m",
                BOOK_OUTAGE_POS[i],
                fl[f"pos_{i}"],
                0.0,
                "le",
                BOOK_OUTAGE_POS[i],
                discrepancy=why.format(a=equivalent_accel(BOOK_OUTAGE_POS[i])),
                expect=FLIGHT_EXPECT_POS[i],
                expect_tol=0.10,
            )
        )
    for i, ax in enumerate("NED"):
        out.append(
            Row(
                g,
                f"max |δv_{ax}| in the outage, m/s",
                BOOK_OUTAGE_VEL[i],
                fl[f"vel_{i}"],
                0.0,
                "le",
                BOOK_OUTAGE_VEL[i],
                discrepancy=why.format(a=BOOK_OUTAGE_VEL[i] / 20.0).replace("2Δr/t²", "Δv/t"),
                expect=FLIGHT_EXPECT_VEL[i],
                expect_tol=0.10,
            )
        )
    return out


def comparison_markdown() -> str:
    """Examples 3.1–3.3 side by side: setting, our errors with GPS and at the end, the book's statement."""
    f = figures()
    lines = [
        "## Book Examples 3.1–3.3 compared (`reproduce.book_ch3_examples`; Ex 3.1 seed 0, the others 5-seed medians)",
        "",
        'Errors of the output against the truth (|μ| °, |δv| m/s, |δr| m). "with GPS": Ex 3.1 at 300 s, '
        'Ex 3.2 at 180 s, Ex 3.3 at 250 s; "outage end": Ex 3.1 at 600 s (no correction), Ex 3.2 at 420 s '
        "(magnetometer + baro only).",
        "",
        "| example | states / sensors / loop | with GPS: μ, δv, δr | outage end: μ, δr | end: μ, δv, δr | book |",
        "|---|---|---|---|---|---|",
    ]
    spec = (
        ("EX31", "Ex 3.1", "9 / GPS / feedback", "figures only; noise-free 10⁻³ arcsec"),
        ("EX32", "Ex 3.2", "9 / GPS+mag+baro / Γ = D = 0", "< 1°, ≈ 0.2 m/s, < 1 m"),
        ("EX32_FEEDBACK", "Ex 3.2", "9 / GPS+mag+baro / feedback", "< 1°, ≈ 0.2 m/s, < 1 m"),
        ("EX33", "Ex 3.3", "12 / GPS+mag+baro / feedback", "bias in 2–3 corrections"),
        ("EX33_NO_BIAS", "Ex 3.3 without δc", "9 / GPS+mag+baro / feedback", "worse than with δc"),
    )
    for key, name, what, book in spec:
        x = f[key]
        out = f"{x['att_out']:.2f}, {x['pos_out']:.0f}" if "att_out" in x else "—"
        lines.append(
            f"| {name} | {what} | {x['att_gps']:.2f}, {x['vel_gps']:.2f}, {x['pos_gps']:.1f} | {out} | "
            f"{x['att_end']:.2f}, {x['vel_end']:.2f}, {x['pos_end']:.1f} | {book} |"
        )
    lines += [
        "",
        "Ex 3.1's noise-free INS stays within "
        f"{f['EX31']['noise_free_arcsec']:.1e} arcsec over 300 s (book: of order 10⁻³). The book's Ex 3.2 bounds "
        "(< 1 m with 50 m GPS) are below what its own GPS noise allows; Ex 3.3's bias estimate converges "
        f"(log₁₀ ratio {f['EX33']['log_end']:.2f} at 250 s) but only after "
        f"{f['EX33']['t_log_below_0']:.0f} s, and compensating it lowers the attitude RMS of the last 100 s from "
        f"{f['EX33_NO_BIAS']['att_rms_tail']:.2f}° to {f['EX33']['att_rms_tail']:.2f}°.",
        "",
    ]
    return "\n".join(lines)
