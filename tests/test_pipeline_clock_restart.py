"""An IMU whose clock restarts, passed through by a driver (defence in depth: the drivers' clock model
re-anchors its own counters): the pipeline re-anchors it on the second sample and navigates on. Before, every
sample after the restart was refused as reject_imu_time: 0 of 1,000 processed."""

from __future__ import annotations

import math

import numpy as np
import pytest

from ins_hil.runtime.pipeline import Pipeline, PipelineConfig
from ins_hil.types import ImuSample, NavState

G = 9.80665
DT = 0.01


def _imu(t: float, host_s: float | None, imu_id: int = 0) -> ImuSample:
    return ImuSample(t=t, dt=DT, dtheta=np.array((1e-6, 0.0, 0.0)), dvel=np.array((0.0, 0.0, -G * DT)),
                     imu_id=imu_id, t_arrival_ns=0 if host_s is None else round(host_s * 1e9))  # fmt: skip


def _pipe() -> Pipeline:
    return Pipeline(PipelineConfig(init="config", init_lat_deg=50.0, init_lon_deg=30.0, init_h=100.0))


@pytest.mark.parametrize("host", [True, False], ids=["arrival-times", "no-arrival-times"])
def test_clock_restart_is_reanchored_and_navigation_goes_on(host: bool) -> None:
    p = _pipe()
    states: list[NavState] = []
    for k in range(1, 501):  # 5 s at sensor time 1000 s
        st = p.imu(_imu(1000.0 + k * DT, 50.0 + k * DT if host else None))
        assert st is not None
        states.append(st)
    gap = 0.3  # the sensor rebooted: 0.3 s of silence, its clock starts again near 0
    after = [p.imu(_imu(0.001 + k * DT, 55.0 + gap + k * DT if host else None)) for k in range(1000)]
    took = [s for s in after if s is not None]
    assert len(took) == 999, p.counts  # the first sample of the new time base is the candidate
    assert p.counts["imu_clock_reanchor"] == 1 and p.counts["reject_imu_time"] == 1
    t = [s.t for s in [*states, *took]]
    assert np.all(np.diff(t) > 0)
    step = took[0].t - states[-1].t  # the time base continues: the host's gap, or the sensor's own intervals
    assert step == pytest.approx(gap + DT if host else 2 * DT, abs=1e-6)
    assert np.allclose(np.diff([s.t for s in took]), DT)
    assert all(math.isfinite(s.lat) and abs(s.h - 100.0) < 5.0 for s in took)


def test_a_lone_sample_with_an_old_time_costs_that_sample_only() -> None:
    p = _pipe()
    for k in range(1, 101):
        assert p.imu(_imu(10.0 + k * DT, None)) is not None
    assert p.imu(_imu(3.0, None)) is None  # a glitch: refused, kept as the candidate
    for k in range(101, 201):
        assert p.imu(_imu(10.0 + k * DT, None)) is not None  # the clock goes on: no re-anchoring
    assert "imu_clock_reanchor" not in p.counts and p.counts["reject_imu_time"] == 1
    assert p.imu(_imu(11.0, None)) is None  # a re-sent old sample, then one far from it: no restart either
    assert p.imu(_imu(4.0, None)) is None
    assert "imu_clock_reanchor" not in p.counts and p.counts["reject_imu_time"] == 3
