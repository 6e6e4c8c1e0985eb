"""The lost-IMU-data rule (``ins_hil.core.imu_lost``) at its boundary: a sample whose start lies exactly half a
step after the previous sample's end is jitter, one a float's ulp later has data lost before it. Both cores and
every caller that predicts their record (``CNavCore.run_states`` in its short and its numpy form,
``CNavCore.lost_before``, the replay's ``_BaroPlan``) draw the line at the same place."""

from __future__ import annotations

import math

import numpy as np
import pytest

from ins_hil.core import NavCore, imu_lost, imu_lost_v
from ins_hil.cref import CNavCore
from ins_hil.datasets import config
from ins_hil.datasets.run import _BaroPlan
from ins_hil.nav.mechanization import StrapdownState
from ins_hil.types import FaultMode, ImuSample

DT = 1.0 / 128.0  # a power of two: every time below is exact in binary
G = 9.80665


def _times(regular: int = 8) -> tuple[list[float], int, int]:
    """Sample end times (s), all ``DT`` long: ``regular`` back to back, then one starting exactly half a step
    after the previous end, then one starting half a step and one ulp of its end time later; the indices of
    those two."""
    t = [DT * (k + 1) for k in range(regular)]
    t.append(t[-1] + 1.5 * DT)  # lost = 0.5 DT exactly
    half = len(t) - 1
    t.append(math.nextafter(t[-1] + 1.5 * DT, math.inf))  # lost = 0.5 DT + ulp
    over = len(t) - 1
    t += [t[-1] + DT * (k + 1) for k in range(regular)]
    return t, half, over


def _samples(t: list[float]) -> list[ImuSample]:
    return [ImuSample(tk, DT, np.zeros(3), np.array([0.0, 0.0, -G * DT])) for tk in t]


def _cores() -> tuple[NavCore, CNavCore]:
    nav = config.from_dict({"dataset": {"name": "t"}, "nav": {"alignment": {"mode": "given"}}}).nav_config()
    init = StrapdownState(np.array([1.0, 0.0, 0.0, 0.0]), np.zeros(3), 0.8, 0.5, 100.0, 0.0)
    return NavCore(init.copy(), nav), CNavCore(init.copy(), nav, fixed_step=False)


def test_the_rule_at_half_a_step_and_one_ulp_over() -> None:
    t, half, over = _times()
    assert t[half] - DT - t[half - 1] == 0.5 * DT  # the arithmetic is exact: the boundary itself
    assert imu_lost(t[half], DT, t[half - 1]) is None
    lost = imu_lost(t[over], DT, t[half])
    assert lost is not None and lost > 0.5 * DT and lost == pytest.approx(0.5 * DT, abs=1e-15)
    assert imu_lost(t[1], DT, t[0]) is None  # back to back
    assert imu_lost(t[0], DT, t[1]) is None  # a sample starting before the previous end
    ta = np.array(t)
    lost_v, gap = imu_lost_v(ta[1:], np.full(len(t) - 1, DT), ta[:-1])
    assert np.nonzero(gap)[0].tolist() == [over - 1]
    assert lost_v[half - 1] == 0.5 * DT and lost_v[over - 1] == lost


def test_both_cores_coast_only_across_more_than_half_a_step() -> None:
    t, _, over = _times()
    for core in _cores():
        for k, s in enumerate(_samples(t)):
            if isinstance(core, CNavCore) and k:
                assert core.lost_before(s.t, s.dt) == (k == over), k
            core.step(s)
            assert core.imu_lost[0] == (k >= over), (type(core).__name__, k)
        ev = [e for e in core.drain_events() if e.sensor == "imu"]
        assert [(e.mode, e.t) for e in ev] == [(FaultMode.DROPOUT, t[over] - DT)], type(core).__name__


@pytest.mark.parametrize("regular", [4, 20])  # run_states' short form (n <= 16) and its numpy form
def test_run_states_records_the_same_rows(regular: int) -> None:
    t, half, over = _times(regular)
    _, c = _cores()
    s = _samples(t)
    c.step(s[0])
    inc = np.array([np.concatenate([x.dtheta, x.dvel]) for x in s[1:]])
    c.run_states(inc, np.array(t[1:]), np.full(len(t) - 1, DT))
    assert c.run_gap_rows == [over - 1]
    assert c.imu_lost == (1, imu_lost(t[over], DT, t[half]))


def test_the_replays_baro_plan_sees_the_same_loss() -> None:
    t, _, over = _times()
    plan = _BaroPlan(_samples(t), [], [], None)
    # lost[k]: the samples before index k with data lost before them
    assert plan.lost == [0] * (over + 1) + [1] * (len(t) - over)
