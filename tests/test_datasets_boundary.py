"""The replay's validation boundary (issue 39): the gateway's SampleValidator between every reader and the core;
allocations sized by the samples, loops that advance, non-finite states refused with where they began."""

from __future__ import annotations

import dataclasses
import itertools
import math

import numpy as np
import pytest

from ins_hil.datasets.config import DatasetConfig, OutageProtocol
from ins_hil.datasets.dataset import Dataset
from ins_hil.datasets.run import ReplayError, prepare, rate_bins, run_dataset
from ins_hil.nav import earth
from ins_hil.types import FixType, GnssFix, ImuSample, MagSample

LAT, LON, H = math.radians(45.0), math.radians(7.0), 300.0
M_UT = (20.0, 1.0, 40.0)


def _rest(n: int = 3000, dt: float = 0.01) -> list[ImuSample]:
    g = earth.normal_gravity(LAT, H)
    return [ImuSample(dt * k, dt, np.zeros(3), np.array((0.0, 0.0, -g * dt))) for k in range(1, n + 1)]


def _fixes(n: int = 150, every: float = 0.2) -> list[GnssFix]:
    return [GnssFix(every * k, LAT, LON, H, np.zeros(3), 0.5, 1.0, 0.1, FixType.FIX_3D) for k in range(n)]


def _cfg() -> DatasetConfig:
    return DatasetConfig(name="t", use_baro=False, mag_reference=np.array(M_UT))


def _ds(imu: list[ImuSample], gnss: list[GnssFix] | None = None) -> Dataset:
    mag = [MagSample(0.1 * k, np.array(M_UT) * 1e-6) for k in range(1, 300)]  # level, heading north
    return Dataset(imu, _fixes() if gnss is None else gnss, mag=mag, meta={"source": "mem.csv", "format": "csv"})


def test_an_hour_long_dt_is_never_integrated():
    imu = _rest()
    imu[1500] = dataclasses.replace(imu[1500], dt=3600.0, dvel=imu[1500].dvel * 360000)
    p = prepare(_ds(imu), _cfg())
    assert len(p.imu) == len(imu) - 1 and all(s.dt < 1.0 for s in p.imu)
    assert any("validation: 1 of 3000 IMU samples dropped (imu_dt 1)" in n for n in p.notes), p.notes
    r = run_dataset(p)
    assert np.all(np.isfinite(r.ned)) and float(np.max(np.abs(r.ned))) < 100.0  # was 550,547 km off track


def test_nan_and_out_of_range_samples_are_dropped_before_the_core():
    imu = _rest()
    imu[100] = dataclasses.replace(imu[100], dtheta=np.array((math.nan, 0.0, 0.0)))
    imu[200] = dataclasses.replace(imu[200], dvel=np.array((0.0, 0.0, 1e30)))
    fixes = _fixes()
    fixes[40] = dataclasses.replace(fixes[40], h=math.inf)
    fixes[41] = dataclasses.replace(fixes[41], std_ne=0.0)
    p = prepare(_ds(imu, fixes), _cfg())
    assert len(p.imu) == 2998 and len(p.gnss) == 148
    assert any("imu_accel 1, imu_nonfinite 1" in n for n in p.notes) and any("gnss_nonfinite 1, gnss_std 1" in n
                                                                          for n in p.notes)  # fmt: skip
    r = run_dataset(p)
    assert len(r.t) and np.all(np.isfinite(r.q_nb)) and np.all(np.isfinite(r.ned))


def test_time_out_of_order_keeps_the_longest_increasing_run():
    imu = _rest()
    imu[700] = dataclasses.replace(imu[700], t=imu[700].t + 3600.0)  # one stamp an hour ahead
    fixes = _fixes()
    fixes[30] = dataclasses.replace(fixes[30], t=2.0)  # aiding time backwards
    fixes[31] = dataclasses.replace(fixes[31], t=fixes[29].t)  # and repeated
    p = prepare(_ds(imu, fixes), _cfg())
    t = [s.t for s in p.imu]
    assert len(t) == 2999 and all(b > a for a, b in itertools.pairwise(t))
    g = [f.t for f in p.gnss]
    assert all(b > a for a, b in itertools.pairwise(g)) and len(g) == 148
    r = run_dataset(p)
    assert np.all(np.diff(r.t) > 0)  # the replay's state time never runs backwards


def test_an_hour_long_gap_splits_the_log():
    a, b = _rest(1000), _rest(2000)
    b = [dataclasses.replace(s, t=s.t + 3600.0) for s in b]
    fixes = _fixes(50) + [dataclasses.replace(f, t=f.t + 3600.0) for f in _fixes(100)]
    p = prepare(_ds(a + b, fixes), _cfg())
    assert len(p.imu) == 2000 and p.imu[0].t > 3600.0 and all(f.t >= 3600.0 - 10.0 for f in p.gnss)
    assert any("split the log in 2 parts" in n for n in p.notes)


def test_rate_bins_are_sized_by_the_samples_not_the_time_span():
    imu = _rest(10)
    imu[-1] = dataclasses.replace(imu[-1], t=1e12)  # was 4e12 bins (MemoryError); a negative span: negative dims
    rb = rate_bins(imu)
    assert rb.shape == (2, 2) and rb[-1, 0] == pytest.approx(1e12, rel=1e-9)
    same = rate_bins(_rest(100))
    assert same.shape == (4, 2) and np.allclose(same[:, 0], [0.01, 0.26, 0.51, 0.76])


def test_crash_cut_off_before_the_first_imu_sample():
    ds = _ds(_rest())
    ds.t_end_valid = -5.0
    with pytest.raises(ReplayError, match=r"mem\.csv: the end of valid data \(-5\.00 s\) comes before the first IMU"):
        prepare(ds, _cfg())  # was an IndexError


def test_no_valid_imu_sample_is_one_line():
    imu = [dataclasses.replace(s, dvel=np.full(3, math.nan)) for s in _rest(50)]
    with pytest.raises(ReplayError, match=r"mem\.csv: no IMU sample passes the validation boundary \(imu_nonfinite"):
        prepare(_ds(imu), _cfg())


def test_a_sample_past_prepare_meets_the_pipelines_boundary():
    """The replay runs through the gateway's pipeline: a sample slipped into a hand-made Prepared (past
    prepare's screening) is refused at the pipeline's own validation boundary, counted, and never integrated."""
    p = prepare(_ds(_rest()), _cfg())
    p.imu[2000] = dataclasses.replace(p.imu[2000], dvel=np.full(3, 1e308))
    p.imu[2100] = dataclasses.replace(p.imu[2100], dvel=np.full(3, math.nan))
    r = run_dataset(p)
    assert r.counts.get("reject_imu_accel") == 1 and r.counts.get("reject_imu_nonfinite") == 1, r.counts
    assert np.all(np.isfinite(r.ned)) and float(np.max(np.abs(r.ned))) < 100.0
    assert any("reject_imu_accel 1" in n for n in r.notes), r.notes


def test_non_finite_states_fail_and_say_where_they_began(monkeypatch):
    """A core whose state turns non-finite (the pipeline's guard catches it) gives no figures: one line, its time."""
    from ins_hil.core import NavCore

    step = NavCore.step_begin

    def bad(self, imu):
        st = step(self, imu)
        if imu.t > 20.0:
            self.ins.state.vel_ned = np.full(3, math.inf)
            return self.state()
        return st

    monkeypatch.setattr(NavCore, "step_begin", bad)
    with pytest.raises(ReplayError, match=r"mem\.csv: non-finite navigation states from t = 20\.010 s"):
        run_dataset(prepare(_ds(_rest()), _cfg()))


def test_a_core_exception_fails_the_replay_in_one_line(monkeypatch):
    """An exception inside the core (recovered from live by a restart) fails the replay: one line, its time."""
    from ins_hil.core import NavCore

    step = NavCore.step_begin

    def bad(self, imu):
        if imu.t > 20.0:
            raise np.linalg.LinAlgError("singular")
        return step(self, imu)

    monkeypatch.setattr(NavCore, "step_begin", bad)
    with pytest.raises(ReplayError, match=r"mem\.csv: the replay failed at t = 20\.010 s \(LinAlgError: singular"):
        run_dataset(prepare(_ds(_rest()), _cfg()))


def test_outage_windows_always_advance():
    # (the first case fails on a loop without the bound; the other two never ended: a + step == a)
    cases = ((OutageProtocol("start", 0.0, 1e-3, 0.0), 0.0), (OutageProtocol("start", 0.0, 1e-300, 0.0), 1e6),
             (OutageProtocol("start", -1e308, 1.0, 0.0), 0.0))  # fmt: skip
    for proto, t_ref in cases:
        with pytest.raises(ValueError, match=r"outages: .*more than 10000 windows or a step lost"):
            proto.windows(t_ref, 100.0 if t_ref == 0.0 else 2e6)
    assert OutageProtocol("start", 20.0, 10.0, 20.0).windows(0.0, 100.0) == [(20.0, 30.0), (50.0, 60.0), (80.0, 90.0)]
