"""Rotational mechanization of the book (ch. 2.3.1, DIGEST_000 §2.2) and a registry
of attitude algorithms selectable by name.

Elementary quaternions (all for the body-frame update λ_i = λ_{i-1} ⊗ δλ_i,
book eq. 2.15/2.16, which is :func:`ins_hil.nav.rotation.quat_mul`):

* ``dl1``  δλ¹  = [1, ½∇θ]                                   (eq. 2.17, Euler)
* ``dl2``  δλ²  = [1 − ‖∇θ‖²/8, ½∇θ]                          (eq. 2.17, modified Euler)
* ``dl2m`` δλ²_m = [1 − ‖∇θ‖²/12, ½∇θ]                        (Larin & Naumenko 1983)
* ``dl3``  δλ³  = [1 − ‖∇θ‖²/8, ½(1 − ‖∇θ‖²/24)∇θ − (1/24) ∇θ_i × ∇θ_{i−1}]  (eq. 2.17)
* ``dl3m`` δλ³_m = [1 − ‖∇θ‖²/12, ½∇θ − (1/24) ∇θ_i × ∇θ_{i−1}]  (eq. 2.27 = 2.18, Larin's update)
* ``dlq``  δλ_q = [1 − q‖∇θ‖², ½∇θ]                           (eq. 2.28; q* of eq. 2.31 by default)

∇θ_i is the quasi-coordinate (the integral of the body rate over the step).
From increments it is the delta angle; from rate samples ω(t_i) at a fixed step
it is the quadratic spline of eq. 2.19. The 1/12 quaternions are not unit norm:
the book normalises only for output (DIGEST_000 §10 item 7); the registry
algorithms never normalise (the strapdown core renormalises its state).

Start-up (DIGEST_000 §10 item 6, the book is silent): the cross term uses
∇θ_0 = 0 at the first step (the reading that reproduces Table 2.2, column δλ³);
eq. 2.19 falls back to the rectangle and trapezoid rules for the first two rate
samples unless :meth:`AttitudeAlgorithm.prime_rate` supplied ω(t_0).

Accuracy formulas: the optimal q* (eq. 2.31, both forms, typo of the Euler-angle
form fixed: DIGEST_000 §10 item 11), the drift rate U (eq. 2.32) and the drift
with a reference-vector correction U_m = U cos γ (eq. 2.33).

Registry: :func:`make_attitude` (by name), :func:`attitude_names`. Every
algorithm has the same interface (:class:`AttitudeAlgorithm`): it updates
q_nb by one step either from a delta angle (:meth:`~AttitudeAlgorithm.step_increment`)
or from the rate sample at the end of the step (:meth:`~AttitudeAlgorithm.step_rate`);
``native_input`` says which form the published algorithm was written for, the
other form is adapted as each class documents.
"""

from __future__ import annotations

import math
from abc import ABC, abstractmethod
from collections.abc import Callable
from typing import Any, ClassVar

import numpy as np

from ins_hil.nav.rotation import quat_from_rotvec, quat_mul
from ins_hil.registry import Registry
from ins_hil.types import Vec

__all__ = [
    "ARCSEC_PER_RAD",
    "AttitudeAlgorithm",
    "ElementaryQuaternion",
    "RotationVector",
    "attitude_names",
    "dl1",
    "dl2",
    "dl2m",
    "dl3",
    "dl3m",
    "dlq",
    "drift_rate",
    "drift_rate_corrected",
    "make_attitude",
    "propagate",
    "q_star",
    "q_star_euler",
    "quasi_coordinates_spline",
]

ARCSEC_PER_RAD = 180.0 / math.pi * 3600.0  # 206264.806...


# ---------------------------------------------------------------------------------------------
# Elementary quaternions (vectorised: ∇θ of shape (..., 3) → δλ of shape (..., 4))


def _sq(th: Vec) -> Vec:
    return np.einsum("...i,...i->...", th, th)


def dlq(th: Vec, q: float) -> Vec:
    """δλ_q = [1 − q‖∇θ‖², ½∇θ] (book eq. 2.28; q = 0, 1/8, 1/16, 1/12 give eq. 2.26's family)."""
    th = np.asarray(th, dtype=np.float64)
    out = np.empty((*th.shape[:-1], 4))
    out[..., 0] = 1.0 - q * _sq(th)
    out[..., 1:] = 0.5 * th
    return out


def dl1(th: Vec) -> Vec:
    """δλ¹ = [1, ½∇θ] (book eq. 2.17, Euler method)."""
    return dlq(th, 0.0)


def dl2(th: Vec) -> Vec:
    """δλ² = [1 − ‖∇θ‖²/8, ½∇θ] (book eq. 2.17, modified Euler)."""
    return dlq(th, 1.0 / 8.0)


def dl2m(th: Vec) -> Vec:
    """δλ²_m = [1 − ‖∇θ‖²/12, ½∇θ] (book p. after Table 2.1, Larin & Naumenko 1983)."""
    return dlq(th, 1.0 / 12.0)


def dl3(th: Vec, th_prev: Vec) -> Vec:
    """δλ³ = [1 − ‖∇θ_i‖²/8, ½(1 − ‖∇θ_i‖²/24)∇θ_i − (1/24) ∇θ_i × ∇θ_{i−1}] (book eq. 2.17)."""
    th = np.asarray(th, dtype=np.float64)
    s = _sq(th)
    out = np.empty((*th.shape[:-1], 4))
    out[..., 0] = 1.0 - s / 8.0
    out[..., 1:] = 0.5 * (1.0 - s / 24.0)[..., None] * th - np.cross(th, th_prev) / 24.0
    return out


def dl3m(th: Vec, th_prev: Vec) -> Vec:
    """δλ³_m = [1 − ‖∇θ_i‖²/12, ½∇θ_i − (1/24) ∇θ_i × ∇θ_{i−1}] (book eq. 2.18 = 2.27, Larin's update)."""
    th = np.asarray(th, dtype=np.float64)
    out = np.empty((*th.shape[:-1], 4))
    out[..., 0] = 1.0 - _sq(th) / 12.0
    out[..., 1:] = 0.5 * th - np.cross(th, th_prev) / 24.0
    return out


def quasi_coordinates_spline(w_i: Vec, w_im1: Vec, w_im2: Vec, dt: float) -> Vec:
    """∇θ_i = Δt/12 (5ω(t_i) + 8ω(t_{i−1}) − ω(t_{i−2})) (book eq. 2.19; exact for quadratic ω(t)).

    Rates in rad/s (body), dt in s; arrays may carry leading dimensions.
    """
    return (dt / 12.0) * (5.0 * np.asarray(w_i) + 8.0 * np.asarray(w_im1) - np.asarray(w_im2))


def propagate(q0: Vec, dq: Vec) -> Vec:
    """All partial products q0 ⊗ dq[0] ⊗ … ⊗ dq[k] (book eq. 2.15/2.16), shape (n + 1, 4), row 0 = q0.

    No normalisation (the book normalises only the output)."""
    n = len(dq)
    out = np.empty((n + 1, 4))
    out[0] = q = np.asarray(q0, dtype=np.float64)
    for k in range(n):
        q = quat_mul(q, dq[k])
        out[k + 1] = q
    return out


# ---------------------------------------------------------------------------------------------
# Optimal q* and drift formulas


def q_star(a: float, b: float, c: float) -> float:
    """q* = (1/12)[1 + a²c² / ((a² + b²)(a² + b² + bc))] (book eq. 2.31, body-rate form)
    for ω = [a cos ct, a sin ct, b] (rad/s)."""
    s = a * a + b * b
    return (1.0 + a * a * c * c / (s * (s + b * c))) / 12.0


def q_star_euler(phi_dot: float, psi_dot: float, theta: float) -> float:
    """q* from the classic Euler-angle rates of a regular precession (book eq. 2.30/2.31, first line).

    The printed denominator "(φ̇ cos θ + φ̇)" is a typo for (φ̇ cos θ + ψ̇) = ω_z
    (DIGEST_000 §10 item 11); this is the corrected form.
    """
    c = math.cos(theta)
    num = psi_dot * phi_dot**2 * math.sin(theta) ** 2
    den = (phi_dot * c + psi_dot) * (phi_dot**2 + psi_dot**2 + 2.0 * phi_dot * psi_dot * c)
    return (1.0 + num / den) / 12.0


def drift_rate(q: float, q_opt: float, omega_z: float, omega_norm: float, f: float) -> float:
    """Average drift rate U = |(q − q*) ω_z| ‖ω‖² / f² (rad/s) of δλ_q (book eq. 2.32).

    ω_z: rate component on the precession axis (rad/s); ‖ω‖: rate magnitude
    (rad/s); f: sampling frequency (Hz)."""
    return abs((q - q_opt) * omega_z) * omega_norm**2 / f**2


def drift_rate_corrected(u: float, gamma: float) -> float:
    """U_m = U cos γ (book eq. 2.33): drift with a correction by a reference vector at angle γ (rad) from Z."""
    return u * math.cos(gamma)


# ---------------------------------------------------------------------------------------------
# Registry: one interface for every algorithm


class AttitudeAlgorithm(ABC):
    """One attitude-update algorithm with its own input history.

    ``step_increment(q, dtheta, dt)``: body delta angle Δθ = ∫ω dt (rad) over
    the step of ``dt`` s. ``step_rate(q, omega, dt)``: the body rate sample
    ω(t_i) (rad/s) at the END of the step (fixed step ``dt``). Both return the
    new q_nb = q ⊗ δq (never normalised). Do not mix the two forms without
    :meth:`reset`. ``native_input`` is ``"increment"`` or ``"rate"``.
    """

    name: ClassVar[str] = ""
    summary: ClassVar[str] = ""
    native_input: ClassVar[str] = "increment"

    def __init__(self) -> None:
        self.reset()

    def reset(self) -> None:
        """Forget all input history (start-up rules apply to the next steps)."""
        self._th_prev = np.zeros(3)
        self._w_hist: list[Vec] = []

    def prime_rate(self, omega0: Vec) -> None:
        """Give the rate sample ω(t_0) at the start of the first step (rad/s)."""
        self._w_hist = [np.asarray(omega0, dtype=np.float64)]

    @abstractmethod
    def delta(self, dtheta: Vec, dt: float) -> Vec:
        """Increment quaternion δq of one step from the delta angle (updates the history)."""

    def step_increment(self, q: Vec, dtheta: Vec, dt: float) -> Vec:
        return quat_mul(q, self.delta(np.asarray(dtheta, dtype=np.float64), dt))

    def _rate_to_increment(self, omega: Vec, dt: float) -> Vec:
        """∇θ from rate samples: eq. 2.19 with two past samples, else trapezoid, else rectangle."""
        w = np.asarray(omega, dtype=np.float64)
        h = self._w_hist
        if len(h) >= 2:
            th = quasi_coordinates_spline(w, h[-1], h[-2], dt)
        elif len(h) == 1:
            th = 0.5 * dt * (w + h[-1])
        else:
            th = w * dt
        self._w_hist = [*h[-1:], w]
        return th

    def step_rate(self, q: Vec, omega: Vec, dt: float) -> Vec:
        return self.step_increment(q, self._rate_to_increment(omega, dt), dt)


class ElementaryQuaternion(AttitudeAlgorithm):
    """Book elementary quaternions δλ (eq. 2.17, 2.18/2.27, 2.28).

    Native input: the quasi-coordinate ∇θ (= delta angle). Rate samples are
    turned into ∇θ by the quadratic spline (eq. 2.19).
    """

    def __init__(self, kind: str, q: float | None = None) -> None:
        if kind not in ("dl1", "dl2", "dl2m", "dl3", "dl3m", "dlq"):
            raise ValueError(f"unknown elementary quaternion {kind!r}")
        self.kind = kind
        self.q = q_star(3.0, 1.0, 1.25) if (kind == "dlq" and q is None) else q
        super().__init__()

    def delta(self, dtheta: Vec, dt: float) -> Vec:
        # one step in scalar floats (numpy's per-call overhead dominates for 3-vectors);
        # the same formulas as the vectorised dl* functions above
        x, y, z = float(dtheta[0]), float(dtheta[1]), float(dtheta[2])
        s2 = x * x + y * y + z * z
        k = self.kind
        if k in ("dl3", "dl3m"):
            px, py, pz = float(self._th_prev[0]), float(self._th_prev[1]), float(self._th_prev[2])
            cx, cy, cz = (y * pz - z * py) / 24.0, (z * px - x * pz) / 24.0, (x * py - y * px) / 24.0
            if k == "dl3":  # eq. 2.17
                h = 0.5 * (1.0 - s2 / 24.0)
                d = np.array((1.0 - s2 / 8.0, h * x - cx, h * y - cy, h * z - cz))
            else:  # eq. 2.18 / 2.27
                d = np.array((1.0 - s2 / 12.0, 0.5 * x - cx, 0.5 * y - cy, 0.5 * z - cz))
        else:  # eq. 2.17 / 2.28
            q = {"dl1": 0.0, "dl2": 1.0 / 8.0, "dl2m": 1.0 / 12.0}.get(k, self.q)
            d = np.array((1.0 - float(q) * s2, 0.5 * x, 0.5 * y, 0.5 * z))  # type: ignore[arg-type]
        self._th_prev = dtheta
        return d


class RotationVector(AttitudeAlgorithm):
    """Exact rotation-vector update with the two-sample coning correction
    φ = Δθ_k + (1/12) Δθ_{k−1} × Δθ_k, δq = q(φ) — the strapdown core's default.

    Native input: delta angles. Rate samples → ∇θ by eq. 2.19.
    """

    name = "rotvec"
    summary = "exact rotation vector + two-sample coning correction (core default)"

    def __init__(self, coning: bool = True) -> None:
        self.coning = coning
        super().__init__()

    def delta(self, dtheta: Vec, dt: float) -> Vec:
        phi = dtheta + np.cross(self._th_prev, dtheta) / 12.0 if self.coning else dtheta
        self._th_prev = dtheta
        return quat_from_rotvec(phi)


_BOOK = {
    "dl1": "book δλ¹ (eq. 2.17), Euler, first order",
    "dl2": "book δλ² (eq. 2.17), modified Euler",
    "dl2m": "book δλ²_m = [1 − ‖∇θ‖²/12, ½∇θ] (Larin & Naumenko)",
    "dl3": "book δλ³ (eq. 2.17), third order with the non-commutativity term",
    "dl3m": "book δλ³_m = Larin's update (eq. 2.18/2.27)",
    "dlq": "book δλ_q (eq. 2.28), parameter q (default q* = 0.09375 of eq. 2.31)",
}


#: the attitude algorithms by name: (one-line summary, factory), the seeds' modules imported when first named
#: (:class:`ins_hil.registry.Registry`; ``ins_hil.nav.onestep`` and ``poisson`` build on this module, which
#: therefore never imports them)
ALGORITHMS: Registry[tuple[str, Callable[..., AttitudeAlgorithm]]] = Registry(
    "attitude algorithm",
    {
        "rotvec": (RotationVector.summary, RotationVector),
        **{k: (s, lambda _k=k, **kw: ElementaryQuaternion(_k, **kw)) for k, s in _BOOK.items()},
        **{k: ("ins_hil.nav.onestep", "ALGORITHMS")
           for k in ("revers1h", "rk21", "exprvrs1h", "picard1", "picard", "picard_literal")},
        "poisson": ("ins_hil.nav.poisson", "ALGORITHMS"),
    },
)  # fmt: skip


def _registry() -> Registry[tuple[str, Callable[..., AttitudeAlgorithm]]]:
    return ALGORITHMS


def attitude_names() -> dict[str, str]:
    """Registered algorithm names with a one-line description and their native input form."""
    return {k: f"{v[0]} [native input: {v[1]().native_input}]" for k, v in _registry().items()}


def make_attitude(name: str, **params: Any) -> AttitudeAlgorithm:
    """A fresh attitude algorithm by name (see :func:`attitude_names`); ``params`` go to its constructor."""
    if name not in ALGORITHMS:
        raise ValueError(f"unknown attitude algorithm {name!r}; known: {', '.join(sorted(ALGORITHMS))}")
    return ALGORITHMS[name][1](**params)
