"""Detection thresholds from sensor noise and a false-alarm probability (the book gives none, §10 item 39).

With the outputs whitened by their noise (y/σ), the parity vector p = U₂ᵀ y/σ of a
healthy set is N(0, I_m), so ‖p‖² is χ²_m (the statistic of eq. 5.22 generalised).

* Fast test (every sample): an alarm needs ``persistence`` consecutive exceedances.
  For white noise a run of N exceedances of per-sample probability p_s starts
  about (epochs per hour)·p_s^N times an hour, so p_s = (P_fa / epochs)^{1/N}.
* Slow test (exponential average of p with time constant τ): its samples are
  correlated over τ, so it is counted as 3600/τ independent trials per hour and the
  persistence is not credited: p_s = P_fa·τ/3600. Its covariance is
  (α/(2−α) + β²) I_m with α = dt/τ and β = σ_bias·dt/σ_inc the residual sensor
  bias (e.g. bias instability) relative to the per-sample increment noise.
"""

from __future__ import annotations

import math


def chi2_sf(x: float, dof: int) -> float:
    """P(χ²_dof > x) for an integer ``dof`` ≥ 1, in closed form (the regularised upper incomplete gamma function
    Q(dof/2, x/2): a finite sum for an even ``dof``, erfc plus a finite sum for an odd one)."""
    if x <= 0.0:
        return 1.0
    y = 0.5 * x
    if dof % 2 == 0:
        term, total = 1.0, 1.0
        for k in range(1, dof // 2):
            term *= y / k
            total += term
        return math.exp(-y) * total
    r = math.sqrt(y)
    term = r / math.gamma(1.5)  # y^(k-1/2) / Γ(k+1/2), k = 1
    total = term if dof > 1 else 0.0
    for k in range(2, (dof + 1) // 2):
        term *= y / (k - 0.5)
        total += term
    return math.erfc(r) + math.exp(-y) * total


def chi2_threshold(p: float, dof: int) -> float:
    """x with P(χ²_dof > x) = p (what ``scipy.stats.chi2.isf`` computes, to a few ulps): :func:`chi2_sf` inverted
    by bisection, without scipy (its import cost every replay a quarter of a second at start-up)."""
    if not 0.0 < p < 1.0:
        raise ValueError(f"false-alarm probability must be in (0, 1), got {p}")
    if dof < 1 or int(dof) != dof:
        raise ValueError(f"degrees of freedom must be an integer ≥ 1, got {dof}")
    dof = int(dof)
    lo, hi = 0.0, float(dof) + 10.0
    while chi2_sf(hi, dof) > p:  # bracket the root
        lo, hi = hi, 2.0 * hi
    for _ in range(200):  # bisection to adjacent floats: Q is monotone, so this cannot fail
        mid = 0.5 * (lo + hi)
        if mid <= lo or mid >= hi:
            break
        if chi2_sf(mid, dof) > p:
            lo = mid
        else:
            hi = mid
    return hi if abs(chi2_sf(hi, dof) - p) <= abs(chi2_sf(lo, dof) - p) else lo


def fast_threshold(p_fa_hour: float, dt: float, persistence: int, dof: int) -> float:
    """χ² threshold on ‖p‖² per sample for a false-alarm probability ``p_fa_hour`` per hour."""
    if persistence < 1:
        raise ValueError(f"persistence must be ≥ 1 sample, got {persistence}")
    epochs = 3600.0 / dt
    ps = (p_fa_hour / epochs) ** (1.0 / persistence)
    return chi2_threshold(min(ps, 0.5), dof)


def slow_variance(dt: float, tau: float, bias_ratio: float) -> float:
    """Per-component variance of the averaged whitened parity vector (see module doc)."""
    a = dt / tau
    return a / (2.0 - a) + bias_ratio * bias_ratio


def slow_threshold(p_fa_hour: float, tau: float, dof: int) -> float:
    """χ² threshold on ‖p̄‖²/var for the averaged test (3600/τ trials an hour)."""
    if tau <= 0:
        raise ValueError(f"slow-test time constant must be positive, got {tau}")
    return chi2_threshold(min(p_fa_hour * tau / 3600.0, 0.5), dof)


def increment_sigma(noise_density: float, dt: float) -> float:
    """1-σ of one increment (rad or m/s) for a white-noise density (unit/s/√Hz) over ``dt`` s."""
    return noise_density * math.sqrt(dt)
