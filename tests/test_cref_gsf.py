"""The GNSS-velocity yaw bank on the C core (``ins_gsf_t``, firmware_ref/src/gsf.c, through ``CYawGsf``) held
against the Python bank (``ins_hil.fusion.yaw_gsf.YawGsf``), and the C core's alignment running it."""

from __future__ import annotations

import dataclasses
import math

import numpy as np
import pytest

from ins_hil.core import NavConfig
from ins_hil.cref import CNavCore, CYawGsf
from ins_hil.fusion.yaw_gsf import GsfConfig, YawGsf
from ins_hil.types import GnssFix, ImuSample


def _accelerating_flight(seed: int = 1) -> list[tuple[str, tuple]]:
    """A vehicle at yaw 0.7 rad accelerating in the horizontal plane (100 Hz IMU, 10 Hz GNSS velocity with
    noise, one 40-m/s velocity spike; every 7th interval with a forward speed: the centripetal correction)."""
    rng = np.random.default_rng(seed)
    dt, yaw = 0.01, 0.7
    C = np.array(((math.cos(yaw), -math.sin(yaw), 0.0), (math.sin(yaw), math.cos(yaw), 0.0), (0.0, 0.0, 1.0)))
    out: list[tuple[str, tuple]] = []
    for k in range(6000):
        t = k * dt
        acc_n = np.array((2.0 * math.sin(0.3 * t), 1.5 * math.cos(0.2 * t), 0.0))
        f_b = C.T @ (acc_n - np.array((0.0, 0.0, 9.80665))) + rng.normal(0.0, 0.2, 3)
        w = rng.normal(0.0, 0.02, 3)
        out.append(("imu", (w * dt, f_b * dt, dt, 3.0 if k % 7 == 0 else 0.0)))
        if k % 10 == 5:
            v = np.array((-2.0 / 0.3 * math.cos(0.3 * t), 1.5 / 0.2 * math.sin(0.2 * t), 0.0)) + rng.normal(0, 0.3, 3)
            if k == 2005:
                v[:2] += 40.0  # a spike: the innovation is shortened to 5 σ
            out.append(("vel", (v, 0.3)))
    return out


def test_c_yaw_bank_matches_python() -> None:
    py, c = YawGsf(), CYawGsf()
    worst = np.zeros(3)
    seen = 0
    for kind, args in _accelerating_flight():
        if kind == "imu":
            py.predict(*args)
            c.predict(*args)
            continue
        py.fuse_velocity(*args)
        c.fuse_velocity(*args)
        assert (c.started, c.tilt_aligned, c.updates) == (py.started, py.tilt_aligned, py.updates)
        assert c.converged() == py.converged()
        if py.updates >= 1:  # (at the start the weights are equal: the circular mean of the spread is round-off)
            seen += 1
            worst = np.maximum(worst, [
                abs(math.remainder(c.yaw - py.yaw, math.tau)),
                abs(c.yaw_var / py.yaw_var - 1.0),
                float(np.max(np.abs(c.W - py.W))),
            ])  # fmt: skip
    assert seen > 550 and py.converged() and abs(math.remainder(py.yaw - 0.7, math.tau)) < 0.1
    assert np.all(worst <= 1e-9), worst


def test_c_yaw_bank_reads_its_state_off_the_c_struct() -> None:
    """The bank's scalars are the C struct's, with the Python bank's types, and cannot be set from Python."""
    py, c = YawGsf(), CYawGsf()
    for name in ("started", "tilt_aligned", "yaw", "yaw_var", "updates"):
        assert type(getattr(c, name)) is type(getattr(py, name)), name
        with pytest.raises(AttributeError):
            setattr(c, name, getattr(py, name))
    c._g.updates, c._g.yaw = 3, 0.25
    assert (c.updates, c.yaw) == (3, 0.25)


def test_c_yaw_bank_refuses_other_settings() -> None:
    with pytest.raises(ValueError, match="PX4's settings"):
        CYawGsf(GsfConfig(tilt_gain=0.3))


def test_c_core_alignment_runs_the_c_bank() -> None:
    """CNavCore's alignment (NavCore until the hand-over) takes its yaw from the C bank, and feeds no yaw-reset
    bank (nothing reads it before the hand-over)."""
    base = NavConfig()
    cfg = dataclasses.replace(base, alignment=dataclasses.replace(base.alignment, mode="static", yaw_gsf=True))
    c = CNavCore(None, cfg)
    assert isinstance(c._align.yaw_gsf, CYawGsf)
    assert not isinstance(c._align.yaw_reset.gsf, CYawGsf) and c._align.yaw_reset.gsf.updates == 0


def _car_stream(seconds: float = 60.0) -> tuple[list[ImuSample], list[GnssFix]]:
    """A car at rest for 5 s, then slowly driving off (50-Hz MEMS IMU, 5-Hz GNSS with velocity): the static
    alignment levels at rest and waits in its heading phase (from 9 s to 15 s) until the yaw bank converges."""
    from ins_hil.sim.sensors import GnssModel, corrupt_imu, gnss_fixes, mems_accel, mems_gyro
    from ins_hil.sim.trajectory import car_profile, generate

    truth = generate(car_profile(speed=5.0, t_start=5.0, t_stop=60.0, ramp=20.0), seconds, 0.02, 0.88, 0.53, 180.0)
    rng = np.random.default_rng(3)
    imu = corrupt_imu(truth, mems_gyro(rng), mems_accel(rng), seed=4)
    samples = [ImuSample(t=float(imu.t[k]), dt=0.02, dtheta=imu.dtheta[k], dvel=imu.dvel[k]) for k in range(len(imu.t))]
    return samples, list(gnss_fixes(truth, GnssModel(rate=5.0), seed=5))


def test_the_heading_phase_on_c_is_navcores_step_by_step() -> None:
    """The alignment's heading phase through ``CNavCore.run_states`` (its gyro-only steps and the yaw bank in one
    C call per run of samples) gives the states ``step_begin`` gives one sample at a time (NavCore's Python
    mechanization), and the same hand-over."""
    base = NavConfig()
    cfg = dataclasses.replace(base, alignment=dataclasses.replace(base.alignment, mode="static", time=3.0,
                                                                  yaw_gsf=True))  # fmt: skip
    imu, fixes = _car_stream()
    one, run = CNavCore(None, cfg, fixed_step=False), CNavCore(None, cfg, fixed_step=False)
    rng = np.random.default_rng(7)
    k = j = batched = 0
    worst = 0.0
    while k < len(imu) and one.phase != "nav":
        if run.can_run():
            n = int(min(rng.integers(1, 12), len(imu) - k))
            while j < len(fixes) and n > 1 and fixes[j].t <= imu[k + n - 2].t:
                n -= 1  # the run ends at the sample that reaches the next fix
            part = imu[k : k + n]
            inc = np.array([np.r_[s.dtheta, s.dvel] for s in part])
            got = run.run_states(inc, np.array([s.t for s in part]), np.array([s.dt for s in part]))
            want = [one.step_begin(s) for s in part]
            batched += 1
            for a, b in zip(want, got, strict=True):
                assert (a.t, a.lat, a.lon, a.h, a.aligned) == (b.t, b.lat, b.lon, b.h, b.aligned)
                for f in ("q_nb", "vel_ned", "omega_b", "gyro_bias", "std_att"):
                    worst = max(worst, float(np.max(np.abs(getattr(a, f) - getattr(b, f)))))
            k += n
        else:
            one.step_begin(imu[k])
            run.step_begin(imu[k])
            k += 1
        while j < len(fixes) and fixes[j].t <= imu[k - 1].t:
            one.fuse(fixes[j])
            run.fuse(fixes[j])
            j += 1
        assert one.phase == run.phase
    assert one.phase == run.phase == "nav" and batched > 40
    assert worst == 0.0  # the C mechanization is the Python one bit for bit (the same formulas in the same order)
    a, b = one.state(), run.state()
    assert (a.t, a.lat, a.lon, a.h) == (b.t, b.lat, b.lon, b.h) and np.array_equal(a.q_nb, b.q_nb)
