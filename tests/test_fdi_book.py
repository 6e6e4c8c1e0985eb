"""Book ch. 5 reproductions (DIGEST_000 §5, reference cases 21–25 and 39, typo notes §10 items 37–43)."""

from __future__ import annotations

import math

import numpy as np
import pytest

from ins_hil.fdi.bias import bias_isolation, ls_matrix, run_example_5_3
from ins_hil.fdi.parity import (
    BOOK_CONE_A,
    cone_geometry,
    determinant_isolation,
    determinant_scores,
    lebedev_isolation,
    parity_basis,
    svd_isolation,
    svd_isolation_literal,
)
from ins_hil.fdi.recursive import BOOK_TABLE_5_2, cyclic_decision, cyclic_isolation, recursive_ks

A = BOOK_CONE_A
OMEGA = np.array([1.0, 2.0, 3.0])
U2T_PRINTED = np.array(
    [[-0.0752, -0.4300, -0.6205, 0.5740, 0.3082], [0.6280, 0.4638, 0.1225, 0.2656, 0.5523]]
)  # Ex 5.1
LO, HI = (5 - math.sqrt(5)) / 20, (5 + math.sqrt(5)) / 20  # 0.1382, 0.3618
TABLE_5_1 = np.array(
    [
        [0.0000, 0.1382, 0.3618, 0.3618, 0.1382],
        [0.1382, 0.0000, 0.1382, 0.3618, 0.3618],
        [0.3618, 0.1382, 0.0000, 0.1382, 0.3618],
        [0.3618, 0.3618, 0.1382, 0.0000, 0.1382],
        [0.1382, 0.3618, 0.3618, 0.1382, 0.0000],
    ]
)
TABLE_5_3 = np.array(
    [
        [0.0814, 0.6730, 1.0075, 0.9572, 0.5413],
        [0.4245, 0.1671, 0.6949, 0.9572, 0.8539],
        [0.7371, 0.3388, 0.1890, 0.6446, 0.8539],
        [0.8999, 0.9857, 0.6949, 0.1387, 0.4705],
        [0.5873, 0.9857, 1.0075, 0.6446, 0.0354],
    ]
)


def test_book_geometry_and_parity_basis() -> None:
    # case 21 / §10 item 43: unit rows, isotropic AᵀA = (5/3) I; numpy's SVD gives the printed U2ᵀ, signs included
    assert np.allclose(np.linalg.norm(A, axis=1), 1.0, atol=1e-5)
    assert np.allclose(A.T @ A, 5 / 3 * np.eye(3), atol=1e-5)
    U2 = parity_basis(A)
    assert U2.shape == (5, 2)  # m×n parity matrix V = U2ᵀ, A is n×(n−m) (the printed n×m is a typo, item 37)
    assert np.allclose(U2.T, U2T_PRINTED, atol=1e-4)
    assert np.allclose(U2.T @ A, 0.0, atol=1e-12)
    Q2 = parity_basis(A, "qr")
    assert np.allclose(Q2.T @ A, 0.0, atol=1e-12)
    assert np.allclose(Q2 @ Q2.T, U2 @ U2.T, atol=1e-12)  # same projector G (eq. 5.14)
    G = U2 @ U2.T
    assert np.allclose(np.diag(G), 0.4, atol=1e-4)
    # a generated cone with the magic angle is isotropic too
    C = cone_geometry(5)
    assert np.allclose(C.T @ C, 5 / 3 * np.eye(3), atol=1e-9)


@pytest.mark.parametrize("method", ["svd", "qr"])
def test_table_5_1_exact(method: str) -> None:
    """Table 5.1 with the corrected eq. 5.17 (§10 item 38); rows = failed sensor, columns = candidate."""
    U2 = parity_basis(A, method)
    J = np.array([svd_isolation(A @ OMEGA + np.eye(5)[i], U2).scores for i in range(5)])
    assert np.allclose(J, TABLE_5_1, atol=1e-4)
    off = J[~np.eye(5, dtype=bool)]
    assert np.all(np.minimum(np.abs(off - LO), np.abs(off - HI)) < 2e-5)  # (5 ∓ √5)/20 exactly
    for i in range(5):
        y = A @ OMEGA + np.eye(5)[i]
        assert np.allclose(svd_isolation_literal(y, U2), J[i], atol=1e-12)
        lb = lebedev_isolation(y, U2)
        assert np.allclose(lb.scores, J[i], atol=1e-12)
        iso = svd_isolation(y, U2)
        assert iso.index == i and iso.size == pytest.approx(1.0, abs=1e-12)  # ρ_k of eq. 5.16 (fixed)


def test_table_5_3_from_recovered_noise() -> None:
    """Table 5.3 (case 24) from the digest's recovered noise w, tolerance 3e-4; minimum on the diagonal."""
    w = np.array([0.0801, 0.0425, -0.0112, 0.0607, 0.0870])
    d = np.array([determinant_scores(A @ OMEGA + np.eye(5)[i] + w, A) for i in range(5)])
    assert np.abs(d - TABLE_5_3).max() <= 3e-4
    assert [determinant_isolation(A @ OMEGA + np.eye(5)[i] + w, A).index for i in range(5)] == list(range(5))
    # noise-free structure: |c_ij| = 0.5059 adjacent, 0.8185 otherwise (golden ratio), 0 on the diagonal;
    # independent of ω (the Aω column cancels)
    c = np.array([determinant_scores(np.eye(5)[i] + A @ np.array([0.3, -2.0, 7.0]), A) for i in range(5)])
    for i in range(5):
        for j in range(5):
            dist = min((i - j) % 5, (j - i) % 5)
            expect = 0.0 if dist == 0 else (0.5059 if dist == 1 else 0.8185)
            assert c[i, j] == pytest.approx(expect, abs=1e-4)


def test_table_5_2_decisions_and_monte_carlo() -> None:
    """Case 25: the printed μ* rows give i = 5 − r* (eq. 5.23); our statistic picks the failed sensor
    at σ = 0.1 (uniform noise, as rand.m) in a Monte-Carlo run. The printed magnitudes depend on an
    unknown draw and are not reproducible."""
    assert [cyclic_decision(row) for row in BOOK_TABLE_5_2] == [0, 1, 2, 3, 4]
    rng = np.random.default_rng(2019)
    h = 0.1 * math.sqrt(3.0)  # uniform with σ = 0.1
    hits = np.zeros(5)
    trials = 80
    for i in range(5):
        for _ in range(trials):
            y = A @ OMEGA + np.eye(5)[i] + rng.uniform(-h, h, 5)
            res = cyclic_isolation(y, A, 0.1)
            hits[i] += res.index == i
    rate = hits / trials
    assert rate.min() > 0.8 and rate.mean() > 0.88
    # noise-free, the failed sensor's shift gives an unbounded ratio
    y = A @ OMEGA + np.eye(5)[2]
    assert cyclic_isolation(y, A, 0.1).index == 2


def test_recursive_ls_matches_batch() -> None:
    """Eq. 5.21 added one equation at a time equals the batch LS (eq. 5.20); k_s is χ² with ℓ = 1."""
    rng = np.random.default_rng(3)
    sig = 0.05
    ks_all = []
    for _ in range(400):
        y = A @ OMEGA + rng.normal(0, sig, 5)
        ks_all.append(recursive_ks(y, A, sig))
    ks = np.array(ks_all)
    assert ks.shape == (400, 2)
    assert ks.mean() == pytest.approx(1.0, abs=0.15)  # E[χ²_1] = 1


def test_example_5_3_isolation_logic() -> None:
    """Case 22/23: printed Z = 0.6 Aᵀ; δĉ = 0.1 z₁ isolates sensor 1 with â₁ = 0.1 exactly (eqs. 5.28–5.30)."""
    Z = ls_matrix(A)
    Z_printed = np.array(
        [
            [0.5832, -0.3605, 0.0000, 0.0000, -0.3605],
            [-0.0000, -0.4659, 0.2880, -0.2880, 0.4659],
            [-0.1409, -0.1140, 0.5264, 0.5264, -0.1140],
        ]
    )
    assert np.allclose(Z, Z_printed, atol=1e-4)
    assert np.allclose(Z, 0.6 * A.T, atol=1e-5)
    dc = 0.1 * Z[:, 0]
    assert np.allclose(dc, [0.058322, 0.0, -0.014089], atol=1e-5)
    iso = bias_isolation(dc, Z)
    assert iso.index == 0
    assert iso.size == pytest.approx(0.1, abs=1e-12)
    assert iso.scores[0] == pytest.approx(0.0, abs=1e-15)
    assert (iso.scores[1:] > 1e-4).all()


def test_example_5_3_filter_run() -> None:
    """Ex 5.3 closed loop (20 s, corrections every 2 s): the indicator settles at i = 1 and â₁ → 0.1."""
    res = run_example_5_3(a1=0.1, failed=0, seed=0)
    assert len(res.t) == 10
    assert (res.index[-5:] == 0).all()
    assert res.a_hat[-1] == pytest.approx(0.1, abs=0.01)
    assert np.linalg.norm(res.dc_hat[-1] - res.dc_true) < 0.1 * np.linalg.norm(res.dc_true)
    # another sensor, another seed: the same logic finds it
    res4 = run_example_5_3(a1=0.1, failed=3, seed=5)
    assert (res4.index[-3:] == 3).all()


def test_all_methods_agree_noise_free() -> None:
    """Case 39: random ω and one large fault: SVD-J, determinant and bias projection all find it."""
    rng = np.random.default_rng(39)
    U2 = parity_basis(A)
    Z = ls_matrix(A)
    for _ in range(20):
        w = rng.normal(0, 1, 3)
        i = int(rng.integers(5))
        rho = rng.choice([-1, 1]) * rng.uniform(0.5, 5)
        y = A @ w + rho * np.eye(5)[i]
        assert svd_isolation(y, U2).index == i
        assert determinant_isolation(y, A).index == i
        assert determinant_isolation(y, A).size == pytest.approx(rho, rel=1e-9)
        assert bias_isolation(Z @ (y - A @ w), Z).index == i
        assert cyclic_isolation(y, A, 0.01).index == i


def test_bad_inputs_raise() -> None:
    with pytest.raises(ValueError, match="method"):
        parity_basis(A, "lu")
    with pytest.raises(ValueError, match="more sensors"):
        parity_basis(A[:3])
    with pytest.raises(ValueError, match="n = unknowns"):
        determinant_scores(np.zeros(6), np.vstack([A, A[:1]]))
    with pytest.raises(ValueError, match="sigma"):
        recursive_ks(np.zeros(5), A, 0.0)
