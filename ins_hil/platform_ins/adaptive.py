"""Adaptive Kalman filter for the seed-004 correction (DIGEST_001_004 §4.4).

The seed names an adaptive filter that copes with unknown input and measurement noise but gives no
equations; this one adapts both, by bounded Sage–Husa scale factors
(:class:`~ins_hil.fusion.innovation.SageHusa`).
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from ins_hil.fusion.innovation import SageHusa
from ins_hil.types import Vec

from .model import VecLike

__all__ = ["AdaptiveKF"]


@dataclass
class AdaptiveKF:
    """Linear Kalman filter x_k = F x_{k−1} + w, y_k = H x_k + v with bounded Sage–Husa Q and R scales.

    R = D_R R_nom D_R and Q = D_Q Q_nom D_Q with D = diag(√s_i): one scale s_i per measurement
    component and per state with Q_nom,ii > 0 (the reduced measurements differ in quality by
    orders of magnitude, so one common scale would be set by the worst of them). Each s_i is a
    :class:`~ins_hil.fusion.innovation.SageHusa` estimator: for R on the innovation sample
    (ν_i² − (HP⁻Hᵀ)_ii)/R_nom,ii, for Q on the Sage–Husa process-noise sample
    ((Kν)_i² + P⁺_ii − (F P⁺_{k−1} Fᵀ)_ii)/Q_nom,ii. All scales stay in [s_min, s_max];
    ``adapt=False`` gives the conventional filter with the nominal Q, R.
    """

    F: Vec
    H: Vec
    q_nom: VecLike  # Q_nom: diagonal (1-D) or full matrix
    r_nom: VecLike  # R_nom: diagonal (1-D) or full matrix
    x: Vec
    P: Vec
    adapt: bool = True
    b: float = 0.98
    s_min: float = 1e-3
    s_max: float = 1e3
    sq: list[SageHusa] = field(init=False)
    sr: list[SageHusa] = field(init=False)

    def __post_init__(self) -> None:
        q = np.asarray(self.q_nom, dtype=float)
        r = np.asarray(self.r_nom, dtype=float)
        self.q_nom = np.diag(q) if q.ndim == 1 else q
        self.r_nom = np.diag(r) if r.ndim == 1 else r
        self.sq = [SageHusa(b=self.b, s_min=self.s_min, s_max=self.s_max) for _ in range(self.q_nom.shape[0])]
        self.sr = [SageHusa(b=self.b, s_min=self.s_min, s_max=self.s_max) for _ in range(self.r_nom.shape[0])]

    @property
    def q_scales(self) -> Vec:
        return np.array([e.scale for e in self.sq])

    @property
    def r_scales(self) -> Vec:
        return np.array([e.scale for e in self.sr])

    @property
    def Q(self) -> Vec:
        d = np.sqrt(self.q_scales)
        return d[:, None] * self.q_nom * d[None, :]

    @property
    def R(self) -> Vec:
        d = np.sqrt(self.r_scales)
        return d[:, None] * self.r_nom * d[None, :]

    def predict(self) -> Vec:
        """Time update only (no measurement this step)."""
        self.x = self.F @ self.x
        self.P = self.F @ self.P @ self.F.T + self.Q
        return self.x

    def step(self, y: Vec) -> Vec:
        """Predict one step and update with measurement ``y``; returns the new estimate."""
        F, H = self.F, self.H
        x_pred = F @ self.x
        FPF = F @ self.P @ F.T
        P_pred = FPF + self.Q
        nu = np.asarray(y, dtype=float) - H @ x_pred
        hph = H @ P_pred @ H.T
        if self.adapt:
            rd = np.diag(self.r_nom)
            for i, e in enumerate(self.sr):
                e.update(nu[i : i + 1], hph[i : i + 1, i], rd[i : i + 1])
        S = hph + self.R
        K = np.linalg.solve(S, H @ P_pred).T
        self.x = x_pred + K @ nu
        I_KH = np.eye(len(self.x)) - K @ H
        self.P = I_KH @ P_pred @ I_KH.T + K @ self.R @ K.T  # Joseph form
        if self.adapt:
            qd = np.diag(self.q_nom)
            kn = K @ nu
            dd = np.diag(FPF - self.P)
            for i, e in enumerate(self.sq):
                if qd[i] > 0.0:
                    e.update(kn[i : i + 1], dd[i : i + 1], qd[i : i + 1])
        return self.x
