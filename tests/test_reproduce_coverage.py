"""The coverage table: every digest case is listed, each row selector matches, every row belongs to a case."""

from __future__ import annotations

import pytest

from ins_hil.reproduce import all_rows
from ins_hil.reproduce import coverage as cv

CASES = cv.SEED_CASES + cv.BOOK_CASES


@pytest.fixture(scope="module")
def rows():
    return all_rows()


@pytest.mark.slow
def test_every_selector_matches_and_every_row_has_a_case(rows) -> None:
    for c in CASES:
        if c.group is None:
            assert c.why, c.id  # not a row: the reason is given
        else:
            assert c.rows(rows), f"{c.id}: no rows matched"
    used = {id(r) for c in CASES for r in c.rows(rows)}
    orphans = [(r.group, r.case) for r in rows if id(r) not in used]
    assert not orphans, orphans


@pytest.mark.slow
def test_markdown_lists_all_digest_cases_with_counts(rows) -> None:
    text = cv.markdown(rows)
    ids_seed = [c.id for c in cv.SEED_CASES]
    assert ids_seed[0] == "001-A" and ids_seed[-1] == "004-D" and len(ids_seed) == 35  # + 001-M, 003-E…G
    for c in CASES:
        assert f"| {c.id} | {c.what} |" in text
    n = cv.counts(rows)
    assert n["cases"] == len(CASES) == n["all pass"] + n["with discrepancies"] + n["not rows"]
    assert f"{n['cases']} entries of the digests' case lists: {n['all pass']} reproduced" in text
    assert "FAIL" not in text and "no rows matched" not in text


@pytest.mark.slow
def test_readme_states_the_counts(rows) -> None:
    from pathlib import Path

    readme = (Path(__file__).resolve().parents[1] / "README.md").read_text(encoding="utf-8")
    line = next(ln for ln in readme.splitlines() if ln.startswith("| `ins-hil reproduce` |"))
    n = cv.counts(rows)
    covered = n["all pass"] + n["with discrepancies"]
    assert f"recomputes {len(rows)} rows covering {covered} of the {n['cases']} entries" in line
    assert f"{n['all pass']} with every row passing, {n['with discrepancies']} with discrepancies" in line
    assert f"{n['not rows']} not rows" in line


def test_status_text() -> None:
    from ins_hil.reproduce import Row

    c = cv.Case("x", "demo", "^g$")
    rs = [Row("g", "a", 1.0, 1.0), Row("g", "b", 1.0, 2.0, discrepancy="why", expect=2.0), Row("h", "c", 1.0, 1.0)]
    assert cv.status(c, rs) == "1 pass, 1 discrepancy"
    assert cv.status(cv.Case("y", "none", why="no data"), rs) == "not a row"
    assert cv.status(cv.Case("z", "bad", "^g$"), [Row("g", "a", 1.0, 3.0)]) == "0 pass, **1 FAIL**"
