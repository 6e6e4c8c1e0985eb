"""Book ch. 3–5 printed values as reproduction rows (ins_hil.reproduce.book_tables)."""

from __future__ import annotations

from ins_hil.reproduce import book_tables


def test_all_rows_pass_and_the_table_4_2_typo_is_marked() -> None:
    rows = book_tables.rows()
    assert len(rows) >= 35
    bad = [r.case for r in rows if r.status != "pass"]
    assert not bad, bad
    typo = [r for r in rows if r.typo]
    assert len(typo) == 2 and all("(2,1)" in r.case for r in typo)
    assert abs(next(r for r in typo if r.published == 0.0010).ours - 0.0010) > 5e-4  # printed value not reproduced


def test_furthest_entry_catches_one_wrong_value() -> None:
    import numpy as np

    v = np.array([0.1382, 0.1382, 0.1390])
    assert book_tables._furthest(v, 0.1382) == 0.1390
