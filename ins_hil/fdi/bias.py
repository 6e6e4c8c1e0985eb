"""Isolation from the estimated gyro bias of an integrated INS/GNSS filter (book 5.4, Ex 5.3).

DIGEST_000 §5.4, §3.9, §3.10, §10 items 18–20, 41. With y = A ω + e (eq. 5.24),
ω = Z (y − e), Z = (AᵀA)⁻¹Aᵀ (eq. 5.26), a single failure e = a_i e_i (eq. 5.25)
enters the navigation as the body-frame gyro bias δc = Z e = a_i z_i (eq. 5.27),
which the 12-state filter of book 3.3 estimates as δĉ. Then

    dis_i = ‖δĉ − â_i z_i‖²,  â_i = z_iᵀ δĉ / z_iᵀ z_i,  i* = argmin_i dis_i   (eqs. 5.28–5.30).

:func:`run_example_5_3` is the small filter the example needs, following the
book's model: state x = [μ; δv; δr; δc] (book 3.3), Φ of eq. 3.41 every INS
step, H of eq. 3.43 (magnetometer μ₂, μ₃; GPS δv, δr; baro δr_z) every 2 s,
Q, R, P₀ of eq. 5.31, error feedback and reset after each correction with the
bias fed back to the gyro input (eq. 3.45). Frame as in the book: x South,
y East, z Zenith, flat, Earth rate neglected (as in eq. 3.1). Sign convention
(DIGEST_000 §9): Ĉ_b^n = (I + [μ×]) C_b^n, δv = true − computed,
δr = true − computed, δc = measured − true. The attitude motion is the literal
reading of the example (§10 item 18): classic angles with ϑ = 0 reduce to a
yaw χ = ψ + φ, ψ = 2πt/T, φ = 0.3 sin 10ψ. The magnetometer is modelled at
the level of its H row (μ₂, μ₃ plus noise), not as a field vector.
The fault size a₁ is taken in rad/s (the book gives no unit, §10 item 20).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from ins_hil.fdi.parity import BOOK_CONE_A, Isolation
from ins_hil.nav.rotation import dcm_from_quat, quat_from_rotvec, quat_mul, quat_normalize, skew
from ins_hil.types import Vec


def bias_isolation(dc_hat: Vec, Z: Vec) -> Isolation:
    """Eqs. 5.28–5.30: the sensor whose column z_i best explains the estimated bias δĉ.

    ``Z`` is the 3×n LS matrix (eq. 5.26); returns the 0-based index, â_i and dis_i for all i.
    """
    zz = np.einsum("ij,ij->j", Z, Z)
    a = (Z.T @ dc_hat) / zz  # eq. 5.29
    dis = float(dc_hat @ dc_hat) - a * a * zz  # ‖δĉ − â z‖² expanded
    i = int(np.argmin(dis))
    return Isolation(i, float(a[i]), np.maximum(dis, 0.0))


def ls_matrix(A: Vec) -> Vec:
    """Z = (AᵀA)⁻¹Aᵀ (eq. 5.26); for the book's A, Z = 0.6 Aᵀ (case 22)."""
    return np.linalg.solve(A.T @ A, A.T)


@dataclass
class Example53Result:
    """History at each correction (every 2 s): time (s), isolated index (0-based), â, δĉ (rad/s)."""

    t: Vec
    index: Vec
    a_hat: Vec
    dc_hat: Vec
    dc_true: Vec
    pos_err: Vec  # ‖δr‖ after each correction, m
    att_err: Vec  # ‖μ‖ after each correction, rad


def _uniform(rng: np.random.Generator, std: float, size: int | tuple[int, ...]) -> Vec:
    """Zero-mean uniform noise with standard deviation ``std`` (book: "uniform, variance σ", §10 item 19)."""
    h = std * math.sqrt(3.0)
    return rng.uniform(-h, h, size)


def run_example_5_3(
    a1: float = 0.1,
    failed: int = 0,
    duration: float = 20.0,
    seed: int = 0,
    A: Vec | None = None,
) -> Example53Result:
    """Ex 5.3: INS/GPS/mag/baro run with five skewed gyros, sensor ``failed`` biased by ``a1`` (rad/s).

    Book data (DIGEST_000 §5.4): T = 300 s, V = 60 m/s, Δt = 0.05 s, correction every 2 s,
    σ_ω = 0.05 °/s, σ_a = 1e-2 m/s², GPS 0.1 m/s / 50 m, σ_m = 0.0524 rad, σ_h = 1 m,
    λ(0) = [1, 0.005, −0.005, 0.005], ε_r = ε_v = 0.01 (relative initial errors),
    m₀ = diag{0.04 I, 0.6 I, 28.65 I, 0.4 I}, q̄ and η of eq. 5.31.
    """
    A = BOOK_CONE_A if A is None else np.asarray(A, dtype=np.float64)
    n = A.shape[0]
    Z = ls_matrix(A)
    rng = np.random.default_rng(seed)
    T, V, dt, g = 300.0, 60.0, 0.05, 9.81
    R0 = V * T / (2 * math.pi)
    wpsi = 2 * math.pi / T
    steps = round(duration / dt)
    every = round(2.0 / dt)
    sig_w, sig_a = math.radians(0.05), 1e-2
    e = np.zeros(n)
    e[failed] = a1
    dc_true = Z @ e  # eq. 5.27

    def chi(t: float) -> float:  # yaw of the literal z-x-z reading with ϑ = 0
        psi = wpsi * t
        return psi + 0.3 * math.sin(10 * psi)

    def kin(t: float) -> tuple[Vec, Vec, Vec]:
        psi = wpsi * t
        r = R0 * np.array([-math.sin(psi), math.cos(psi), 0.0])
        v = V * np.array([-math.cos(psi), -math.sin(psi), 0.0])
        a = V * wpsi * np.array([math.sin(psi), -math.cos(psi), 0.0])
        return r, v, a

    gl_x, gl_w = np.polynomial.legendre.leggauss(5)
    gl_x, gl_w = 0.5 * (gl_x + 1), 0.5 * gl_w
    gvec = np.array([0.0, 0.0, -g])

    # initial INS state with the book's errors
    r0, v0, _ = kin(0.0)
    q_true0 = quat_from_rotvec(np.array([0.0, 0.0, chi(0.0)]))
    lam0 = quat_normalize(np.array([1.0, 0.005, -0.005, 0.005]))
    q = quat_mul(lam0, q_true0)
    v = v0 * 1.01
    r = r0 * 1.01
    # filter (eq. 5.31)
    qbar = 1e-3 * np.concatenate([np.full(3, 0.0218), np.full(3, 0.25), np.full(3, 0.0063), np.full(3, 5e-5)])
    Q = np.diag(qbar**2)
    eta = np.array([0.0524, 0.0524, 0.1, 0.1, 0.1, 50.0, 50.0, 50.0, 1.0])
    Rm = np.diag(eta**2)
    m0 = np.concatenate([np.full(3, 0.04), np.full(3, 0.6), np.full(3, 28.65), np.full(3, 0.4)])
    P = np.diag(m0**2)
    H = np.zeros((9, 12))  # eq. 3.43: [0_{8×1} I_8 0_{8×3}; 0_{1×8} 1 0_{1×3}]
    H[:8, 1:9] = np.eye(8)
    H[8, 8] = 1.0
    dc_hat = np.zeros(3)
    I3 = np.eye(3)
    out_t, out_i, out_a, out_dc, out_pe, out_ae = [], [], [], [], [], []
    for k in range(steps):
        t0, t1 = k * dt, (k + 1) * dt
        # exact body increments: rotation about z only
        dth = np.array([0.0, 0.0, chi(t1) - chi(t0)])
        fb = np.zeros(3)
        for x, w in zip(gl_x, gl_w):
            tt = t0 + x * dt
            _, _, a = kin(tt)
            c, s = math.cos(chi(tt)), math.sin(chi(tt))
            fn = a - gvec
            fb += w * np.array([c * fn[0] + s * fn[1], -s * fn[0] + c * fn[1], fn[2]])
        # redundant gyros (eq. 5.24) and accelerometers, uniform noise
        y = A @ (dth / dt) + e + _uniform(rng, sig_w, n)
        w_hat = Z @ y - dc_hat  # eqs. 5.26 and 3.45
        f_hat = fb + _uniform(rng, sig_a, 3)
        dth_hat, dv_hat = w_hat * dt, f_hat * dt
        # mechanization (flat, z up; book eq. 2.14 without Earth rate)
        Cb = dcm_from_quat(q)
        dv_n = Cb @ (dv_hat + 0.5 * np.cross(dth_hat, dv_hat))
        v_new = v + dv_n + gvec * dt
        r = r + 0.5 * (v + v_new) * dt
        v = v_new
        q = quat_normalize(quat_mul(q, quat_from_rotvec(dth_hat)))
        # covariance propagation with Φ of eq. 3.41
        Cm = skew(Cb @ f_hat)
        At = Cb  # Aᵀ = C_b^n
        Phi = np.eye(12)
        Phi[0:3, 9:12] = At * dt
        Phi[3:6, 0:3] = Cm * dt
        Phi[3:6, 9:12] = Cm @ At * (dt * dt / 2)
        Phi[6:9, 0:3] = Cm * (dt * dt / 2)
        Phi[6:9, 3:6] = I3 * dt
        P = Phi @ P @ Phi.T + Q  # eq. 3.7
        if (k + 1) % every:
            continue
        # correction: measurements of the error state (δ = true − computed)
        rt, vt, _ = kin(t1)
        Ct = dcm_from_quat(quat_from_rotvec(np.array([0.0, 0.0, chi(t1)])))
        D = dcm_from_quat(q) @ Ct.T  # Ĉ Cᵀ ≈ I + [μ×]
        mu = 0.5 * np.array([D[2, 1] - D[1, 2], D[0, 2] - D[2, 0], D[1, 0] - D[0, 1]])
        dr = rt - r
        z = np.concatenate([mu[1:3], vt - v, dr, dr[2:3]]) + _uniform(rng, 1.0, 9) * eta
        S = H @ P @ H.T + Rm
        K = np.linalg.solve(S, H @ P).T  # eq. 3.6
        xh = K @ z  # x̄ = 0 after the previous reset
        IKH = np.eye(12) - K @ H
        P = IKH @ P @ IKH.T + K @ Rm @ K.T  # Joseph form of eq. 3.8
        # feedback and reset (DIGEST_000 §10 item 23)
        q = quat_normalize(quat_mul(quat_from_rotvec(-xh[0:3]), q))
        v = v + xh[3:6]
        r = r + xh[6:9]
        dc_hat = dc_hat + xh[9:12]
        iso = bias_isolation(dc_hat, Z)  # eqs. 5.28–5.30
        D = dcm_from_quat(q) @ Ct.T
        mu = 0.5 * np.array([D[2, 1] - D[1, 2], D[0, 2] - D[2, 0], D[1, 0] - D[0, 1]])
        out_t.append(t1)
        out_i.append(iso.index)
        out_a.append(iso.size)
        out_dc.append(dc_hat.copy())
        out_pe.append(float(np.linalg.norm(rt - r)))
        out_ae.append(float(np.linalg.norm(mu)))
    return Example53Result(
        np.array(out_t),
        np.array(out_i),
        np.array(out_a),
        np.array(out_dc),
        dc_true,
        np.array(out_pe),
        np.array(out_ae),
    )
