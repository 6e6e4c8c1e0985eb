"""Book §3.1.2–3.1.4: the singular-r QR update and the operation counts (3.23)–(3.25) (DIGEST_000 §8 cases 16, 36)."""

from __future__ import annotations

from functools import lru_cache

import numpy as np

from ins_hil.fusion.sqrt import conventional_update, qr_update, qr_update_singular_r

from . import Row


def e_ud_closed(m: int) -> float:
    """Bierman factorisation count, closed form of (3.24): (2/3)m³ + (1/2)m² − (7/6)m."""
    return 2.0 / 3.0 * m**3 + 0.5 * m**2 - 7.0 / 6.0 * m


def e_ud_sum(m: int) -> float:
    """(3.24) as the printed sum Σ_{j=1}^{m} (m − j + Σ_{i=j}^{m} 2(m − i))."""
    return float(sum(m - j + sum(2 * (m - i) for i in range(j, m + 1)) for j in range(1, m + 1)))


def e_qort_closed(n: int, m: int) -> float:
    """QR factorisation count, closed form of (3.25)."""
    d = n - m
    return 5 / 3 * n**3 + 2 * n**2 + 25 / 3 * n - 5 / 3 * d**3 - 2 * d**2 - 25 / 3 * d + 2 * n**2 * m * (n + m + 1)


def e_qort_sum(n: int, m: int) -> float:
    """(3.23) as the printed sum Σ_{j=n−m}^{n} (5j² − j + 8) + 2n²(n + m + 1)m."""
    return float(sum(5 * j * j - j + 8 for j in range(n - m, n + 1)) + 2 * n * n * (n + m + 1) * m)


def singular_r_agreement(seed: int = 36) -> tuple[float, float, float]:
    """Max |ΔP(+)| vs the conventional filter (singular r), vs (3.10)–(3.12) (invertible r), and max |Δx(+)|."""
    rng = np.random.default_rng(seed)
    n, k = 9, 4
    m = np.tril(rng.normal(size=(n, n))) + 3 * np.eye(n)
    H = rng.normal(size=(k, n))
    x, z = rng.normal(size=n), rng.normal(size=k)
    r_sing = np.diag([0.5, 0.2, 0.0, 0.0])
    x1, p1 = qr_update_singular_r(x, m, z, H, r_sing)
    xc, Pc = conventional_update(x, m @ m.T, z, H, r_sing @ r_sing.T)
    r_inv = np.tril(rng.normal(size=(k, k))) + np.eye(k)
    x2, p2 = qr_update_singular_r(x, m, z, H, r_inv)
    x3, p3 = qr_update(x, m, z, H, r_inv)
    return (
        float(np.max(np.abs(p1 @ p1.T - Pc))),
        float(np.max(np.abs(p2 @ p2.T - p3 @ p3.T))),
        float(max(np.max(np.abs(x1 - xc)), np.max(np.abs(x2 - x3)))),
    )


@lru_cache(maxsize=1)
def rows() -> list[Row]:
    g = "§3.1.4 operation counts, 9 × 9 (eqs. 3.23–3.25)"
    out = [
        Row(g, "E_UD(9), closed form (3.24)", 516.0, e_ud_closed(9), 1e-9, "abs"),
        Row(g, "E_QORT(9, 9), closed form (3.25)", 29154.0, e_qort_closed(9, 9), 1e-9, "abs"),
        Row(
            g,
            "E_UD(9), the printed sum of (3.24)",
            516.0,
            e_ud_sum(9),
            1e-9,
            "abs",
            discrepancy="the printed sum (276) does not equal its own closed form (516)",
            expect=276.0,
        ),
        Row(
            g,
            "E_QORT(9, 9), the printed sum of (3.23)",
            29154.0,
            e_qort_sum(9, 9),
            1e-9,
            "abs",
            discrepancy="the printed sum from j = n − m (29 162) differs from the closed form by 8",
            expect=29162.0,
        ),
    ]
    g = "§3.1.2 QR update with a singular r (9 states, 4 measurements, rank r = 2)"
    ps, pi_, dx = singular_r_agreement()
    out += [
        Row(g, "max |P(+) − P(+) conventional (3.8)|, singular r", None, ps, 1e-10, "abs", 0.0, "DIGEST_000 case 36"),
        Row(g, "max |P(+) − P(+) of (3.10)–(3.12)|, invertible r", None, pi_, 1e-10, "abs", 0.0),
        Row(g, "max |x(+) − x(+) reference|", None, dx, 1e-9, "abs", 0.0),
    ]
    return out
