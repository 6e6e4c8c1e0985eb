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
def _same_row(a: str, b: str) -> bool:
    """Two table rows alike: text cells equal, number cells equal to their printed digits or both round-off
    (|x| <= 1e-12: a difference of two equal formulas, whose last bits vary with the host's BLAS and CPU)."""
    ca, cb = a.split(" | "), b.split(" | ")
    if len(ca) != len(cb):
        return False
    for x, y in zip(ca, cb, strict=True):
        if x == y:
            continue
        try:
            fx, fy = float(x), float(y)
        except ValueError:
            return False
        if not (abs(fx) <= 1e-12 and abs(fy) <= 1e-12):
            return False
    return True


def test_same_row_tells_a_moved_value_from_round_off() -> None:
    row = "| 001-K | μ ← δr | — | {} | 0 | {} | ±1e-09 | pass | J |"
    assert _same_row(row.format("0", "0"), row.format("3.724e-16", "3.724e-16"))
    assert not _same_row(row.format("0", "0"), row.format("2.1e-06", "2.1e-06"))
    assert not _same_row(row.format("1.5", "x"), row.format("1.5", "y"))


def test_committed_report_is_current(tmp_path: Path) -> None:
    out = tmp_path / "r.md"
    assert main(["reproduce", "--output", str(out), "--quiet", "--no-plots"]) == 0
    committed = _table_lines((ROOT / "docs" / "reproduction.md").read_text(encoding="utf-8"))
    fresh = _table_lines(out.read_text(encoding="utf-8"))
    assert len(committed) == len(fresh), "run `ins-hil reproduce`"
    moved = [(c, f) for c, f in zip(committed, fresh, strict=True) if not _same_row(c, f)]
    assert not moved, f"run `ins-hil reproduce`: {len(moved)} rows differ, the first: {moved[0]}"


def test_unwritable_output_is_reported(tmp_path: Path, capsys) -> None:
    blocker = tmp_path / "file"
    blocker.write_text("x")
    assert main(["reproduce", "--output", str(blocker / "r.md"), "--quiet", "--no-plots"]) == 2
    assert "cannot write" in capsys.readouterr().err
