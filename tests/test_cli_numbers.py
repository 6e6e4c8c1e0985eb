"""Numbers out of range (negative, zero, NaN, infinite, absurd) are one line naming the flag, exit status 2,
before any work: not a ValueError from deep inside, a MemoryError after a long allocation, or a silent run."""

from __future__ import annotations

from typing import Any

import pytest

from ins_hil.cli import main


def _started(calls: list[str], name: str) -> Any:
    def work(*a: Any, **k: Any) -> Any:
        calls.append(name)
        raise AssertionError(f"the work started: {name}")

    return work


@pytest.mark.parametrize(
    "argv, says",
    [
        (["--duration", "nan"], "--duration nan: must be a finite number of seconds"),
        (["--duration", "1e9"], "--duration 1e+09 x --rate 200 = 2e+11 IMU samples: at most 720,000"),
        (["--duration", "1", "--rate", "1e7"], "IMU samples: at most 720,000"),
        (["--duration", "1", "--rate", "inf"], "--rate inf: must be a positive number of Hz"),
        (["--duration", "1", "--rate", "0.5"], "fewer than 2 IMU samples"),
        (["--duration", "-1"], "--duration and --rate must be positive"),
        (["--lat", "200"], "--lat 200: must be within ±90°"),
        (["--lon", "nan"], "--lon nan: must be within ±180°"),
        (["platform-ins", "--duration", "nan"], "--duration nan: must be a finite number of seconds"),
        (["platform-ins", "--duration", "1e12"], "--duration 1e+12: at most 86400 s"),
        (["platform-ins", "--duration", "10"], "--duration 10: platform-ins needs at least"),
    ],
)
def test_demo_refuses_bad_numbers(
    argv: list[str], says: str, monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture[str]
) -> None:
    from ins_hil.commands import demo
    from ins_hil.platform_ins import testbed

    calls: list[str] = []
    monkeypatch.setattr(demo, "generate", _started(calls, "generate"))
    monkeypatch.setattr(testbed, "simulate", _started(calls, "simulate"))
    rc = main(["demo", *argv])
    err = [x for x in capsys.readouterr().err.splitlines() if x.strip()]
    assert rc == 2 and calls == [] and len(err) == 1 and err[0].startswith("ins-hil demo: ") and says in err[0], err


@pytest.mark.parametrize("duration", ["nan", "inf", "0", "-3"])
def test_run_refuses_a_duration_that_is_not_a_positive_number(
    duration: str, monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture[str]
) -> None:
    """``--duration nan`` ran the gateway for 0 s and exited 0; ``inf`` ran for ever."""
    from ins_hil import config

    calls: list[str] = []
    monkeypatch.setattr(config, "load_outputs", _started(calls, "load_outputs"))
    rc = main(["run", "--duration", duration, "--no-status"])
    err = [x for x in capsys.readouterr().err.splitlines() if x.strip()]
    assert rc == 2 and calls == [] and len(err) == 1, err
    assert err[0].startswith(f"ins-hil run: --duration {float(duration):g}: must be a positive number of seconds")


@pytest.mark.parametrize(
    "argv, says",
    [
        (
            ["--budget", "1"],
            "--budget 1: too short, no target would run (a share of 0.5 s or less is skipped): at least",
        ),
        (["--budget", "0.4", "--targets", "dbc"], "--budget 0.4: too short, no target would run"),
        (["--budget", "100", "--memory-mib", "-5"], "--memory-mib -5: must be ≥ 0 (0: no cap)"),
        (["--budget", "100", "--jobs", "100000"], "--jobs 100000: at most "),
    ],
)
def test_fuzz_refuses_a_budget_that_runs_nothing(
    argv: list[str], says: str, monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture[str]
) -> None:
    """``--budget 1`` ran none of the 16 targets (each share under 0.5 s is skipped) and exited 0."""
    from ins_hil.commands import fuzz

    calls: list[str] = []
    monkeypatch.setattr(fuzz, "run_target", _started(calls, "run_target"))
    monkeypatch.setattr(fuzz, "_run_jobs", _started(calls, "_run_jobs"))  # a regression must not start 100000 processes
    rc = main(["fuzz", *argv, "--no-doc"])
    err = [x for x in capsys.readouterr().err.splitlines() if x.strip()]
    assert rc == 2 and calls == [] and len(err) == 1 and err[0].startswith("ins-hil fuzz: ") and says in err[0], err


@pytest.mark.parametrize(
    "argv, says",
    [
        (["--duration", "nan"], "--duration nan: must be a finite number"),
        (["--duration", "1", "--rate", "inf"], "--rate inf: must be a finite number"),
        (["--duration", "1", "--baseline", "nan"], "--baseline nan: must be a finite number"),
        (["--duration", "1", "--gcs-rate", "0"], "--gcs-rate and --sweep-duration must be positive"),
        (["--duration", "1", "--sweep", "500,nan"], "--sweep: rates must be positive, got '500,nan'"),
    ],
)
def test_soak_refuses_bad_numbers(
    argv: list[str], says: str, tmp_path: Any, monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture[str]
) -> None:
    """``--duration nan`` started the sensor simulator, which died on it (a traceback, exit 3)."""
    from ins_hil.soak import suite

    calls: list[str] = []
    monkeypatch.setattr(suite, "campaign", _started(calls, "campaign"))
    rc = main(["soak", *argv, "--no-rt", "--out", str(tmp_path / "soak")])
    err = [x for x in capsys.readouterr().err.splitlines() if x.strip()]
    assert rc == 2 and calls == [] and len(err) == 1 and err[0].startswith("ins-hil soak: ") and says in err[0], err


@pytest.mark.parametrize(
    "argv, says",
    [
        (["--rate", "nan"], "--rate, --trials and --nominal-hours must be positive"),
        (["--trials", "0"], "--rate, --trials and --nominal-hours must be positive"),
        (["--nominal-hours", "inf"], "--rate, --trials and --nominal-hours must be positive"),
        (["--p-fa", "2"], "--p-fa 2: a false-alarm probability per hour in [1e-12, 1)"),
        (["--configs", "nope"], "unknown configuration 'nope' in --configs"),
        (["--configs", ","], "--configs ',': name at least one of"),
        (["--aiding-trials", "0"], "--aiding-trials must be ≥ 1"),
    ],
)
def test_bench_fdi_refuses_bad_numbers_before_the_first_trial(
    argv: list[str], says: str, tmp_path: Any, monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture[str]
) -> None:
    """``--rate nan`` and ``--p-fa 2`` failed after the book reproductions and the first trials had run."""
    from ins_hil.bench import fdi

    calls: list[str] = []
    monkeypatch.setattr(fdi, "book_section", _started(calls, "book_section"))
    monkeypatch.setattr(fdi, "bench_aiding", _started(calls, "bench_aiding"))
    rc = main(["bench-fdi", *argv, "--out", str(tmp_path / "fdi.md")])
    err = [x for x in capsys.readouterr().err.splitlines() if x.strip()]
    assert rc == 2 and calls == [] and len(err) == 1 and err[0].startswith(f"ins-hil bench-fdi: {says}"), err


def test_bench_drivers_refuses_few_samples_with_status_2(tmp_path: Any, capsys: pytest.CaptureFixture[str]) -> None:
    rc = main(["bench-drivers", "--samples", "10", "--out", str(tmp_path / "d.md")])
    assert rc == 2 and capsys.readouterr().err.strip() == "ins-hil bench-drivers: --samples must be ≥ 100"
