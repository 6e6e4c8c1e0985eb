"""Square-root and factorised Kalman-filter forms (book §3.1.2–3.1.3, appendix A).

Factors (book eq. 3.9): P(−) = m m^T, P(+) = p p^T, Q = q q^T, R = r r^T.

* ``"qr"``: the book's QR ("Cholesky multiplier") filter. Measurement update
  (3.10)–(3.12): N = [I, m^T H^T r^{−T}], [S; 0] = U N^T (QR), p = m S^{−1},
  gain K = p p^T H^T R^{−1} (3.54). Time update (3.13)–(3.15): T = [Φ p, q],
  [X^T; 0] = V T^T (QR), m_{k+1} = X.
* ``"cholesky"``: the Joseph form carried on Cholesky factors (3.20)–(3.22):
  K = m m^T H^T (H m m^T H^T + r r^T)^{−1}, p = tria([(I − KH) m, K r]).
* ``"ud"``: Bierman's UD measurement update (scalar, sequential; Bierman 1977,
  Grewal & Andrews Table 6.4) and Thornton's modified weighted Gram–Schmidt
  time update, P = U D U^T, U unit upper triangular.

All of them give the conventional filter's estimates (3.6)–(3.8) to round-off;
``tests/test_fusion_sqrt.py`` checks it. Factor objects are tuples
``(kind, S)`` with P = S S^T (lower triangular S) or ``("ud", U, d)``.
"""

from __future__ import annotations

from typing import Any

import numpy as np

from ins_hil.types import Vec

Factor = tuple[Any, ...]


# ---------------------------------------------------------------- conventional / Joseph
def conventional_update(x: Vec, P: Vec, z: Vec, H: Vec, R: Vec) -> tuple[Vec, Vec]:
    """Book eqs. (3.6) and (3.8): K = P H^T S^{−1}, P(+) = P − K S K^T (batch)."""
    S = H @ P @ H.T + R
    K = np.linalg.solve(S, H @ P).T
    x = x + K @ (z - H @ x)
    P = P - K @ S @ K.T
    return x, 0.5 * (P + P.T)


def joseph_update(x: Vec, P: Vec, z: Vec, H: Vec, R: Vec) -> tuple[Vec, Vec]:
    """Book eq. (3.16)–(3.17), batch Joseph form."""
    S = H @ P @ H.T + R
    K = np.linalg.solve(S, H @ P).T
    x = x + K @ (z - H @ x)
    A = np.eye(len(x)) - K @ H
    return x, A @ P @ A.T + K @ R @ K.T


def predict_cov(P: Vec, Phi: Vec, Q: Vec) -> Vec:
    """Book eq. (3.7)/(3.19): M = Φ P Φ^T + Q."""
    return Phi @ P @ Phi.T + Q


# ---------------------------------------------------------------- triangularisation
def tria(A: Vec) -> Vec:
    """Lower-triangular S with S S^T = A A^T, by QR of A^T (book's block factorisation, §3.1.1)."""
    r = np.asarray(np.linalg.qr(A.T, mode="r"))
    S = r.T
    # make the diagonal non-negative (unique factor)
    sgn = np.sign(np.diag(S))
    sgn[sgn == 0] = 1.0
    return S * sgn[None, :]


def qr_update(x: Vec, m: Vec, z: Vec, H: Vec, r: Vec) -> tuple[Vec, Vec]:
    """Book eqs. (3.10)–(3.12) and (3.54) for an invertible noise factor r (R = r r^T).

    Returns (x(+), p) with P(+) = p p^T. N uses r^{−T} (DIGEST_000 §10 item 28)."""
    n = m.shape[0]
    rinv = np.linalg.inv(r)
    N = np.hstack([np.eye(n), m.T @ H.T @ rinv.T])  # n × (n+p)
    S = np.asarray(np.linalg.qr(N.T, mode="r"))[:n, :n]  # [S; 0] = U N^T  (3.11), S upper triangular
    p = np.linalg.solve(S.T, m.T).T  # p = m S^{-1}  (3.12)
    K = p @ p.T @ H.T @ rinv.T @ rinv  # K = P(+) H^T R^{-1}  (3.54)
    return x + K @ (z - H @ x), p


def qr_update_singular_r(x: Vec, m: Vec, z: Vec, H: Vec, r: Vec) -> tuple[Vec, Vec]:
    """The book's QR measurement update without inverting r (§3.1.2, R = r r^T may be singular).

    [Y; 0] = Ω m^T H^T (QR, Y p × p, assumed invertible: H m of full row rank), W̃ = diag{r^T Y^{−1}, I},
    Ñ = [W̃ Ω, [I; 0]], [R̃; 0] = Ũ Ñ^T (QR) and p = m Ω^T W̃^T R̃^{−1}, with the upper-triangular R̃
    (the book writes S̃; DIGEST_000 §10 item 28). N = Ω^T W̃^{−1} Ñ reproduces (3.10)'s factor, so
    P(+) = p p^T equals (3.8). Gain K = m A (A^T A + r r^T)^{−1}, A = m^T H^T (= P(−) H^T (H P(−) H^T + R)^{−1}),
    since (3.54)'s R^{−1} does not exist here. Returns (x(+), p)."""
    n = m.shape[0]
    A = m.T @ H.T  # n × p
    k = A.shape[1]
    Q, Rfull = np.linalg.qr(A, mode="complete")  # A = Q [Y; 0]  ⇒  Ω = Q^T
    Om = Q.T
    Y = Rfull[:k, :k]
    W = np.eye(n)
    W[:k, :k] = np.linalg.solve(Y.T, r).T  # r^T Y^{-1}
    Nt = np.hstack([W @ Om, np.vstack([np.eye(k), np.zeros((n - k, k))])])  # Ñ, n × (n + p)
    Rt = np.asarray(np.linalg.qr(Nt.T, mode="r"))[:n, :n]  # [R̃; 0] = Ũ Ñ^T
    p = np.linalg.solve(Rt.T, (m @ Om.T @ W.T).T).T  # p = m Ω^T W̃^T R̃^{-1}
    K = m @ A @ np.linalg.inv(A.T @ A + r @ r.T)
    return x + K @ (z - H @ x), p


def qr_predict(p: Vec, Phi: Vec, q: Vec) -> Vec:
    """Book eqs. (3.13)–(3.15): m_{k+1} = tria([Φ p, q])."""
    return tria(np.hstack([Phi @ p, q]))


def cholesky_joseph_update(x: Vec, m: Vec, z: Vec, H: Vec, r: Vec) -> tuple[Vec, Vec]:
    """Book eqs. (3.20)–(3.21): Joseph form carried on Cholesky factors."""
    P = m @ m.T
    R = r @ r.T
    K = np.linalg.solve(H @ P @ H.T + R, H @ P).T
    A = np.eye(len(x)) - K @ H
    p = tria(np.hstack([A @ m, K @ r]))
    return x + K @ (z - H @ x), p


# ---------------------------------------------------------------- UD
def ud_decompose(P: Vec) -> tuple[Vec, Vec]:
    """P = U diag(d) U^T with U unit upper triangular (Bierman 1977)."""
    P = np.array(P, dtype=np.float64)
    n = P.shape[0]
    U = np.eye(n)
    d = np.zeros(n)
    for j in range(n - 1, -1, -1):
        d[j] = P[j, j]
        if d[j] > 0:
            U[:j, j] = P[:j, j] / d[j]
        for i in range(j):
            P[: i + 1, i] -= U[: i + 1, j] * d[j] * U[i, j]
    return U, d


def bierman_update(x: Vec, U: Vec, d: Vec, z: float, h: Vec, r: float) -> tuple[Vec, Vec, Vec]:
    """Bierman's scalar UD measurement update (Grewal & Andrews Table 6.4)."""
    U = U.copy()
    d = d.copy()
    n = len(d)
    f = U.T @ h
    v = d * f
    alpha = r
    K = np.zeros(n)
    for j in range(n):
        a_prev = alpha
        alpha = alpha + f[j] * v[j]
        dj = d[j] * a_prev / alpha
        lam = -f[j] / a_prev
        d[j] = dj
        if j > 0:
            Uj = U[:j, j].copy()
            U[:j, j] = Uj + lam * K[:j]
            K[:j] = K[:j] + v[j] * Uj
        K[j] = v[j]
    x = x + K / alpha * (z - float(h @ x))
    return x, U, d


def thornton_predict(U: Vec, d: Vec, Phi: Vec, qd: Vec) -> tuple[Vec, Vec]:
    """UD time update by modified weighted Gram–Schmidt (Thornton): P = Φ U D U^T Φ^T + diag(qd)."""
    n = len(d)
    W = np.hstack([Phi @ U, np.eye(n)])  # n × 2n
    Dw = np.concatenate([d, qd])
    Un = np.eye(n)
    dn = np.zeros(n)
    for k in range(n - 1, -1, -1):
        wk = W[k]
        dk = float(np.sum(wk * wk * Dw))
        dn[k] = dk
        if dk > 0:
            for j in range(k):
                u = float(np.sum(W[j] * Dw * wk)) / dk
                Un[j, k] = u
                W[j] = W[j] - u * wk
    return Un, dn


# ---------------------------------------------------------------- factor objects used by the EKF
def factor_from_cov(kind: str, P: Vec) -> Factor:
    """Factor of P for ``kind`` in {"qr", "cholesky", "ud"}."""
    if kind in ("qr", "cholesky"):
        return (kind, np.linalg.cholesky(P))
    if kind == "ud":
        U, d = ud_decompose(P)
        return ("ud", U, d)
    raise ValueError(f"unknown factor kind {kind!r}")


def factor_cov(f: Factor) -> Vec:
    """P from a factor."""
    if f[0] == "ud":
        U, d = f[1], f[2]
        return (U * d[None, :]) @ U.T
    S = f[1]
    return S @ S.T


def factor_predict(f: Factor, Phi: Vec, qd: Vec, root: Vec | None = None) -> Factor:
    """Time update of a factor with diagonal process noise qd, or (QR/Cholesky factors) with a full
    process noise given by its root (Q = root rootᵀ)."""
    if f[0] == "ud":
        if root is not None:
            raise ValueError("factor_predict: the UD (Thornton) update takes a diagonal process noise only")
        U, d = thornton_predict(f[1], f[2], Phi, qd)
        return ("ud", U, d)
    return (f[0], qr_predict(f[1], Phi, np.diag(np.sqrt(qd)) if root is None else root))


def factor_update(f: Factor, x: Vec, z: Vec, H: Vec, r_diag: Vec) -> tuple[Vec, Factor]:
    """Measurement update of a factor with diagonal measurement noise r_diag."""
    if f[0] == "ud":
        U, d = f[1], f[2]
        for j in range(len(z)):
            x, U, d = bierman_update(x, U, d, float(z[j]), H[j], float(r_diag[j]))
        return x, ("ud", U, d)
    r = np.diag(np.sqrt(r_diag))
    if f[0] == "qr":
        x, p = qr_update(x, f[1], z, H, r)
        return x, ("qr", tria(p))
    x, p = cholesky_joseph_update(x, f[1], z, H, r)
    return x, ("cholesky", p)


# ---------------------------------------------------------------- observability
def observability_matrix(Phi: Vec, H: Vec) -> Vec:
    """Ob = [H; HΦ; …; HΦ^{n−1}] (book §3.1, MATLAB obsv)."""
    n = Phi.shape[0]
    rows = [H]
    M = H
    for _ in range(n - 1):
        M = M @ Phi
        rows.append(M)
    return np.vstack(rows)


def observability_rank(Phi: Vec, H: Vec, tol: float = 1e-9) -> int:
    """Rank of the observability matrix, relative tolerance ``tol`` on the singular values."""
    s = np.linalg.svd(observability_matrix(Phi, H), compute_uv=False)
    return int(np.sum(s > tol * s[0]))
