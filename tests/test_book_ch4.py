"""Book eq. 4.9 against the strapdown (ins_hil.reproduce.book_ch4): each error term recomputed here."""

from __future__ import annotations

import math

import numpy as np
import pytest

from ins_hil.nav import earth
from ins_hil.reproduce import book_ch4

G = earth.normal_gravity(math.radians(45.0), 100.0)


def test_terms_of_eq_4_9_against_the_strapdown() -> None:
    t = 60.0
    assert book_ch4.free_run(dv0=0.1)[0] == pytest.approx(0.1 * t, rel=1e-5)
    assert book_ch4.free_run(b_a=np.array([1e-3, 0.0, 0.0]))[0] == pytest.approx(1e-3 * t * t / 2, rel=1e-5)
    assert abs(book_ch4.free_run(tilt=1e-3)[0]) == pytest.approx(1e-3 * G * t * t / 2, rel=1e-5)
    # the gyro term needs g: g b_g t³/6 = 3.53 m, not the printed b_g t³/6 = 0.36
    assert abs(book_ch4.free_run(b_g=np.array([0.0, 1e-5, 0.0]))[0]) == pytest.approx(G * 1e-5 * t**3 / 6, rel=1e-5)
    # the accelerometer scale-factor term needs F (= g on the vertical at rest)
    assert abs(book_ch4.free_run(sf_z=1e-3)[2]) == pytest.approx(1e-3 * G * t * t / 2, rel=2e-3)
    assert np.max(np.abs(book_ch4.free_run())) < 1e-6  # no error, no drift


def test_rows_pass_and_the_printed_terms_are_marked() -> None:
    rows = book_ch4.rows()
    assert len(rows) == 7 and all(r.status == "pass" for r in rows)
    typo = [r for r in rows if r.typo]
    assert len(typo) == 2 and all(abs(r.ours - G) < 0.05 for r in typo)
