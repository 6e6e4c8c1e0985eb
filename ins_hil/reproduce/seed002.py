"""Seed 002 coning test (DIGEST_001_004 §2.6–2.7, cases 002-A…K).

Base motion (the paper's generator UgDvObj_laz is not given; the digest's
reading, §2.7): Euler sequence ψ about the vertical y, ϑ about z′, γ about x″
(body x forward, y up, z right); ψ ≡ 0, ϑ = a sin ωt, γ = a sin(ωt + ε).
Body rates ω = (γ̇, ϑ̇ sin γ, ϑ̇ cos γ). The computed heading is
ψ = atan2(−C31, C11) of C = C(Λ) (body → reference; insensitive to |Λ|).

Drift: least-squares fit of ψ(t) = α + βt + Σ_{k≤4}(a_k cos kωt + b_k sin kωt)
over 40 periods (removes the periodic error exactly, at any step, where a
plain slope fit would leave a spurious floor: DIGEST_001_004 §2.7);
dimensionless drift δ = β/(ω a²) (signed), μ = ωh.
"""

from __future__ import annotations

import math

import numpy as np

from ins_hil.nav.attitude import propagate
from ins_hil.nav.onestep import increments
from ins_hil.nav.rotation import quat_from_rotvec, quat_mul
from ins_hil.types import Vec

A_M = 0.1  # rad, amplitude of ϑ and γ
OMEGA = 1.0  # rad/s
PHASE = math.pi / 2  # ε = 90°: coning
STEPS = (0.1, 0.01, 0.001)  # s


def coning_rates(t: Vec, a: float = A_M, w: float = OMEGA, eps: float = PHASE) -> Vec:
    """Body rates (n, 3) rad/s of the coning motion at times t (s)."""
    g = a * np.sin(w * t + eps)
    gd = a * w * np.cos(w * t + eps)
    td = a * w * np.cos(w * t)
    return np.stack([gd, td * np.sin(g), td * np.cos(g)], axis=-1)


def coning_initial(a: float = A_M, eps: float = PHASE) -> Vec:
    """Exact Λ(0) = Λ_ψ ∘ Λ_ϑ ∘ Λ_γ with ψ = 0, ϑ(0) = 0, γ(0) = a sin ε."""
    return quat_mul(quat_from_rotvec(np.array([0.0, 0.0, 0.0])), quat_from_rotvec(np.array([a * math.sin(eps), 0, 0])))


def heading_yup(q: Vec) -> Vec:
    """ψ = atan2(−C31, C11) of C = C_b^r(Λ) (seed 002/003 y-up convention), vectorised over rows."""
    q0, q1, q2, q3 = q[:, 0], q[:, 1], q[:, 2], q[:, 3]
    c11 = q0 * q0 + q1 * q1 - q2 * q2 - q3 * q3
    c31 = 2.0 * (q1 * q3 - q0 * q2)
    return np.arctan2(-c31, c11)


def fit_drift(t: Vec, psi: Vec, w: float = OMEGA, harmonics: int = 4) -> float:
    """Secular slope (rad/s) of ψ(t) with the periodic part at kω (k ≤ harmonics) fitted out."""
    cols = [np.ones_like(t), t - t.mean()]
    for k in range(1, harmonics + 1):
        cols += [np.cos(k * w * t), np.sin(k * w * t)]
    coef, *_ = np.linalg.lstsq(np.stack(cols, axis=1), psi, rcond=None)
    return float(coef[1])


def coning_run(kind: str, h: float, a: float = A_M, w: float = OMEGA, eps: float = PHASE, periods: int = 40) -> Vec:
    """Quaternions Λ(t_n) (un-normalised) of one algorithm over the coning run, shape (n + 1, 4)."""
    n = int(round(periods * 2 * math.pi / w / h))
    t = h * np.arange(n + 1)
    om = coning_rates(t, a, w, eps)
    return propagate(coning_initial(a, eps), increments(om[:-1], om[1:], h, kind))


def coning_drift(kind: str, mu: float, a: float = A_M, w: float = OMEGA, eps: float = PHASE, periods: int = 40) -> float:
    """Signed dimensionless drift δ = (dψ/dt)/(ω a²) of a seed-002 algorithm at μ = ωh."""
    h = mu / w
    q = coning_run(kind, h, a, w, eps, periods)
    t = h * np.arange(len(q))
    return fit_drift(t, heading_yup(q), w) / (w * a * a)


def rows():
    return []
