"""Options that conflict with the chosen mode are one line, exit status 2, before any work (not ignored)."""

from __future__ import annotations

from pathlib import Path

import pytest

from ins_hil.cli import main


@pytest.mark.parametrize("extra", [["--output", "r.md"], ["--no-plots"]])
def test_reproduce_mutations_refuses_report_options(
    extra: list[str], monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture[str]
) -> None:
    """``--mutations`` writes no report: ``--output`` was ignored silently (a few minutes of mutations later)."""
    from ins_hil.commands import reproduce

    monkeypatch.setattr(reproduce, "_run_mutations", lambda quiet: pytest.fail("the work started"))
    assert main(["reproduce", "--mutations", *extra]) == 2
    err = capsys.readouterr().err.strip()
    assert err == "ins-hil reproduce: --mutations writes no report: no --output / --no-plots"


@pytest.mark.parametrize(
    "argv, line",
    [
        (["replay", "--seeds", "abc"], "ins-hil replay: error: argument --seeds: invalid int value: 'abc'"),
        (["soak", "--rate", "x"], "ins-hil soak: error: argument --rate: invalid float value: 'x'"),
        (["replay", "a", "b"], "ins-hil replay: error: unrecognized arguments: b"),
        (["replay", "--nope"], "ins-hil replay: error: unrecognized arguments: --nope"),
        (["--nope"], "ins-hil: error: unrecognized arguments: --nope"),
        (["nope"], "ins-hil: error: argument COMMAND: invalid choice: 'nope'"),
    ],
)
def test_an_argument_error_is_one_line_naming_the_command(
    argv: list[str], line: str, capsys: pytest.CaptureFixture[str]
) -> None:
    """argparse printed the command's usage first: a dozen lines for replay or soak, the error last."""
    with pytest.raises(SystemExit) as e:
        main(argv)
    err = capsys.readouterr().err.splitlines()
    prog = line.split(": error")[0]
    assert e.value.code == 2 and len(err) == 1 and err[0].startswith(line), err
    assert err[0].endswith(f"(see {prog} --help)")


def test_run_does_not_overwrite_an_earlier_recording(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture[str]
) -> None:
    """``run --record FILE`` truncated FILE: a second run with the same name lost the first recording."""
    from ins_hil import config

    rec = tmp_path / "flight.ihlog"
    rec.write_bytes(b"IHLOG2\nprecious")
    monkeypatch.setattr(config, "load_outputs", lambda *a: pytest.fail("the gateway started"))
    assert main(["run", "--duration", "1", "--no-status", "--record", str(rec)]) == 2
    err = capsys.readouterr().err.strip()
    assert err == f"ins-hil run: --record {rec}: exists (an earlier recording?): give a new name or remove it"
    assert rec.read_bytes() == b"IHLOG2\nprecious"
