"""Overlapping Allan variance of a static inertial record and the noise terms read off it.

Book §4.2.2 (eq. 4.24 and Fig. 4.7: the Allan plot gives the best averaging
time for the bias); method and slopes after IEEE Std 952-1997 Annex C
(El-Sheimy, Hou & Niu 2008, cited by the book). For a rate signal Ω(t) sampled
at dt and its integral θ_k = Σ Ω_i dt (for increments: θ_k = Σ Δθ_i)::

    σ²(τ) = 1 / (2 τ² (L − 2m)) Σ_{k=0}^{L−2m−1} (θ_{k+2m} − 2 θ_{k+m} + θ_k)²,   τ = m dt

(overlapping estimator, L = N + 1 cumulative samples). The noise terms and
their log–log slopes on σ(τ):

=====================  ========  =============================================
term                   slope     read off
=====================  ========  =============================================
white noise N          −1/2      σ(τ = 1 s) on the −½ line (ARW rad/s/√Hz, VRW m/s²/√Hz)
bias instability B     0         flat floor (median of the slope-0 points, else the minimum) / 0.664
rate random walk K     +1/2      σ(τ = 3 s) on the +½ line (rad/s/√s, m/s²/√s)
=====================  ========  =============================================

Besides the read-off, :func:`noise_parameters` fits σ²(τ) = N²/τ + (2 ln2/π) B²
+ K² τ/3 by non-negative weighted least squares over the whole curve, which is
less sensitive to where the regimes overlap. Pure numpy, vectorised over the
record (one pass per τ).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
import scipy.optimize

from ins_hil.types import Vec

#: σ_B(flat) = B·√(2 ln2 / π): the bias-instability floor factor (IEEE 952 C.1.3)
B_FACTOR = math.sqrt(2.0 * math.log(2.0) / math.pi)


@dataclass
class AllanResult:
    """Allan deviation per τ (s) and axis: ``adev`` (M, k) in the rate unit; ``n_clusters`` (M,)."""

    tau: Vec
    adev: Vec
    n_clusters: Vec

    @property
    def rel_error(self) -> Vec:
        """Approximate 1-σ relative error of each σ(τ): 1/√(2(N/m − 1)) (IEEE 952 C.1)."""
        return 1.0 / np.sqrt(2.0 * np.maximum(self.n_clusters - 1.0, 1.0))


def cluster_sizes(n: int, points_per_decade: int = 10, max_fraction: float = 0.1) -> Vec:
    """Log-spaced cluster sizes m (integers ≥ 1, unique) up to ``max_fraction``·n."""
    mmax = max(1, int(n * max_fraction))
    k = max(1, math.ceil(math.log10(mmax) * points_per_decade) + 1)
    return np.unique(np.round(np.logspace(0, math.log10(mmax), k)).astype(np.int64))


def allan_deviation(increments: Vec, dt: float, points_per_decade: int = 10, max_fraction: float = 0.1) -> AllanResult:
    """Overlapping Allan deviation of increments (N,) or (N, k) — Δθ (rad) or Δv (m/s) per dt (s).

    The result is in the rate unit (rad/s or m/s²). τ runs from dt to ``max_fraction`` of
    the record (beyond that the estimate has too few independent clusters).
    """
    inc = np.asarray(increments, dtype=np.float64)
    if inc.ndim == 1:
        inc = inc[:, None]
    n = len(inc)
    if n < 20:
        raise ValueError(f"Allan variance needs a long static record; got {n} samples")
    if dt <= 0:
        raise ValueError(f"dt must be positive, got {dt}")
    # remove the mean rate (σ² is invariant to it) so the running sum stays small
    inc = inc - inc.mean(axis=0)
    theta = np.vstack([np.zeros((1, inc.shape[1])), np.cumsum(inc, axis=0)])
    big_l = len(theta)
    ms = cluster_sizes(n, points_per_decade, max_fraction)
    adev = np.empty((len(ms), inc.shape[1]))
    for j, m in enumerate(ms):
        d = theta[2 * m :] - theta[m:-m]
        d -= theta[m:-m]
        d += theta[: big_l - 2 * m]
        tau = m * dt
        adev[j] = np.sqrt(np.einsum("ij,ij->j", d, d) / (2.0 * tau * tau * (big_l - 2 * m)))
    return AllanResult(ms * dt, adev, (n / ms).astype(np.float64))


@dataclass
class NoiseParameters:
    """Noise terms of one axis (rate units: rad/s or m/s²).

    random_walk N (·/√Hz = ·√s), bias_instability B, rate_random_walk K (·/√s);
    ``*_readoff`` are read off the curve (slope lines / minimum), the plain fields
    are the weighted least-squares fit; ``tau_min`` is the τ (s) of the minimum,
    the best bias-averaging time (book Fig. 4.7: 100–200 s for the ADIS16362).
    """

    random_walk: float
    bias_instability: float
    rate_random_walk: float
    random_walk_readoff: float
    bias_instability_readoff: float
    rate_random_walk_readoff: float
    tau_min: float
    adev_min: float

    def as_dict(self) -> dict[str, float]:
        return {
            "random_walk": self.random_walk,
            "bias_instability": self.bias_instability,
            "rate_random_walk": self.rate_random_walk,
            "random_walk_readoff": self.random_walk_readoff,
            "bias_instability_readoff": self.bias_instability_readoff,
            "rate_random_walk_readoff": self.rate_random_walk_readoff,
            "tau_min": self.tau_min,
            "adev_min": self.adev_min,
        }


def _line_readoff(tau: Vec, adev: Vec, slope: float, tau_read: float, tol: float = 0.15) -> float:
    """Value at ``tau_read`` of the line of ``slope`` through the points whose local slope is within tol.

    The points are those where the log–log slope (central differences) is close to
    ``slope``; the intercept is the median of log σ − slope·log τ over them. NaN if none.
    """
    lt, la = np.log10(tau), np.log10(adev)
    if len(lt) < 3:
        return math.nan
    local = np.gradient(la, lt)
    sel = np.abs(local - slope) <= tol
    if not sel.any():
        return math.nan
    icpt = float(np.median(la[sel] - slope * lt[sel]))
    return 10.0 ** (icpt + slope * math.log10(tau_read))


def noise_parameters(res: AllanResult, axis: int = 0, min_clusters: float = 30.0) -> NoiseParameters:
    """Read N, B, K off the Allan curve of one axis and fit them jointly (see module doc).

    The minimum and the +½ line use only τ with ≥ ``min_clusters`` clusters (T/τ).
    """
    tau = res.tau
    ad = res.adev[:, axis]
    ok = ad > 0
    tau, ad, nc = tau[ok], ad[ok], res.n_clusters[ok]
    # the minimum (and the +½ line) only where the estimate has enough clusters
    conf = nc >= min_clusters
    if not conf.any():
        raise ValueError(f"record too short: no τ with at least {min_clusters} clusters")
    j = int(np.argmin(np.where(conf, ad, np.inf)))
    n_ro = _line_readoff(tau, ad, -0.5, 1.0)
    k_ro = _line_readoff(tau[j:][conf[j:]], ad[j:][conf[j:]], 0.5, 3.0)
    # flat part (slope 0) of the confident points; the bare minimum if there is none
    b_flat = _line_readoff(tau[conf], ad[conf], 0.0, 1.0)
    b_ro = float((ad[j] if math.isnan(b_flat) else b_flat) / B_FACTOR)
    # σ² = N²/τ + (2ln2/π)B² + K²τ/3, relative weights ∝ 1/(σ² · rel_err)
    g = np.column_stack([1.0 / tau, np.full_like(tau, B_FACTOR**2), tau / 3.0])
    # two passes: weights from the measured, then from the fitted curve (less biased by dips)
    sig2 = ad**2
    coef = np.zeros(3)
    for _ in range(2):
        w = np.sqrt(np.maximum(nc - 1.0, 1.0)) / sig2
        coef, _ = scipy.optimize.nnls(g * w[:, None], ad**2 * w)
        sig2 = np.maximum(g @ coef, 1e-300)
    return NoiseParameters(
        random_walk=math.sqrt(coef[0]),
        bias_instability=math.sqrt(coef[1]),
        rate_random_walk=math.sqrt(coef[2]),
        random_walk_readoff=n_ro,
        bias_instability_readoff=b_ro,
        rate_random_walk_readoff=k_ro,
        tau_min=float(tau[j]),
        adev_min=float(ad[j]),
    )


def model_adev(tau: Vec, p: NoiseParameters) -> Vec:
    """σ(τ) of the fitted three-term model (for plotting)."""
    return np.sqrt(p.random_walk**2 / tau + (B_FACTOR * p.bias_instability) ** 2 + p.rate_random_walk**2 * tau / 3.0)
