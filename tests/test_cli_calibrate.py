"""``ins-hil calibrate``: a bad argument, a missing log or a broken file to update is one line naming it, before
the log is read (a long log takes a while); exit status 2 for arguments, 1 for what the data says."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import pytest

from ins_hil.cli import main


@pytest.mark.parametrize(
    "argv, says, status",
    [
        (["gyro", "TMP/none.csv"], "TMP/none.csv: no such file", 2),
        (["gyro", "TMP"], "TMP: a folder, not a log file", 2),
        (["gyro", "TMP/log.ulg"], "TMP/log.ulg: unknown log type '.ulg'; known: .csv, .ihlog", 2),
        (["gyro"], "the log file argument is missing", 2),
        (["gyro", "TMP/log.csv", "--rates", "abc"], "--rates abc: expected comma-separated numbers", 2),
        (["gyro", "TMP/log.csv", "--rates", "nan,5"], "--rates nan,5: table rates must be positive numbers", 2),
        (["gyro", "TMP/log.csv", "--lat", "100"], "--lat 100: must be within ±90°", 2),
        (["accel", "TMP/log.csv", "--height", "nan"], "--height nan: must be a finite number", 2),
        (["gyro", "TMP/log.csv", "--plan", "TMP/none.csv"], "--plan TMP/none.csv: cannot read", 1),
        (["gyro", "TMP/log.csv", "-o", "TMP/bad.toml"], "TMP/bad.toml: not valid TOML", 1),
        (["gyro", "TMP/log.csv", "--simulate"], "TMP/log.csv: exists; --simulate writes a new simulated log", 2),
        (["gyro", "TMP/log.csv", "--force"], "--force: only with --simulate", 2),
    ],
)
def test_calibrate_refuses_before_reading_the_log(
    argv: list[str], says: str, status: int, tmp_path: Path, monkeypatch: pytest.MonkeyPatch,
    capsys: pytest.CaptureFixture[str],
) -> None:  # fmt: skip
    from ins_hil.commands import calibrate

    calls: list[str] = []

    def read_log(*a: Any, **k: Any) -> Any:
        calls.append("read_log")
        raise AssertionError("the log was read")

    monkeypatch.setattr(calibrate, "read_log", read_log)
    for name, text in (("log.csv", "t,dt\n"), ("log.ulg", ""), ("bad.toml", "x = [1,\n")):
        (tmp_path / name).write_text(text)
    args = [a.replace("TMP", str(tmp_path)) for a in argv]
    if "-o" not in args and len(args) > 1:
        args += ["-o", str(tmp_path / "c.toml")]
    rc = main(["calibrate", *args])
    err = [x for x in capsys.readouterr().err.splitlines() if x.strip()]
    assert rc == status and calls == [] and len(err) == 1, err
    assert err[0].startswith(f"ins-hil calibrate {argv[0]}: {says.replace('TMP', str(tmp_path))}"), err
    assert not (tmp_path / "c.toml").exists() and not (tmp_path / "c_report").exists()


def test_a_failed_fit_leaves_no_empty_report_folder(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture[str]
) -> None:
    """'no calibration written', yet an empty <output>_report folder was left behind."""
    from ins_hil.commands import calibrate
    from ins_hil.nav.calibration import CalibrationError

    def fit(*a: Any, **k: Any) -> Any:
        raise CalibrationError("gyro: fitted scale factor 10 on y is implausible")

    monkeypatch.setattr(calibrate, "read_log", lambda *a, **k: object())
    monkeypatch.setattr(calibrate, "fit_triad_log", fit)
    (tmp_path / "log.csv").write_text("t,dt\n")
    rc = main(["calibrate", "gyro", str(tmp_path / "log.csv"), "-o", str(tmp_path / "c.toml")])
    assert rc == 1 and "(no calibration written)" in capsys.readouterr().err
    assert sorted(p.name for p in tmp_path.iterdir()) == ["log.csv"]


def test_simulate_with_force_overwrites_the_simulated_log(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    """The tutorial run a second time: --simulate refuses the log it wrote the first time, --force writes it anew."""
    log, out = tmp_path / "accel.csv", tmp_path / "imu.toml"
    assert main(["calibrate", "accel", str(log), "--simulate", "-o", str(out)]) == 0
    first = log.read_bytes()
    assert main(["calibrate", "accel", str(log), "--simulate", "-o", str(out)]) == 2
    assert "add --force" in capsys.readouterr().err
    assert main(["calibrate", "accel", str(log), "--simulate", "--force", "--seed", "2", "-o", str(out)]) == 0
    assert log.read_bytes() != first  # written anew (another seed)
