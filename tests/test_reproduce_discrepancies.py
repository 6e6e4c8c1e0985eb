"""Reproduction rows that need a changed parameter or an unstated unit are reported as discrepancies, not passes."""

from __future__ import annotations

import math
from dataclasses import replace

import pytest

from ins_hil.commands.reproduce import render
from ins_hil.reproduce import Row, book_ch5, coverage
from ins_hil.reproduce.gyrofree import EX26_LAMBDA_PRINTED, EX26_LAMBDA_READ, ex25_run


def test_discrepancy_row_is_never_a_pass() -> None:
    ok = Row("g", "c", 1.0, 1.0, 0.1)
    disc = Row("g", "c", 1.0, 1.0, 0.1, discrepancy="parameter changed", expect=1.0)
    bad = Row("g", "c", 1.0, 2.0, 0.1)
    assert (ok.status, disc.status, bad.status) == ("pass", "discrepancy", "fail")
    text = render([("s", [ok, disc, bad])], 0.0)
    assert "**1 of 3 rows pass, 1 are reported as discrepancies (with the reason), 1 fail.**" in text
    assert "**discrepancy** (ours held at 1 ± 0 %) — parameter changed" in text


def test_ex26_printed_lambda_misses_the_books_outcome_and_lambda_7_reaches_it() -> None:
    """Ex 2.6: λ = 700 as printed leaves ≈ 38 °/s and a ≈ 176° attitude error; λ = 7 (Ex 2.7's value) gives the
    book's 'same order as Ex 2.5, smaller attitude error'."""
    r9 = ex25_run(9, 1e-3, 0.1)
    printed = ex25_run(12, 1e-1, EX26_LAMBDA_PRINTED)
    read = ex25_run(12, 1e-1, EX26_LAMBDA_READ)
    assert printed.dom_final == pytest.approx(37.6, abs=1.0)
    assert printed.att_err_final > 170.0
    assert printed.dom_final / r9.dom_final > 3.0
    assert read.dom_final / r9.dom_final < 3.0
    assert read.att_err_final < r9.att_err_final


def test_ex53_isolates_only_in_the_rad_per_s_reading() -> None:
    assert book_ch5.isolated_fraction(0.1) == 1.0
    assert book_ch5.isolated_fraction(math.radians(0.1)) == 0.0
    rows = book_ch5.rows()
    assert all(r.status == "discrepancy" for r in rows)


def test_coverage_names_every_seed_004_case() -> None:
    cases = {c.id for c in coverage.SEED_CASES}
    assert {"004-A", "004-B", "004-C", "004-D", "001-C", "001-H", "001-J", "001-K"} <= cases
    assert all(c.group for c in coverage.SEED_CASES if c.id.startswith("004"))  # all four are rows
    assert "| 004-D |" in coverage.markdown([])


def test_seed002_phase_dependence_rows() -> None:
    """002-J: drifts ∝ sin ε, anti-phase, largest at ±90°."""
    from ins_hil.reproduce.seed002 import phase_dependence, phase_rows

    d = phase_dependence("revers1h")
    assert abs(d[0]) < 1e-12 and abs(d[180]) < 1e-12
    assert d[90] == pytest.approx(-d[-90], rel=1e-9)
    assert all(r.status == "pass" for r in phase_rows())


def test_seed002_norm_growth() -> None:
    """002-K: Revers1h's step quaternion grows by h²(|ω0|² + |ω1|²)/16, RK21's only by h²|ω1 − ω0|²/16 + O(h⁴)."""
    from ins_hil.reproduce.seed002 import norm_growth, norm_rows

    d, law = norm_growth("revers1h", 1e-3)
    assert d == pytest.approx(law, rel=1e-5)
    d2, law2 = norm_growth("rk21", 1e-3)
    assert d2 == pytest.approx(law2, rel=1e-8)
    assert d2 < 0.5 * d
    assert all(r.status == "pass" for r in norm_rows())


def test_seed003_guards() -> None:
    """003-A…D: the printed DCM is not orthogonal, i∘j = +k, J2 (not 1.09e-10) gives γ_a/γ_b, Table 1.1 corrected."""
    from ins_hil.reproduce import seed003

    P = seed003.dcm_printed(0.3, 0.2, 0.1)
    assert abs((P @ P.T)[0, 1]) > 0.4
    eq, pole = seed003.j2_gravity(seed003.J2)
    assert eq == pytest.approx(9.78028, abs=2e-4) and pole == pytest.approx(9.83207, abs=2e-4)
    assert all(r.status == "pass" for r in seed003.rows())


def test_a_discrepancy_row_must_document_its_value_and_fails_when_it_moves() -> None:
    """A discrepancy is held at ``expect`` ± ``expect_tol``: no documented value, or a value that moved, is a FAIL."""
    held = Row("g", "c", 1.0, 2.0, 0.1, discrepancy="reason", expect=2.0, expect_tol=0.05)
    moved = replace(held, ours=2.2)
    undocumented = Row("g", "c", 1.0, 2.0, 0.1, discrepancy="reason")
    zero = Row("g", "c", 1.0, 0.004, 0.1, discrepancy="reason", expect=0.0, expect_tol=0.01)
    assert (held.status, moved.status, undocumented.status, zero.status) == (
        "discrepancy",
        "fail",
        "fail",
        "discrepancy",
    )
    assert replace(held, ours=math.nan).status == "fail"
    text = render([("s", [held, moved])], 0.0)
    assert "**discrepancy** (ours held at 2 ± 5 %) — reason" in text
    assert "**FAIL** (discrepancy moved: ours should be 2 ± 5 %)" in text
    assert "**1 of 2 rows pass" not in text and "1 fail.**" in text


def test_every_fast_discrepancy_row_documents_its_value() -> None:
    """Recomputed here rather than from Row.status: each discrepancy row has a value and a band ≤ 15 % and holds."""
    from ins_hil.reproduce import book_ch2, book_ch3, book_tables, gyrofree, seed002

    rows = [r for mod in (book_ch2, book_ch3, book_ch5, book_tables, gyrofree, seed002) for r in mod.rows()]
    disc = [r for r in rows if r.discrepancy]
    assert len(disc) >= 25
    for r in disc:
        assert r.expect is not None and 0 <= r.expect_tol <= 0.15, r.case
        band = r.expect_tol * abs(r.expect) if r.expect else r.expect_tol
        assert abs(r.ours - r.expect) <= band, (r.group, r.case, r.ours, r.expect)


def test_ex26_reason_does_not_misquote_ex27() -> None:
    """Ex 2.7 sets μ = 7 in eq. 2.54 (λ = γ/μ), not λ = 7: the reason says so."""
    from ins_hil.reproduce import gyrofree

    rs = [r for r in gyrofree.rows() if r.case.startswith("Ex 2.6 with λ = 7")]
    assert len(rs) == 2
    assert all("Ex 2.7 sets μ = 7" in r.discrepancy and "the value Ex 2.7 quotes" not in r.discrepancy for r in rs)


def test_ex27_twelve_accelerometers_on_ex24() -> None:
    """Ex 2.7: on Ex 2.4's circle the 12-accelerometer correction (λ = 7) lowers the 15-s attitude error of the
    6-accelerometer Ex 2.4 and its ω error; the literal μ = 7 (λ = γ/μ ≈ 6e-4) diverges; ode45 ≡ the discrete scheme."""
    from ins_hil.reproduce import gyrofree as gf

    e24, e27 = gf.ex24_run(6), gf.ex24_run(12, 7.0)
    assert e27.att_err < 0.8 * e24.att_err and e27.w_err < 0.5 * e24.w_err
    assert gf.ex24_run(12, gf.ex27_gamma() / 7.0).att_err > 45.0
    assert abs(gf.ex24_run_ode45(sigma=0.0).att_err - gf.ex24_run(6, sigma=0.0).att_err) < 1e-3
    assert gf.ex27_gamma() == pytest.approx(2**0.5 * 1e-3 / (3**0.5 * 0.2))
