"""Book §3.1: the QR update with a singular measurement-noise factor and the operation counts (3.23)–(3.25)."""

from __future__ import annotations

import numpy as np
import pytest

from ins_hil.fusion.sqrt import conventional_update, qr_update_singular_r
from ins_hil.reproduce import book_ch3


def test_operation_counts() -> None:
    assert book_ch3.e_ud_closed(9) == pytest.approx(516.0)
    assert book_ch3.e_qort_closed(9, 9) == pytest.approx(29154.0)
    assert book_ch3.e_ud_sum(9) == 276.0  # the printed sum disagrees with its closed form
    assert book_ch3.e_qort_sum(9, 9) == 29162.0


@pytest.mark.parametrize("seed", range(5))
@pytest.mark.parametrize("rank", [0, 1, 3])
def test_singular_r_matches_the_conventional_filter(seed: int, rank: int) -> None:
    rng = np.random.default_rng(seed)
    n, k = 7, 3
    m = np.tril(rng.normal(size=(n, n))) + 2 * np.eye(n)
    H = rng.normal(size=(k, n))
    x, z = rng.normal(size=n), rng.normal(size=k)
    r = np.zeros((k, k))
    r[:rank, :rank] = np.tril(rng.normal(size=(rank, rank))) + np.eye(rank)
    x1, p = qr_update_singular_r(x, m, z, H, r)
    x2, P2 = conventional_update(x, m @ m.T, z, H, r @ r.T)
    np.testing.assert_allclose(p @ p.T, P2, atol=1e-10)
    np.testing.assert_allclose(x1, x2, atol=1e-10)
    if rank == 0:  # perfect measurements: the posterior satisfies H P(+) H^T = 0
        np.testing.assert_allclose(H @ p @ p.T @ H.T, 0.0, atol=1e-10)


def test_rows() -> None:
    rows = book_ch3.rows()
    assert [r.status for r in rows].count("discrepancy") == 2
    assert all(r.status != "fail" for r in rows)
