"""The multirotor drag aid (NavConfig.aids.drag, measurements.multirotor_drag): its linearisation against the
nonlinear model, its config checks, and a flight in wind whose wind states it recovers."""

from __future__ import annotations

import math

import numpy as np
import pytest

from ins_hil.core import NavConfig, NavCore
from ins_hil.core_parts.config import AidsConfig
from ins_hil.fusion import measurements as mm
from ins_hil.fusion.ekf import FilterConfig, StateIndex
from ins_hil.nav import earth
from ins_hil.nav.mechanization import StrapdownState
from ins_hil.nav.rotation import dcm_from_euler, dcm_from_quat, quat_from_euler, quat_from_rotvec
from ins_hil.types import GnssFix, ImuSample

MU = 0.15  # 1/s
LAT, LON, H = math.radians(47.0), math.radians(8.0), 400.0


def _model(C_bn: np.ndarray, v: np.ndarray, w_ne: np.ndarray, b_a: np.ndarray) -> np.ndarray:
    """The measured body x/y specific force of the drag model (with the accelerometer bias)."""
    u = v - np.array((w_ne[0], w_ne[1], 0.0))
    return -MU * (C_bn.T @ u)[0:2] + b_a[0:2]


def test_the_drag_jacobian_matches_the_nonlinear_model() -> None:
    idx = StateIndex.build(FilterConfig(wind_states=True))
    assert idx.wind is not None and idx.ba is not None and idx.n == 17
    rng = np.random.default_rng(3)
    C_hat = dcm_from_euler(0.1, -0.2, 2.0)
    v_hat, w_hat, b_hat = np.array((3.0, -2.0, 0.5)), np.array((4.0, 1.0)), np.array((0.1, -0.05, 0.02))
    for _ in range(5):
        dx = np.zeros(idx.n)
        dx[idx.vel : idx.vel + 3] = rng.normal(0.0, 0.05, 3)
        dx[idx.att : idx.att + 3] = rng.normal(0.0, 1e-3, 3)
        dx[idx.wind : idx.wind + 2] = rng.normal(0.0, 0.05, 2)
        dx[idx.ba : idx.ba + 3] = rng.normal(0.0, 0.01, 3)
        # the truth: δv = true − computed, Ĉ = (I + [μ×]) C, so C = exp(−[μ×]) Ĉ
        C = dcm_from_quat(quat_from_rotvec(-dx[idx.att : idx.att + 3])) @ C_hat
        f_meas = _model(C, v_hat + dx[3:6], w_hat + dx[idx.wind : idx.wind + 2], b_hat + dx[idx.ba : idx.ba + 3])
        f_comp = np.r_[f_meas - b_hat[0:2], -9.8]  # the core's compensated specific force
        z, Hm = mm.multirotor_drag(idx, C_hat, v_hat, w_hat, f_comp, MU)
        assert np.max(np.abs(z)) > 1e-3  # the perturbation is seen ...
        assert np.max(np.abs(z - Hm @ dx)) < 0.01 * np.max(np.abs(z)), (z, Hm @ dx)  # ... to first order


def test_drag_needs_the_wind_states_and_positive_parameters() -> None:
    with pytest.raises(ValueError, match="wind_states"):
        NavConfig(aids=AidsConfig(drag=True))
    with pytest.raises(ValueError, match="drag_coef"):
        AidsConfig(drag=True, drag_coef=0.0)
    with pytest.raises(ValueError, match="init_wind"):
        FilterConfig(wind_states=True, init_wind=-1.0)


def _flight(drag: bool, wind_n: float = 3.0, v_n: float = 2.0, seconds: float = 60.0) -> NavCore:
    """Level flight north at ``v_n`` m/s in a wind of ``wind_n`` m/s toward north: the vehicle pitches so that
    its thrust balances the drag −μ (v − w) (body x), GNSS position and velocity at 5 Hz."""
    pitch = -math.atan(MU * (v_n - wind_n) / earth.normal_gravity(LAT, H))  # g sinθ = −μ (v − w) cosθ
    C = dcm_from_euler(0.0, pitch, 0.0)
    v = np.array((v_n, 0.0, 0.0))
    w_ie = earth.earth_rate_ned(LAT)
    w_in = w_ie + earth.transport_rate_ned(LAT, H, v)
    f_n = np.cross(w_ie + w_in, v) - earth.gravity_ned(LAT, H)  # (2ω_ie + ω_en) × v − g: no acceleration
    f_b, w_b = C.T @ f_n, C.T @ w_in
    assert abs(f_b[0] - MU * (wind_n - v_n) * math.cos(pitch)) < 1e-3  # the drag, as the model has it
    init = StrapdownState(quat_from_euler(0.0, pitch, 0.0), v.copy(), LAT, LON, H, 0.0)
    filt = FilterConfig(accel_bias=False, wind_states=drag, init_wind=5.0, wind_sigma_rw=0.01,
                        init_att=math.radians(0.5), init_yaw=math.radians(2.0), init_vel=0.2, init_pos=1.0)  # fmt: skip
    core = NavCore(init, NavConfig(filter=filt, aids=AidsConfig(drag=drag, drag_coef=MU, drag_std=0.05)))
    dt = 0.01
    for k in range(1, int(seconds / dt) + 1):
        t = k * dt
        core.step(ImuSample(t=t, dt=dt, dtheta=w_b * dt, dvel=f_b * dt))
        if k % 20 == 0:
            lat, lon, h = earth.geodetic_from_ned(v * t, LAT, LON, H)
            core.fuse(GnssFix(t=t, lat=lat, lon=lon, h=h, vel_ned=tuple(v), std_ne=0.5, std_d=1.0, std_vel=0.1))
    return core


def test_the_drag_aid_recovers_the_wind_in_flight() -> None:
    core = _flight(drag=True)
    assert core.stats["drag"].accepted > 250 and core.stats["drag"].rejected == 0
    assert abs(float(core.wind[0]) - 3.0) < 0.2 and abs(float(core.wind[1])) < 0.2, core.wind
    sd = core.kf.std()
    assert np.all(sd[core.idx.wind : core.idx.wind + 2] < 1.0)  # from 5 m/s: learnt, not the prior
    calm = _flight(drag=True, wind_n=0.0)
    assert abs(float(calm.wind[0])) < 0.2 and abs(float(calm.wind[1])) < 0.2, calm.wind
    assert "drag" not in _flight(drag=False, seconds=2.0).stats
