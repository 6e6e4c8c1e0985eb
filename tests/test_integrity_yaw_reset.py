"""Issue 40 item 1: a yaw that later disagrees with the GNSS-velocity yaw estimator while the vehicle moves and the
filter's innovations fail is reset from the estimator (EKF2's emergency yaw reset, core_parts/yaw_reset.py), counted
in ``NavCore.yaw_resets`` and reported as a FaultEvent / STATUSTEXT; a filter whose yaw is right is never reset."""

from __future__ import annotations

import math

import numpy as np
import pytest

from ins_hil.core import NavConfig, NavCore
from ins_hil.core_parts.config import AidsConfig
from ins_hil.nav.mechanization import StrapdownState
from ins_hil.nav.rotation import euler_from_quat, quat_from_rotvec, quat_mul
from ins_hil.sim import sensors as se
from ins_hil.sim import trajectory as tr

LAT0, LON0, H0 = math.radians(47.0), math.radians(8.0), 400.0
DEG = math.pi / 180
DT = 0.01


def _run(
    seed: int, kick_deg: float = 0.0, init_err_deg: float = 0.0, seconds: float = 70.0, t_kick: float = 50.0
) -> tuple[NavCore, list[tuple[float, float]]]:
    """A car on a 15 m/s, 60-s circle (MEMS IMU, GNSS position + velocity at 5 Hz, σ 0.5 m / 0.1 m/s, NHC on).
    ``init_err_deg``: the given initial yaw is off by that much (σ the default 10°); ``kick_deg``: the core's yaw is
    turned by that much at ``t_kick`` (a disturbed heading the filter believes). Returns the core and (t s, yaw
    error °) every 0.5 s."""
    truth = tr.generate(tr.circle_profile(period=60.0, speed=15.0, roll_amp=0.0), seconds, DT, LAT0, LON0, H0)
    rng = np.random.default_rng(seed)
    imu = se.corrupt_imu(truth, se.mems_gyro(rng), se.mems_accel(rng), seed=seed + 10).samples()
    fixes = se.gnss_fixes(truth, se.GnssModel(rate=5, std_ne=0.5, std_d=1.0, std_vel=0.1), seed=seed + 20)
    q0 = quat_mul(quat_from_rotvec(np.array((0.0, 0.0, init_err_deg * DEG))), truth.q_nb[0])
    s0 = StrapdownState(q0, truth.vel_ned[0].copy(), truth.lat[0], truth.lon[0], truth.h[0], t=0.0)
    core = NavCore(s0, NavConfig(aids=AidsConfig(nhc=True)))
    fi = 0
    err: list[tuple[float, float]] = []
    for k, s in enumerate(imu):
        core.step(s)
        if kick_deg and abs(s.t - t_kick) < 0.5 * DT:
            core.ins.state.q_nb = quat_mul(quat_from_rotvec(np.array((0.0, 0.0, kick_deg * DEG))), core.ins.state.q_nb)
        while fi < len(fixes) and fixes[fi].t <= s.t + 1e-9:
            core.fuse(fixes[fi])
            fi += 1
        if (k + 1) % 50 == 0:
            e = math.remainder(euler_from_quat(core.ins.state.q_nb)[2] - truth.euler[k + 1, 2], math.tau)
            err.append((s.t, math.degrees(e)))
    return core, err


@pytest.mark.parametrize("kick", [60.0, -120.0])
def test_a_yaw_knocked_off_in_motion_is_reset_from_the_yaw_estimator(kick: float) -> None:
    """The yaw turned by 60° / −120° at 50 s (its σ still ≈ 2°): the NHC rejects the sideways body velocity, and
    1.4 s later (EKF2's 1-s reset delay, at the next fix) the yaw is reset onto the estimator's; from 2 s after the
    kick it stays within 2° of the truth (measured 0.5°). Before, nothing reset the yaw: the run ended ≈ 35° off."""
    core, err = _run(1, kick_deg=kick)
    assert len(core.yaw_resets) == 1, core.yaw_resets
    t_r, why = core.yaw_resets[0]
    assert 50.0 < t_r <= 52.0 and why.startswith("yaw ")
    assert max(abs(e) for t, e in err if t >= 52.0) < 2.0
    assert core.divergences == []
    ev = [e for e in core.drain_events() if e.sensor == "nav"]
    assert len(ev) == 1 and ev[0].detail.startswith("yaw reset")


def test_a_wrong_initial_yaw_is_reset_once_the_estimator_converges() -> None:
    """A given initial yaw 90° off with a 10° σ: the GNSS velocity is accepted (the filter's velocity follows it) but
    the NHC fails; once the estimator's σ is below 15° (≈ 6 s of turning) the yaw is reset. Before, the run stayed
    ≈ 69° off to its end."""
    core, err = _run(1, init_err_deg=90.0, seconds=30.0)
    assert len(core.yaw_resets) == 1 and core.yaw_resets[0][0] < 10.0, core.yaw_resets
    assert max(abs(e) for t, e in err if t >= 12.0) < 2.0


def test_a_right_yaw_is_never_reset() -> None:
    core, err = _run(2)
    assert core.yaw_resets == []
    assert max(abs(e) for _, e in err) < 2.0


def test_a_yaw_reset_reads_as_one_statustext() -> None:
    from ins_hil.runtime.mavlink_msgs.common import fault_text

    core, _ = _run(1, kick_deg=60.0, seconds=55.0)
    ev = [e for e in core.drain_events() if e.sensor == "nav"]
    sev, text = fault_text(ev[0])
    assert text == "INS yaw reset to the GNSS yaw estimator" and len(text) <= 50 and sev == 4
