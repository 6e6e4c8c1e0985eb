"""The aid registry (ins_hil/aids): one source per sample type, dispatch by type in the core, the validation
boundary and the recorder; a new aid (the odometer) live through the Pipeline and replayed from its .ihlog bit for
bit; the runtime's initialisation through the core's (ins_hil.core.initial_state)."""

from __future__ import annotations

import dataclasses
import math
import re
from pathlib import Path

import numpy as np
import pytest

from ins_hil import aids
from ins_hil.aids.airspeed import AirspeedSample
from ins_hil.aids.odometer import OdometerSample
from ins_hil.core import NavConfig, NavCore
from ins_hil.nav.mechanization import StrapdownState
from ins_hil.nav.rotation import dcm_from_quat, euler_from_quat
from ins_hil.runtime.pipeline import Pipeline, PipelineConfig
from ins_hil.runtime.recorder import Recorder
from ins_hil.runtime.replay import replay_log
from ins_hil.sim import sensors as se
from ins_hil.sim import trajectory as tr
from ins_hil.types import BaroSample, GnssFix, ImuSample, MagSample
from ins_hil.validation import REASONS, SampleValidator

LAT0, LON0, H0 = math.radians(45.0), 0.5, 100.0


def test_one_source_per_sample_type_and_record() -> None:
    by = aids.by_sample()
    assert {GnssFix, BaroSample, MagSample, OdometerSample, AirspeedSample} <= set(by)
    recs = [s.record for s in aids.sources() if s.record]
    assert len(recs) == len(set(recs)) and 1 not in recs and 15 not in recs  # the IMU's and the end frame's
    assert all(r in REASONS for r in aids.reasons())
    assert set(aids.sections()) == {"odometer", "airspeed"}


def test_an_unknown_sample_is_refused_in_one_line() -> None:
    @dataclasses.dataclass
    class Foo:
        t: float = 0.0
        t_arrival_ns: int = 0

    with pytest.raises(TypeError, match="SampleValidator: unsupported sample Foo"):
        SampleValidator().check(Foo())
    core = NavCore(StrapdownState(np.array([1.0, 0, 0, 0]), np.zeros(3), LAT0, LON0, H0), NavConfig())
    with pytest.raises(TypeError, match="no aid source reads Foo"):
        core.fuse(Foo())


def _inputs(seconds: float = 20.0) -> list:
    """The simulated car's IMU, GNSS (5 Hz) and odometer (10 Hz) samples in time order."""
    truth = tr.generate(tr.car_profile(speed=8.0, t_start=2.0, t_stop=60.0, ramp=3.0), seconds, 0.01, LAT0, LON0, H0)
    rng = np.random.default_rng(1)
    imu = se.corrupt_imu(truth, se.mems_gyro(rng), se.mems_accel(rng), seed=2).samples()
    fixes = se.gnss_fixes(truth, se.GnssModel(rate=5, std_ne=0.5, std_d=1.0, std_vel=0.05), seed=3)
    odo = [OdometerSample(float(truth.t[i]), float((dcm_from_quat(truth.q_nb[i]).T @ truth.vel_ned[i])[0]))
           for i in range(10, len(truth.t), 10)]  # fmt: skip
    return sorted([*imu, *fixes, *odo], key=lambda s: (s.t, not isinstance(s, ImuSample)))


def test_the_odometer_live_through_the_pipeline_and_replayed_bit_for_bit(tmp_path: Path) -> None:
    nav = {"aids": {"nhc": True}, "odometer": {"enabled": True, "init_scale_std": 0.01}}
    cfg = PipelineConfig(init="config", init_lat_deg=45.0, init_lon_deg=math.degrees(0.5), init_h=100.0,
                         aiding_fdi=False, nav=nav)  # fmt: skip
    pipe = Pipeline(cfg)
    rec = Recorder(tmp_path / "odo.ihlog", header={"pipeline": cfg.to_dict()})
    live = []
    for s in _inputs():
        rec.write(s)
        if s.kind == "imu":
            st = pipe.imu(s)
            if st is not None:
                live.append(st)
        else:
            pipe.aid(s)
    pipe.flush()
    rec.close()
    assert pipe.counts.get("fused_OdometerSample", 0) > 150, pipe.counts
    assert pipe.core is not None and pipe.core.stats["odometer"].accepted > 150  # type: ignore[attr-defined]
    res = replay_log(tmp_path / "odo.ihlog")
    assert len(res.states) == len(live)
    for a, b in zip(live, res.states, strict=True):
        assert a.t == b.t and a.lat == b.lat and a.lon == b.lon and np.array_equal(a.vel_ned, b.vel_ned)
        assert np.array_equal(a.q_nb, b.q_nb)
    # the .ihlog reader keeps the aid modules' records (Dataset.of_samples sorts them by kind)
    from ins_hil.datasets.ihlog import read_ihlog

    ds = read_ihlog(tmp_path / "odo.ihlog")
    assert len(ds.aids) == pipe.counts["fused_OdometerSample"] and all(a.kind == "odometer" for a in ds.aids)
    assert ds.gnss and all(g.kind == "gnss" for g in ds.gnss)


def test_every_sample_type_names_its_kind_and_nothing_dispatches_on_the_types_outside_the_registry() -> None:
    assert ImuSample.kind == "imu" and all(s.sample.kind == s.name for s in aids.sources() if s.sample is not None)
    root = Path(__file__).resolve().parent.parent
    names = "|".join(["ImuSample", "AidSample", *(t.__name__ for t in aids.sample_types())])
    pat = re.compile(rf"isinstance\([^)]*\b({names})\b")
    hits = [f"{p.relative_to(root)}:{k}" for d in ("ins_hil", "drivers", "scripts") for p in (root / d).rglob("*.py")
            if "aids" not in p.relative_to(root).parts
            for k, line in enumerate(p.read_text().splitlines(), 1) if pat.search(line)]  # fmt: skip
    assert not hits, hits


def test_the_fdi_and_aiding_monitor_configs_are_built_once() -> None:
    from runtime_helpers import sim_config_dict

    from ins_hil.config import from_dict
    from ins_hil.runtime.pipeline import nav_config
    from ins_hil.settings import ConfigError

    d = sim_config_dict()
    d["fdi"] = {"aiding": {"p_fa_hour": 1e-4}}
    p = from_dict(d).pipeline
    built = p.aiding_config()
    pipe = Pipeline(p)
    assert pipe._aid_mon is not None and pipe._aid_mon.cfg is built  # the loader's object, not a second build
    p.aiding_options = {"p_fa_hour": 1e-3}  # a changed table is built again
    assert p.aiding_config() is not built and p.aiding_config().p_fa_hour == 1e-3
    with pytest.raises(ConfigError, match=r"core\.nav\.sources"):  # a header's old `sources` table is no key
        nav_config({"sources": {"odometer": {"enabled": True}}})


def test_the_runtime_starts_the_core_with_the_cores_yaw_from_course() -> None:
    """init = "gnss": the yaw is the GNSS course above the core's ``alignment.gnss_yaw_speed`` (1 m/s by default;
    the runtime had its own 3 m/s threshold before, and took the configured yaw at 2 m/s)."""
    pipe = Pipeline(PipelineConfig(init="gnss", init_yaw_deg=0.0, level_samples=10, aiding_fdi=False))
    for k in range(1, 21):
        pipe.imu(ImuSample(t=k * 0.01, dt=0.01, dtheta=np.zeros(3), dvel=np.array((0.0, 0.0, -9.80665 * 0.01))))
    v = 2.0 / math.sqrt(2.0)
    pipe.aid(GnssFix(t=0.2, lat=LAT0, lon=LON0, h=H0, vel_ned=np.array((v, v, 0.0)), std_ne=1.0, std_vel=0.1))
    assert pipe.core is not None
    yaw = euler_from_quat(pipe.core.state().q_nb)[2]
    assert yaw == pytest.approx(math.pi / 4, abs=1e-9)
    slow = Pipeline(PipelineConfig(init="gnss", init_yaw_deg=10.0, level_samples=10, aiding_fdi=False,
                                   nav={"alignment": {"gnss_yaw_speed": 3.0}}))  # fmt: skip
    for k in range(1, 21):
        slow.imu(ImuSample(t=k * 0.01, dt=0.01, dtheta=np.zeros(3), dvel=np.array((0.0, 0.0, -9.80665 * 0.01))))
    slow.aid(GnssFix(t=0.2, lat=LAT0, lon=LON0, h=H0, vel_ned=np.array((v, v, 0.0)), std_ne=1.0, std_vel=0.1))
    assert slow.core is not None
    assert euler_from_quat(slow.core.state().q_nb)[2] == pytest.approx(math.radians(10.0), abs=1e-9)
