"""A C-core replay hands a stretch of baro samples and the IMU samples between them to the core in one C call
(``Pipeline.baro_runs`` → ``CNavCore.run_baro`` → ``cref_run_baro``): the run is the one the per-measurement
protocol gives (one ``imu_run`` and one ``aid`` + ``flush`` per baro sample), state for state, count for count,
event for event, also when the gate rejects baro samples and when states fail the core guard mid-stretch."""

from __future__ import annotations

import dataclasses
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
    p = prepared
    aids = sorted([*p.gnss, *p.aux], key=lambda m: (m.t, 0 if m.kind == "gnss" else 2))
    out = []
    for batched in (True, False):
        track = run.Track(p.origin)
        with monkeypatch.context() as m:
            if not batched:
                m.setattr(pipeline.Pipeline, "baro_runs", lambda self, imu, arrays, k0, end, ab, *a: (k0, int(ab[0])))
            with pytest.raises(run.ReplayError, match="non-finite navigation states") as e:
                run.replay(p.imu, aids, p.nav, [track], pipeline=run.offline_config(p.aiding_fdi, "c"), screened=True,
                           on_aid_kinds=frozenset({"mag"}), imu_arrays=p.imu_arrays())  # fmt: skip
        out.append((str(e.value), track.arrays()))
    assert out[0][0] == out[1][0]
    a, b = out[0][1], out[1][1]
    assert len(a["t"]) > 1000
    for k in a:
        assert np.array_equal(a[k], b[k]), k
