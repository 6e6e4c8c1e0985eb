"""The validation boundary (ins_hil.validation) on its own, at the pipeline's entry, and as a property:
random samples of any float values through the pipeline never give a non-finite state and never raise."""

from __future__ import annotations

import math
from typing import Any

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from ins_hil.config import ConfigError, from_dict
from ins_hil.runtime.pipeline import Pipeline, PipelineConfig
from ins_hil.types import BaroSample, FixType, GnssFix, ImuSample, MagSample, NavState
from ins_hil.validation import REASONS, Limits, SampleValidator

G = 9.80665


def _imu(t: float, dt: float = 0.001, w: float = 0.0, f: float = -G, imu_id: int = 0) -> ImuSample:
    return ImuSample(t=t, dt=dt, dtheta=np.array((w * dt, 0.0, 0.0)), dvel=np.array((0.0, 0.0, f * dt)), imu_id=imu_id)


def _fix(t: float, **kw: Any) -> GnssFix:
    a: dict[str, Any] = dict(t=t, lat=0.88, lon=0.52, h=100.0, vel_ned=np.zeros(3))
    a.update(kw)
    return GnssFix(**a)


def test_imu_ranges_follow_the_configured_sensor_range() -> None:
    v = SampleValidator(Limits(gyro_range_dps=500.0, accel_range_g=8.0, range_margin=1.0))
    w = math.radians(500.0)
    assert v.imu(_imu(0.001, w=0.99 * w)) is None
    assert v.imu(_imu(0.002, w=-1.01 * w)) == "imu_rate"
    assert v.imu(_imu(0.003, f=-7.9 * G)) is None
    assert v.imu(_imu(0.004, f=8.1 * G)) == "imu_accel"
    # the default: 2000 °/s, 16 g, × 1.5
    d = SampleValidator()
    assert d.imu(_imu(0.001, w=math.radians(2900.0), f=-23.0 * G)) is None
    assert d.imu(_imu(0.002, w=math.radians(3100.0))) == "imu_rate"


def test_imu_dt_band_is_learnt_per_imu_or_configured() -> None:
    v = SampleValidator()
    t = 0.0
    for _ in range(8):  # the nominal period is learnt from the first 8 intervals
        t += 0.001
        assert v.imu(_imu(t)) is None
    assert v.imu(_imu(t + 0.0001, dt=0.0001)) == "imu_dt"  # 0.1 nominal periods
    assert v.imu(_imu(t + 0.006, dt=0.006)) == "imu_dt"  # 6 periods
    assert v.imu(_imu(t + 0.004, dt=0.004)) is None  # 4 periods: a lost frame or two
    # another IMU id learns its own period (100 Hz)
    for k in range(1, 9):
        assert v.imu(_imu(k * 0.01, dt=0.01, imu_id=1)) is None
    assert v.imu(_imu(0.2, dt=0.001, imu_id=1)) == "imu_dt"
    # configured: the band from the first sample on; never outside 1e-5..1 s
    c = SampleValidator(Limits(imu_period_s=0.005))
    assert c.imu(_imu(0.005, dt=0.0005)) == "imu_dt"
    assert c.imu(_imu(0.01, dt=0.005)) is None
    u = SampleValidator()
    assert u.imu(_imu(1.0, dt=5e-6)) == "imu_dt" and u.imu(_imu(3.0, dt=2.0)) == "imu_dt"


def test_imu_time_strictly_increasing_per_id_and_nonfinite() -> None:
    v = SampleValidator()
    assert v.imu(_imu(1.0)) is None
    assert v.imu(_imu(1.0)) == "imu_time"
    assert v.imu(_imu(0.5)) == "imu_time"
    assert v.imu(_imu(0.5, imu_id=2)) is None  # per id
    assert v.imu(_imu(math.inf)) == "imu_nonfinite"
    assert v.imu(_imu(math.nan)) == "imu_nonfinite"
    assert v.imu(ImuSample(t=2.0, dt=0.001, dtheta=np.array((0.0, math.nan, 0.0)), dvel=np.zeros(3))) == "imu_nonfinite"
    assert v.imu(ImuSample(t=2.0, dt=0.001, dtheta=np.zeros(2), dvel=np.zeros(3))) == "imu_nonfinite"
    assert v.imu(ImuSample(t=2.0, dt=0.001, dtheta=[0.0, 0.0, 0.0], dvel=[0.0, 0.0, -G * 1e-3])) is None  # type: ignore[arg-type]


def test_gnss_checks() -> None:
    v = SampleValidator()
    assert v.gnss(_fix(1.0)) is None
    assert v.gnss(_fix(1.0)) == "gnss_time"  # re-sent
    assert v.gnss(_fix(1.0, source=1)) is None  # another receiver
    assert v.gnss(_fix(2.0, fix_type=FixType.FIX_2D)) == "gnss_fix_type"
    assert v.gnss(_fix(2.0, lat=-1.58)) == "gnss_position"
    assert v.gnss(_fix(2.0, lon=3.2)) == "gnss_position"
    assert v.gnss(_fix(2.0, h=-1500.0)) == "gnss_height"
    assert v.gnss(_fix(2.0, vel_ned=np.array((400.0, 400.0, 200.0)))) == "gnss_velocity"
    assert v.gnss(_fix(2.0, vel_ned=np.zeros(2))) == "gnss_velocity"
    assert v.gnss(_fix(2.0, std_ne=2000.0)) == "gnss_std"
    assert v.gnss(_fix(2.0, std_vel=math.inf)) == "gnss_std"
    assert v.gnss(_fix(2.0, vel_ned=None)) is None  # no velocity is fine
    # a rejected fix does not advance the receiver's time
    assert v.gnss(_fix(3.0, h=math.nan)) == "gnss_nonfinite" and v.gnss(_fix(3.0)) is None
    assert SampleValidator(Limits(gnss_min_fix_type=2)).gnss(_fix(1.0, fix_type=FixType.FIX_2D)) is None


def test_baro_and_mag_checks() -> None:
    v = SampleValidator()
    assert v.baro(BaroSample(t=1.0, pressure=101325.0)) is None
    assert v.baro(BaroSample(t=1.0, pressure=math.nan, altitude=120.0)) is None
    assert v.baro(BaroSample(t=1.0, pressure=math.nan)) == "baro_nonfinite"
    assert v.baro(BaroSample(t=1.0, pressure=500.0)) == "baro_range"
    assert v.baro(BaroSample(t=1.0, pressure=101325.0, altitude=-5000.0)) == "baro_range"
    assert v.mag(MagSample(t=1.0, field_b=np.array((2e-5, 0.0, 4e-5)))) is None
    assert v.mag(MagSample(t=1.0, field_b=np.array((2e-3, 0.0, 0.0)))) == "mag_range"
    assert v.mag(MagSample(t=1.0, field_b=np.array((math.nan, 0.0, 0.0)))) == "mag_nonfinite"
    assert v.check(MagSample(t=1.0, field_b=np.zeros(3))) is None  # one routine for every kind


def test_limits_come_from_core_keys_and_bad_limits_are_one_line_errors() -> None:
    from tests.runtime_helpers import sim_config_dict

    cfg = from_dict(sim_config_dict(core={"gyro_range_dps": 1000.0, "accel_range_g": 8.0}), "t")
    p = Pipeline(cfg.pipeline)
    assert p.validator.limits.gyro_range_dps == 1000.0 and p.validator.limits.accel_range_g == 8.0
    with pytest.raises(ConfigError):
        from_dict(sim_config_dict(core={"gyro_range_dps": "fast"}), "t")
    for bad in ({"gyro_range_dps": -1.0}, {"range_margin": math.nan}, {"imu_dt_min_periods": 2.0},
                {"gnss_min_fix_type": 9}, {"baro_pressure_max_pa": 10.0}):  # fmt: skip
        with pytest.raises(ValueError, match=f"core.{next(iter(bad))} = "):
            Pipeline(PipelineConfig(limits=Limits(**bad)))


def test_rejections_are_counted_once_by_reason_at_the_pipeline_entry() -> None:
    p = Pipeline(PipelineConfig(init="config", init_lat_deg=50.0, init_lon_deg=30.0, init_h=100.0))
    for k in range(1, 20):
        p.imu(_imu(k * 0.001))
    p.imu(_imu(0.0195, dt=0.0))
    p.imu(_imu(0.02, w=1e30))
    p.aid(_fix(0.019, fix_type=FixType.NO_FIX))
    p.aid(BaroSample(t=0.019, pressure=math.nan))
    p.aid(MagSample(t=0.019, field_b=np.array((1.0, 0.0, 0.0))))
    p.flush()
    rej = {k: v for k, v in p.counts.items() if k.startswith("reject_")}
    assert rej == {"reject_imu_dt": 1, "reject_imu_rate": 1, "reject_gnss_fix_type": 1,
                   "reject_baro_nonfinite": 1, "reject_mag_range": 1}  # fmt: skip
    assert all(k[len("reject_") :] in REASONS for k in rej)


# -- property: any floats, never a non-finite state, never an exception -------------------------------
_any = st.floats(allow_nan=True, allow_infinity=True, width=64)
_vec = st.tuples(_any, _any, _any)
_sample = st.one_of(
    st.tuples(st.just("imu"), _any, _any, _vec, _vec),
    st.tuples(st.just("good"), st.floats(0.0005, 0.0015), st.floats(-1.0, 1.0), _vec, _vec),
    st.tuples(st.just("gnss"), _any, _any, st.tuples(_any, _any, _any, _any, _any, _any), _vec),
    st.tuples(st.just("baro"), _any, _any, _vec, _vec),
    st.tuples(st.just("mag"), _any, _any, _vec, _vec),
)


def _finite(s: NavState) -> bool:
    vals = [s.t, s.lat, s.lon, s.h, *s.q_nb, *s.vel_ned, *s.std_pos, *s.std_vel, *s.std_att]
    return bool(np.all(np.isfinite(vals)))


@pytest.mark.parametrize("core", ["python", "c"])
def test_any_float_samples_never_give_a_nonfinite_state_or_raise(core: str) -> None:
    @settings(max_examples=60, deadline=None, suppress_health_check=list(HealthCheck))
    @given(st.lists(_sample, min_size=1, max_size=40))
    def run(seq: list[tuple[Any, ...]]) -> None:
        p = Pipeline(PipelineConfig(core=core, init="config", init_lat_deg=50.0, init_lon_deg=30.0, init_h=100.0))
        t = 0.0
        out: list[NavState] = []
        for kind, a, b, u, w in seq:
            if kind == "good":  # a plausible sample with a perturbed dt, so that navigation does run
                t += a
                s = ImuSample(t=t, dt=a, dtheta=np.array((b * a, 0.0, 0.0)), dvel=np.array((0.0, 0.0, -G * a)))
                kind = "imu"
            elif kind == "imu":
                s = ImuSample(t=a, dt=b, dtheta=np.array(u), dvel=np.array(w))
            if kind == "imu":
                r = p.imu(s)
                if r is not None:
                    out.append(r)
                p.work()
            elif kind == "gnss":
                p.aid(GnssFix(t=a, lat=b, lon=u[0], h=u[1], vel_ned=np.array(w), std_ne=u[2], std_d=u[3],
                              std_vel=u[4], fix_type=FixType.FIX_3D if u[5] == u[5] else FixType.NO_FIX))  # fmt: skip
            elif kind == "baro":
                p.aid(BaroSample(t=a, pressure=b, altitude=u[0]))
            else:
                p.aid(MagSample(t=a, field_b=np.array(u)))
        p.flush()
        assert all(_finite(x) for x in out)
        if p.core is not None:
            assert _finite(p.core.state())

    run()


def test_recorded_limits_load_back_in_both_header_layouts() -> None:
    """A log header holds PipelineConfig.limits as a table; older headers hold its keys flat: both replay."""
    import dataclasses

    from ins_hil.runtime.replay import pipeline_config_from_header

    cfg = PipelineConfig(limits=Limits(gyro_range_dps=900.0, gnss_min_fix_type=4))
    new = pipeline_config_from_header({"pipeline": cfg.to_dict()})
    assert pipeline_config_from_header({"pipeline": dataclasses.asdict(cfg)}).limits == cfg.limits  # older header
    old = pipeline_config_from_header({"pipeline": {"gyro_range_dps": 900.0, "gnss_min_fix_type": 4}})
    assert new.limits == old.limits == cfg.limits
    assert pipeline_config_from_header({}).limits == Limits()
