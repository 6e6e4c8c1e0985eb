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


def chi2_threshold(p: float, dof: int) -> float:
    """x with P(χ²_dof > x) = p: 2·Q⁻¹(dof/2, p), Q the regularised upper incomplete gamma function (what
    ``scipy.stats.chi2.isf`` computes; scipy.special alone loads in half the time of scipy.stats, which every
    replay paid at start-up)."""
    from scipy.special import gammainccinv

    if not 0.0 < p < 1.0:
        raise ValueError(f"false-alarm probability must be in (0, 1), got {p}")
    if dof < 1:
        raise ValueError(f"degrees of freedom must be ≥ 1, got {dof}")
    return float(2.0 * gammainccinv(0.5 * dof, p))


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
