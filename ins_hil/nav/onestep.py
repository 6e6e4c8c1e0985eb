"""One-step quaternion attitude algorithms of seed 002 (Lazarev et al., DIGEST_001_004 §2).

All four use the body-rate samples at both ends of a step, ω0 = ω(t_n) and
ω1 = ω(t_n + h), and update Λ1 = Λ0 ∘ N (Λ: body → reference, Hamilton,
scalar first; ∘ = :func:`ins_hil.nav.rotation.quat_mul`). Written as one
family (DIGEST_001_004 §2.5 [C])::

    N = 1 + (h/4)(ω0 + ω1) + c h² ω0∘ω1,   ω0∘ω1 = (−ω0·ω1, ω0 × ω1)

* ``revers1h``  c = 1/16: the one-step reverse algorithm, seed 002 eq. (2)
  (= its MATLAB code; the printed eq. (1) has mirrored indices in the reverse run,
  DIGEST_001_004 §8 item 17, so the compact form is implemented);
* ``rk21``      c = 1/8: Heun / Runge–Kutta 2nd order, seed 002 eq. (3);
* ``exprvrs1h`` c = 1/12: the authors' new combined algorithm, seed 002 eq. (7);
* ``picard1``   first Picard approximation N₍₁₎ = 1 + (h/4)(ω0 + ω1) (seed 002 eq. (5), c = 0);
* ``picard``    second Picard approximation with the two derivation errors of the
  printed eq. (6) corrected (DIGEST_001_004 §2.4):
  N = [1 − (h²/32)|ω0+ω1|²] + (h/4)(ω0+ω1) + (h²/24) ω0×ω1;
* ``picard_literal`` the printed eq. (6) with ε taken as ω1 − ω0 — the reading that
  reproduces the paper's Picard numbers (DIGEST_001_004 §2.4 item 3):
  N = [1 − (h²/8)|ω0+ω1|²] + (h/4)(ω0+ω1) + (h²/12) ω0×ω1.

Inputs: native form = rate samples (:meth:`AttitudeAlgorithm.step_rate`, the
sample at the end of each step; the previous call's sample is ω0, the first
step uses ω0 = ω1 unless :meth:`prime_rate` gave ω(t_0)). From delta angles
(:meth:`step_increment`) the end-point rates are reconstructed from the mean
rates m_k = Δθ_k/h assuming ω linear over the last two steps:
ω(t_k) = (3m_k − m_{k−1})/2, ω(t_{k−1}) = (m_k + m_{k−1})/2 (m_{−1} = m_0 at start).
DIGEST_001_004 §2.8 warns that this changes the drift constants.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

import numpy as np

from ins_hil.nav.attitude import AttitudeAlgorithm
from ins_hil.nav.rotation import quat_mul
from ins_hil.types import Vec

__all__ = [
    "ALGORITHMS",
    "FAMILY_C",
    "OneStepAttitude",
    "exprvrs1h_code",
    "increments",
    "revers1h_code",
    "rk21_code",
]

#: coefficient c of the family N = 1 + (h/4)(ω0+ω1) + c h² ω0∘ω1
FAMILY_C = {"revers1h": 1.0 / 16.0, "rk21": 1.0 / 8.0, "exprvrs1h": 1.0 / 12.0, "picard1": 0.0}
_KINDS = (*FAMILY_C, "picard", "picard_literal")


def increments(w0: Vec, w1: Vec, h: float, kind: str) -> Vec:
    """Step quaternions N (…, 4) from rate samples ω0, ω1 (…, 3) in rad/s and step h (s)."""
    w0 = np.asarray(w0, dtype=np.float64)
    w1 = np.asarray(w1, dtype=np.float64)
    if w0.ndim == 1 and w1.ndim == 1:
        return _increment_one(w0, w1, h, kind)
    s = w0 + w1
    out = np.empty((*s.shape[:-1], 4))
    cr = np.cross(w0, w1)
    if kind in FAMILY_C:
        c = FAMILY_C[kind] * h * h
        out[..., 0] = 1.0 - c * np.einsum("...i,...i->...", w0, w1)  # seed 002 eq. (2), (3), (7)
        out[..., 1:] = 0.25 * h * s + c * cr
    elif kind == "picard":  # eq. (6) corrected (DIGEST_001_004 §2.4 [C])
        out[..., 0] = 1.0 - h * h / 32.0 * np.einsum("...i,...i->...", s, s)
        out[..., 1:] = 0.25 * h * s + h * h / 24.0 * cr
    elif kind == "picard_literal":  # eq. (6) as printed, ε → ω1 − ω0 (ω0 × ε = ω0 × ω1)
        out[..., 0] = 1.0 - h * h / 8.0 * np.einsum("...i,...i->...", s, s)
        out[..., 1:] = 0.25 * h * s + h * h / 12.0 * cr
    else:
        raise ValueError(f"unknown one-step algorithm {kind!r}; known: {', '.join(_KINDS)}")
    return out


def _increment_one(w0: Vec, w1: Vec, h: float, kind: str) -> Vec:
    """:func:`increments` for one step in scalar floats (same formulas; ~10× less overhead)."""
    a, b, c = float(w0[0]), float(w0[1]), float(w0[2])
    d, e, f = float(w1[0]), float(w1[1]), float(w1[2])
    sx, sy, sz = a + d, b + e, c + f
    cx, cy, cz = b * f - c * e, c * d - a * f, a * e - b * d  # ω0 × ω1
    if kind in FAMILY_C:
        k = FAMILY_C[kind] * h * h
        s0 = 1.0 - k * (a * d + b * e + c * f)
    elif kind == "picard":
        k = h * h / 24.0
        s0 = 1.0 - h * h / 32.0 * (sx * sx + sy * sy + sz * sz)
    elif kind == "picard_literal":
        k = h * h / 12.0
        s0 = 1.0 - h * h / 8.0 * (sx * sx + sy * sy + sz * sz)
    else:
        raise ValueError(f"unknown one-step algorithm {kind!r}; known: {', '.join(_KINDS)}")
    q = 0.25 * h
    return np.array((s0, q * sx + k * cx, q * sy + k * cy, q * sz + k * cz))


def _pure(w: Vec) -> Vec:
    return np.array([0.0, w[0], w[1], w[2]])


def revers1h_code(q0: Vec, w0: Vec, w1: Vec, h: float) -> Vec:
    """Revers1h as the seed's MATLAB code: straight run then reverse run (seed 002 lines 105–113)."""
    qp = q0 + h / 4.0 * quat_mul(q0, _pure(w0))
    return qp + h / 4.0 * quat_mul(qp, _pure(w1))


def rk21_code(q0: Vec, w0: Vec, w1: Vec, h: float) -> Vec:
    """RK21(KwUrAtt) as the seed's MATLAB code (seed 002 lines 150–165)."""
    k1 = 0.5 * quat_mul(q0, _pure(w0))
    k2 = 0.5 * quat_mul(q0 + h * k1, _pure(w1))
    return q0 + h * 0.5 * (k1 + k2)


def exprvrs1h_code(q0: Vec, w0: Vec, w1: Vec, h: float) -> Vec:
    """ExpRvrs1h as the seed's MATLAB code (seed 002 lines 380–390, missing '[' fixed)."""
    qp = q0 + h / 4.0 * quat_mul(q0, _pure(w0) + _pure(w1))
    return qp + h * h / 12.0 * quat_mul(quat_mul(q0, _pure(w0)), _pure(w1))


class OneStepAttitude(AttitudeAlgorithm):
    """A seed-002 one-step algorithm behind the common interface (see the module docstring for inputs)."""

    native_input = "rate"

    def __init__(self, kind: str) -> None:
        if kind not in _KINDS:
            raise ValueError(f"unknown one-step algorithm {kind!r}; known: {', '.join(_KINDS)}")
        self.kind = kind
        super().__init__()

    def reset(self) -> None:
        super().reset()
        self._m_prev: Vec | None = None

    def delta(self, dtheta: Vec, dt: float) -> Vec:
        m = dtheta / dt
        mp = m if self._m_prev is None else self._m_prev
        self._m_prev = m
        return increments(0.5 * (m + mp), 0.5 * (3.0 * m - mp), dt, self.kind)

    def step_rate(self, q: Vec, omega: Vec, dt: float) -> Vec:
        w1 = np.asarray(omega, dtype=np.float64)
        w0 = self._w_hist[-1] if self._w_hist else w1
        self._w_hist = [w1]
        return quat_mul(q, increments(w0, w1, dt, self.kind))


_SUMMARY = {
    "revers1h": "seed 002 one-step reverse algorithm (eq. 2), c = 1/16",
    "rk21": "seed 002 Heun/RK2 (eq. 3), c = 1/8",
    "exprvrs1h": "seed 002 new combined algorithm ExpRvrs1h (eq. 7), c = 1/12, 4th-order coning drift",
    "picard1": "seed 002 Picard, 1st approximation N = 1 + (h/4)(ω0+ω1)",
    "picard": "seed 002 Picard, 2nd approximation, eq. (6) corrected",
    "picard_literal": "seed 002 Picard eq. (6) as printed (ε → ω1 − ω0), reproduces the paper",
}

ALGORITHMS: dict[str, tuple[str, Callable[..., Any]]] = {
    k: (_SUMMARY[k], lambda _k=k: OneStepAttitude(_k)) for k in _KINDS
}
