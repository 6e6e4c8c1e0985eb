"""Ctrl-C (SIGINT) in the middle of a command: one line, exit status 130, no traceback; a batch keeps the
replays that finished (their rows in ``batch.md`` / ``batch.json``, their reports in their folders)."""

from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
from pathlib import Path
from typing import Any

import pytest
from test_datasets_replay import GOOD, _static_csv, _toml

from ins_hil.cli import main
from ins_hil.evaluation import batch


def _interrupt_second_job(monkeypatch: pytest.MonkeyPatch) -> list[str]:
    """``batch.run_job`` replaced: the first job gives a row (and writes its folder), the second is Ctrl-C."""
    ran: list[str] = []

    def run_job(job: batch.Job) -> dict[str, Any]:
        ran.append(job.name)
        if len(ran) == 2:
            raise KeyboardInterrupt
        Path(job.out).mkdir(parents=True)
        (Path(job.out) / "metrics.json").write_text("{}")
        return {"job": job.name, "seed": job.seed, "source": job.source, "config": job.config, "replay_s": 1.0,
                "elapsed_s": 1.0}  # fmt: skip

    monkeypatch.setattr(batch, "run_job", run_job)
    return ran


def test_run_batch_interrupted_gives_the_rows_that_finished(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    ran = _interrupt_second_job(monkeypatch)
    js = batch.jobs([("a.csv", None)], 3, tmp_path)
    with pytest.raises(batch.BatchInterrupted) as e:
        batch.run_batch(js, workers=0)
    assert len(ran) == 2 and e.value.total == 3
    assert [r["job"] for r in e.value.rows] == [ran[0]]


def test_ctrl_c_in_a_batch_keeps_the_finished_replays_and_says_so_in_one_line(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture[str]
) -> None:
    ran = _interrupt_second_job(monkeypatch)
    logs = tmp_path / "logs"
    logs.mkdir()
    for n in ("a", "b"):
        (logs / f"{n}.csv").write_text("# ins-hil dataset csv 1\n")
    out = tmp_path / "out"
    rc = main(["replay", "--batch", str(logs / "a.csv"), str(logs / "b.csv"), "--seeds", "2", "--workers", "0",
               "--quiet", "--out", str(out)])  # fmt: skip
    cap = capsys.readouterr()
    assert rc == 130 and len(ran) == 2
    err = [x for x in cap.err.splitlines() if x.strip()]
    assert err == [f"ins-hil replay: interrupted: 1 of 4 replays finished, kept in {out / 'batch.md'}"]
    md = (out / "batch.md").read_text()
    assert "1 of 4 replays finished" in md and f"| {ran[0]} |" in md and ran[0] in cap.out
    summary = json.loads((out / "batch.json").read_text())
    assert summary["interrupted"] is True and summary["jobs"] == 4 and [r["job"] for r in summary["rows"]] == ran[:1]


def test_ctrl_c_before_any_replay_finished_keeps_an_earlier_summary(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture[str]
) -> None:
    def run_job(job: batch.Job) -> dict[str, Any]:
        raise KeyboardInterrupt

    monkeypatch.setattr(batch, "run_job", run_job)
    log = tmp_path / "a.csv"
    log.write_text("# ins-hil dataset csv 1\n")
    out = tmp_path / "out"
    out.mkdir()
    (out / "batch.json").write_text('{"rows": []}')
    rc = main(["replay", "--batch", str(log), "--workers", "0", "--quiet", "--out", str(out)])
    err = [x for x in capsys.readouterr().err.splitlines() if x.strip()]
    assert rc == 130 and len(err) == 1 and "interrupted: 0 of 1 replays finished, no summary written" in err[0]
    assert (out / "batch.json").read_text() == '{"rows": []}' and not (out / "batch.md").exists()


def test_ctrl_c_in_another_command_is_one_line(
    monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture[str]
) -> None:
    from ins_hil.commands import demo

    def interrupted(*a: Any, **k: Any) -> Any:
        raise KeyboardInterrupt

    monkeypatch.setattr(demo, "generate", interrupted)
    assert main(["demo", "--duration", "5"]) == 130
    err = [x for x in capsys.readouterr().err.splitlines() if x.strip()]
    assert err == ["ins-hil demo: interrupted"]


@pytest.mark.slow  # a Dask LocalCluster of 2 worker processes (~30 s with its start-up)
def test_sigint_to_a_batch_on_dask_keeps_what_finished(tmp_path: Path) -> None:
    """A real Ctrl-C (SIGINT to the process group, workers included) once the first replay is reported: exit
    130, one line, no traceback or Dask warning, the finished replays in batch.md."""
    logs = tmp_path / "logs"
    logs.mkdir()
    _static_csv(logs / "a.csv", yaw_deg=30.0, seconds=120.0)
    _static_csv(logs / "b.csv", yaw_deg=-60.0, seconds=120.0)
    cfg = _toml(tmp_path / "static.toml", GOOD)
    out = tmp_path / "out"
    argv = [sys.executable, "-m", "ins_hil", "replay", "--batch", str(logs), "--dataset", str(cfg), "--seeds", "6",
            "--workers", "2", "--no-plots", "--out", str(out)]  # fmt: skip
    # SIGINT at its default in the child, as a terminal's command has it: a test run started in the background of a
    # non-interactive shell (a CI runner's `cmd &`) inherits SIGINT ignored, and Python then leaves it ignored
    p = subprocess.Popen(argv, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, start_new_session=True,
                         preexec_fn=lambda: signal.signal(signal.SIGINT, signal.SIG_DFL))  # fmt: skip
    assert p.stderr is not None
    lines = []
    for line in p.stderr:
        lines.append(line)
        if line.startswith("  [1/"):
            os.killpg(p.pid, signal.SIGINT)
            break
    _, rest = p.communicate(timeout=120)
    err = "".join(lines) + rest
    assert p.returncode == 130, err
    assert "Traceback" not in err and "WARNING" not in err, err
    last = [x for x in err.splitlines() if x.strip()][-1]
    assert last.startswith("ins-hil replay: interrupted: ") and "of 12 replays finished, kept in" in last, err
    done = int(last.split("interrupted: ")[1].split(" of")[0])
    assert 1 <= done < 12
    summary = json.loads((out / "batch.json").read_text())
    assert summary["interrupted"] is True and len(summary["rows"]) == done


def test_the_soak_sensor_process_stops_on_a_second_sigterm_without_a_traceback(
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    """SIGTERM to the soak's process group (``timeout``): the sensor process got it again while waiting for its
    producer in its clean-up, and printed a ``_Stop`` traceback."""
    from ins_hil.soak import simproc

    def run(a: Any) -> None:
        raise simproc._Stop

    monkeypatch.setattr(simproc, "run", run)
    monkeypatch.setattr(simproc, "die_with_parent", lambda: None)
    assert simproc.main(["--gnss-udp", "127.0.0.1:1", "--out", "unused", "--duration", "1"]) == 0


def test_sigterm_is_handled_like_ctrl_c_with_its_own_line_and_status() -> None:
    """SIGTERM (``timeout``, a service manager) killed a command outright: no clean-up, nothing kept. (In a child
    process: a regression must not kill the test run.)"""
    code = (
        "import os, signal, sys\n"
        "from ins_hil.commands import demo\n"
        "from ins_hil.cli import main\n"
        "def terminated(*a, **k):\n"
        "    os.kill(os.getpid(), signal.SIGTERM)\n"
        "    raise AssertionError('SIGTERM did not interrupt')\n"
        "demo.generate = terminated\n"
        "rc = main(['demo', '--duration', '5'])\n"
        "assert signal.getsignal(signal.SIGTERM) == signal.SIG_DFL, 'not restored'\n"
        "sys.exit(rc)\n"
    )
    p = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=120)
    err = [x for x in p.stderr.splitlines() if x.strip()]
    assert p.returncode == 143 and err == ["ins-hil demo: terminated (SIGTERM)"], (p.returncode, p.stderr)


def test_ctrl_c_in_the_serial_run_of_compare_serial_says_which_run_it_kept(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture[str]
) -> None:
    ran = _interrupt_second_job(monkeypatch)  # in this process: the serial reference run, before any cluster
    log = tmp_path / "a.csv"
    log.write_text("# ins-hil dataset csv 1\n")
    out = tmp_path / "out"
    rc = main(["replay", "--batch", str(log), "--seeds", "3", "--workers", "2", "--compare-serial", "--quiet",
               "--out", str(out)])  # fmt: skip
    assert rc == 130 and len(ran) == 2
    assert f"1 of 3 replays finished, kept in {out / 'batch.md'}" in capsys.readouterr().err
    md = (out / "batch.md").read_text()
    assert f"(serially: --compare-serial's reference run, reports in {out / 'serial'}): 1 of 3" in md
