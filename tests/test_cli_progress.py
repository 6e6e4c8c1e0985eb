"""The progress of a long replay in a log (stderr not a terminal): a few whole lines, no carriage returns."""

from __future__ import annotations

import pytest

from ins_hil.commands.replay import _Progress


def test_progress_in_a_log_is_five_lines_without_carriage_returns(capsys: pytest.CaptureFixture[str]) -> None:
    p = _Progress("replay", quiet=False)
    for k in range(1001):
        p(k, 1000)
    p(1000, 1000)  # a last call repeated: not a second 100 % line
    err = capsys.readouterr().err
    assert "\r" not in err
    pcts = [int(line.split("]")[1].split("%")[0]) for line in err.splitlines()]
    assert pcts == [0, 25, 50, 75, 100]


def test_quiet_progress_writes_nothing(capsys: pytest.CaptureFixture[str]) -> None:
    p = _Progress("replay", quiet=True)
    for k in range(11):
        p(k, 10)
    assert capsys.readouterr().err == ""
