"""Innovation gating and adaptive measurement-noise estimation.

Gating: every scalar innovation ν_i of a measurement group is normalised by its
innovation variance S_ii; the group's test ratio is max_i ν_i² / (g² S_ii) with
the gate g in σ (PX4-style: ratio > 1 ⇒ reject). The normalised innovation
squared NIS = ν^T S^{−1} ν is kept for consistency checks (χ² with dim(ν) dof).

Adaptive R (seed 004 names an adaptive KF but does not specify it,
DIGEST_001_004 §4.4): Sage–Husa covariance matching on a per-group scale
factor, R = s R_nom with

    s_k = (1 − d_k) s_{k−1} + d_k · mean_i (ν_i² − (H P⁻ H^T)_ii) / R_nom,i,
    d_k = (1 − b) / (1 − b^{k+1})   (fading memory b, Sage & Husa 1969),

bounded to [s_min, s_max] so R stays positive and cannot run away.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from ins_hil.types import Vec


@dataclass
class GateStats:
    """Counters and the last test ratio / NIS of one measurement group."""

    accepted: int = 0
    rejected: int = 0
    consecutive_rejects: int = 0
    last_ratio: float = 0.0
    last_nis: float = 0.0
    nis_sum: float = 0.0
    nis_dof: int = 0


def test_ratio(nu: Vec, S: Vec, gate_sigma: float) -> tuple[float, float]:
    """(test ratio, NIS) of an innovation ν with covariance S and a gate in σ."""
    d = np.diag(S)
    ratio = float(np.max(nu * nu / (gate_sigma * gate_sigma * d)))
    return ratio, nis_of(nu, S)


def nis_of(nu: Vec, S: Vec) -> float:
    """ν^T S^{−1} ν; 1–2 dimensions in closed form (a 3-D GNSS group by the Cholesky factors), else solve.

    The closed forms avoid numpy.linalg's per-call overhead (~25 µs, in the GNSS update on the IMU loop);
    they agree with ``np.linalg.solve`` to rounding. Singular or indefinite S: NaN / solve's error."""
    n = len(nu)
    if n == 1:
        return float(nu[0] * nu[0] / S[0, 0])
    if n == 2:
        a, b, c = float(S[0, 0]), float(S[0, 1]), float(S[1, 1])
        x, y = float(nu[0]), float(nu[1])
        return (c * x * x - 2.0 * b * x * y + a * y * y) / (a * c - b * b)
    if n == 3:
        # S = L L^T; NIS = |L^{-1} ν|²
        s00, s10, s11 = float(S[0, 0]), float(S[1, 0]), float(S[1, 1])
        s20, s21, s22 = float(S[2, 0]), float(S[2, 1]), float(S[2, 2])
        if s00 > 0.0:
            l00 = s00**0.5
            l10, l20 = s10 / l00, s20 / l00
            d11 = s11 - l10 * l10
            if d11 > 0.0:
                l11 = d11**0.5
                l21 = (s21 - l20 * l10) / l11
                d22 = s22 - l20 * l20 - l21 * l21
                if d22 > 0.0:
                    y0 = float(nu[0]) / l00
                    y1 = (float(nu[1]) - l10 * y0) / l11
                    y2 = (float(nu[2]) - l20 * y0 - l21 * y1) / d22**0.5
                    return y0 * y0 + y1 * y1 + y2 * y2
    return float(nu @ np.linalg.solve(S, nu))


@dataclass
class SageHusa:
    """Bounded Sage–Husa estimator of a scale factor on the nominal R of one measurement group."""

    b: float = 0.97
    s_min: float = 0.1
    s_max: float = 400.0
    scale: float = 1.0
    k: int = 0
    history: list[float] = field(default_factory=list)

    def update(self, nu: Vec, HPHt_diag: Vec, r_nom: Vec) -> float:
        """Feed one innovation (before the update) and return the new scale."""
        d = (1.0 - self.b) / (1.0 - self.b ** (self.k + 1))
        sample = float(np.mean((nu * nu - HPHt_diag) / r_nom))
        s = (1.0 - d) * self.scale + d * sample
        self.scale = min(self.s_max, max(self.s_min, s))
        self.k += 1
        return self.scale
