"""``ins-hil replay`` refuses arguments out of range, and options its mode would ignore silently, in one line
naming the flag, before anything is loaded or run (``_argument_error``)."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import pytest

from ins_hil.cli import main

ROOT = Path(__file__).resolve().parents[1]
CFG = str(ROOT / "configs" / "datasets" / "px4_hover.toml")


@pytest.mark.parametrize(
    "argv, says",
    [
        (["--batch", CFG, "--seeds", "0"], "--seeds 0: must be ≥ 1"),
        (["--batch", CFG, "--seeds", "-3"], "--seeds -3: must be ≥ 1"),
        (["--batch", CFG, "--workers", "-1"], "--workers -1: must be ≥ 0"),
        (["--batch", CFG, "--workers", "100000"], "--workers 100000: at most "),
        (["LOG", "--batch", CFG], "a SOURCE (LOG) and --batch: give every log to --batch"),
        (["--batch", CFG, "--export", "TMP/t.csv"], "--export: one log's trajectory, not with --batch"),
        (["static", "--export", "TMP/t.csv"], "--export: the trajectory of a flight log / dataset replay or of a"),
        (["--export", "TMP/t.csv"], "--export: the trajectory of a flight log / dataset replay or of a *.ihlog only"),
        (["--batch", CFG, "--estimate-offset"], "--estimate-offset: not with --batch / --variants / --shifts"),
        (["LOG", "--shifts", "5", "--estimate-mounting"], "--estimate-mounting: not with --batch"),
        (["LOG", "--dataset", CFG, "--seeds", "4"], "--seeds: only with --batch"),
        (["LOG", "--dataset", CFG, "--workers", "0"], "--workers: only with --batch"),
        (["LOG", "--dataset", CFG, "--compare-serial"], "--compare-serial: only with --batch"),
        (["LOG", "--dataset", CFG, "--shifts", "nan"], "--shifts nan: must be finite"),
        (["static", "--duration", "-5"], "--duration -5: must be > 0 and at most 3600 s"),
        (["static", "--duration", "0"], "--duration 0: must be > 0"),
        (["static", "--duration", "nan"], "--duration nan: must be > 0"),
        (["static", "--duration", "1e9"], "--duration 1e+09: must be > 0 and at most 3600 s"),
        (["sim", "--duration", "-1"], "--duration -1: must be > 0"),
        (["static", "--runs", "-3"], "--runs -3: must be ≥ 0"),
        (["LOG", "--dataset", CFG, "--duration", "4"], "--duration: only for a simulated scenario or 'sim'"),
        (["LOG", "--dataset", CFG, "--runs", "4"], "--runs: only for a simulated scenario or 'sim'"),
        (["LOG", "--dataset", CFG, "--write-offset"], "--write-offset: only with --estimate-offset"),
        (["LOG", "--dataset", CFG, "--write-mounting"], "--write-mounting: only with --estimate-mounting"),
        (["LOG", "--estimate-offset", "--offset-step", "0"], "--offset-step 0: need a step > 0"),
        (["LOG", "--estimate-mounting", "--mounting-step", "nan"], "--mounting-step nan: need a step > 0"),
        (["LOG", "--estimate-offset", "--offset-span", "0.01"], "--offset-span 0.01 --offset-step 0.02"),
        (["LOG", "--dataset", "TMP"], "--dataset TMP: a folder; give a dataset config"),
        (["LOG", "--dataset", CFG, "--config", CFG], "--config: only for 'sim'"),
        (["sim", "--config", "TMP/none.toml"], "--config TMP/none.toml: no such file"),
        (["sim", "--config", "TMP"], "--config TMP: a folder"),
        (["sim", "--config", "TMP/bad.toml"], "--config TMP/bad.toml: not a readable TOML file (Invalid value"),
    ],
    ids=lambda v: " ".join(v) if isinstance(v, list) else None,
)
def test_a_bad_replay_argument_is_one_line_before_any_work(
    argv: list[str], says: str, tmp_path: Path, monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture[str]
) -> None:
    from ins_hil.commands import replay
    from ins_hil.datasets import offset, report
    from ins_hil.evaluation import batch

    calls: list[str] = []

    def work(name: str) -> Any:
        def started(*a: Any, **k: Any) -> Any:
            calls.append(name)
            raise AssertionError(f"the work started: {name}")

        return started

    started = ((report, "replay_to_dir"), (report, "load"), (batch, "run_batch"), (replay, "run_scenario"),
               (replay, "replay_drive"), (replay, "_runtime_replay"), (offset, "estimate_imu_offset"))  # fmt: skip
    for mod, name in started:
        monkeypatch.setattr(mod, name, work(name))
    log = tmp_path / "log.ulg"
    log.write_bytes(b"")
    (tmp_path / "bad.toml").write_text("x = [1,\n")
    sub = {"LOG": str(log), "TMP": str(tmp_path)}
    args = [next((a.replace(k, v, 1) for k, v in sub.items() if a.startswith(k)), a) for a in argv]
    rc = main(["replay", *args, "--no-plots", "--quiet", "--out", str(tmp_path / "out")])
    err = capsys.readouterr().err
    lines = [x for x in err.splitlines() if x.strip()]
    assert rc == 2 and calls == [] and len(lines) == 1, err
    want = says.replace("LOG", str(log)).replace("TMP", str(tmp_path))
    assert lines[0].startswith("ins-hil replay: ") and want in lines[0], lines[0]
    assert not (tmp_path / "out").exists()


def test_a_batch_with_a_missing_log_is_refused_before_any_replay(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture[str]
) -> None:
    """A log that does not exist (a typo in a config's dataset.path) failed its jobs one by one in the batch."""
    from ins_hil.evaluation import batch

    text = Path(CFG).read_text()
    bad = tmp_path / "typo.toml"
    bad.write_text(text.replace("hover.ulg", "hovr.ulg"))
    calls: list[str] = []
    monkeypatch.setattr(batch, "run_job", lambda job: calls.append(job.name) or {"job": job.name})
    rc = main(["replay", "--batch", CFG, str(bad), "--seeds", "2", "--workers", "0", "--quiet", "--no-plots",
               "--out", str(tmp_path / "out")])  # fmt: skip
    err = [x for x in capsys.readouterr().err.splitlines() if x.strip()]
    assert rc == 2 and calls == [] and len(err) == 1, err
    assert err[0].startswith("ins-hil replay: batch: ") and "hovr.ulg: no such file or folder" in err[0], err
    assert f"(dataset.path of {bad})" in err[0]


def test_a_bad_scheduler_address_is_one_line_naming_it(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    rc = main(["replay", "--batch", CFG, "--scheduler", "foo", "--quiet", "--no-plots", "--out", str(tmp_path / "o")])
    err = [x for x in capsys.readouterr().err.splitlines() if x.strip()]
    assert rc == 2 and err == ["ins-hil replay: --scheduler foo: cannot connect (missing port number in address 'foo')"]


def test_dataset_with_a_batch_of_dataset_configs_only_is_refused(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture[str]
) -> None:
    """--dataset was ignored silently when every --batch entry is a dataset config (each with its own settings)."""
    from ins_hil.evaluation import batch

    monkeypatch.setattr(batch, "run_batch", lambda *a, **k: pytest.fail("the batch started"))
    rc = main(["replay", "--batch", CFG, "--dataset", CFG, "--quiet", "--out", str(tmp_path / "o")])
    err = capsys.readouterr().err.strip()
    assert rc == 2 and err.startswith(f"ins-hil replay: --dataset {CFG}: every --batch entry is a dataset config")
