"""Parity space of a redundant sensor set and the book's "simple" isolation methods.

Book ch. 5 (DIGEST_000 §5.1, §5.2, §5.5; typo notes §10 items 37, 38, 40, 43):

* measurement model y = A ω + e (+ w), y ∈ Rⁿ, ω ∈ R³, A ∈ R^{n×(n−m)}
  (eq. 5.1; the printed "A ∈ R^{n×m}" is a typo, §10 item 37);
* parity vector p = V y with V A = 0 (eqs. 5.3–5.5); here V = U₂ᵀ, the last m
  left singular vectors of A (eqs. 5.9–5.12) or, equivalently, the last m
  columns of the complete QR factor Q of A (the "QR alternative" of §5.2);
* SVD isolation: J(k) = ‖p‖² − (u_kᵀ p)²/‖u_k‖², ρ_k = u_kᵀ p/‖u_k‖²,
  k* = argmin J (the digest's corrected eq. 5.17, §10 item 38);
* the Lebedev projector form (5.6)–(5.8) with G = U₂ U₂ᵀ (5.13–5.15);
* the determinant procedure (5.32, Table 5.3): d_j = |det([y A] without row j)|,
  i = argmin d_j (n = 5, m = 2 in the book; any n = m + 3 with m = 2 here).

Indices are 0-based in the code (sensor k = book's k + 1). Pure numpy.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ins_hil.types import Vec

#: Ex 5.1: five gyros antisymmetrically on a cone of half-angle 54.7° (Deyst et al. 1981); A (5×3).
BOOK_CONE_A: Vec = np.array(
    [
        [0.97204, 0.0, -0.23482],
        [-0.60075, -0.77653, -0.18997],
        [0.0, 0.47992, 0.87731],
        [0.0, -0.47992, 0.87731],
        [-0.60075, 0.77653, -0.18997],
    ]
)


def cone_geometry(n: int = 5, half_angle_deg: float = 54.7356, tilt_deg: float = 0.0) -> Vec:
    """n sensing axes equally spaced in azimuth on a cone about body z (unit rows, n×3).

    With the "magic" half angle acos(1/√3) = 54.7356° the set is isotropic, AᵀA = (n/3) I
    (the property of the book's Ex 5.1 matrix, §10 item 43: its cone axis is not stated).
    """
    if n < 4:
        raise ValueError(f"cone_geometry: n={n}: at least 4 sensors are needed for detection")
    a = np.radians(half_angle_deg)
    az = 2 * np.pi * np.arange(n) / n + np.radians(tilt_deg)
    return np.stack([np.sin(a) * np.cos(az), np.sin(a) * np.sin(az), np.full(n, np.cos(a))], axis=1)


def dodecahedron_geometry() -> Vec:
    """Six sensing axes normal to the faces of a dodecahedron (the classic skewed
    six-sensor array): pairs in the xz, xy and yz planes at ±α, tan 2α = 2; AᵀA = 2 I."""
    a = 0.5 * np.arctan(2.0)
    s, c = np.sin(a), np.cos(a)
    return np.array([[s, 0, c], [-s, 0, c], [c, s, 0], [c, -s, 0], [0, c, s], [0, c, -s]])


def parity_basis(A: Vec, method: str = "svd") -> Vec:
    """U₂ (n×m, orthonormal columns) with U₂ᵀ A = 0 (eq. 5.11).

    ``method="svd"``: last m columns of U in A = U [Σ; 0] Wᵀ (eq. 5.9); for the book's
    Ex 5.1 numpy returns the printed U₂ᵀ signs included. ``method="qr"``: last m columns
    of the complete Q of A = Q R (the alternative named in §5.2; same span, another basis).
    """
    A = np.asarray(A, dtype=np.float64)
    n, r = A.shape
    if n <= r:
        raise ValueError(f"parity_basis: A is {n}×{r}; need more sensors than unknowns")
    if method == "svd":
        u, sv, _ = np.linalg.svd(A, full_matrices=True)
        if sv[-1] < 1e-9 * sv[0]:
            raise ValueError("parity_basis: geometry matrix A is rank deficient")
        return u[:, r:]
    if method == "qr":
        q, _ = np.linalg.qr(A, mode="complete")
        return q[:, r:]
    raise ValueError(f"parity_basis: unknown method {method!r} (use 'svd' or 'qr')")


@dataclass(frozen=True)
class Isolation:
    """Result of a single-fault isolation: 0-based sensor index, fault estimate ρ, J(k) or d_j per candidate."""

    index: int
    size: float
    scores: Vec


def svd_isolation(y: Vec, U2: Vec) -> Isolation:
    """SVD isolation with the corrected eq. 5.17.

    J(k) = yᵀU₂ (I − α_k U₂ₖᵀU₂ₖ) U₂ᵀy with α_k⁻¹ = U₂ₖU₂ₖᵀ (U₂ₖ = k-th row of U₂);
    equivalently ‖p‖² − (u_kᵀp)²/‖u_k‖². Returns argmin J and ρ_k = u_kᵀp/‖u_k‖² (eq. 5.16 fixed).
    """
    p = U2.T @ y  # eq. 5.12
    up = U2 @ p  # u_kᵀ p for every k (U₂ₖ · p)
    nk = np.einsum("ij,ij->i", U2, U2)  # ‖u_k‖² = U₂ₖU₂ₖᵀ
    J = float(p @ p) - up * up / nk
    k = int(np.argmin(J))
    return Isolation(k, float(up[k] / nk[k]), J)


def svd_isolation_literal(y: Vec, U2: Vec) -> Vec:
    """J(k) written exactly as the corrected eq. 5.17 (matrix form), for cross-checking."""
    m = U2.shape[1]
    out = np.empty(U2.shape[0])
    for k in range(U2.shape[0]):
        u = U2[k : k + 1, :]  # 1×m row U₂ₖ
        alpha = 1.0 / float((u @ u.T)[0, 0])
        out[k] = float(y @ U2 @ (np.eye(m) - alpha * (u.T @ u)) @ U2.T @ y)
    return out


def lebedev_isolation(y: Vec, U2: Vec) -> Isolation:
    """Projector form (5.6)–(5.8): e₀ = G y, G = U₂U₂ᵀ (5.13/5.14), g_k = G[:, k] (5.15),
    q_k = ρ_k g_k − e₀, ρ_k = g_kᵀe₀/‖g_k‖², k* = argmin ‖q_k‖²."""
    G = U2 @ U2.T
    e0 = G @ y
    J = np.empty(G.shape[0])
    rho = np.empty(G.shape[0])
    for k in range(G.shape[0]):
        g = G[:, k]
        rho[k] = float(g @ e0) / float(g @ g)
        qk = rho[k] * g - e0
        J[k] = float(qk @ qk)
    k = int(np.argmin(J))
    return Isolation(k, float(rho[k]), J)


def determinant_scores(y: Vec, A: Vec) -> Vec:
    """d_j = |det(Ã_j)|, Ã = [y A] (eq. 5.32) with row j deleted (j = 1..n; the printed
    "j = 2, …, 5" is a typo, §10 item 40). Needs n = r + 2 rows (square after deletion)."""
    At = np.column_stack([y, A])
    n, c = At.shape
    if n != c + 1:
        raise ValueError(f"determinant method needs n = unknowns + 2 sensors; got A {A.shape}")
    return np.array([abs(np.linalg.det(np.delete(At, j, axis=0))) for j in range(n)])


def determinant_isolation(y: Vec, A: Vec) -> Isolation:
    """Simplified determinant procedure (book 5.5): i = argmin_j d_j (Table 5.3)."""
    d = determinant_scores(y, A)
    k = int(np.argmin(d))
    # fault size: LS fit with sensor k as the only failure (column e_k added to A)
    E = np.column_stack([A, np.eye(len(y))[:, k]])
    sol = np.linalg.lstsq(E, y, rcond=None)[0]
    return Isolation(k, float(sol[-1]), d)
