"""Gyro-free (accelerometer-only) INS of book §2.4 (DIGEST_000 §2.5).

Rigid-body kinematics of points ρ fixed in the body (body axes throughout):

* velocities v = v0 + ω × r (eq. 2.34/2.35) → least squares A_v x = B for x = [ω; v0] (eq. 2.36/2.37);
* accelerations w = w0 + ε × ρ + ω × (ω × ρ) (eq. 2.38/2.39) → A_w x = B_w − B_ω for x = [ε; w0] (eq. 2.40/2.41).

**Sign correction** (DIGEST_000 §10 item 15, verified): the first block row of
A_v and A_w is [o, β3, −β2, h, o, o] (resp. −δ2), not the printed +β2; and the
right-hand side of (2.40) is B_w − B_ω. Rows are ordered by component: B stacks
the x-components of all points, then y, then z (B = [γ1; γ2; γ3], γ_j = row j of V).

Accelerometer layouts (distance L from the origin O along the body axes; points
X1 = L e1, Y1 = L e2, Z1 = L e3; :data:`LAYOUTS`):

* ``6``: two tangential accelerometers at each of X1, Y1, Z1 (Fig. 2.5): ε and w0 from the 6×6 system (det −2L³);
* ``9``: + a triad at O: ε by (2.43), products ω_iω_j by (2.44);
* ``12``: + the radial ones a_x^x, a_y^y, a_z^z: squares ω_i² by (2.45).

Readings are specific forces (the common gravity cancels in (2.43)–(2.45)).
The angular rate is corrected by weighted least squares (2.46)–(2.49), in the
QR form (2.50)–(2.54) with λ = γ/μ. :class:`GyroFreeINS` is the discrete
algorithm of §2.4.4 (eq. 2.42).
"""

from __future__ import annotations

from dataclasses import dataclass, field
from functools import lru_cache

import numpy as np

from ins_hil.nav.rotation import dcm_from_quat, quat_mul, quat_normalize
from ins_hil.types import Vec

__all__ = [
    "LAYOUTS",
    "GyroFreeINS",
    "accelerometer_readings",
    "nine_accel_rates",
    "point_matrix",
    "rate_correction_normal",
    "rate_correction_qr",
    "rate_correction_wls",
    "six_accel_matrix",
    "solve_point_accelerations",
    "solve_point_velocities",
    "solve_six_accel",
    "twelve_accel_squares",
]

# (point, axis): point 0 = O, 1 = X1, 2 = Y1, 3 = Z1; axis 0 = x, 1 = y, 2 = z
_SIX = ((2, 0), (3, 0), (1, 1), (3, 1), (1, 2), (2, 2))  # A_w rows without the radial ones, in order
_ORIGIN = ((0, 0), (0, 1), (0, 2))
_RADIAL = ((1, 0), (2, 1), (3, 2))
LAYOUTS: dict[int, tuple[tuple[int, int], ...]] = {6: _SIX, 9: _SIX + _ORIGIN, 12: _SIX + _ORIGIN + _RADIAL}


def point_matrix(P: Vec) -> Vec:
    """A_v (eq. 2.36) / A_w (eq. 2.40), sign-corrected, for points = columns of P (3×m): shape (3m, 6)."""
    P = np.asarray(P, dtype=np.float64)
    m = P.shape[1]
    b1, b2, b3 = P[0], P[1], P[2]
    o, h = np.zeros(m), np.ones(m)
    return np.block(
        [
            [np.stack([o, b3, -b2], 1), np.stack([h, o, o], 1)],  # (ω × r)_x = ω2 r3 − ω3 r2 (corrected sign)
            [np.stack([-b3, o, b1], 1), np.stack([o, h, o], 1)],
            [np.stack([b2, -b1, o], 1), np.stack([o, o, h], 1)],
        ]
    )


def solve_point_velocities(P: Vec, V: Vec) -> tuple[Vec, Vec]:
    """(ω, v0) by least squares from point velocities V (3×m, columns) at points P (3×m) (eq. 2.36/2.37)."""
    x, *_ = np.linalg.lstsq(point_matrix(P), np.asarray(V, dtype=np.float64).reshape(-1), rcond=None)
    return x[:3], x[3:]


def solve_point_accelerations(Pw: Vec, U: Vec, omega: Vec) -> tuple[Vec, Vec]:
    """(ε, w0) by least squares from point accelerations U (3×m) at Pw (3×m), given ω (eq. 2.40/2.41).

    Right-hand side B_w − B_ω with B_ω the stacked ω × (ω × ρ_j) (corrected, DIGEST_000 §10 item 15)."""
    Pw = np.asarray(Pw, dtype=np.float64)
    cent = np.cross(omega, np.cross(omega, Pw.T)).T  # Ω² P_w
    x, *_ = np.linalg.lstsq(point_matrix(Pw), (np.asarray(U) - cent).reshape(-1), rcond=None)
    return x[:3], x[3:]


def _points(L: float) -> Vec:
    return np.array([[0.0, 0, 0], [L, 0, 0], [0, L, 0], [0, 0, L]])  # rows: O, X1, Y1, Z1


def accelerometer_readings(layout: int, L: float, omega: Vec, eps: Vec, w0: Vec) -> Vec:
    """Ideal readings (specific force components, m/s²) of a layout, in :data:`LAYOUTS` order (eq. 2.38).

    ω, ε, w0 may be (3,) or (n, 3) (then the result is (n, k))."""
    omega, eps, w0 = (np.asarray(x, dtype=np.float64) for x in (omega, eps, w0))
    pts = _points(L)  # (4, 3)
    idx_p = np.array([p for p, _ in LAYOUTS[layout]])
    idx_a = np.array([a for _, a in LAYOUTS[layout]])
    rho = pts[idx_p]  # (k, 3): position of each sensor
    e = np.eye(3)[idx_a]  # (k, 3): its sensitive axis
    om = omega[..., None, :]
    w = w0[..., None, :] + np.cross(eps[..., None, :], rho) + np.cross(om, np.cross(om, rho))
    return np.einsum("...ki,ki->...k", w, e)


def six_accel_matrix(L: float) -> Vec:
    """The 6×6 matrix of the six tangential accelerometers: the rows of A_w (eq. 2.40) that remain
    when the three radial components are dropped, in A_w order; det = −2L³."""
    A = point_matrix(_points(L)[1:].T)
    return np.array([A[3 * a + (p - 1)] for p, a in _SIX])


@lru_cache(maxsize=16)
def _six_inverse(L: float) -> Vec:
    return np.linalg.inv(six_accel_matrix(L))


def solve_six_accel(L: float, readings6: Vec, omega: Vec) -> tuple[Vec, Vec]:
    """(ε, w0) from the six tangential readings given ω (book §2.4.3: six accelerometers suffice)."""
    rhs = np.asarray(readings6) - accelerometer_readings(6, L, omega, np.zeros(3), np.zeros(3))  # − Ω²ρ terms
    x = _six_inverse(float(L)) @ rhs
    return x[:3], x[3:]


def _pos(layout: int) -> dict[tuple[int, int], int]:
    return {pa: i for i, pa in enumerate(LAYOUTS[layout])}


_POS = {k: _pos(k) for k in LAYOUTS}


def nine_accel_rates(readings: Vec, L: float, layout: int = 9) -> tuple[Vec, Vec]:
    """ε (eq. 2.43) and Ω_n = [ω2ω3, ω1ω3, ω1ω2] (eq. 2.44) from a 9- (or 12-) accelerometer reading vector.

    n_a^p = a_a^p − a_a^0 (difference to the origin triad's axis a)."""
    r = np.asarray(readings, dtype=np.float64)
    ix = _POS[layout]
    o = (r[ix[(0, 0)]], r[ix[(0, 1)]], r[ix[(0, 2)]])
    nzy = r[ix[(2, 2)]] - o[2]  # n_z^y
    nyz = r[ix[(3, 1)]] - o[1]  # n_y^z
    nxz = r[ix[(3, 0)]] - o[0]  # n_x^z
    nzx = r[ix[(1, 2)]] - o[2]  # n_z^x
    nyx = r[ix[(1, 1)]] - o[1]  # n_y^x
    nxy = r[ix[(2, 0)]] - o[0]  # n_x^y
    k = 1.0 / (2.0 * L)
    eps = np.array([k * (nzy - nyz), k * (nxz - nzx), k * (nyx - nxy)])
    prod = np.array([k * (nzy + nyz), k * (nxz + nzx), k * (nyx + nxy)])
    return eps, prod


def twelve_accel_squares(readings: Vec, L: float) -> Vec:
    """[ω1², ω2², ω3²] from the 12-accelerometer readings (eq. 2.45)."""
    r = np.asarray(readings, dtype=np.float64)
    ix = _POS[12]
    xx = r[ix[(1, 0)]] - r[ix[(0, 0)]]  # n_x^x
    yy = r[ix[(2, 1)]] - r[ix[(0, 1)]]  # n_y^y
    zz = r[ix[(3, 2)]] - r[ix[(0, 2)]]  # n_z^z
    k = 1.0 / (2.0 * L)
    return np.array([k * (xx - yy - zz), k * (-xx + yy - zz), k * (-xx - yy + zz)])


def _h_and_omega_n0(w: Vec, squares: bool) -> tuple[Vec, Vec]:
    """H and Ω_n0 of eq. 2.46 at ω (with the three square rows for 12 accelerometers)."""
    w1, w2, w3 = float(w[0]), float(w[1]), float(w[2])
    H = [[0.0, w3, w2], [w3, 0.0, w1], [w2, w1, 0.0]]
    o = [w2 * w3, w1 * w3, w1 * w2]
    if squares:
        H += [[2 * w1, 0.0, 0.0], [0.0, 2 * w2, 0.0], [0.0, 0.0, 2 * w3]]
        o += [w1 * w1, w2 * w2, w3 * w3]
    return np.array(H), np.array(o)


def rate_correction_wls(w_prev: Vec, dw_prior: Vec, omega_n: Vec, M: Vec, R: Vec) -> Vec:
    """Δω̂ = Δω̄ + P Hᵀ R⁻¹ (z − H Δω̄), P⁻¹ = M⁻¹ + Hᵀ R⁻¹ H, z = Ω_n − Ω_n0 (eqs. 2.46–2.48).

    ``omega_n``: measured products (3) or products + squares (6); H, Ω_n0 at ω(t_{i−1}) = ``w_prev``."""
    H, o0 = _h_and_omega_n0(w_prev, len(omega_n) == 6)
    Ri = np.linalg.inv(R)
    P = np.linalg.inv(np.linalg.inv(M) + H.T @ Ri @ H)
    z = np.asarray(omega_n) - o0
    return dw_prior + P @ H.T @ Ri @ (z - H @ dw_prior)


def rate_correction_qr(w_prev: Vec, dw_prior: Vec, omega_n: Vec, lam: float) -> Vec:
    """The same correction for M = μ²I, R = γ²I in the QR form (eqs. 2.53–2.54), λ = γ/μ:
    ρ = R factor of [λI; H], Δω̂ = Δω̄ + ρ⁻¹ρ⁻ᵀ Hᵀ (z − H Δω̄)."""
    H, o0 = _h_and_omega_n0(w_prev, len(omega_n) == 6)
    rho: Vec = np.linalg.qr(np.vstack([lam * np.eye(3), H]), mode="r")  # type: ignore[assignment]
    g = H.T @ (np.asarray(omega_n) - o0 - H @ dw_prior)
    y = np.linalg.solve(rho.T, g)
    return dw_prior + np.linalg.solve(rho, y)


def rate_correction_normal(w_prev: Vec, dw_prior: Vec, omega_n: Vec, lam: float) -> Vec:
    """(2.53) solved through its normal equations ρᵀρ = λ²I + HᵀH (algebraically identical to
    :func:`rate_correction_qr`; a closed-form 3×3 solve in floats, ~10× cheaper per step)."""
    H, o0 = _h_and_omega_n0(w_prev, len(omega_n) == 6)
    N = H.T @ H
    N[0, 0] += lam * lam
    N[1, 1] += lam * lam
    N[2, 2] += lam * lam
    g = H.T @ (np.asarray(omega_n) - o0 - H @ dw_prior)
    a, b, c, d, e, f = N[0, 0], N[0, 1], N[0, 2], N[1, 1], N[1, 2], N[2, 2]
    A, B, C = d * f - e * e, c * e - b * f, b * e - c * d  # adjugate of the symmetric N
    D, E, F = a * f - c * c, b * c - a * e, a * d - b * b
    det = a * A + b * B + c * C
    g0, g1, g2 = float(g[0]), float(g[1]), float(g[2])
    return dw_prior + np.array(
        [(A * g0 + B * g1 + C * g2) / det, (B * g0 + D * g1 + E * g2) / det, (C * g0 + E * g1 + F * g2) / det]
    )


@dataclass
class GyroFreeINS:
    """Discrete gyro-free INS (book §2.4.4, eq. 2.42) for the 6, 9 or 12 accelerometer layouts.

    State (fixed frame, z as the caller's gravity vector says): q (body → fixed,
    normalised each step), ω (rad/s, body), v (m/s), r (m). ``gravity``: the
    gravity vector in the fixed frame (m/s²; Ex 2.4 uses z up, g = −9.81 on z).
    ``lam``: λ = γ/μ of eq. 2.54 (9/12 layouts); ``qr``: solve (2.53) by QR as
    printed (True) or by the identical normal equations (False, faster). Readings: the layout's vector
    of specific forces (:func:`accelerometer_readings` order).
    """

    layout: int
    L: float
    q: Vec
    omega: Vec
    v: Vec
    r: Vec
    gravity: Vec = field(default_factory=lambda: np.zeros(3))
    lam: float = 0.1
    qr: bool = False
    _eps_prev: Vec | None = None

    def __post_init__(self) -> None:
        if self.layout not in LAYOUTS:
            raise ValueError(f"layout must be one of {sorted(LAYOUTS)}, not {self.layout!r}")

    def step(self, readings: Vec, dt: float) -> None:
        w_prev = self.omega
        if self.layout == 6:
            eps, w0 = solve_six_accel(self.L, readings, w_prev)  # Ω built from ω(t_{i−1})
            w_new = w_prev + eps * dt  # eq. 2.42
        else:
            eps, prod = nine_accel_rates(readings, self.L, self.layout)
            w0 = np.asarray(readings)[6:9]  # the triad at O
            ep = eps if self._eps_prev is None else self._eps_prev
            dw_prior = 0.5 * (eps + ep) * dt
            meas = prod if self.layout == 9 else np.concatenate([prod, twelve_accel_squares(readings, self.L)])
            corr = rate_correction_qr if self.qr else rate_correction_normal
            w_new = w_prev + corr(w_prev, dw_prior, meas, self.lam)  # eqs. 2.49, 2.53
        self._eps_prev = eps
        th = 0.5 * (w_new + w_prev) * dt  # eq. 2.42
        self.q = quat_normalize(quat_mul(self.q, np.array([1.0, 0.5 * th[0], 0.5 * th[1], 0.5 * th[2]])))
        self.omega = w_new
        acc = dcm_from_quat(self.q) @ w0 + self.gravity  # w̃: w0 mapped to the fixed frame (eq. 2.5) + gravity
        v_new = self.v + acc * dt
        self.r = self.r + 0.5 * (v_new + self.v) * dt
        self.v = v_new
