"""`ins-hil reproduce` writes the reproduction report (values are asserted in the per-topic tests;
here: the report is generated, complete, all rows pass, and the committed docs/reproduction.md is current)."""

from __future__ import annotations

import re
from pathlib import Path

import pytest

from ins_hil.cli import main
from ins_hil.reproduce import all_rows

ROOT = Path(__file__).resolve().parents[1]


def _table_lines(text: str) -> list[str]:
    return [ln for ln in text.splitlines() if ln.startswith("| ") and not ln.startswith("| group")]


@pytest.mark.slow
def test_reproduce_command_writes_the_report(tmp_path: Path, capsys) -> None:
    out = tmp_path / "sub" / "reproduction.md"
    assert main(["reproduce", "--output", str(out), "--quiet"]) == 0
    for png in ("reproduction_coning.png", "reproduction_schuler.png", "reproduction_seed004.png"):
        assert (out.parent / png).read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
        assert f"![{png}]({png})" in out.read_text(encoding="utf-8")
    assert "discrepancies; report written to" in capsys.readouterr().out
    text = out.read_text(encoding="utf-8")
    rows = all_rows()
    lines = _table_lines(text.split("\n## Seed 004: simulated test bed")[0])
    assert len(lines) == len(rows)
    disc = [r for r in rows if r.discrepancy]
    assert all(ln.split(" | ")[7] == "pass" or ln.split(" | ")[7].startswith("**discrepancy**") for ln in lines)
    assert sum(ln.split(" | ")[7].startswith("**discrepancy**") for ln in lines) == len(disc) >= 9
    n_pass = len(rows) - len(disc)
    assert f"**{n_pass} of {len(rows)} rows pass, {len(disc)} are reported as discrepancies" in text
    assert "## Digest cases: covered and not covered" in text
    n_typo = sum(r.typo for r in rows)
    assert n_typo >= 6 and text.count("**typo**") == n_typo + 1  # + the legend
    # every published value sits beside ours (the book's Table 2.1 typo 25.7 and its corrected 25.27)
    assert re.search(r"\| n=6, δλ¹ \(q=0\) \| 25\.7 \| 25\.2686 \| 25\.27 \|", text)


@pytest.mark.slow
def test_committed_report_is_current(tmp_path: Path) -> None:
    out = tmp_path / "r.md"
    assert main(["reproduce", "--output", str(out), "--quiet", "--no-plots"]) == 0
    committed = (ROOT / "docs" / "reproduction.md").read_text(encoding="utf-8")
    assert _table_lines(committed) == _table_lines(out.read_text(encoding="utf-8")), "run `ins-hil reproduce`"


def test_unwritable_output_is_reported(tmp_path: Path, capsys) -> None:
    blocker = tmp_path / "file"
    blocker.write_text("x")
    assert main(["reproduce", "--output", str(blocker / "r.md"), "--quiet", "--no-plots"]) == 2
    assert "cannot write" in capsys.readouterr().err
