"""Reproduction of the seeds' published numbers: one module per table/figure group.

Each module exposes ``rows() -> list[Row]`` (cached: computed once per process).
A :class:`Row` holds the published value, the value we compute, the reference
it is checked against (the published value, or the corrected one where the
digest lists the published value as a typo), the tolerance and a note.
``ins-hil reproduce`` renders all rows into ``docs/reproduction.md`` (and :mod:`.plots` draws
the coning-drift and Schuler figures beside it).
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass

__all__ = ["Row", "all_rows", "groups", "notes"]


@dataclass(frozen=True)
class Row:
    """One published value beside ours.

    ``check``: ``"rel"`` |ours − ref| ≤ tol·|ref|; ``"abs"`` |ours − ref| ≤ tol;
    ``"le"`` ours ≤ ref; ``"ge"`` ours ≥ ref (bounds). ``published`` is None
    when the source prints no number (the reference then comes from the digest).
    ``discrepancy`` names why a row is reported rather than passed (a parameter we had to
    change, a unit the source does not state): such a row never counts as a pass, and it
    must document the value we measure: ``expect`` (ours, as measured when the reason was
    written) within ``expect_tol`` (relative; absolute when ``expect`` is 0). A discrepancy row
    whose value leaves that band, or that documents none, is a failure: a code change that
    moves a reported value fails like any other row.
    """

    group: str
    case: str
    published: float | None
    ours: float
    tol: float = 0.0
    check: str = "rel"
    reference: float | None = None
    note: str = ""
    typo: bool = False
    discrepancy: str = ""  # non-empty: the reason our result differs (a changed parameter, a reading); never a pass
    expect: float | None = None  # discrepancy rows: the documented value of ``ours``
    expect_tol: float = 0.0  # relative tolerance on ``expect`` (absolute when expect == 0)

    @property
    def status(self) -> str:
        """Return "pass", "fail" or "discrepancy" (reported with its reason and held at its documented value)."""
        if self.discrepancy:
            return "discrepancy" if self.held else "fail"
        return "pass" if self.passed else "fail"

    @property
    def held(self) -> bool:
        """A discrepancy row's value is where its reason documents it (``expect`` ± ``expect_tol``)."""
        if self.expect is None or not math.isfinite(self.ours):
            return False
        band = self.expect_tol * abs(self.expect) if self.expect != 0.0 else self.expect_tol
        return abs(self.ours - self.expect) <= band

    @property
    def expect_text(self) -> str:
        """The documented value of a discrepancy row, e.g. "17.6 ± 5 %"."""
        if self.expect is None:
            return "no documented value"
        tol = f"{100 * self.expect_tol:g} %" if self.expect != 0.0 else f"{self.expect_tol:g}"
        return f"{self.expect:.4g} ± {tol}"

    @property
    def ref(self) -> float:
        if self.reference is not None:
            return self.reference
        if self.published is None:
            raise ValueError(f"row {self.case!r} has neither a published value nor a reference")
        return self.published

    @property
    def diff(self) -> float:
        return self.ours - self.ref

    @property
    def passed(self) -> bool:
        r, o = self.ref, self.ours
        if not math.isfinite(o):
            return False
        if self.check == "rel":
            return abs(o - r) <= self.tol * abs(r)
        if self.check == "abs":
            return abs(o - r) <= self.tol
        if self.check == "le":
            return o <= r
        if self.check == "ge":
            return o >= r
        raise ValueError(f"unknown check {self.check!r}")

    @property
    def tolerance_text(self) -> str:
        return {
            "rel": f"±{100 * self.tol:g} %",
            "abs": f"±{self.tol:g}",
            "le": "≤ ref",
            "ge": "≥ ref",
        }[self.check]


def groups() -> list[tuple[str, Callable[[], list[Row]]]]:
    from . import (
        book_ch2,
        book_ch3,
        book_ch3_examples,
        book_ch4,
        book_ch5,
        book_tables,
        gyrofree,
        seed001,
        seed001_frames,
        seed001_jacobian,
        seed001_mech,
        seed002,
        seed003,
        seed004,
    )

    return [
        ("Book ch. 2: rotational mechanization (DIGEST_000 §8 cases 1–11)", book_ch2.rows),
        ("Book §2.4: gyro-free INS (DIGEST_000 §8 cases 12–13, 32–33)", gyrofree.rows),
        ("Seed 002: one-step algorithms under coning (DIGEST_001_004 §6 cases 13–23)", seed002.rows),
        ("Seed 001: Schuler oscillation (DIGEST_001_004 §6 cases 6–7)", seed001.rows),
        (
            "Seed 001: WGS84, gravity, frames, attitude, alignment, KF forms (DIGEST_001_004 §6 cases 1–5, 8–10, 12)",
            seed001_frames.rows,
        ),
        ("Seed 001: error-model F vs finite differences (DIGEST_001_004 §6 case 11)", seed001_jacobian.rows),
        ("Seed 001: i- and e-frame mechanizations vs the NED one (seed 001 §3.2.1–3.2.2)", seed001_mech.rows),
        (
            "Seed 001: i-, e-frame and NED mechanizations, order in the step (seed 001 §3.2.1–3.2.2)",
            seed001_mech.order_rows,
        ),
        ("Book §3.1: square-root QR with a singular r, operation counts (DIGEST_000 §8 cases 16, 36)", book_ch3.rows),
        (
            "Book Ex 3.1–3.3 closed loops, the §6.1 lab and §6.5 outage analogues (DIGEST_000 §8 cases 27, 28)",
            book_ch3_examples.rows,
        ),
        ("Book ch. 3–5 printed values (DIGEST_000 §8 cases 14, 15, 17–19, 21–26)", book_tables.rows),
        ("Book eq. 4.9: position-error growth against the strapdown", book_ch4.rows),
        (
            "Seed 003: guards against its typos (DIGEST_001_004 §6 cases 24–27), SLERP, the continuous–discrete "
            "Kalman filter, the orthodromic frame",
            seed003.rows,
        ),
        ("Book Ex 5.3: isolation from the estimated gyro bias (units of a₁)", book_ch5.rows),
        ("Seed 004: platform INS with precession-angle sensors (DIGEST_001_004 §6 cases 28–31)", seed004.rows),
    ]


def notes() -> list[str]:
    """Markdown sections written after the tables: the seed-004 test bed, Ex 3.1–3.3 compared, the coverage list,
    the mutation check's list."""
    from . import book_ch3_examples, coverage, mutations, seed004

    return [
        seed004.comparison_markdown(),
        book_ch3_examples.comparison_markdown(),
        coverage.markdown(all_rows()),
        mutations.list_markdown(),
    ]


def all_rows() -> list[Row]:
    """Every row of every group (computations cached per process)."""
    out: list[Row] = []
    for _, fn in groups():
        out.extend(fn())
    return out
