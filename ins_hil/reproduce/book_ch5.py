"""Book Ex 5.3 (§5.4): failed-gyro isolation from the estimated bias — which unit of a₁ (DIGEST_000 §8).

The book gives σ_ω = 0.05 °/s but the failed gyro's systematic error δc = a₁ z₁ with a₁ = 0.1 and no
unit (DIGEST_000 §9: "a_1 = 0.1 (Ex 5.3): units not stated"). Its stated outcome (Fig. 5.5): after the
transient the failure indicator (5.30) settles at 1, the first sensor.

* a₁ = 0.1 rad/s (5.7 °/s, about 115 σ_ω): the reading consistent with the filter's own units (the
  state is in rad and rad/s, and the initial Cholesky factor of δc is δ_m = 0.4, of the order of a
  0.1 rad/s bias); :func:`ins_hil.fdi.bias.run_example_5_3` isolates sensor 1 in every seed.
* a₁ = 0.1 °/s (2 σ_ω): 0.1 °/s over 20 s turns the attitude by 2°, below the magnetometer's
  σ_m = 3°, so the bias is barely observable in the run; the indicator never settles.

The unit is a reading the book does not state, and with it isolation is easy: the row is reported as a
discrepancy with the reason, not counted as a pass.
"""

from __future__ import annotations

import math
from functools import lru_cache

from ins_hil.fdi.bias import run_example_5_3

from . import Row

SEEDS = (0, 1, 2, 3, 4)


def isolated_fraction(a1: float, seeds: tuple[int, ...] = SEEDS, last: int = 5) -> float:
    """Fraction of seeds whose indicator is sensor 1 at each of the ``last`` corrections of the 20 s run."""
    ok = 0
    for s in seeds:
        r = run_example_5_3(a1=a1, failed=0, seed=s)
        ok += bool((r.index[-last:] == 0).all())
    return ok / len(seeds)


@lru_cache(maxsize=1)
def rows() -> list[Row]:
    g = "Ex 5.3 (five gyros, first biased, 20 s, corrections every 2 s; 5 seeds)"
    rad = isolated_fraction(0.1)
    deg = isolated_fraction(math.radians(0.1))
    return [
        Row(
            g,
            "fraction of seeds isolating sensor 1, a₁ = 0.1 rad/s",
            None,
            rad,
            0.0,
            "abs",
            1.0,
            "book Fig. 5.5: indicator settles at 1",
            discrepancy="a₁'s unit is not stated; rad/s (≈ 115 σ_ω) is our reading and makes isolation easy",
            expect=1.0,
        ),
        Row(
            g,
            "fraction of seeds isolating sensor 1, a₁ = 0.1 °/s",
            None,
            deg,
            0.0,
            "abs",
            1.0,
            "book Fig. 5.5: indicator settles at 1",
            discrepancy="in the °/s reading (2 σ_ω, the unit of σ_ω) the book's outcome is not reproduced",
            expect=0.0,
        ),
    ]
