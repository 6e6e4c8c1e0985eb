"""FDI in the pipeline: redundant IMU epochs → FdiMonitor → core; a step fault is isolated,
the event leaves the pipeline, and the recorder + replay reproduce the states and events exactly."""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np

from ins_hil.fdi.geometry import triple_imu
from ins_hil.runtime.pipeline import Pipeline, PipelineConfig
from ins_hil.runtime.recorder import Recorder
from ins_hil.runtime.replay import replay_log
from ins_hil.sim.faults import FaultSpec, inject
from ins_hil.sim.redundant import simulate
from ins_hil.sim.trajectory import generate, static_profile
from ins_hil.types import FaultMode

RATE = 200.0


def test_step_fault_isolated_in_the_pipeline_and_replayed(tmp_path: Path) -> None:
    lat, lon, h = math.radians(50.45), math.radians(30.52), 180.0
    truth = generate(static_profile(yaw=0.3), 8.0, 1 / RATE, lat, lon, h)
    series = simulate(truth, triple_imu(), seed=4)
    series = inject(series, FaultSpec(FaultMode.STEP_BIAS, sensor=4, t_start=4.0, size=math.radians(5.0)))
    cfg = PipelineConfig(
        init="config",
        init_lat_deg=50.45,
        init_lon_deg=30.52,
        init_h=h,
        init_yaw_deg=math.degrees(0.3),
        imu_ids=[0, 1, 2],
        fdi=True,
        fdi_options={"geometry": "triple_imu", "dt": 1 / RATE, "gyro_noise": 0.15 * math.pi / 180 / 60,
                     "accel_noise": 70e-6 * 9.80665},
    )  # fmt: skip
    pipe = Pipeline(cfg)
    rec = Recorder(tmp_path / "fdi.ihlog", header={"pipeline": cfg.__dict__})
    states, events = [], []
    # the three IMUs arrive interleaved, in varying order, as from three drivers
    for k in range(len(series.t)):
        ep = series.epoch(k)
        for s in ep[k % 3 :] + ep[: k % 3]:
            rec.write(s)
            st = pipe.imu(s)
            if st is not None:
                states.append(st)
        events += pipe.drain_events()
    rec.close()
    assert len(states) == len(series.t)  # one state per complete epoch
    faults = [e for e in events if not e.cleared]
    assert faults and faults[0].t >= 4.0 and faults[0].isolated
    assert "gyro" in faults[0].sensor
    # the excluded sensor does not spoil the attitude: static, error-free truth attitude
    q_ref = truth.q_nb[-1]
    from ins_hil.nav.rotation import quat_angle_between

    assert math.degrees(quat_angle_between(states[-1].q_nb, q_ref)) < 1.0
    res = replay_log(tmp_path / "fdi.ihlog")
    assert len(res.states) == len(states)
    assert all(np.array_equal(a.q_nb, b.q_nb) and a.t == b.t for a, b in zip(states, res.states))
    assert [(e.t, e.sensor, e.mode) for e in res.events] == [(e.t, e.sensor, e.mode) for e in events]
