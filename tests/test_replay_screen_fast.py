"""The replay's validation boundary (``ins_hil.datasets.run.screen``) checks a log of one IMU in one numpy pass once
the validator knows the IMU's period (``SampleValidator.imu_in_range``): the samples kept, the reasons counted, the
split at long gaps and the validator's state are those of the sample-by-sample check, also with bad samples
injected anywhere (non-finite, out of range, a wrong step, times out of order, a gap that splits the log)."""

from __future__ import annotations

import math
from typing import Any

import numpy as np
import pytest

from ins_hil.datasets import run
from ins_hil.types import ImuSample
from ins_hil.validation import SampleValidator


def _log(n: int, seed: int = 1) -> list[ImuSample]:
    rng = np.random.default_rng(seed)
    dt = 0.005
    return [ImuSample(t=(k + 1) * dt, dt=dt, dtheta=rng.normal(0.0, 1e-3, 3),
                      dvel=np.array([0.0, 0.0, -9.81 * dt]) + rng.normal(0.0, 1e-3, 3)) for k in range(n)]  # fmt: skip


def _bad(imu: list[ImuSample]) -> list[ImuSample]:
    """Bad samples at the start, inside the learning of the period and later, and a gap that splits the log."""
    s = [ImuSample(x.t, x.dt, x.dtheta.copy(), x.dvel.copy()) for x in imu]
    s[0].dtheta[1] = math.nan  # before the period is known
    s[3].dt = 0.5  # a wrong step while it is learnt
    s[40].dvel[2] = 1e3  # out of the accelerometer range
    s[41].dtheta[0] = -50.0  # out of the gyro range
    s[42].dt = math.nan
    s[60].dt = 0.2  # 40 periods: outside the learnt band (20)
    s[70].t = s[69].t  # a repeated time
    s[90].t = 1e6  # one stamp far ahead (dropped as out of order)
    s[120].dvel[0] = math.inf
    s[121].dt = 0.02  # inside the band (20 periods max): passes
    for x in s[300:]:
        x.t += 20.0  # a gap the core does not coast across: the log is split
    s[-1].dtheta[2] = math.nan  # the last one
    return s


def _screen(imu: list[ImuSample], fast: bool, monkeypatch: pytest.MonkeyPatch) -> tuple[Any, SampleValidator]:
    made: list[SampleValidator] = []
    orig = run.SampleValidator

    def keep(*a: Any) -> SampleValidator:
        made.append(orig(*a))
        return made[-1]

    with monkeypatch.context() as m:
        m.setattr(run, "SampleValidator", keep)
        if not fast:
            m.setattr(run, "_imu_arrays_or_none", lambda imu: None)
        sc = run.screen(imu, [], [], "test")
    return sc, made[0]


@pytest.mark.parametrize("bad", [False, True])
def test_fast_screen_is_the_per_sample_one(bad: bool, monkeypatch: pytest.MonkeyPatch) -> None:
    imu = _log(700)
    if bad:
        imu = _bad(imu)
    fast, v_fast = _screen(imu, True, monkeypatch)
    slow, v_slow = _screen(imu, False, monkeypatch)
    assert fast.imu_arrays is not None and slow.imu_arrays is None  # the numpy pass ran (and the reference did not)
    assert [id(s) for s in fast.imu] == [id(s) for s in slow.imu]
    assert fast.notes == slow.notes
    if bad:
        for why in ("imu_rate 1", "imu_accel 1", "imu_dt 1", "imu_time 2", "imu_nonfinite 4"):
            assert why in fast.notes[0]
        assert "split the log" in fast.notes[1]
    assert v_fast.imu_time(0) == v_slow.imu_time(0)
    ref = run.imu_arrays(fast.imu)
    for a, b in zip(fast.imu_arrays, ref, strict=True):
        assert np.array_equal(a, b)


@pytest.mark.parametrize("fast", [True, False])
def test_a_sample_out_of_order_gets_the_live_validators_reason(fast: bool, monkeypatch: pytest.MonkeyPatch) -> None:
    """Out of the log's time order and also non-finite (or with a step outside the band): the reason the live
    validator gives it (its finiteness and step checks come before the time's), not ``imu_time``."""
    imu = _log(700)
    imu[200] = ImuSample(imu[150].t, imu[200].dt, imu[200].dtheta, np.array([math.nan, 0.0, 0.0]))
    imu[250] = ImuSample(imu[240].t, 0.2, imu[250].dtheta, imu[250].dvel)
    imu[260] = ImuSample(math.nan, imu[260].dt, imu[260].dtheta, imu[260].dvel)
    imu[270] = ImuSample(imu[265].t, imu[270].dt, imu[270].dtheta, imu[270].dvel)  # only its time: imu_time
    sc, _ = _screen(imu, fast, monkeypatch)
    live = SampleValidator(run.REPLAY_LIMITS)
    said = [live.imu(x) for x in imu]
    assert [said[k] for k in (200, 250, 260, 270)] == ["imu_nonfinite", "imu_dt", "imu_nonfinite", "imu_time"]
    assert "imu_dt 1, imu_nonfinite 2, imu_time 1" in sc.notes[0]


def test_prepared_arrays_follow_its_samples() -> None:
    """Screen's arrays are the prepared replay's (``Prepared.imu_arrays``, its rate bins) only for its samples."""
    imu = _log(500)
    sc = run.screen(imu, [], [], "test")
    assert sc.imu_arrays is not None
    p = run.Prepared(sc.imu, [], [], run.NavConfig(), imu[0].t, imu[-1].t, (0.0, 0.0, 0.0))
    p.use_imu_arrays(sc.imu_arrays)
    assert p.imu_arrays() is sc.imu_arrays
    assert np.array_equal(p.rate_bins(), run.rate_bins(sc.imu))
    p2 = run.Prepared(sc.imu[:100], [], [], run.NavConfig(), imu[0].t, imu[99].t, (0.0, 0.0, 0.0))
    p2.use_imu_arrays(sc.imu_arrays)  # another sample list: rebuilt
    assert len(p2.imu_arrays()[1]) == 100


def test_an_ordered_run_is_the_one_checked_sample_by_sample(monkeypatch: pytest.MonkeyPatch) -> None:
    """A screened replay of one IMU hands its runs to ``Pipeline.imu_run`` as ``ordered`` (only the first sample's
    time compared): the states, counts and events of the runs whose every sample's time is compared."""
    from ins_hil.cref import CNavCore
    from ins_hil.datasets.config import from_dict
    from ins_hil.nav.mechanization import StrapdownState
    from ins_hil.runtime.pipeline import Pipeline
    from ins_hil.types import GnssFix

    origin = (0.8, 0.5, 100.0)
    nav = from_dict({"dataset": {"name": "t"}, "nav": {"alignment": {"mode": "given"}}}).nav_config()
    sc = run.screen(_log(800), [], [], "t")
    fixes = [GnssFix(s.t, *origin, np.zeros(3), 1.0, 2.0, 0.3) for s in sc.imu[10::20]]
    init = StrapdownState(np.array([1.0, 0.0, 0.0, 0.0]), np.zeros(3), *origin, 0.0)
    orig = Pipeline.imu_run

    def replay(ordered: bool) -> tuple[Any, run.Track, list[bool]]:
        seen: list[bool] = []

        def imu_run(self: Pipeline, samples: Any, screened: bool = False, arrays: Any = None,
                    ordered_: bool = False) -> None:  # fmt: skip
            seen.append(ordered_)
            orig(self, samples, screened, arrays, ordered_ and ordered)

        def setup(pipe: Pipeline) -> None:
            pipe.core = CNavCore(init.copy(), nav, fixed_step=False)

        track = run.Track(origin)
        with monkeypatch.context() as m:
            m.setattr(Pipeline, "imu_run", imu_run)
            pipe, ev = run.replay(sc.imu, fixes, nav, [track], initial=init, pipeline=run.offline_config(True, "c"),
                                  setup=setup, screened=True, imu_arrays=sc.imu_arrays)  # fmt: skip
        return (pipe.counts, [(e.t, e.detail) for e in ev]), track, seen

    a, ta, seen = replay(True)
    b, tb, _ = replay(False)
    assert seen and all(seen)  # every run handed over as ordered
    assert a == b and a[0].get("fused_GnssFix", 0) > 30
    ra, rb = ta.arrays(), tb.arrays()
    assert len(ra["t"]) == len(sc.imu)
    for k in ra:
        assert np.array_equal(ra[k], rb[k]), k


def test_median_is_numpys_and_the_scores_do_not_import_numpy_ma() -> None:
    """``run.median`` is ``np.median``'s number (signed zeros, NaN, even and odd lengths); the replay's scores that
    take a median (``typical_corrections``, ``autocorrelation``) do not import ``numpy.ma`` (np.median's NaN
    check does: ~38 ms of a C replay's start-up)."""
    import subprocess
    import sys

    rng = np.random.default_rng(2)
    for n in range(1, 40):
        for _ in range(20):
            x = np.round(rng.normal(size=n), int(rng.integers(0, 3)))
            if rng.random() < 0.3:
                x[rng.integers(0, n, size=max(1, n // 2))] = rng.choice([0.0, -0.0])
            a, b = float(np.median(x)), run.median(x)
            assert a == b and math.copysign(1.0, a) == math.copysign(1.0, b), (x, a, b)
            assert run.median(x.tolist()) == a
    assert math.isnan(run.median([1.0, math.nan, 2.0])) and math.isnan(run.median([]))
    code = (
        "import sys, types\n"
        "import numpy as np\n"
        "from ins_hil.datasets import run\n"
        "t = np.arange(0.0, 60.0, 0.25)\n"
        "r = types.SimpleNamespace(sf_corr=np.column_stack([t, np.sin(t), np.cos(t)]))\n"
        "print(run.typical_corrections(r), run.autocorrelation(t, np.sin(3 * t)))\n"
        "print('numpy.ma' in sys.modules)\n"
    )
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True)
    assert out.stdout.splitlines()[-1] == "False", out.stdout + out.stderr
