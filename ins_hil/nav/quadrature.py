"""The book's translational quadratures (ch. 2.3.2, eqs. 2.20–2.21; DIGEST_000 §2.3).

The navigation-frame acceleration ã(t) = dV/dt = C_b^n f_b + ḡ (− 2Ω × V), the
right-hand side of eq. 2.14 (DIGEST_000 §1.4: the quantity integrated is dV/dt,
not the "specific force" the text names), sampled at a fixed step Δt, is
integrated by the quadratic spline through t_{i−2}, t_{i−1}, t_i:

    v_i = v_{i−1} + (5ã_i + 8ã_{i−1} − ã_{i−2}) Δt/12                       (2.20)
    r_i = r_{i−1} + (3ã_i + 10ã_{i−1} − ã_{i−2}) Δt²/24 + Δt v_{i−1}         (2.21)

Both are exact for a quadratic ã(t). Start-up (the book is silent, DIGEST_000
§10 item 6): :class:`SplineTranslational` uses the trapezoid rule (and its
position analogue, exact for linear ã) while fewer than three samples exist.
"""

from __future__ import annotations

import numpy as np

from ins_hil.types import Vec

__all__ = ["SplineTranslational", "position_step", "velocity_step"]


def velocity_step(v_prev: Vec, a_i: Vec, a_im1: Vec, a_im2: Vec, dt: float) -> Vec:
    """Book eq. 2.20: v(t_i) from v(t_{i−1}) and ã at t_i, t_{i−1}, t_{i−2} (m/s, m/s², s)."""
    return np.asarray(v_prev) + (5.0 * np.asarray(a_i) + 8.0 * np.asarray(a_im1) - np.asarray(a_im2)) * (dt / 12.0)


def position_step(r_prev: Vec, v_prev: Vec, a_i: Vec, a_im1: Vec, a_im2: Vec, dt: float) -> Vec:
    """Book eq. 2.21: r(t_i) from r(t_{i−1}), v(t_{i−1}) and ã at t_i, t_{i−1}, t_{i−2} (m, m/s, m/s², s)."""
    a = 3.0 * np.asarray(a_i) + 10.0 * np.asarray(a_im1) - np.asarray(a_im2)
    return np.asarray(r_prev) + a * (dt * dt / 24.0) + dt * np.asarray(v_prev)


class SplineTranslational:
    """Velocity/position integrator of eqs. 2.20–2.21 on acceleration samples at a fixed step.

    ``r``, ``v``: position (m) and velocity (m/s) in the navigation frame at the
    time of the last sample; ``step(a_i)`` advances by one step ``dt`` given
    ã(t_i). The first sample is given to the constructor (ã(t_0)).
    """

    def __init__(self, r0: Vec, v0: Vec, a0: Vec, dt: float) -> None:
        if dt <= 0.0:
            raise ValueError(f"dt must be positive, got {dt!r}")
        self.r = np.asarray(r0, dtype=np.float64).copy()
        self.v = np.asarray(v0, dtype=np.float64).copy()
        self.dt = dt
        self._a: list[Vec] = [np.asarray(a0, dtype=np.float64)]

    def step(self, a_i: Vec) -> tuple[Vec, Vec]:
        a_i = np.asarray(a_i, dtype=np.float64)
        dt = self.dt
        if len(self._a) >= 2:
            r = position_step(self.r, self.v, a_i, self._a[-1], self._a[-2], dt)
            v = velocity_step(self.v, a_i, self._a[-1], self._a[-2], dt)
        else:  # start-up: trapezoid (exact for linear ã)
            a1 = self._a[-1]
            v = self.v + 0.5 * dt * (a_i + a1)
            r = self.r + dt * self.v + dt * dt / 6.0 * (2.0 * a1 + a_i)
        self.r, self.v = r, v
        self._a = [self._a[-1], a_i]
        return r, v
