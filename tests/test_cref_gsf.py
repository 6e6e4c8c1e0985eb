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
