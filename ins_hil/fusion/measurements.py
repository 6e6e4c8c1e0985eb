"""Measurement models of the error-state filter: residual z = measured − predicted, rows H, noise.

Conventions of :mod:`ins_hil.fusion.ekf` (DIGEST_000 §9): δr = true − computed (NED m),
δv = true − computed, Ĉ_b^n = (I + [μ×]) C_b^n, δb = true − estimated.

* GNSS position with lever arm l (body FRD, IMU → antenna):
  z = r_gnss − (r̂ + Ĉ l) = δr + [(Ĉ l)×] μ            (book eq. 3.3 with lever arm)
* GNSS velocity: z = v_gnss − (v̂ + Ĉ(ω̂ × l)) = δv + [(Ĉ(ω̂×l))×] μ + Ĉ [l×] δb_g
* barometric height: z = h_baro − ĥ = −δr_D           (book eq. 3.30 last row, NED sign, §10 item 26)
* magnetometer, book §3.2 eqs. 3.28–3.38: with the unit reference field m (NED) and the
  rotation τ of eq. 3.33 (τ m = e1), z = rows 2–3 of τ (m × Ĉ m̄) = rows 2–3 of τ μ
  (the two-component measurement −γ̄ of eq. 3.38; for m = e1, τ = I and z = [μ2, μ3], eq. 3.30);
  with the hard-iron states m̄ = (m̃/|m_ref| − b̂_m)/|·| and H_b = τ_{2:3} [m×] Ĉ (I − m̄ m̄^T)/|m̃/|m_ref| − b̂_m|,
  plus the magnitude row z_3 = 1 − |m̃/|m_ref| − b̂_m| = −m̄^T δb_m
* non-holonomic constraint (ground vehicle): body lateral/vertical velocity 0:
  z = 0 − (Ĉ^T v̂)_{y,z} = rows of Ĉ^T δv − Ĉ^T [v̂×] μ
* zero-velocity update: z = 0 − v̂ = δv.
* ground-vehicle longitudinal acceleration (a motion prior: a wheeled vehicle's speed changes slowly): the
  kinematic acceleration along the vehicle's forward axis, averaged over a window, is 0 ± the vehicle's
  acceleration; z = 0 − (R (f̂_b + Ĉ^T g))_x = −(R (Ĉ^T [g×] μ + δb_a))_x, g = (0, 0, g) NED, R: IMU body → vehicle.
* multirotor drag (rotor momentum drag, a multirotor's only horizontal body force besides noise): the body
  x/y specific force f̃ = −μ (C^T (v − w))_{x,y} + b_a, w = (w_N, w_E, 0) the wind;
  z = f̃ − f̂ = −μ (Ĉ^T δv − Ĉ^T [û×] μ_att − Ĉ^T δw)_{x,y} + δb_a,{x,y}, û = v̂ − ŵ.
"""

from __future__ import annotations

import math

import numpy as np

from ins_hil.fusion import generated_jacobians as gj
from ins_hil.fusion.ekf import StateIndex
from ins_hil.nav import earth
from ins_hil.types import Vec


def placed(h: Vec, idx: StateIndex) -> Vec:
    """Rows of the generated Jacobians (``ins_hil.fusion.generated_jacobians``: the 15-state layout δr, δv, μ,
    δb_g, δb_a) in the filter's layout ``idx`` (the bias columns moved, or dropped with their states off)."""
    if idx.n == gj.NX and idx.bg == 9 and idx.ba == 12:
        return h
    H = np.zeros((h.shape[0], idx.n))
    H[:, 0:9] = h[:, 0:9]
    if idx.bg is not None:
        H[:, idx.bg : idx.bg + 3] = h[:, 9:12]
    if idx.ba is not None:
        H[:, idx.ba : idx.ba + 3] = h[:, 12:15]
    return H


def placed_ext(h: Vec, idx: StateIndex, *blocks: tuple[int | None, int]) -> Vec:
    """A generated aid row (the 15 base columns, then the aid's own states, ``gj.H_<aid>``) in the filter's layout:
    the base columns by :func:`placed`, then each of ``blocks`` (its start in ``idx`` or None when off, its size)
    in turn from column 15."""
    H = np.ascontiguousarray(placed(h[:, : gj.NX], idx))  # a fresh array when idx has more states than 15
    k = gj.NX
    for start, size in blocks:
        if start is not None:
            H[:, start : start + size] = h[:, k : k + size]
        k += size
    return H


def ned_residual(lat_m: float, lon_m: float, h_m: float, lat: float, lon: float, h: float) -> Vec:
    """NED metres of (measured − computed) geodetic position (small differences)."""
    m, n = earth.radii(lat)
    return np.array(((lat_m - lat) * (m + h), (lon_m - lon) * (n + h) * math.cos(lat), -(h_m - h)))


def gnss_position(
    idx: StateIndex,
    C_bn: Vec,
    lat: float,
    lon: float,
    h: float,
    meas_lat: float,
    meas_lon: float,
    meas_h: float,
    lever_b: Vec,
    shift_ned: Vec | None = None,
) -> tuple[Vec, Vec]:
    """(z, H) of a GNSS position; ``shift_ned`` moves the measurement (e.g. −v·Δt time alignment)."""
    la = C_bn @ lever_b
    z = ned_residual(meas_lat, meas_lon, meas_h, lat, lon, h) - la
    if shift_ned is not None:
        z = z + shift_ned
    return z, placed(gj.H_gnss_pos(C_bn, lever_b), idx)


def gnss_velocity(idx: StateIndex, C_bn: Vec, vel: Vec, omega_b: Vec, meas_vel: Vec, lever_b: Vec) -> tuple[Vec, Vec]:
    """(z, H) of a GNSS velocity with the lever-arm rotation term."""
    w0, w1, w2 = float(omega_b[0]), float(omega_b[1]), float(omega_b[2])
    l0, l1, l2 = float(lever_b[0]), float(lever_b[1]), float(lever_b[2])
    # ω × l component-wise (the numbers of np.cross, without its ~50 µs of overhead on 3-vectors)
    wl = C_bn @ np.array((w1 * l2 - w2 * l1, w2 * l0 - w0 * l2, w0 * l1 - w1 * l0))
    z = meas_vel - (vel + wl)
    return z, placed(gj.H_gnss_vel(C_bn, omega_b, lever_b), idx)


def baro_height(idx: StateIndex, h: float, baro_h: float) -> tuple[Vec, Vec]:
    """(z, H) of a barometric height already referred to the ellipsoid (m)."""
    return np.array((baro_h - h,)), placed(gj.H_baro(), idx)


def tau_matrix(m: Vec) -> Vec:
    """Book eq. (3.33): orthogonal τ with τ m = e1 for a unit vector m (m_x > −1)."""
    mx, my, mz = float(m[0]), float(m[1]), float(m[2])
    if mx <= -1.0 + 1e-12:
        raise ValueError("tau_matrix: m_x = -1 is singular (eq. 3.33)")
    k = 1.0 / (1.0 + mx)
    return np.array(
        (
            (mx, my, mz),
            (-my, 1.0 - my * my * k, -my * mz * k),
            (-mz, -my * mz * k, 1.0 - mz * mz * k),
        )
    )


def magnetometer(idx: StateIndex, C_bn: Vec, field_b: Vec, ref_ned: Vec, bias_b: Vec | None = None) -> tuple[Vec, Vec]:
    """(z, H) of the book's reduced two-component magnetometer measurement (eqs. 3.28–3.38; + a magnitude row).

    field_b: measured field (any unit, body FRD); ref_ned: reference field (NED, any unit).
    Both are normalised (the book works with unit vectors, σ_m per component).

    With the hard-iron states (``idx.mb``, ``FilterConfig.mag_bias``) field_b and ref_ned share a unit and
    the model is m̃_b = C_nb m_ref + b_m; ``bias_b`` is b̂_m in units of |m_ref|. The corrected direction
    m̄ = u/|u|, u = m̃_b/|m_ref| − b̂_m, enters eq. 3.38 as before. With u_true = u − δb_m,
    m̄ = m̄_true + (I − m̄ m̄^T) δb_m/|u|, so m × Ĉ m̄ = m × (μ × m) + [m×] Ĉ (I − m̄ m̄^T) δb_m/|u| and
    H_b = τ_{2:3} [m×] Ĉ (I − m̄ m̄^T)/|u| (H_μ = τ_{2:3} unchanged). The direction rows see no bias along m̄
    (it changes the magnitude only), so a third row takes the magnitude: |u_true| = 1 gives
    z_3 = 1 − |u| = −m̄^T δb_m. Without it the along-field bias is unobservable and wanders (on the PX4 hover,
    where the field is nearly vertical, to −0.9 |m_ref| in 80 s); with it all three are seen once the vehicle
    turns. The reference magnitude must then be the field's (WMM, or the field at rest)."""
    rn = float(np.linalg.norm(ref_ned))
    m = ref_ned / rn
    mb_s = idx.mb
    if mb_s is not None:
        u = field_b / rn - (np.zeros(3) if bias_b is None else bias_b)
        un = float(np.linalg.norm(u))
        mb = u / un
    else:
        mb = field_b / np.linalg.norm(field_b)
    tau = tau_matrix(m)
    g = tau @ np.cross(m, C_bn @ mb)  # −γ̄ = m × τ Ā m̄  (eq. 3.38, in τ coordinates)
    h_att = placed(gj.H_mag(m), idx)  # rows 2-3 of τ on μ
    if mb_s is None:
        return g[1:3], h_att
    H = np.zeros((3, idx.n))
    H[0:2] = h_att
    H[:, mb_s : mb_s + 3] = gj.H_mag_bias(m, C_bn, mb, un)  # rows 2-3 of τ [m×] Ĉ (I − m̄ m̄^T)/|u|; −m̄^T
    return np.array((g[1], g[2], 1.0 - un)), H


def nonholonomic(idx: StateIndex, C_bn: Vec, vel: Vec) -> tuple[Vec, Vec]:
    """(z, H) of the non-holonomic constraint v_b,y = v_b,z = 0 (ground vehicle)."""
    vb = C_bn.T @ vel
    return -vb[1:3], placed(gj.H_nhc(C_bn, vel), idx)


def longitudinal_accel(idx: StateIndex, C_bn: Vec, R_vb: Vec, a_x: float, g: float) -> tuple[Vec, Vec]:
    """(z, H) of the ground-vehicle longitudinal-acceleration prior: ``a_x`` (m/s²) is the averaged kinematic
    acceleration along the vehicle's forward axis, (R (f_b + Ĉ^T g))_x (R: IMU body → vehicle; g m/s², down);
    the constraint is a_x,true = 0 (its σ, the vehicle's acceleration, in R of the update)."""
    return np.array((-a_x,)), placed(gj.H_long_accel(C_bn, R_vb, g), idx)


def zero_velocity(idx: StateIndex, vel: Vec) -> tuple[Vec, Vec]:
    """(z, H) of a zero-velocity update."""
    return -vel, placed(gj.H_zupt(), idx)


def zero_rate(idx: StateIndex, omega_b: Vec) -> tuple[Vec, Vec]:
    """(z, H) of a zero-angular-rate update: the averaged compensated rate ``omega_b`` (rad/s, body) of a
    vehicle at rest is the residual gyro bias, z = 0 − ω̄ = −δb_g (needs the gyro bias states)."""
    return -omega_b, placed(gj.H_zaru(), idx)


def nonholonomic_mounted(
    idx: StateIndex, C_bn: Vec, vel: Vec, R_vb: Vec, omega_b: Vec, lever_b: Vec
) -> tuple[Vec, Vec, Vec]:
    """(z, H, u) of the non-holonomic constraint at a reference point of the vehicle (e.g. the rear
    axle) in vehicle axes: u = R̂ (Ĉ^T v̂ + ω̂ × l), constraint u_y = u_z = 0.

    R_vb: estimated residual rotation IMU body → vehicle axes (R_true = (I − [δε×]) R̂, δε the
    boresight error state ``idx.mnt`` if estimated); lever_b: IMU → reference point (body FRD, m).
    Linearisation (δv, μ, δb_g as in :func:`nonholonomic`; ω = ω̂ − δb_g):
    H_v = R̂ Ĉ^T, H_μ = −R̂ Ĉ^T [v̂×], H_bg = R̂ [l×], H_ε = [u×]  (rows y, z)."""
    u = R_vb @ (C_bn.T @ vel) + R_vb @ np.cross(omega_b, lever_b)
    H = placed_ext(gj.H_nhc_mounted(C_bn, vel, R_vb, omega_b, lever_b), idx, (idx.mnt, 3))
    return -u[1:3], H, u


def multirotor_drag(idx: StateIndex, C_bn: Vec, vel: Vec, wind_ne: Vec, f_b: Vec, mu: float) -> tuple[Vec, Vec]:
    """(z, H) of the multirotor drag model on the body x/y specific force ``f_b`` (m/s², bias-compensated,
    averaged): f_b,xy = −μ (Ĉ^T (v̂ − ŵ))_xy with the drag coefficient ``mu`` (1/s; PX4's EKF2_MCOEF) and the
    wind ŵ = (``wind_ne``, 0) (NED m/s, the ``idx.wind`` states)."""
    Cnb = C_bn.T
    u = np.array((float(vel[0]) - float(wind_ne[0]), float(vel[1]) - float(wind_ne[1]), float(vel[2])))
    A = Cnb[0:2]
    z = np.asarray(f_b[0:2], dtype=np.float64) + mu * (A @ u)
    return z, placed_ext(gj.H_drag(C_bn, u, mu), idx, (idx.wind, 2))
