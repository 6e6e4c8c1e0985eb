"""The GNSS-velocity yaw bank (ins_hil.fusion.yaw_gsf) and the core's heading phase with it (alignment.yaw_gsf)."""

from __future__ import annotations

import math

import numpy as np
import pytest

from ins_hil.core import NavConfig, NavCore
from ins_hil.core_parts.config import AlignmentConfig
from ins_hil.fusion.yaw_gsf import GsfConfig, YawGsf
from ins_hil.nav import earth
from ins_hil.nav.rotation import dcm_from_euler, euler_from_quat
from ins_hil.types import GnssFix, ImuSample

G = 9.80665
DT = 0.01
LAT, LON, H = math.radians(47.0), math.radians(8.0), 400.0
REST = 5.0  # s at rest before the motion


def flight(yaw_deg: float, seconds: float, accelerate: bool = True, seed: int = 0):
    """A level vehicle at a fixed yaw, at rest for REST s, then flying a figure eight (course ≠ heading, as a
    multicopter does): IMU increments at 100 Hz and GNSS fixes at 5 Hz (with noise); ``accelerate=False``:
    constant velocity from the start."""
    rng = np.random.default_rng(seed)
    C_nb = dcm_from_euler(0.0, 0.0, math.radians(yaw_deg))
    w = 2 * math.pi / 20.0

    def vel(t: float) -> np.ndarray:
        if not accelerate:
            return np.array((1.5, 1.0, 0.0))
        if t < REST:
            return np.zeros(3)
        tau = t - REST
        return np.array((3.0 * math.sin(w * tau), 2.0 * math.sin(2 * w * tau), 0.0))

    imu, fixes = [], []
    pos = np.zeros(3)
    n = round(seconds / DT)
    for k in range(1, n + 1):
        t0, t1 = (k - 1) * DT, k * DT
        v0, v1 = vel(t0), vel(t1)
        f_n = (v1 - v0) / DT - np.array((0.0, 0.0, G))  # specific force = a − g (NED, g down)
        dv = C_nb.T @ f_n * DT + rng.normal(0.0, 0.02 * math.sqrt(DT), 3)
        dth = rng.normal(0.0, 0.002 * math.sqrt(DT), 3)
        imu.append(ImuSample(t=t1, dt=DT, dtheta=dth, dvel=dv))
        pos = pos + 0.5 * (v0 + v1) * DT
        if k % 20 == 0:
            lat, lon, h = earth.geodetic_from_ned(pos, LAT, LON, H)
            fixes.append(GnssFix(t=t1, lat=lat, lon=lon, h=h, vel_ned=v1 + rng.normal(0.0, 0.05, 3),
                                 std_ne=0.5, std_d=1.0, std_vel=0.1))  # fmt: skip
    return imu, fixes


def run_bank(imu, fixes, cfg: GsfConfig | None = None) -> YawGsf:
    g = YawGsf(cfg)
    j = 0
    for s in imu:
        g.predict(s.dtheta, s.dvel, s.dt)
        while j < len(fixes) and fixes[j].t <= s.t:
            g.fuse_velocity(fixes[j].vel_ned, fixes[j].std_vel)
            j += 1
    return g


def yaw_err(a: float, b_deg: float) -> float:
    return abs((math.degrees(a) - b_deg + 180.0) % 360.0 - 180.0)


@pytest.mark.parametrize("yaw_deg", [60.0, -150.0, 5.0])
def test_bank_finds_the_yaw_from_velocity_changes(yaw_deg: float) -> None:
    g = run_bank(*flight(yaw_deg, 40.0))
    assert g.converged(), f"σ {math.degrees(math.sqrt(g.yaw_var)):.1f}°"
    assert yaw_err(g.yaw, yaw_deg) < 5.0
    assert g.W.max() > 0.5  # the weights moved onto the right hypotheses


def test_bank_does_not_claim_a_yaw_it_cannot_see() -> None:
    """At constant velocity the yaw is unobservable: the bank must not converge."""
    g = run_bank(*flight(60.0, 40.0, accelerate=False))
    assert g.started and not g.converged()
    assert np.allclose(g.W, g.W[0], atol=0.05)


def test_bank_config_is_checked() -> None:
    with pytest.raises(ValueError, match="n_models"):
        GsfConfig(n_models=1)
    with pytest.raises(ValueError, match="accel_noise"):
        GsfConfig(accel_noise=math.nan)


def _align(imu, fixes, gsf: bool, until_end: bool = False) -> tuple[NavCore, float, float]:
    """Run the core; returns it, its yaw (rad) and yaw σ (rad) when it starts navigating (and runs on to the
    end of the data with ``until_end``)."""
    core = NavCore(None, NavConfig(alignment=AlignmentConfig(mode="static", yaw_gsf=gsf)))
    j = 0
    yaw0 = sd0 = math.nan
    for s in imu:
        core.step(s)
        while j < len(fixes) and fixes[j].t <= s.t:
            core.fuse(fixes[j])
            j += 1
        if core.phase == "nav" and math.isnan(yaw0):
            yaw0, sd0 = euler_from_quat(core.ins.state.q_nb)[2], core.state().std_att[2]
            if not until_end:
                break
    return core, yaw0, sd0


def test_core_heading_phase_takes_the_banks_yaw_not_the_course() -> None:
    imu, fixes = flight(-120.0, 80.0)
    core, yaw0, sd0 = _align(imu, fixes, gsf=True, until_end=True)
    assert core.phase == "nav", core.align_status()
    assert math.degrees(sd0) < 15.0 and yaw_err(yaw0, -120.0) < 2.0 * math.degrees(sd0)  # within its σ
    assert yaw_err(euler_from_quat(core.ins.state.q_nb)[2], -120.0) < 3.0  # the filter refines it in the turns
    _, course, _ = _align(imu, fixes, gsf=False)  # the default takes the course at 1 m/s: wrong for this vehicle
    assert yaw_err(course, -120.0) > 20.0  # the course starts at 53°


def test_core_says_it_waits_for_the_bank() -> None:
    imu, fixes = flight(60.0, 12.0, accelerate=False)
    core, _, _ = _align(imu, fixes, gsf=True)
    assert core.phase == "heading"
    assert "GNSS-velocity yaw estimator" in core.align_status()
