"""The mutation check of the reproduction (ins_hil/reproduce/mutations.py): every listed formula mutation makes a
row of its report section fail; the list stays applicable to the current source."""

from __future__ import annotations

import math

import numpy as np
import pytest

from ins_hil.reproduce import mutations as mu

BY_ID = {m.id: m for m in mu.MUTATIONS}


def test_the_list_covers_the_issue_and_every_seed() -> None:
    assert {"004-D adaptation off", "004-B eq. 5 cross-term sign", "Ex 3.x halved attitude feedback"} <= set(BY_ID)
    # one for each algorithm added for issue 43: the continuous–discrete filter, the i-/e-frame mechanizations,
    # the orthodromic frame
    assert {"003 continuous–discrete Ṗ", "001 e-frame Coriolis", "001 i-frame gravity for gravitation",
            "003 orthodromic torsion sign"} <= set(BY_ID)  # fmt: skip
    assert {"seed 001", "seed 002", "seed 003", "seed 004"} <= {m.source for m in mu.MUTATIONS}
    assert len(BY_ID) == len(mu.MUTATIONS)


@pytest.mark.parametrize("m", mu.MUTATIONS, ids=[m.id for m in mu.MUTATIONS])
def test_each_mutation_applies_and_is_undone(m: mu.Mutation) -> None:
    """The snippet is found once in the current source (the list does not rot) and the patch is undone."""
    _, owner, name = mu._resolve(m.target)
    before = getattr(owner, name)
    value = dict(before) if m.key else None
    with mu.applied(m):
        if m.key:
            assert getattr(owner, name)[m.key] == float(m.new)
        else:
            assert getattr(owner, name) is not before
    assert getattr(owner, name) is before
    if m.key:
        assert dict(before) == value


def test_a_mutation_changes_what_the_callers_compute() -> None:
    """In-process: the patched function is the one every importer calls (here J2 gravity via the mechanization)."""
    from ins_hil.nav import earth
    from ins_hil.reproduce import seed003

    g0 = earth.gravity_j2_ned(math.pi / 2, 0.0)[2]
    with mu.applied(BY_ID["003 J2 polar term"]):
        assert abs(earth.gravity_j2_ned(math.pi / 2, 0.0)[2] - g0) > 1e-3
        assert abs(seed003.j2_navigation_drift(seconds=1.0)[2]) > 0.0
    assert earth.gravity_j2_ned(math.pi / 2, 0.0)[2] == g0


def test_an_unknown_snippet_is_a_clear_error() -> None:
    bad = mu.Mutation("x", "seed 003", "", "ins_hil.nav.rotation:quat_slerp", "no such text", "y", "^Seed 003")
    with pytest.raises(ValueError, match="occurs 0 times"):
        with mu.applied(bad):
            pass


def test_fast_mutations_are_caught_in_process() -> None:
    """The cheap ones, in this process (their sections' caches are cleared before and after)."""
    from ins_hil.reproduce import book_ch2, book_tables, seed003

    for fn in (book_ch2.rows, book_tables.rows, seed003.rows):
        fn.cache_clear()
    try:
        for mid in (
            "003 SLERP rotation order",
            "003 J2 polar term",
            "003 continuous–discrete Ṗ",
            "003 orthodromic torsion sign",
            "book ch. 2 δλ_q sign",
            "book ch. 5 decision rule",
        ):
            o = mu.check(BY_ID[mid])
            for fn in (book_ch2.rows, book_tables.rows, seed003.rows):
                fn.cache_clear()
            assert o.caught, (mid, o)
    finally:
        for fn in (book_ch2.rows, book_tables.rows, seed003.rows):
            fn.cache_clear()
    assert np.isfinite(seed003.rows()[0].ours)


@pytest.mark.slow
@pytest.mark.campaign  # 226 s on an idle 2-vCPU machine: `ins-hil reproduce --mutations` is its command
def test_every_mutation_is_caught() -> None:
    """Each mutation in a fresh interpreter (`ins-hil reproduce --mutations`): a row fails, nothing crashes."""
    outcomes = mu.run()
    missed = [(o.id, o.crash) for o in outcomes if not o.caught]
    assert not missed, missed
