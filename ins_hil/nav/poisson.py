"""DCM integration by Poisson's equation (seed 003 §3.4, DIGEST_001_004 §3.4).

Poisson's equation for the body → reference DCM C = C_b^n with the absolute body
rate ω (rad/s, body axes): Ċ = C [ω×] (seed 003, scalar form lines 760–775, with
its two index typos ċ21, ċ32 corrected: DIGEST_001_004 §3.4 [C]; the printed
matrix form Ċ = −[ω]A is inconsistent with the scalar form and not used).

Discrete update over one step with the delta angle Δθ (Θ = [Δθ×]):
C_{k+1} = C_k ΔC with ΔC the truncated exponential series (order 1: I + Θ;
order 2: + Θ²/2; order 3: + Θ³/6) or the exact Rodrigues form (seed 001 eq. 61)
``order=0``. Truncated updates lose orthogonality; :func:`orthonormalize`
restores it (the nearest orthogonal matrix, C (CᵀC)^(−1/2)).
"""

from __future__ import annotations

import math
from collections.abc import Callable
from typing import Any

import numpy as np

from ins_hil.nav.attitude import AttitudeAlgorithm
from ins_hil.nav.rotation import dcm_from_quat, quat_from_dcm, skew
from ins_hil.types import Vec

__all__ = [
    "ALGORITHMS",
    "PoissonAttitude",
    "angles_yup",
    "dcm_increment",
    "dcm_yup",
    "integrate_dcm",
    "orthonormalize",
    "poisson_rhs",
    "poisson_rhs_printed",
    "poisson_rhs_scalar",
]


def dcm_yup(psi: float, theta: float, gamma: float) -> Vec:
    """Body → navigation DCM in seed 003's convention (navigation x North, y Up, z East; body x forward,
    y up, z right; ψ about y, ϑ about z′, γ about x″): C = R_y(ψ) R_z(ϑ) R_x(γ).

    The thesis prints a non-orthogonal matrix (line 688, signs of C12/C23); this is the corrected one
    (DIGEST_001_004 §3.4 [C])."""
    cp, sp = math.cos(psi), math.sin(psi)
    ct, st = math.cos(theta), math.sin(theta)
    cg, sg = math.cos(gamma), math.sin(gamma)
    return np.array(
        [
            [cp * ct, -cp * st * cg + sp * sg, cp * st * sg + sp * cg],
            [st, ct * cg, -ct * sg],
            [-sp * ct, sp * st * cg + cp * sg, -sp * st * sg + cp * cg],
        ]
    )


def angles_yup(C: Vec) -> tuple[float, float, float]:
    """(ψ, ϑ, γ) from :func:`dcm_yup`: ψ = atan2(−c31, c11), ϑ = asin c21, γ = atan2(−c23, c22)
    (the thesis's "γ = arcsin(−c23/c22)" must be an arctangent)."""
    return (
        math.atan2(-C[2, 0], C[0, 0]),
        math.asin(max(-1.0, min(1.0, float(C[1, 0])))),
        math.atan2(-C[1, 2], C[1, 1]),
    )


def poisson_rhs(C: Vec, omega: Vec) -> Vec:
    """Ċ = C [ω×] (seed 003 Poisson equation, corrected; C body→reference, ω rad/s in body axes)."""
    return np.asarray(C) @ skew(omega)


def poisson_rhs_scalar(C: Vec, omega: Vec) -> Vec:
    """The seed's scalar Poisson equations with the ċ21 and ċ32 index typos fixed (DIGEST_001_004 §3.4)."""
    c = np.asarray(C)
    wx, wy, wz = float(omega[0]), float(omega[1]), float(omega[2])
    d = np.empty((3, 3))
    for i in range(3):  # each row (triad) integrates independently
        d[i, 0] = c[i, 1] * wz - c[i, 2] * wy
        d[i, 1] = c[i, 2] * wx - c[i, 0] * wz
        d[i, 2] = c[i, 0] * wy - c[i, 1] * wx
    return d


def poisson_rhs_printed(C: Vec, omega: Vec) -> Vec:
    """The seed's scalar equations exactly as printed (typos in ċ21 and ċ32): a regression guard only."""
    d = poisson_rhs_scalar(C, omega)
    c = np.asarray(C)
    wx, wy, wz = float(omega[0]), float(omega[1]), float(omega[2])
    d[1, 0] = c[0, 1] * wz - c[0, 2] * wy  # printed ċ21 = c12ωz − c13ωy
    d[2, 1] = c[0, 2] * wx - c[0, 0] * wz  # printed ċ32 = c13ωx − c11ωz
    return d


def dcm_increment(dtheta: Vec, order: int = 0) -> Vec:
    """ΔC = exp([Δθ×]) truncated after ``order`` terms (1, 2, 3) or exact (0, Rodrigues, seed 001 eq. 61)."""
    T = skew(dtheta)
    if order == 0:
        a2 = float(np.dot(dtheta, dtheta))
        a = math.sqrt(a2)
        if a < 1e-6:
            s, k = 1.0 - a2 / 6.0, 0.5 - a2 / 24.0
        else:
            s, k = math.sin(a) / a, (1.0 - math.cos(a)) / a2
        return np.eye(3) + s * T + k * (T @ T)
    if order not in (1, 2, 3):
        raise ValueError(f"Poisson update order must be 0 (exact), 1, 2 or 3, not {order!r}")
    out = np.eye(3) + T
    if order >= 2:
        T2 = T @ T
        out += 0.5 * T2
        if order == 3:
            out += (T2 @ T) / 6.0
    return out


def orthonormalize(C: Vec) -> Vec:
    """Nearest orthogonal matrix C (CᵀC)^(−1/2) (by SVD)."""
    u, _, vt = np.linalg.svd(C)
    return u @ vt


def integrate_dcm(C0: Vec, dthetas: Vec, order: int = 0, renorm_every: int = 0) -> Vec:
    """Integrate C_{k+1} = C_k ΔC(Δθ_k) over delta angles (n, 3); returns C_n.

    ``renorm_every`` > 0 orthonormalises every that many steps."""
    C = np.array(C0, dtype=np.float64)
    for k, th in enumerate(np.asarray(dthetas)):
        C = C @ dcm_increment(th, order)
        if renorm_every > 0 and (k + 1) % renorm_every == 0:
            C = orthonormalize(C)
    return C


class PoissonAttitude(AttitudeAlgorithm):
    """Poisson DCM update behind the quaternion interface: C = C(q) ΔC(Δθ), then q from C
    (Shepperd, normalised: the DCM's non-orthogonality is projected out every step).

    Native input: delta angles; rate samples → Δθ by the book's spline (eq. 2.19).
    """

    def __init__(self, order: int = 2) -> None:
        dcm_increment(np.zeros(3), order)  # validate
        self.order = order
        super().__init__()

    def delta(self, dtheta: Vec, dt: float) -> Vec:
        return quat_from_dcm(orthonormalize(dcm_increment(dtheta, self.order)))

    def step_increment(self, q: Vec, dtheta: Vec, dt: float) -> Vec:
        C = dcm_from_quat(q) @ dcm_increment(np.asarray(dtheta, dtype=np.float64), self.order)
        n = float(np.linalg.norm(q))
        return n * quat_from_dcm(orthonormalize(C))


ALGORITHMS: dict[str, tuple[str, Callable[..., Any]]] = {
    "poisson": ("seed 003 Poisson DCM update Ċ = C[ω×] (order=0 exact, 1, 2 (default), 3)", PoissonAttitude),
}
