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
    nis = float(nu @ np.linalg.solve(S, nu))
    return ratio, nis


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
