"""Linear Kalman filters for a continuous-time model with asynchronous, per-sensor discrete measurements.

Seed 003 §3 (lines 782–866; DIGEST_001_004 §3.5), after Beard & McLain ch. 8: the model

    ẋ = A x + B u + ξ,  ξ white with spectral density Q;   y_i(t_n) = C_i x(t_n) + η_i,  η_i ~ (0, R_i)

Between measurements the estimate and its covariance are integrated in continuous time,

    x̂̇ = A x̂ + B u,    Ṗ = A P + P Aᵀ + Q,

and when sensor i reports at its own time t_n (any spacing, sensors interleaved)

    L_i = P⁻ C_iᵀ (R_i + C_i P⁻ C_iᵀ)⁻¹,   P⁺ = (I − L_i C_i) P⁻,   x̂⁺ = x̂⁻ + L_i (y_i − C_i x̂⁻).

The seed's intermediate line "L = P⁻Cᵀ(R + CP⁻)⁻¹" lacks a Cᵀ; its final form (above) is used. The thesis prints
no numbers to reproduce; tests/test_fusion_continuous_discrete.py holds the filter against Van Loan's exact
discretisation, a closed-form scalar case and the discrete filter in the small-step limit.

Two filters share one interface (:data:`LINEAR_FILTERS`, :func:`make_linear_filter`):

* ``"continuous_discrete"`` (:class:`ContinuousDiscreteKF`): the seed's filter, x̂ and P integrated by classical
  RK4 in sub-steps of at most ``max_step`` s up to each measurement time;
* ``"discrete"`` (:class:`DiscreteKF`): the same model discretised exactly over each interval (Φ = e^{AΔt},
  Q_d by Van Loan's matrix exponential; u held constant over the interval), the discrete filter of book §3.1.

Offline and tool use (analysis, simulation, the reproduction): not part of the real-time core's hot path, which
runs :class:`ins_hil.fusion.ekf.ErrorStateEKF`.
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field

import numpy as np
from numpy.typing import ArrayLike
from scipy.linalg import expm

from ins_hil.types import Vec

__all__ = [
    "LINEAR_FILTERS",
    "ContinuousDiscreteKF",
    "DiscreteKF",
    "Sensor",
    "make_linear_filter",
    "van_loan",
]


@dataclass(frozen=True)
class Sensor:
    """One measurement channel: y = C x + η, η ~ (0, R) (C: m×n, R: m×m)."""

    C: Vec
    R: Vec


def van_loan(A: Vec, Q: Vec, dt: float) -> tuple[Vec, Vec]:
    """(Φ, Q_d) of ẋ = A x + ξ over dt s: Φ = e^{AΔt}, Q_d = ∫₀^Δt e^{As} Q e^{Aᵀs} ds (Van Loan 1978)."""
    n = A.shape[0]
    M = np.zeros((2 * n, 2 * n))
    M[:n, :n] = -A
    M[:n, n:] = Q
    M[n:, n:] = A.T
    E = expm(M * dt)
    Phi = E[n:, n:].T
    Qd = Phi @ E[:n, n:]
    return Phi, 0.5 * (Qd + Qd.T)


@dataclass
class _LinearKF:
    """State, covariance, time and the named sensors of a linear filter (see the module docstring)."""

    A: Vec
    Q: Vec
    x: Vec
    P: Vec
    B: Vec | None = None
    t: float = 0.0
    sensors: dict[str, Sensor] = field(default_factory=dict)
    n_updates: int = 0

    def __post_init__(self) -> None:
        self.A = np.atleast_2d(np.asarray(self.A, dtype=np.float64))
        self.Q = np.atleast_2d(np.asarray(self.Q, dtype=np.float64))
        self.x = np.asarray(self.x, dtype=np.float64).reshape(-1).copy()
        self.P = np.atleast_2d(np.asarray(self.P, dtype=np.float64)).copy()
        n = self.x.shape[0]
        for name, m in (("A", self.A), ("Q", self.Q), ("P", self.P)):
            if m.shape != (n, n):
                raise ValueError(f"{type(self).__name__}: {name} has shape {m.shape}, expected ({n}, {n})")
        if self.B is not None:
            self.B = np.atleast_2d(np.asarray(self.B, dtype=np.float64))
            if self.B.shape[0] != n:
                raise ValueError(f"{type(self).__name__}: B has {self.B.shape[0]} rows, expected {n}")
        self.sensors = {k: self._sensor(v.C, v.R, k) for k, v in self.sensors.items()}

    def _sensor(self, C: ArrayLike, R: ArrayLike, name: str) -> Sensor:
        c = np.atleast_2d(np.asarray(C, dtype=np.float64))
        r = np.atleast_2d(np.asarray(R, dtype=np.float64))
        m = c.shape[0]
        if c.shape[1] != self.x.shape[0] or r.shape != (m, m):
            raise ValueError(f"sensor {name!r}: C {c.shape} / R {r.shape} do not fit a state of {self.x.shape[0]}")
        return Sensor(c, r)

    def add_sensor(self, name: str, C: ArrayLike, R: ArrayLike) -> None:
        """Register sensor ``name`` (y = C x + η, η ~ (0, R))."""
        self.sensors[name] = self._sensor(C, R, name)

    def _drive(self, u: ArrayLike | None) -> Vec:
        if u is None or self.B is None:
            return np.zeros(self.x.shape[0])
        return self.B @ np.asarray(u, dtype=np.float64).reshape(-1)

    def _advance(self, dt: float, bu: Vec) -> None:
        raise NotImplementedError

    def predict_to(self, t: float, u: ArrayLike | None = None) -> None:
        """Propagate x̂ and P from the filter's time to ``t`` (s) with input ``u`` held over the interval."""
        dt = float(t) - self.t
        if not math.isfinite(dt) or dt < 0.0:
            raise ValueError(f"predict_to({t!r}): before the filter's time {self.t!r} s (measurements in time order)")
        if dt > 0.0:
            self._advance(dt, self._drive(u))
        self.t = float(t)

    def update(self, sensor: str, y: ArrayLike, t: float | None = None, u: ArrayLike | None = None) -> None:
        """Measurement ``y`` of ``sensor`` at its own time ``t`` (default: the filter's time): propagate to ``t``,
        then L = P⁻Cᵀ(R + CP⁻Cᵀ)⁻¹, P⁺ = (I − LC)P⁻, x̂⁺ = x̂⁻ + L(y − Cx̂⁻) (seed 003)."""
        s = self.sensors.get(sensor)
        if s is None:
            raise ValueError(f"unknown sensor {sensor!r}; registered: {sorted(self.sensors)}")
        if t is not None:
            self.predict_to(t, u)
        yv = np.asarray(y, dtype=np.float64).reshape(-1)
        if yv.shape[0] != s.C.shape[0]:
            raise ValueError(f"sensor {sensor!r}: {yv.shape[0]} values, expected {s.C.shape[0]}")
        P, C = self.P, s.C
        S = s.R + C @ P @ C.T
        L = np.linalg.solve(S, C @ P).T  # P⁻Cᵀ S⁻¹ (S, P symmetric)
        self.x = self.x + L @ (yv - C @ self.x)
        P = (np.eye(P.shape[0]) - L @ C) @ P
        self.P = 0.5 * (P + P.T)
        self.n_updates += 1

    def run(
        self, measurements: Sequence[tuple[float, str, ArrayLike]], u: ArrayLike | None = None
    ) -> list[tuple[float, Vec, Vec]]:
        """Fuse (t, sensor, y) in time order (ties keep their order); returns (t, x̂⁺, P⁺) after each."""
        out = []
        for t, name, y in sorted(measurements, key=lambda m: m[0]):
            self.update(name, y, t, u)
            out.append((self.t, self.x.copy(), self.P.copy()))
        return out


@dataclass
class ContinuousDiscreteKF(_LinearKF):
    """Seed 003's continuous–discrete filter: x̂̇ = Ax̂ + Bu and Ṗ = AP + PAᵀ + Q integrated by RK4 in sub-steps
    of at most ``max_step`` s between the (asynchronous) measurements."""

    max_step: float = 0.01

    def __post_init__(self) -> None:
        super().__post_init__()
        if not (math.isfinite(self.max_step) and self.max_step > 0.0):
            raise ValueError(f"ContinuousDiscreteKF.max_step={self.max_step!r}: expected a finite value > 0 (s)")

    def _advance(self, dt: float, bu: Vec) -> None:
        A, Q = self.A, self.Q
        k = max(1, math.ceil(dt / self.max_step - 1e-9))
        h = dt / k
        x, P = self.x, self.P

        def fx(x: Vec) -> Vec:
            return A @ x + bu

        def fP(P: Vec) -> Vec:
            AP = A @ P
            return AP + AP.T + Q  # Ṗ = AP + PAᵀ + Q (P symmetric)

        for _ in range(k):
            k1, m1 = fx(x), fP(P)
            k2, m2 = fx(x + 0.5 * h * k1), fP(P + 0.5 * h * m1)
            k3, m3 = fx(x + 0.5 * h * k2), fP(P + 0.5 * h * m2)
            k4, m4 = fx(x + h * k3), fP(P + h * m3)
            x = x + (h / 6.0) * (k1 + 2.0 * k2 + 2.0 * k3 + k4)
            P = P + (h / 6.0) * (m1 + 2.0 * m2 + 2.0 * m3 + m4)
        self.x, self.P = x, 0.5 * (P + P.T)


@dataclass
class DiscreteKF(_LinearKF):
    """The same model discretised exactly over each interval: x̂ ← Φx̂ + Γu, P ← ΦPΦᵀ + Q_d (:func:`van_loan`)."""

    def _advance(self, dt: float, bu: Vec) -> None:
        Phi, Qd = van_loan(self.A, self.Q, dt)
        n = self.x.shape[0]
        if np.any(bu):  # Γu = ∫₀^Δt e^{As} ds · Bu, from the augmented exponential
            M = np.zeros((n + 1, n + 1))
            M[:n, :n] = self.A
            M[:n, n] = bu
            drive = expm(M * dt)[:n, n]
        else:
            drive = np.zeros(n)
        self.x = Phi @ self.x + drive
        P = Phi @ self.P @ Phi.T + Qd
        self.P = 0.5 * (P + P.T)


LINEAR_FILTERS: dict[str, type[_LinearKF]] = {"continuous_discrete": ContinuousDiscreteKF, "discrete": DiscreteKF}


def make_linear_filter(
    kind: str,
    A: ArrayLike,
    Q: ArrayLike,
    x0: ArrayLike,
    P0: ArrayLike,
    sensors: Mapping[str, tuple[ArrayLike, ArrayLike]] | None = None,
    B: ArrayLike | None = None,
    t0: float = 0.0,
    **options: float,
) -> _LinearKF:
    """A linear filter of ``kind`` ("continuous_discrete" | "discrete") for ẋ = Ax + Bu + ξ (ξ density Q) from
    (x0, P0) at t0 s, with named sensors {name: (C, R)}; ``options``: ``max_step`` (s, continuous_discrete)."""
    cls = LINEAR_FILTERS.get(kind)
    if cls is None:
        raise ValueError(f"linear filter {kind!r}: expected one of {sorted(LINEAR_FILTERS)}")
    if options and cls is not ContinuousDiscreteKF:
        raise ValueError(f"linear filter {kind!r} takes no options ({sorted(options)})")
    sens = {k: Sensor(np.asarray(c, dtype=np.float64), np.asarray(r, dtype=np.float64))
            for k, (c, r) in (sensors or {}).items()}  # fmt: skip
    return cls(A=A, Q=Q, x=x0, P=P0, B=B, t=t0, sensors=sens, **options)  # type: ignore[arg-type]
