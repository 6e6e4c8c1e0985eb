"""Fuzz campaign: the oracle, the engine (escapes counted, harness rebuilt), every target runs, the command."""

from __future__ import annotations

import math
import random
from pathlib import Path
from typing import Any

import numpy as np
import pytest

from ins_hil.cli import main
from ins_hil.fuzz import STALL, NavCheck, Target, TargetResult, bad_sample, run_target
from ins_hil.fuzz.targets import TARGETS, Wrong, by_name
from ins_hil.types import BaroSample, FixType, GnssFix, ImuSample, MagSample


def _imu(**kw: Any) -> ImuSample:
    d: dict[str, Any] = {"t": 1.0, "dt": 0.005, "dtheta": np.array((1e-4, 0, 0)), "dvel": np.array((0, 0, -0.049))}
    d.update(kw)
    return ImuSample(**d)


def test_oracle_flags_the_impossible_samples_the_issue_lists() -> None:
    assert bad_sample(_imu()) == ""
    assert bad_sample(_imu(dt=1.4e-45)) == "imu_dt"  # the DroneCAN integration_interval that stopped the loop
    assert bad_sample(_imu(dvel=np.array((1e30, 0, 0)))) == "imu_accel_range"
    assert bad_sample(_imu(dtheta=np.array((math.nan, 0, 0)))) == "imu_nonfinite"
    assert bad_sample(_imu(dt=1e-4, dtheta=np.array((0.9, 0, 0)))) == "imu_rate_range"  # 0.9 rad in 0.1 ms
    fix = GnssFix(1.0, 0.8, 0.2, 100.0, None, 1.0, 2.0, 0.3, FixType.FIX_3D)
    assert bad_sample(fix) == ""
    assert bad_sample(GnssFix(1.0, 0.0, 0.0, 0.0, None, 1.0, 2.0, 0.3, FixType.NO_FIX)) == "gnss_no_fix_delivered"
    assert bad_sample(GnssFix(1.0, 0.8, 0.2, math.nan, None)) == "gnss_height"
    assert bad_sample(GnssFix(1.0, 0.8, 0.2, 100.0, None, math.inf)) == "gnss_std"
    assert bad_sample(BaroSample(1.0, 98_000.0)) == "" and bad_sample(BaroSample(1.0, -5.0)) == "baro_pressure"
    assert bad_sample(MagSample(1.0, np.array((2e-5, 0, 4e-5)))) == ""
    assert bad_sample(MagSample(1.0, np.array((1.0, 0, 0)))) == "mag_field"
    assert bad_sample(Wrong("x")) == "recorder_misread"


def test_engine_counts_escapes_rebuilds_the_harness_and_checks_samples() -> None:
    setups = []

    def setup(rng: random.Random) -> Any:
        n = [0]
        setups.append(n)

        def step() -> tuple[int, list[Any]]:
            n[0] += 1
            if n[0] == 3:
                raise ZeroDivisionError("boom")
            return 2, [_imu(t=float(n[0])), _imu(dt=0.0)]

        return step

    r = run_target(Target("toy", "a toy", setup, nav=False), None, inputs=200)
    assert 200 <= r.inputs <= 201  # the input budget, whatever the machine's speed
    assert r.escaped == len(setups) - 1 >= 1  # every escape rebuilt the harness
    assert r.inputs == 2 * (r.accepted // 2) + r.escaped
    assert r.decoded_bad == r.accepted // 2  # the dt = 0 samples are out of range ...
    assert r.accepted_bad == 0  # ... and the validation boundary stops every one of them
    assert r.findings["escaped ZeroDivisionError"].count == r.escaped
    assert "test_fuzz_targets.py" in r.findings["escaped ZeroDivisionError"].example


def test_nan_state_and_stall_are_counted() -> None:
    res = TargetResult("x", "x")
    nav = NavCheck()
    t = 0.0
    for _ in range(400):  # level + GNSS init, then navigating
        t += 0.005
        nav.feed(_imu(t=t, dvel=np.array((0.0, 0.0, -9.80665 * 0.005))), res)
    assert res.nav_states > 0 and res.nan_states == 0
    nav.feed(_imu(t=t + 0.005, dvel=np.array((1e300, 1e300, 1e300))), res)
    nav.feed(_imu(t=t + 0.010, dvel=np.array((1e300, 1e300, 1e300))), res)
    # the validation boundary stops 1e300 m/s increments: no NaN state, no exception, both rejections counted
    assert res.nan_states + res.nav_exceptions == 0
    assert sum(v for k, v in nav.pipe.counts.items() if k.startswith("reject_imu")) == 2, nav.pipe.counts
    res2 = TargetResult("y", "y")
    nav = NavCheck()
    t = 0.0
    for _ in range(400):
        t += 0.005
        nav.feed(_imu(t=t, dvel=np.array((0.0, 0.0, -9.80665 * 0.005))), res2)
    nav.feed(_imu(t=t + 1e6), res2)  # one sample far ahead: the later ones go "backwards", the pipeline re-anchors
    for _ in range(20):
        t += 0.005
        nav.feed(_imu(t=t, dvel=np.array((0.0, 0.0, -9.80665 * 0.005))), res2)
    assert nav.pipe.counts["imu_clock_reanchor"] == 1 and res2.nav_stalls == 0
    for _ in range(STALL + 5):  # every sample refused (1,000 g): no state for STALL samples, a stall
        t += 0.005
        nav.feed(_imu(t=t, dvel=np.array((0.0, 0.0, 50.0))), res2)
    assert res2.nav_stalls == 1 and "pipeline stall" in res2.findings


#: inputs per target in the smoke test (the former 1-s budget made more than 50 of each target)
SMOKE_INPUTS = 60


@pytest.mark.parametrize("target", TARGETS, ids=[t.name for t in TARGETS])
def test_every_target_runs_and_reaches_past_the_checksums(target: Target) -> None:
    n = 3 if target.name == "replay_process" else SMOKE_INPUTS  # a child process a run: seconds each
    r = run_target(target, None, seed=3, inputs=n)  # an input budget: the same inputs under any load
    assert r.inputs >= n
    if target.decoder:
        assert r.accepted > 0  # structure-aware: valid and mutated-but-checksummed inputs get through
    if target.name == "recorder_reader":
        assert r.escaped == 0 and r.accepted_bad == 0  # any bytes: records or RecordError, never a misread


def test_targets_by_name() -> None:
    assert [t.name for t in by_name(["dbc", "config"])] == ["dbc", "config"]
    with pytest.raises(ValueError, match="nope"):
        by_name(["nope"])
    assert {t.name for t in TARGETS} >= {"serial_frame", "dronecan", "dbc", "mavlink_in", "config", "recorder_reader"}


def test_fuzz_command_prints_per_target_and_writes_the_report(tmp_path: Path, capsys) -> None:
    doc = tmp_path / "robustness.md"
    rc = main(["fuzz", "--budget", "2", "--targets", "dbc", "recorder_reader", "--doc", str(doc)])
    out = capsys.readouterr().out
    assert rc in (0, 1)
    assert "dbc" in out and "recorder_reader" in out and "inputs in" in out and "escaped" in out
    text = doc.read_text()
    assert "| dbc |" in text and "| recorder_reader |" in text and "Machine:" in text and "CPUs" in text
    assert "--budget 2" in text
    assert main(["fuzz", "--targets", "nope"]) == 2
    assert "unknown fuzz target" in capsys.readouterr().err
