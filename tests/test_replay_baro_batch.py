"""A C-core replay hands a stretch of baro samples and the IMU samples between them to the core in one C call
(``Pipeline.baro_runs`` → ``CNavCore.run_baro`` → ``cref_run_baro``): the run is the one the per-measurement
protocol gives (one ``imu_run`` and one ``aid`` + ``flush`` per baro sample), state for state, count for count,
event for event, also when the gate rejects baro samples and when states fail the core guard mid-stretch."""

from __future__ import annotations

import dataclasses
import math
import types
from pathlib import Path
from typing import Any

import numpy as np
import pytest

from ins_hil.cref import CNavCore
from ins_hil.datasets import config, report, run
from ins_hil.runtime import pipeline
from ins_hil.types import BaroSample

CONFIGS = Path(__file__).resolve().parent.parent / "configs" / "datasets"


@pytest.fixture(scope="module")
def prepared() -> run.Prepared:
    cfg = config.load(CONFIGS / "px4_quad.toml")
    assert cfg.path is not None
    return run.prepare(report.load(cfg.path, cfg), cfg)


def _replay(p: run.Prepared, monkeypatch: pytest.MonkeyPatch, batched: bool) -> tuple[run.RunResult, list[int]]:
    """``run_dataset`` on the C core; ``batched`` False: ``Pipeline.baro_runs`` takes nothing (the caller's one
    call per sample). Returns the result and the baro updates each ``run_baro`` call ran."""
    taken: list[int] = []
    orig = CNavCore.run_baro

    def counted(self: CNavCore, *a: Any) -> Any:
        r = orig(self, *a)
        taken.append(r.updates)
        return r

    with monkeypatch.context() as m:
        m.setattr(CNavCore, "run_baro", counted)
        if not batched:
            m.setattr(pipeline.Pipeline, "baro_runs", lambda self, imu, arrays, k0, end, ab, *a: (k0, int(ab[0])))
        return run.run_dataset(p, core="c"), taken


def _tracked(p: run.Prepared, monkeypatch: pytest.MonkeyPatch, batched: bool) -> tuple[run.Track, str | None]:
    """``run.replay`` of ``p`` on the C core with a Track (``batched`` False: one call per baro sample): the track
    and the ReplayError's text, if it stopped (the track keeps the states published before it)."""
    aids = sorted([*p.gnss, *p.aux], key=lambda m: (m.t, 0 if m.kind == "gnss" else 2))
    track = run.Track(p.origin)
    with monkeypatch.context() as m:
        if not batched:
            m.setattr(pipeline.Pipeline, "baro_runs", lambda self, imu, arrays, k0, end, ab, *a: (k0, int(ab[0])))
        try:
            run.replay(p.imu, aids, p.nav, [track], pipeline=run.offline_config(p.aiding_fdi, "c"), screened=True,
                       on_aid_kinds=frozenset({"mag"}), imu_arrays=p.imu_arrays())  # fmt: skip
        except run.ReplayError as e:
            return track, str(e)
    return track, None


def _same(a: run.RunResult, b: run.RunResult) -> None:
    for f in ("t", "q_nb", "vel_ned", "ned", "std_pos", "std_att", "std_vel", "gnss_t", "gnss_err", "gnss_post",
              "gnss_std", "imu_gaps", "sf_corr"):  # fmt: skip
        assert np.array_equal(getattr(a, f), getattr(b, f), equal_nan=True), f
    assert a.stats == b.stats
    assert a.counts == b.counts
    assert [repr(dataclasses.astuple(e)) for e in a.events] == [repr(dataclasses.astuple(e)) for e in b.events]
    assert a.imu_lost == b.imu_lost and a.t_nav == b.t_nav


def test_baro_stretches_in_one_call_give_the_per_sample_run(prepared: run.Prepared,
                                                            monkeypatch: pytest.MonkeyPatch) -> None:  # fmt: skip
    r1, taken = _replay(prepared, monkeypatch, batched=True)
    r0, none = _replay(prepared, monkeypatch, batched=False)
    assert not none
    n_baro = r1.counts["fused_BaroSample"]
    assert sum(taken) > 0.8 * n_baro > 500  # nearly every baro sample went through run_baro
    assert len(taken) < n_baro / 5  # in stretches of many
    _same(r1, r0)


def test_rejected_baro_samples_stop_a_stretch_with_the_same_events(
    prepared: run.Prepared, monkeypatch: pytest.MonkeyPatch
) -> None:
    """Baro outliers (+40 m on 3 samples in a row, 30 times): the gate's rejections and its JUMP events (first
    rejection, accepted again) as one sample at a time gives them."""
    aux = list(prepared.aux)
    baro = [i for i, m in enumerate(aux) if isinstance(m, BaroSample)]
    for i in baro[len(baro) // 4 :: len(baro) // 40][:30]:
        for k in (i, i + 1, i + 2):
            if isinstance(aux[k], BaroSample):
                aux[k] = dataclasses.replace(aux[k], altitude=aux[k].altitude + 40.0)
    p = dataclasses.replace(prepared, aux=aux)
    r1, taken = _replay(p, monkeypatch, batched=True)
    r0, _ = _replay(p, monkeypatch, batched=False)
    assert r1.stats["baro"]["rejected"] >= 30
    assert sum(1 for e in r1.events if e.sensor == "baro") >= 30
    assert sum(taken) > 500
    _same(r1, r0)


def test_states_failing_the_core_guard_mid_stretch(prepared: run.Prepared, monkeypatch: pytest.MonkeyPatch) -> None:
    """A core guard whose height bound the flight crosses: the replay stops with the same error at the same state
    (a replay gives no figures from a faulted core), every state before it published alike."""
    r, _ = _replay(prepared, monkeypatch, batched=False)
    h = np.asarray(r.llh)[:, 2]
    monkeypatch.setattr(pipeline, "STATE_H_MAX", float(np.quantile(h, 0.6)))
    out = []
    for batched in (True, False):
        track, err = _tracked(prepared, monkeypatch, batched)
        assert err is not None and "non-finite navigation states" in err
        out.append((err, track.arrays()))
    assert out[0][0] == out[1][0]
    a, b = out[0][1], out[1][1]
    assert len(a["t"]) > 1000
    for k in a:
        assert np.array_equal(a[k], b[k]), k


def test_each_state_of_a_stretch_carries_the_baro_ratio_in_force_when_it_ran(
    prepared: run.Prepared, monkeypatch: pytest.MonkeyPatch
) -> None:
    """The states an observer is handed: each with the baro test ratio of the update before it (as one run per
    sample gives them), not the stretch's last."""
    out = []
    for batched in (True, False):
        track, err = _tracked(prepared, monkeypatch, batched)
        assert err is None
        st = track.states
        out.append(([s.test_ratios.get("baro") for s in st], [s.t for s in st]))
    (r1, t1), (r0, t0) = out
    assert t1 == t0 and len(t1) > 10_000
    assert len(set(r1)) > 1000  # the ratios change along the flight
    assert r1 == r0


def test_a_stretch_leaves_a_group_that_shares_its_hand_over_with_another_kind_to_the_caller() -> None:
    """Baro groups handed over after IMU samples 2 and 5; a GNSS fix after sample 5 too: the stretch is the first
    group alone (the second goes one sample at a time with the fix, so a core fault in its update drops the fix
    as well, as ``Pipeline.flush`` does); with the fix after sample 6 instead, both groups."""
    from ins_hil.types import ImuSample

    imu = [ImuSample(0.01 * (i + 1), 0.01, np.zeros(3), np.zeros(3)) for i in range(10)]
    baro = [BaroSample(t, math.nan, 10.0) for t in (0.025, 0.03, 0.055)]
    for t_fix, ends, ab in ((0.06, [3], [0, 2]), (0.07, [3, 6], [0, 2, 3])):
        aids = [*baro, types.SimpleNamespace(t=t_fix, kind="gnss")]
        plan = run._BaroPlan(imu, aids, [m.t for m in aids], None)
        e, a = plan.stretch(0, 0)
        assert e.tolist() == ends and a.tolist() == ab


def test_run_baro_refuses_indices_and_arrays_the_c_call_would_misread(
    prepared: run.Prepared, monkeypatch: pytest.MonkeyPatch
) -> None:
    """On a navigating core, in the replay's first stretch of two groups or more: ``end`` not rising, past the
    log, not after ``k0``; ``ab`` beyond the baro samples; float32 altitudes: each a ValueError before C runs."""
    orig = CNavCore.run_baro
    refused: list[str] = []

    def probing(self: CNavCore, inc: Any, t: Any, dt: Any, k0: int, end: Any, ab: Any, bt: Any, alt: Any,
                b: Any) -> Any:  # fmt: skip
        if not refused and len(end) > 1:
            bad = {"end falling": (end[::-1].copy(), ab, alt), "end past n": (end + len(t), ab, alt),
                   "end at k0": (np.r_[k0, end[1:]].astype(np.int64), ab, alt),
                   "ab past": (end, ab + len(bt), alt), "float32": (end, ab, alt.astype(np.float32))}  # fmt: skip
            for what, (e, a, al) in bad.items():
                with pytest.raises(ValueError, match="run_baro"):
                    orig(self, inc, t, dt, k0, e, a, bt, al, b)
                refused.append(what)
        return orig(self, inc, t, dt, k0, end, ab, bt, alt, b)

    monkeypatch.setattr(CNavCore, "run_baro", probing)
    run.run_dataset(dataclasses.replace(prepared, imu=prepared.imu[: len(prepared.imu) // 3]), core="c")
    assert len(refused) == 5
