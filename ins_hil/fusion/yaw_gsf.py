"""Yaw from GNSS velocity alone: a Gaussian-sum filter of yaw hypotheses (the EKF-GSF yaw estimator).

A vehicle whose course is not its heading (a multicopter flies sideways and hovers) has no yaw from its GNSS
course and, without a magnetometer, none at all at rest. The yaw becomes observable when the vehicle
accelerates: the body-frame specific force, rotated by a wrong yaw, predicts a velocity change in a wrong
direction. This bank runs :attr:`GsfConfig.n_models` hypotheses, their yaw spread evenly round the circle,
each with

- its own attitude reference (a complementary filter of the gyro increments with an accelerometer tilt
  correction whose gain fades as the specific force departs from 1 g, and its own gyro bias), and
- a three-state EKF of ``[v_N, v_E, ψ]`` (m/s, m/s, rad): the horizontal velocity integrated from the
  specific force rotated by the model's attitude, corrected by the GNSS velocity.

Each GNSS velocity updates every model and re-weights it by the Gaussian likelihood of its innovation; the
composite yaw is the weighted circular mean and its variance the weighted spread plus the models' own
variances (Riseborough's EKF-GSF, as in PX4 EKF2's ``EKFGSF_yaw`` and ArduPilot's EKF3; see
docs/references.md). The defaults are PX4's (``EKFGSF_*`` constants). Pure and deterministic: no I/O.

Frames: NED navigation frame, body FRD; ``R`` is C_b^n (body → NED).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from ins_hil.types import Vec

G0 = 9.80665  # m/s², the 1 g of the accelerometer-gain fade


@dataclass(frozen=True)
class GsfConfig:
    """The yaw bank's settings (PX4 EKF2 ``EKFGSF_yaw`` defaults; SI units).

    n_models: yaw hypotheses, spread evenly over 360°. tilt_gain: accelerometer tilt-correction gain (1/s) at
    1 g, fading quadratically to 0 at ±0.5 g from it. gyro_bias_gain: gain of each model's gyro bias learning
    (1/s, only below ``bias_spin_max`` rad/s), limited to ±``gyro_bias_max`` rad/s. gyro_noise (rad/s) and
    accel_noise (m/s²): the yaw-rate and horizontal specific-force noise of the covariance prediction.
    vel_std_min: floor on the GNSS velocity σ (m/s). converged_std: the composite yaw σ (rad) below which
    :meth:`YawGsf.converged` holds (PX4 ``EKFGSF_yaw_err_max``, 15°).
    """

    n_models: int = 5
    tilt_gain: float = 0.2
    gyro_bias_gain: float = 0.04
    gyro_bias_max: float = 0.05
    bias_spin_max: float = 0.175
    gyro_noise: float = 0.1
    accel_noise: float = 2.0
    vel_std_min: float = 0.5
    converged_std: float = math.radians(15.0)

    def __post_init__(self) -> None:
        if self.n_models < 2:
            raise ValueError(f"GsfConfig.n_models={self.n_models}: expected >= 2")
        for name in ("tilt_gain", "gyro_bias_gain", "gyro_noise", "accel_noise", "vel_std_min", "converged_std"):
            v = getattr(self, name)
            if not (math.isfinite(v) and v > 0.0):
                raise ValueError(f"GsfConfig.{name}={v!r}: expected a finite number > 0")


def _exp_so3(phi: Vec) -> Vec:
    """exp([φ×]) for a stack of rotation vectors φ (n, 3) → (n, 3, 3) (Rodrigues)."""
    th2 = np.einsum("ij,ij->i", phi, phi)
    th = np.sqrt(th2)
    small = th < 1e-6
    a = np.where(small, 1.0 - th2 / 6.0, np.sin(th) / np.where(small, 1.0, th))
    b = np.where(small, 0.5 - th2 / 24.0, (1.0 - np.cos(th)) / np.where(small, 1.0, th2))
    K = np.zeros((len(phi), 3, 3))
    K[:, 0, 1], K[:, 0, 2], K[:, 1, 2] = -phi[:, 2], phi[:, 1], -phi[:, 0]
    K[:, 1, 0], K[:, 2, 0], K[:, 2, 1] = phi[:, 2], -phi[:, 1], phi[:, 0]
    return np.eye(3) + a[:, None, None] * K + b[:, None, None] * (K @ K)


def _wrap(a: Vec) -> Vec:
    return (a + np.pi) % (2.0 * np.pi) - np.pi


class YawGsf:
    """The bank of yaw hypotheses; feed it every IMU interval (:meth:`predict`) and every GNSS velocity
    (:meth:`fuse_velocity`); read :attr:`yaw`, :attr:`yaw_var` and :meth:`converged`."""

    def __init__(self, cfg: GsfConfig | None = None) -> None:
        self.cfg = cfg if cfg is not None else GsfConfig()
        n = self.cfg.n_models
        self.tilt_aligned = False  # the models' tilt set from a 1-g specific force
        self.started = False  # velocity fusion started (the yaw states are live)
        self.R = np.tile(np.eye(3), (n, 1, 1))  # C_b^n of each model
        self.bias = np.zeros((n, 3))  # each model's gyro bias (rad/s, body)
        self.X = np.zeros((n, 3))  # [v_N, v_E, ψ] (m/s, m/s, rad)
        self.P = np.zeros((n, 3, 3))
        self.W = np.full(n, 1.0 / n)  # model weights (sum 1)
        self.accel = np.zeros(3)  # low-passed specific force (m/s², body)
        self.yaw = 0.0  # composite yaw (rad)
        self.yaw_var = math.inf  # composite yaw variance (rad²)
        self.updates = 0  # GNSS velocities fused

    # ------------------------------------------------------------------ IMU
    def predict(self, dtheta: Vec, dvel: Vec, dt: float, forward_speed: float = 0.0) -> None:
        """One IMU interval: Δθ (rad) and Δv (m/s) in body FRD over ``dt`` s. ``forward_speed`` (m/s, along body
        x: a ground vehicle or a fixed wing; 0 = unknown): the tilt correction then removes the centripetal
        acceleration ω × (V, 0, 0) of a turn from the specific force, as EKF2 does with its true airspeed
        (PX4 ``src/modules/ekf2/EKF/yaw_estimator/EKFGSF_yaw.cpp``, ``predictEKF``/``ahrsPredict``): a steady
        turn otherwise tilts every model towards the turn's inside and biases the yaw bank."""
        c = self.cfg
        dt_s = max(dt, 1e-3)
        f = dvel / dt_s
        if not self.tilt_aligned:
            fn = math.sqrt(float(f @ f))
            if 0.9 * G0 < fn < 1.1 * G0:  # at (near) rest: the specific force is gravity's
                self.accel = f.copy()
                self._align_tilt(f)
            return
        k = min(10.0 * dt_s * c.tilt_gain, 1.0)  # vibration low-pass: 1/10 of the tilt correction's time constant
        self.accel = self.accel + k * (f - self.accel)
        acc = self.accel
        if forward_speed > 0.0:
            w = dtheta / dt_s
            acc = acc - np.array((0.0, forward_speed * float(w[2]), -forward_speed * float(w[1])))
        an = math.sqrt(float(acc @ acc))
        gain = c.tilt_gain * (1.0 - min(2.0 * abs(an - G0) / G0, 1.0)) ** 2
        tilt = np.zeros_like(self.bias)
        if gain > 0.0 and an > 0.0:
            down_b = self.R[:, 2, :]  # NED down in body, each model
            k_t = gain / an  # down_b × acc (written out: np.cross costs more than the rest of the step)
            tilt = np.empty_like(down_b)
            tilt[:, 0] = (down_b[:, 1] * float(acc[2]) - down_b[:, 2] * float(acc[1])) * k_t
            tilt[:, 1] = (down_b[:, 2] * float(acc[0]) - down_b[:, 0] * float(acc[2])) * k_t
            tilt[:, 2] = (down_b[:, 0] * float(acc[1]) - down_b[:, 1] * float(acc[0])) * k_t  # turns down onto −f
        rate = dtheta / dt_s - self.bias
        learn = np.sqrt(np.einsum("ij,ij->i", rate, rate)) < c.bias_spin_max
        self.bias = np.where(learn[:, None], self.bias - tilt * (c.gyro_bias_gain * dt_s), self.bias)
        np.clip(self.bias, -c.gyro_bias_max, c.gyro_bias_max, out=self.bias)
        self.R = self.R @ _exp_so3(dtheta + (tilt - self.bias) * dt_s)
        if self.started:
            self._predict_ekf(dvel, dt_s)

    def _align_tilt(self, f: Vec) -> None:
        """Every model's attitude from a specific force at rest, yaw 0 (set per model when fusion starts)."""
        d = -f / math.sqrt(float(f @ f))  # NED down, in body
        x = np.array((1.0, 0.0, 0.0))
        north = x - d * float(x @ d)
        north /= math.sqrt(float(north @ north))
        east = np.cross(d, north)
        self.R[:] = np.array((north, east, d))  # rows: the NED axes in body → C_b^n
        self.tilt_aligned = True

    def _model_yaw(self) -> Vec:
        """Each model's yaw from its C_b^n (321 Euler yaw, or the 312 one near ±90° of pitch/roll)."""
        R = self.R
        use321 = np.abs(R[:, 2, 0]) < np.abs(R[:, 2, 1])
        return np.where(use321, np.arctan2(R[:, 1, 0], R[:, 0, 0]), np.arctan2(-R[:, 0, 1], R[:, 1, 1]))

    def _predict_ekf(self, dvel: Vec, dt: float) -> None:
        c = self.cfg
        psi = self._model_yaw()
        self.X[:, 2] = psi
        dv = self.R @ dvel  # (n, 3) NED
        self.X[:, 0] += dv[:, 0]
        self.X[:, 1] += dv[:, 1]
        n = len(psi)
        F = np.tile(np.eye(3), (n, 1, 1))
        F[:, 0, 2] = -dv[:, 1]  # ∂v_N/∂ψ
        F[:, 1, 2] = dv[:, 0]  # ∂v_E/∂ψ
        q_v = (c.accel_noise * dt) ** 2  # horizontal Δv variance, the same on both axes
        q_psi = (c.gyro_noise * dt) ** 2
        P = F @ self.P @ F.transpose(0, 2, 1)
        P[:, 0, 0] += q_v
        P[:, 1, 1] += q_v
        P[:, 2, 2] += q_psi
        self.P = 0.5 * (P + P.transpose(0, 2, 1))

    # ------------------------------------------------------------------ GNSS velocity
    def fuse_velocity(self, vel_ne: Vec, std: float) -> None:
        """A GNSS horizontal velocity (m/s, NE) with its σ (m/s)."""
        if not self.tilt_aligned:
            return
        c = self.cfg
        n = c.n_models
        var = max(std, c.vel_std_min) ** 2
        v = np.asarray(vel_ne, dtype=float)[:2]
        if not self.started:
            inc = 2.0 * math.pi / n
            psi0 = -math.pi + 0.5 * inc + inc * np.arange(n)
            turn = psi0 - self._model_yaw()
            self._turn(turn)
            self.X[:, 0], self.X[:, 1], self.X[:, 2] = v[0], v[1], psi0
            self.P[:] = np.diag((var, var, (0.5 * inc) ** 2))
            self.W[:] = 1.0 / n
            self.started = True
            self._composite()
            return
        innov = self.X[:, :2] - v  # (n, 2)
        S = self.P[:, :2, :2] + var * np.eye(2)
        det = S[:, 0, 0] * S[:, 1, 1] - S[:, 0, 1] * S[:, 1, 0]
        Si = np.empty_like(S)
        Si[:, 0, 0], Si[:, 1, 1] = S[:, 1, 1] / det, S[:, 0, 0] / det
        Si[:, 0, 1], Si[:, 1, 0] = -S[:, 0, 1] / det, -S[:, 1, 0] / det
        d2 = np.einsum("ni,nij,nj->n", innov, Si, innov)  # the test ratio (χ², 2 dof)
        K = self.P[:, :, :2] @ Si  # (n, 3, 2)
        # an innovation beyond 5 σ is shortened to 5 σ (a velocity spike moves no model far)
        scale = np.where(d2 > 25.0, np.sqrt(25.0 / np.maximum(d2, 1e-300)), 1.0)
        dx = np.einsum("nij,nj->ni", K, innov) * scale[:, None]
        self.X = self.X - dx
        self.X[:, 2] = _wrap(self.X[:, 2])
        P = self.P - K @ self.P[:, :2, :]
        self.P = 0.5 * (P + P.transpose(0, 2, 1))
        self._turn(-dx[:, 2])
        dens = np.exp(-0.5 * d2) / (2.0 * math.pi * np.sqrt(det))
        w = np.maximum(dens * self.W, 0.0)
        total = float(w.sum())
        if total > 0.0 and math.isfinite(total):
            self.W = w / total
        self.updates += 1
        self._composite()

    def _turn(self, dpsi: Vec) -> None:
        """Turn each model's attitude about NED down by ``dpsi`` (rad): its yaw moves by it, its tilt does not."""
        c, s = np.cos(dpsi), np.sin(dpsi)
        Rz = np.zeros((len(dpsi), 3, 3))
        Rz[:, 0, 0], Rz[:, 0, 1], Rz[:, 1, 0], Rz[:, 1, 1], Rz[:, 2, 2] = c, -s, s, c, 1.0
        self.R = Rz @ self.R

    def _composite(self) -> None:
        psi = self.X[:, 2]
        self.yaw = math.atan2(float(self.W @ np.sin(psi)), float(self.W @ np.cos(psi)))
        d = _wrap(psi - self.yaw)
        self.yaw_var = float(self.W @ (self.P[:, 2, 2] + d * d))

    def converged(self) -> bool:
        """The composite yaw σ is below :attr:`GsfConfig.converged_std`."""
        return self.started and self.yaw_var < self.cfg.converged_std**2
