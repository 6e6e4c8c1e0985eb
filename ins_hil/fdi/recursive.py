"""Isolation under noise with the recursive least-squares (Kalman) statistic (book 5.3).

DIGEST_000 §5.3, §10 item 39. Model y = A ω + e + w, ⟨ww'⟩ = σ² I (eq. 5.18).
The LS solution is started on the first r = n − m equations (eq. 5.20) and the
remaining equations α'x = z are added one at a time (eq. 5.21, Lee 1964):

    v = z − α' x̄,   Y_v = (α' P̃ α + σ²)⁻¹,
    x̄ ← x̄ + P̃ α Y_v v,   P̃ ← P̃ − P̃ α Y_v α' P̃,    P̃ = σ² (AᵀA)⁻¹

with the χ² statistic k_s = v' Y_v v / ℓ, ℓ = 1 (eq. 5.22). The ratios
μ_j = k_s,j+1 / k_s,j are formed; the last one, μ*_r, is taken for each cyclic
transposition r = 0..n−1 of the equations (each shift moves the last equation
to the first place, i.e. ``np.roll(·, r)``), and the failed sensor is
i = n − r* with r* = argmax_r μ*_r (eq. 5.23; 1-based i as in the book).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ins_hil.types import Vec

# Book Table 5.2: the printed μ* of the five cyclic transpositions (columns r = 0..4) for a failure
# of sensor i = 1..5 (rows), book §5.3 (DIGEST_000 case 25). Kept here once for tests and bench-fdi.
BOOK_TABLE_5_2: Vec = np.array(
    [
        [0.2849, 0.0303, 0.3440, 1.4821, 367.6578],
        [0.0091, 0.2664, 1.1265, 24.3626, 0.6189],
        [0.6098, 3.5288, 5.7698, 0.0232, 0.1194],
        [2.8948, 10.2930, 0.0438, 0.0988, 0.5483],
        [58.3723, 0.1144, 0.0634, 0.4445, 2.0705],
    ]
)


def recursive_ks(y: Vec, A: Vec, sigma: float) -> Vec:
    """k_s of each added equation (eq. 5.22), the LS started on the first r equations."""
    n, r = A.shape
    if n < r + 2:
        raise ValueError(f"recursive LS isolation needs n ≥ unknowns + 2 sensors; got A {A.shape}")
    if sigma <= 0:
        raise ValueError(f"sigma must be positive, got {sigma}")
    A0, b0 = A[:r], y[:r]
    P = sigma**2 * np.linalg.inv(A0.T @ A0)  # P̃ = σ² (AᵀA)⁻¹
    x = np.linalg.solve(A0, b0) if r == A0.shape[0] else np.linalg.lstsq(A0, b0, rcond=None)[0]  # eq. 5.20
    ks = np.empty(n - r)
    s2 = sigma * sigma
    for j in range(r, n):
        a = A[j]
        Pa = P @ a
        yv = 1.0 / (float(a @ Pa) + s2)
        v = float(y[j] - a @ x)  # innovation
        ks[j - r] = v * yv * v  # eq. 5.22, ℓ = 1
        x = x + Pa * (yv * v)  # eq. 5.21
        P = P - np.outer(Pa, Pa) * yv
    return ks


@dataclass(frozen=True)
class CyclicResult:
    """μ*_r for r = 0..n−1 and the isolated sensor (0-based ``index``; book's i = index + 1)."""

    mu: Vec
    index: int


def cyclic_isolation(y: Vec, A: Vec, sigma: float) -> CyclicResult:
    """Cyclic transposition of the equations (eq. 5.23): i = n − argmax_r μ*_r."""
    n = A.shape[0]
    mu = np.empty(n)
    for r in range(n):
        ks = recursive_ks(np.roll(y, r), np.roll(A, r, axis=0), sigma)
        mu[r] = ks[-1] / max(ks[-2], 1e-300)
    return CyclicResult(mu, cyclic_decision(mu))


def cyclic_decision(mu: Vec) -> int:
    """Eq. 5.23: r* = argmax_r μ*_r, failed sensor i = n − r* (1-based), returned 0-based."""
    return len(mu) - int(np.argmax(mu)) - 1
