"""Options that conflict with the chosen mode are one line, exit status 2, before any work (not ignored)."""

from __future__ import annotations

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
