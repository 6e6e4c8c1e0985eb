"""Book ch. 2 rotational/translational mechanization (DIGEST_000 §2.2–2.4, §8 cases 1–11 and 29–30).

The published-value rows (Table 2.1 all 32 entries, Ex 2.1, Table 2.2, q = 0.0939, q* = 0.09375,
Tables 2.3/2.4 formula and simulated rows) come from ``ins_hil.reproduce.book_ch2`` — the same
rows ``ins-hil reproduce`` writes to docs/reproduction.md. Typo rows are checked against the
corrected value the digest gives (DIGEST_000 §10 items 8–13); the row's note says which.
"""

from __future__ import annotations

import math

import numpy as np
import pytest

from ins_hil.nav import attitude as att
from ins_hil.nav.quadrature import SplineTranslational, position_step, velocity_step
from ins_hil.nav.rotation import quat_angle_between, quat_from_rotvec, quat_mul
from ins_hil.reproduce import book_ch2

ROWS = book_ch2.rows()


@pytest.mark.parametrize("row", ROWS, ids=[f"{r.group}: {r.case}" for r in ROWS])
def test_published_value(row) -> None:
    """Recomputed here: a relative tolerance of at most 2 % (the book prints 3 digits), an absolute one of at
    most 1 (the book truncates); a discrepancy row held at its documented value within 2 %."""
    if row.discrepancy:
        assert row.expect is not None and 0 < row.expect_tol <= 0.02
        assert abs(row.ours - row.expect) <= row.expect_tol * abs(row.expect), (row.ours, row.expect)
        return
    if row.check == "le":  # the book's round-off of an exact zero (Table 2.2 |λ2|)
        assert row.ref <= 1e-5 and abs(row.ours) <= 1e-12, (row.ours, row.ref)
        return
    cap = 0.10 if row.case.startswith("δλ³") else 0.02  # δλ³: the book's start-up is undefined (case 4)
    assert (row.check == "rel" and row.tol <= cap) or (row.check == "abs" and row.tol <= 1.0), (
        f"tolerance {row.tolerance_text} wider than the book's precision"
    )
    assert abs(row.ours - row.ref) <= (row.tol * abs(row.ref) if row.check == "rel" else row.tol)


# Table 2.3 / 2.4 simulated values that our exact simulation does not reproduce: ours and the printed value
TABLE_23_24_GAPS = {
    ("Table 2.3 (simulation)", "case I, δλ¹"): (5130, 5252.0),
    ("Table 2.3 (simulation)", "case I, δλ²"): (2626, 2644.9),
    ("Table 2.3 (simulation)", "case II, δλ¹"): (5797, 5766.8),
    ("Table 2.3 (simulation)", "case II, δλ²"): (1938, 1927.8),
    ("Table 2.4 (simulation)", "γ=90°, δλ¹"): (10, 1.620),
    ("Table 2.4 (simulation)", "γ=90°, δλ²"): (2, 7.047),
    ("Table 2.4 (simulation)", "γ=90°, δλ²_m"): (0.8, 1.671),
}


def test_simulated_rows_the_book_misses_are_discrepancies() -> None:
    """No tolerance is widened to the observed gap: these rows are discrepancies held at our value."""
    rows = {(r.group, r.case): r for r in ROWS}
    for key, (printed, ours) in TABLE_23_24_GAPS.items():
        r = rows[key]
        assert r.published == printed and r.discrepancy, key
        assert r.ours == pytest.approx(ours, rel=2e-3), key
    # Table 2.3 II's own γ = 0 twin in Table 2.4 agrees to the printed (truncated) digit
    for col, pub in (("δλ¹", 5766), ("δλ²", 1927)):
        assert 0 <= rows[("Table 2.4 (simulation)", f"γ=0°, {col}")].ours - pub < 1


def test_table_2_1_has_all_32_entries() -> None:
    assert sum(r.group == "Table 2.1" for r in ROWS) == 32


def test_table_2_1_closed_form() -> None:
    """Δ_n = 100·tan((2π − nφ)/2), φ = 2 atan2(χ/2, 1 − qχ²) (DIGEST_000 §2.4) equals the recursion."""
    for n in (5, 9, 12):
        for q in book_ch2.TABLE_2_1_Q:
            chi = 2 * math.pi / n
            phi = 2 * math.atan2(chi / 2, 1 - q * chi * chi)
            assert book_ch2.table_2_1_value(n, q) == pytest.approx(
                100 * math.tan((2 * math.pi - n * phi) / 2), rel=1e-9
            )


def test_spline_quasi_coordinates_exact_for_quadratic_rate() -> None:
    """Eq. 2.19 integrates a quadratic ω(t) exactly (DIGEST_000 §8 case 29)."""
    c0, c1, c2 = np.array([0.3, -1.0, 2.0]), np.array([0.5, 0.2, -0.7]), np.array([-1.1, 0.4, 0.9])
    w = lambda t: c0 + c1 * t + c2 * t * t
    W = lambda t: c0 * t + c1 * t**2 / 2 + c2 * t**3 / 3
    dt, ti = 0.05, 0.7
    th = att.quasi_coordinates_spline(w(ti), w(ti - dt), w(ti - 2 * dt), dt)
    np.testing.assert_allclose(th, W(ti) - W(ti - dt), rtol=0, atol=1e-14)


def test_translational_quadratures_exact_for_quadratic_acceleration() -> None:
    """Eqs. 2.20/2.21 are exact for quadratic ã(t) (DIGEST_000 §8 case 29)."""
    a0, a1, a2 = np.array([0.1, -9.8, 1.0]), np.array([2.0, 0.3, -0.5]), np.array([-0.6, 0.25, 0.8])
    a = lambda t: a0 + a1 * t + a2 * t * t
    v = lambda t: 3.0 + a0 * t + a1 * t**2 / 2 + a2 * t**3 / 3
    r = lambda t: -1.0 + 3.0 * t + a0 * t**2 / 2 + a1 * t**3 / 6 + a2 * t**4 / 12
    dt, ti = 0.1, 1.3
    np.testing.assert_allclose(velocity_step(v(ti - dt), a(ti), a(ti - dt), a(ti - 2 * dt), dt), v(ti), atol=1e-12)
    np.testing.assert_allclose(
        position_step(r(ti - dt), v(ti - dt), a(ti), a(ti - dt), a(ti - 2 * dt), dt), r(ti), atol=1e-12
    )
    # the stepping class is exact for linear ã from the first step (start-up by the trapezoid rule) ...
    b = lambda t: a0 + a1 * t
    vb = lambda t: 3.0 + a0 * t + a1 * t**2 / 2
    rb = lambda t: -1.0 + 3.0 * t + a0 * t**2 / 2 + a1 * t**3 / 6
    s = SplineTranslational(rb(0.0), vb(0.0), b(0.0), dt)
    for k in range(1, 30):
        rr, vv = s.step(b(k * dt))
    np.testing.assert_allclose(vv, vb(29 * dt), atol=1e-12)
    np.testing.assert_allclose(rr, rb(29 * dt), atol=1e-12)
    # ... and for quadratic ã once started on exact values
    s = SplineTranslational(r(0.2), v(0.2), a(0.1), dt)
    s._a.append(a(0.2))
    for k in range(3, 30):
        rr, vv = s.step(a(k * dt))
    np.testing.assert_allclose(vv, v(2.9), atol=1e-11)
    np.testing.assert_allclose(rr, r(2.9), atol=1e-11)
    with pytest.raises(ValueError, match="dt"):
        SplineTranslational(r(0), v(0), a(0), 0.0)


def test_elementary_quaternions_match_their_formulas() -> None:
    rng = np.random.default_rng(3)
    th, tp = rng.normal(size=3) * 0.1, rng.normal(size=3) * 0.1
    s = float(th @ th)
    np.testing.assert_allclose(att.dl1(th), [1, *(th / 2)])
    np.testing.assert_allclose(att.dl2(th), [1 - s / 8, *(th / 2)])
    np.testing.assert_allclose(att.dl2m(th), [1 - s / 12, *(th / 2)])
    np.testing.assert_allclose(att.dl3(th, tp), [1 - s / 8, *(0.5 * (1 - s / 24) * th - np.cross(th, tp) / 24)])
    np.testing.assert_allclose(att.dl3m(th, tp), [1 - s / 12, *(0.5 * th - np.cross(th, tp) / 24)])
    # the registry's one-step path uses the same formulas
    for kind, fn in (("dl1", att.dl1), ("dl2", att.dl2), ("dl2m", att.dl2m)):
        np.testing.assert_allclose(att.make_attitude(kind).delta(th, 0.01), fn(th), atol=1e-16)
    np.testing.assert_allclose(att.make_attitude("dlq", q=0.09).delta(th, 0.01), att.dlq(th, 0.09), atol=1e-16)
    for kind, fn3 in (("dl3", att.dl3), ("dl3m", att.dl3m)):
        a = att.make_attitude(kind)
        a.delta(tp, 0.01)
        np.testing.assert_allclose(a.delta(th, 0.01), fn3(th, tp), atol=1e-16)
    # vectorised over leading dimensions
    ths = rng.normal(size=(5, 3))
    np.testing.assert_allclose(att.dl3m(ths, ths[::-1])[2], att.dl3m(ths[2], ths[2]))


def test_q_star_euler_form_equals_body_rate_form() -> None:
    """Eq. 2.31's two lines agree for any regular precession once the denominator typo is fixed."""
    rng = np.random.default_rng(4)
    for _ in range(20):
        a, c, theta = rng.uniform(0.5, 3), rng.uniform(0.3, 2), rng.uniform(0.3, 1.2)
        psi_d = a / math.sin(theta)
        b = psi_d * math.cos(theta) - c
        assert att.q_star_euler(-c, psi_d, theta) == pytest.approx(att.q_star(a, b, c), rel=1e-12)


def test_drift_formula_zero_at_q_star_and_cos_gamma() -> None:
    u = att.drift_rate(0.1, 0.1, 3.0, 3.2, 10.0)
    assert u == 0.0
    u = att.drift_rate(0.0, 1 / 12, math.pi, math.pi, 10.0)
    assert att.drift_rate_corrected(u, math.radians(60)) == pytest.approx(u / 2)


def _cone_exact(t: float, a: float, b: float, c: float) -> np.ndarray:
    """Closed-form λ(t) for ω = R_z(ct)[a, 0, b]: λ = q((ω̄ + c ẑ)t) ⊗ q(−c ẑ t)."""
    return quat_mul(quat_from_rotvec(t * np.array([a, 0.0, b + c])), quat_from_rotvec(np.array([0.0, 0.0, -c * t])))


@pytest.mark.parametrize("name", sorted(att.attitude_names()))
@pytest.mark.parametrize("form", ["increment", "rate"])
def test_every_registered_algorithm_tracks_a_slow_cone(name: str, form: str) -> None:
    """Every algorithm of the registry, fed either form, follows a coning motion
    ω = [a cos ct, a sin ct, b] (closed-form λ(t)) at 100 Hz for 2 s."""
    a, b, c, dt, n = 0.3, 0.2, 1.0, 0.01, 200
    alg = att.make_attitude(name)
    w = lambda t: np.array([a * math.cos(c * t), a * math.sin(c * t), b])
    q = np.array([1.0, 0, 0, 0])
    if form == "rate":
        alg.prime_rate(w(0.0))
    for k in range(n):
        t0, t1 = k * dt, (k + 1) * dt
        inc = np.array(
            [a / c * (math.sin(c * t1) - math.sin(c * t0)), -a / c * (math.cos(c * t1) - math.cos(c * t0)), b * dt]
        )
        q = alg.step_increment(q, inc, dt) if form == "increment" else alg.step_rate(q, w(t1), dt)
    ref = _cone_exact(n * dt, a, b, c)
    np.testing.assert_allclose(_cone_exact(0.0, a, b, c), [1, 0, 0, 0], atol=1e-15)
    assert quat_angle_between(q, ref) < 1e-4


def test_registry_rejects_unknown_name() -> None:
    with pytest.raises(ValueError, match=r"'nope'.*known: .*dl3m"):
        att.make_attitude("nope")
    assert {"rotvec", "dl1", "dl2", "dl2m", "dl3", "dl3m", "dlq", "revers1h", "rk21", "picard", "exprvrs1h",
            "poisson"} <= set(att.attitude_names())  # fmt: skip


def test_larin_update_with_spline_is_third_order_on_rate_samples() -> None:
    """The book's working combination (2.18)+(2.19) on raw rate samples: Ex 2.3 error falls ≥ 6× per step halving."""
    a, b, c, T = book_ch2.EX23_A, book_ch2.EX23_B, book_ch2.EX23_C, book_ch2.EX23_T
    w = lambda t: np.array([a * math.cos(c * t), a * math.sin(c * t), b])
    errs = []
    for n in (200, 400):
        alg = att.make_attitude("dl3m")
        alg.prime_rate(w(0.0))
        dt = T / n
        q = np.array([1.0, 0, 0, 0])
        for k in range(1, n + 1):
            q = alg.step_rate(q, w(k * dt), dt)
        errs.append(quat_angle_between(q, np.array([1.0, 0, 0, 0])))  # λ(T) = λ(0)
    assert errs[1] < errs[0] / 6
