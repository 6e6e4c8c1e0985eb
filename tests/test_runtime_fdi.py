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
    rec = Recorder(tmp_path / "fdi.ihlog", header={"pipeline": cfg.to_dict()})
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


def test_gnss_pull_flagged_and_excluded_by_the_pipeline() -> None:
    """A 1 m/s position-only GNSS pull at t = 30 s: the pipeline's aiding monitor reports a gnss DRIFT event
    through drain_events within 5 s and stops fusing the GNSS (counted as excluded_GnssFix)."""
    from ins_hil.sim import sensors as se
    from ins_hil.sim import trajectory as tr
    from ins_hil.sim.faults import gnss_drift

    lat, lon, h = math.radians(45.0), 0.5, 100.0
    truth = tr.generate(tr.uav_profile(t_takeoff=2.0, ramp=8.0, turn_period=40.0), 45.0, 0.01, lat, lon, h)
    rng = np.random.default_rng(5)
    imu = se.corrupt_imu(truth, se.mems_gyro(rng), se.mems_accel(rng), seed=6).samples()
    fixes = gnss_drift(se.gnss_fixes(truth, se.GnssModel(rate=5, std_ne=0.5, std_d=1.0, std_vel=0.05), seed=15),
                       30.0, (0.7, 0.7, 0.0))  # fmt: skip
    baro = se.baro_samples(truth, rate=25, std=0.3, seed=25)
    e = truth.euler[0]
    cfg = PipelineConfig(
        init="config", init_lat_deg=45.0, init_lon_deg=math.degrees(lon), init_h=h,
        init_roll_deg=math.degrees(e[0]), init_pitch_deg=math.degrees(e[1]), init_yaw_deg=math.degrees(e[2]),
        aiding_fdi=True, aiding_options={"baro_std": 0.3}, nav={"filter": {"cov_every": 5}},
    )  # fmt: skip
    pipe = Pipeline(cfg)
    meas = sorted([*fixes, *baro], key=lambda m: m.t)
    j, events = 0, []
    for s in imu:
        while j < len(meas) and meas[j].t <= s.t:
            pipe.aid(meas[j])
            j += 1
        pipe.imu(s)
        events += pipe.drain_events()
    drift = [ev for ev in events if ev.mode == FaultMode.DRIFT and not ev.cleared]
    assert drift and drift[0].sensor == "gnss" and 30.0 <= drift[0].t <= 35.0
    assert not [ev for ev in events if ev.mode == FaultMode.DRIFT and ev.t < 30.0]
    assert pipe.counts.get("excluded_GnssFix", 0) > 40
    assert pipe.counts.get("fused_GnssFix", 0) > 140


def test_fdi_aiding_config_table_is_validated() -> None:
    import pytest
    from runtime_helpers import sim_config_dict

    from ins_hil.config import ConfigError, from_dict

    d = sim_config_dict()
    assert from_dict(d).pipeline.aiding_fdi  # on by default (tests/test_aiding_live.py: no false alarm live)
    d["fdi"] = {"aiding": {"enabled": True, "p_fa_hour": 1e-4}}
    p = from_dict(d).pipeline
    assert p.aiding_fdi and p.aiding_options == {"p_fa_hour": 1e-4}
    for bad, msg in (
        ({"p_fa": 1e-3}, "fdi.aiding.p_fa"),
        ({"p_fa_hour": 3.0}, "p_fa_hour"),
        ({"window": "long"}, "fdi.aiding.window"),
        ({"exclude": 1}, "fdi.aiding.exclude"),
        ({"enabled": "yes"}, "fdi.aiding.enabled"),
    ):
        d["fdi"] = {"aiding": bad}
        with pytest.raises(ConfigError, match=msg):
            from_dict(d)


def test_lost_frames_with_fdi_never_make_the_state_non_finite() -> None:
    """Soak finding: with redundant IMUs, FDI and lost frames the state went NaN. Epochs that arrive
    with units missing (frames lost) are run incomplete; the core must never see a non-finite sample."""
    lat, lon, h = math.radians(50.45), math.radians(30.52), 180.0
    truth = generate(static_profile(yaw=0.3), 6.0, 1 / RATE, lat, lon, h)
    series = simulate(truth, triple_imu(), seed=5)
    cfg = PipelineConfig(
        init="config", init_lat_deg=50.45, init_lon_deg=30.52, init_h=h, init_yaw_deg=math.degrees(0.3),
        imu_ids=[0, 1, 2], fdi=True,
        fdi_options={"geometry": "triple_imu", "dt": 1 / RATE, "gyro_noise": 0.15 * math.pi / 180 / 60,
                     "accel_noise": 70e-6 * 9.80665},
    )  # fmt: skip
    pipe = Pipeline(cfg)
    rng = np.random.default_rng(1)
    states = []
    for k in range(len(series.t)):
        ep = series.epoch(k)
        # from 2 s on, lose frames: keep a random subset of the units (sometimes only one)
        keep = ep if series.t[k] < 2.0 else [s for s in ep if rng.random() < 0.5] or ep[:1]
        for s in keep:
            st = pipe.imu(s)
            if st is not None:
                states.append(st)
    assert states
    for st in states:
        assert np.all(np.isfinite(st.q_nb)) and np.all(np.isfinite(st.vel_ned)) and math.isfinite(st.lat)
