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
from functools import lru_cache

import numpy as np

from ins_hil.nav.attitude import propagate
from ins_hil.nav.onestep import increments
from ins_hil.nav.rotation import quat_from_rotvec, quat_mul
from ins_hil.types import Vec

from . import Row

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
    """Exact Λ(0) = Λ_ψ ∘ Λ_ϑ ∘ Λ_γ with ψ = 0 (Λ_ψ = 1), ϑ(0) = a sin 0 = 0 (about z′), γ(0) = a sin ε (about x″)."""
    theta0, gamma0 = 0.0, a * math.sin(eps)
    return quat_mul(quat_from_rotvec(np.array([0.0, 0.0, theta0])), quat_from_rotvec(np.array([gamma0, 0.0, 0.0])))


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
    n = round(periods * 2 * math.pi / w / h)
    t = h * np.arange(n + 1)
    om = coning_rates(t, a, w, eps)
    return propagate(coning_initial(a, eps), increments(om[:-1], om[1:], h, kind))


def default_periods(mu: float) -> int:
    """Periods to simulate: 40 (the digest's run) where cheap, fewer at small μ (≥ 2; the harmonic fit
    needs whole periods only approximately) so a run stays below ~6000 steps where possible."""
    return int(min(40, max(2, math.floor(6000 * mu / (2 * math.pi)))))


@lru_cache(maxsize=256)
def coning_drift(
    kind: str, mu: float, a: float = A_M, w: float = OMEGA, eps: float = PHASE, periods: int | None = None
) -> float:
    """Signed dimensionless drift δ = (dψ/dt)/(ω a²) of a seed-002 algorithm at μ = ωh."""
    periods = default_periods(mu) if periods is None else periods
    h = mu / w
    q = coning_run(kind, h, a, w, eps, periods)
    t = h * np.arange(len(q))
    return fit_drift(t, heading_yup(q), w) / (w * a * a)


def ratio_crossover(target: float = 2600.0, mu: float = 0.04) -> float:
    """μ below which δ_Revers/δ_new ≥ target, from the drift laws δ_R = A μ², δ_new = B μ⁴ fitted at μ."""
    a_r = coning_drift("revers1h", mu) / mu**2
    b_n = coning_drift("exprvrs1h", mu) / mu**4
    return math.sqrt(a_r / b_n / target)


@lru_cache(maxsize=1)
def rows() -> list[Row]:
    out: list[Row] = []
    g = "Seed 002 coning drift (a = 0.1 rad, ω = 1 rad/s, ε = 90°)"
    for h in STEPS:
        mu = OMEGA * h
        r = coning_drift("revers1h", mu)
        k = coning_drift("rk21", mu)
        out.append(Row(g, f"Revers1h δ/μ², h = {h} s", 0.042, r / mu**2, 0.05))
        out.append(
            Row(
                g,
                f"RK21 |δ|/μ², h = {h} s",
                0.083,
                abs(k) / mu**2,
                0.05,
                note="printed δ = 0.083 μ²",
            )
        )
        out.append(
            Row(
                g,
                f"sign of RK21 drift × sign of Revers1h drift, h = {h} s",
                -1.0,
                float(np.sign(k) * np.sign(r)),
                0.0,
                "abs",
                note="'anti-phase': opposite signs",
            )
        )
        if h >= 0.01:
            out.append(Row(g, f"RK21/Revers1h drift ratio, h = {h} s", 2.0, abs(k / r), 0.10, note="'about twice'"))
    lit_note = "literal eq. (6) with ε → ω1 − ω0 (DIGEST_001_004 §2.4 item 3); ∝ a², matches only at a = 0.1"
    for h in (0.1, 0.01):
        mu = OMEGA * h
        p = coning_drift("picard_literal", mu)
        out.append(Row(g, f"Picard δ/μ², h = {h} s", 0.0021, abs(p) / mu**2, 0.10, note=lit_note))
        out.append(
            Row(
                g,
                f"Revers1h/Picard drift ratio, h = {h} s",
                20.0,
                coning_drift("revers1h", mu) / abs(p),
                0.10,
                note="'more than 20 times less than Revers1h'",
            )
        )
    pc = coning_drift("picard", 0.1)
    out.append(
        Row(
            g,
            "Picard (corrected eq. 6) δ/μ², h = 0.1 s",
            None,
            abs(pc) / 0.01,
            0.05,
            "rel",
            0.0828,
            "no published value: the correct Picard formula is no better than RK21 (digest §2.7)",
        )
    )
    for mu in (1.0, 0.5, 0.1):
        out.append(
            Row(
                g,
                f"ExpRvrs1h δ/μ⁴, μ = {mu}",
                7.3e-3,
                abs(coning_drift("exprvrs1h", mu)) / mu**4,
                0.10,
                note="fourth-order law, printed for 0.05 < μ < 1",
            )
        )
    out.append(
        Row(
            g,
            "ExpRvrs1h δ/μ⁴, μ = 0.01",
            None,
            abs(coning_drift("exprvrs1h", 0.01)) / 1e-8,
            0.10,
            "rel",
            7.64e-3,
            "printed law here is 1.6e-7 μ² (likely 1.6e-5, DIGEST_001_004 §8 item 22); the 4th-order law persists",
        )
    )
    # 002-I: the printed small-μ law δ = 1.6e-7 μ² (0.001 < μ < 0.05). Ours keeps the fourth-order law
    # 7.64e-3 μ⁴, so δ/μ² = 7.64e-3 μ² is 7.64e-7 at μ = 0.01 (4.8× the printed coefficient) and 1.22e-5 at
    # μ = 0.04: the law is not reproduced with either the printed 1.6e-7 or the digest's 1.6e-5 reading.
    for mu, expect in ((0.04, 1.222e-5), (0.01, 7.64e-7)):
        out.append(
            Row(
                g,
                f"ExpRvrs1h δ/μ² (small-μ law 1.6e-7 μ²), μ = {mu}",
                1.6e-7,
                abs(coning_drift("exprvrs1h", mu)) / mu**2,
                0.10,
                note="printed for 0.001 < μ < 0.05 (1.6e-5 in the digest's reading, DIGEST_001_004 §8 item 22)",
                discrepancy=f"small-μ law not reproduced: the fourth-order 7.64e-3 μ⁴ persists, δ/μ² = "
                f"{expect / 1.6e-7:.2g}× the printed 1.6e-7"
                + (" and 0.76× the 1.6e-5 reading" if mu == 0.04 else " (0.048× the 1.6e-5 reading)"),
                expect=expect,
                expect_tol=0.03,
            )
        )
    r1 = abs(coning_drift("exprvrs1h", 1.0) / coning_drift("picard_literal", 1.0))
    for bound, chk in ((0.5, "ge"), (2.0, "le")):
        out.append(
            Row(g, f"ExpRvrs1h/Picard drift ratio at μ = 1 ({chk} {bound})", None, r1, check=chk, reference=bound,
                note="'at μ = 1 similar to Picard': checked within 0.5…2 (digest: 1.2)")
        )  # fmt: skip
    for mu in (0.04, 0.02):
        rr = coning_drift("revers1h", mu) / coning_drift("exprvrs1h", mu)
        out.append(
            Row(
                g,
                f"Revers1h/ExpRvrs1h drift ratio, μ = {mu}",
                2600.0,
                rr,
                check="ge",
                note="'2600 times' holds only for μ ≲ 0.046",
            )
        )
    rr5 = coning_drift("revers1h", 0.05) / coning_drift("exprvrs1h", 0.05)
    out.append(
        Row(
            g,
            "Revers1h/ExpRvrs1h drift ratio, μ = 0.05",
            2600.0,
            rr5,
            check="ge",
            note="digest: 2183",
            discrepancy="the '2600 times' claim fails at μ = 0.05 (it holds for μ ≲ 0.046, row below)",
            expect=2180.0,
            expect_tol=0.02,
        )
    )
    out.append(
        Row(
            g,
            "largest μ with ratio ≥ 2600",
            None,
            ratio_crossover(),
            0.002,
            "abs",
            0.046,
            "from the fitted laws 0.0416 μ² / 7.64e-3 μ⁴ (DIGEST_001_004 §2.7)",
        )
    )
    out += phase_rows()
    out += norm_rows()
    return out


def phase_dependence(kind: str, mu: float = 0.1) -> dict[int, float]:
    """δ(ε) (signed) for ε = −180°…180° in 15° steps (002-J)."""
    return {e: coning_drift(kind, mu, eps=math.radians(e)) for e in range(-180, 181, 15)}


def phase_rows() -> list[Row]:
    """002-J: Revers1h and RK21 drifts ∝ sin ε, of opposite sign, zero at 0°/180°, largest at ±90° (μ = 0.1)."""
    g = "Seed 002 phase dependence (002-J, μ = 0.1, ε = −180°…180° step 15°)"
    out: list[Row] = []
    dr, dk = phase_dependence("revers1h"), phase_dependence("rk21")
    for name, d in (("Revers1h", dr), ("RK21", dk)):
        amp = d[90]
        dev = max(abs(v - amp * math.sin(math.radians(e))) for e, v in d.items()) / abs(amp)
        out.append(Row(g, f"{name}: max |δ(ε) − δ(90°) sin ε| / |δ(90°)|", None, dev, 1e-3, "abs", 0.0, "'∝ sin ε'"))
        argmax = max(d, key=lambda e: abs(d[e]))
        out.append(Row(g, f"{name}: |ε| of the largest drift [deg]", None, float(abs(argmax)), 0.0, "abs", 90.0))
    opp = all(dr[e] * dk[e] < 0 for e in dr if e % 180)
    out.append(
        Row(g, "opposite signs at every ε ≠ 0°, 180° (1 = yes)", None, float(opp), 0.0, "abs", 1.0, "'anti-phase'")
    )
    return out


def norm_growth(kind: str, h: float, seed: int = 0) -> tuple[float, float]:
    """(|N|² − 1, the digest's law) for one step with random ω0, ω1 (002-K).

    Revers1h: h²(|ω0|² + |ω1|²)/16 + O(h⁴); RK21: h²|ω1 − ω0|²/16 + h⁴|ω0|²|ω1|²/64 (exact)."""
    rng = np.random.default_rng(seed)
    w0, w1 = rng.normal(size=3), rng.normal(size=3)
    n = increments(w0, w1, h, kind)
    if kind == "revers1h":
        law = h * h * (w0 @ w0 + w1 @ w1) / 16.0
    else:
        law = h * h * ((w1 - w0) @ (w1 - w0)) / 16.0 + h**4 * (w0 @ w0) * (w1 @ w1) / 64.0
    return float(n @ n - 1.0), float(law)


def norm_rows() -> list[Row]:
    """002-K: the step quaternion's norm growth (the claim 'steady' for RK21, growing for Revers1h)."""
    g = "Seed 002 normalisation (002-K, one step, random ω0, ω1, h = 1e-3 s)"
    out = []
    for kind, name, tol in (("revers1h", "Revers1h", 1e-5), ("rk21", "RK21", 1e-8)):
        d, law = norm_growth(kind, 1e-3)
        out.append(Row(g, f"{name}: (|N|² − 1) / law", None, d / law, tol, "abs", 1.0, "DIGEST_001_004 §6 case 22"))
    return out
