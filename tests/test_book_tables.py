"""Book ch. 3–5 printed values as reproduction rows (ins_hil.reproduce.book_tables)."""

from __future__ import annotations

from ins_hil.reproduce import book_tables


def test_all_rows_pass_and_the_table_4_2_typo_is_marked() -> None:
    rows = book_tables.rows()
    assert len(rows) >= 35
    bad = [r.case for r in rows if r.status != "pass" and not r.group.startswith("§4.2.1 accelerometer")]
    assert not bad, bad
    typo = [r for r in rows if r.typo]
    assert len(typo) == 2 and all("(2,1)" in r.case for r in typo)
    assert abs(next(r for r in typo if r.published == 0.0010).ours - 0.0010) > 5e-4  # printed value not reproduced


def test_furthest_entry_catches_one_wrong_value() -> None:
    import numpy as np

    v = np.array([0.1382, 0.1382, 0.1390])
    assert book_tables._furthest(v, 0.1382) == 0.1390


def test_accelerometer_decomposition_recomputed_from_the_printed_a() -> None:
    """Case 20: eq. 4.19 on the printed A (own numpy here) gives sym (1,1) 0.9917, (1,2) −0.0159 and skew (1,2)
    −0.0672, not the printed 0.9850, 0.0249, −0.1032: the rows are discrepancies held at these values."""
    import numpy as np

    A = np.array([[0.9917, -0.0830, -0.0229], [0.0513, 0.9922, 0.0085], [0.0194, -0.0239, 1.0026]])
    sym = np.eye(3) + 0.5 * ((A - np.eye(3)) + (A - np.eye(3)).T)
    skew = np.eye(3) + 0.5 * ((A - np.eye(3)) - (A - np.eye(3)).T)
    rows = {r.case: r for r in book_tables.rows() if r.group.startswith("§4.2.1 accelerometer")}
    for case, ours, printed in (
        ("I + sym(A − I), element (1,1)", sym[0, 0], 0.9850),
        ("I + sym(A − I), element (1,2)", sym[0, 1], 0.0249),
        ("I + skew(A − I), element (1,2)", skew[0, 1], -0.1032),
    ):
        r = rows[case]
        assert r.published == printed and r.status == "discrepancy"
        assert abs(r.ours - ours) < 1e-12 and abs(ours - printed) > 0.005
    assert sym[0, 0] == 0.9917 and abs(sym[0, 1] + 0.01585) < 1e-12 and abs(skew[0, 1] + 0.06715) < 1e-12
    # eq. 4.20 holds for ours to within ε², not for the printed factors
    S = np.array([[0.9850, 0.0249, -0.0033], [0.0249, 0.9905, -0.0083], [-0.0033, -0.0083, 1.0038]])
    K = np.array([[1.0, -0.1032, -0.0161], [0.1032, 1.0, 0.0140], [0.0161, -0.0140, 1.0]])
    assert np.max(np.abs(sym @ skew - A)) < 0.002 < 0.07 < np.max(np.abs(S @ K - A))


def test_table_5_2_runs_the_projects_isolation() -> None:
    """Case 25: the Monte-Carlo rate comes from fdi.recursive.cyclic_isolation; a broken decision rule drops it."""
    import numpy as np
    import pytest

    from ins_hil.fdi import recursive

    rates = book_tables.table_5_2_isolation_rate(draws=100)
    assert np.all(rates > 0.85)
    with pytest.MonkeyPatch.context() as mp:
        mp.setattr(book_tables, "cyclic_isolation", lambda y, A, s: recursive.CyclicResult(np.zeros(5), 0))
        assert book_tables.table_5_2_isolation_rate(draws=20)[1:].max() == 0.0
