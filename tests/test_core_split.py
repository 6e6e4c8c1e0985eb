"""NavCore.step_begin/step_end (the real-time split of a step) equal NavCore.step."""

from __future__ import annotations

import numpy as np

from ins_hil.core import NavConfig, NavCore
from ins_hil.core_parts.config import AidsConfig
from ins_hil.nav.mechanization import StrapdownState
from ins_hil.nav.rotation import quat_from_euler
from ins_hil.types import GnssFix, ImuSample

G = 9.80665


def _run(split: bool) -> list[tuple[float, ...]]:
    init = StrapdownState(quat_from_euler(0.01, -0.02, 0.3), np.array((5.0, 1.0, 0.0)), 0.87, 0.52, 100.0, 0.0)
    core = NavCore(init, NavConfig(aids=AidsConfig(nhc=True, nhc_min_speed=0.5)))  # ground aids run in the time update
    rng = np.random.default_rng(5)
    out = []
    for k in range(1, 600):
        imu = ImuSample(t=k * 1e-3, dt=1e-3, dtheta=rng.normal(0, 1e-5, 3),
                        dvel=np.array((0.0, 0.0, -G * 1e-3)) + rng.normal(0, 1e-4, 3))  # fmt: skip
        if split:
            core.step_begin(imu)
            if k % 3 == 0:
                core.step_end()  # otherwise the next step_begin / fuse finishes it
        else:
            core.step(imu)
        if k % 3 == 0:
            st = core.state()
            out.append((st.t, *st.q_nb, *st.vel_ned, st.lat, st.lon, st.h, *st.std_pos, *st.std_att))
        if k % 100 == 0:
            for _ in core.fuse_steps(GnssFix(t=k * 1e-3, lat=0.87, lon=0.52 + 1e-8 * k, h=100.5,
                                             vel_ned=(5.0, 1.0, 0.0))):  # fmt: skip
                pass
    core.step_end()
    s = core.state()
    out.append((*s.std_pos, *s.std_vel, *s.std_att, *core.kf.P.ravel()))
    return out


def test_step_begin_end_equals_step_bit_for_bit() -> None:
    whole, split = _run(False), _run(True)
    assert len(whole) == len(split) == 200
    assert whole == split


def test_step_begin_publishes_the_mechanized_state() -> None:
    init = StrapdownState(quat_from_euler(0.0, 0.0, 0.3), np.array((5.0, 0.0, 0.0)), 0.87, 0.52, 100.0, 0.0)
    a, b = NavCore(init, NavConfig()), NavCore(init, NavConfig())
    imu = ImuSample(t=1e-3, dt=1e-3, dtheta=np.array((0.0, 0.0, 1e-4)), dvel=np.array((1e-3, 0.0, -G * 1e-3)))
    st_b = b.step_begin(imu)
    st_a = a.step(imu)  # no aid in this step: the same state, σ of the step before
    assert (st_a.t, *st_a.q_nb, *st_a.vel_ned, st_a.lat, st_a.h) == (
        st_b.t,
        *st_b.q_nb,
        *st_b.vel_ned,
        st_b.lat,
        st_b.h,
    )
    assert np.all(st_b.std_pos < st_a.std_pos)  # the time update (run by step_end) grows P
    b.step_end()
    assert np.array_equal(b.state().std_pos, st_a.std_pos)
