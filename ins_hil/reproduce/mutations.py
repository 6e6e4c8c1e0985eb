"""A mutation check of the reproduction: small formula changes that the report's rows must catch.

Each :class:`Mutation` changes one formula in the running process (the function's source with one
snippet replaced, recompiled in its module and patched everywhere the original is referenced; or
one entry of a coefficient table) and recomputes the rows of the report sections it affects. It is
*caught* when at least one of those rows fails (a crash is not a catch: the report must say what
moved). ``ins-hil reproduce --mutations`` runs the list, each mutation in a fresh interpreter (the
row computations are cached per process), and exits with status 1 if one is not caught;
tests/test_reproduce_mutations.py does the same as a slow test.
"""

from __future__ import annotations
import __future__

import importlib
import inspect
import json
import re
import subprocess
import sys
import textwrap
import traceback
from collections.abc import Iterator
from contextlib import contextmanager
from dataclasses import dataclass
from typing import Any

__all__ = ["MUTATIONS", "Mutation", "Outcome", "applied", "check", "run"]


@dataclass(frozen=True)
class Mutation:
    """One formula change: ``target`` is "module:qualname" (a function or Class.method) whose source has ``old``
    exactly once, replaced by ``new``; with ``key`` set, ``target`` names a dict and ``old``/``new`` are the
    entry's value before and after. ``sections``: a regex on the report's section titles whose rows must catch it.
    """

    id: str
    source: str  # which seed / book part
    what: str
    target: str
    old: str
    new: str
    sections: str
    key: str | None = None


MUTATIONS: tuple[Mutation, ...] = (
    Mutation(
        "004-D adaptation off",
        "seed 004",
        "the reduced adaptive KF of the test bed runs with adapt=False",
        "ins_hil.platform_ins.testbed:simulate",
        '("reduced adaptive", True)',
        '("reduced adaptive", False)',
        "^Seed 004",
    ),
    Mutation(
        "004-B eq. 5 cross-term sign",
        "seed 004",
        "eq. 5: the second cross term of Φ1's integrand, −(Jϑ̈ + hϑ̇)(Jλ̇ + hλ)/H, with +",
        "ins_hil.platform_ins.model:reconstruct_angles",
        "i1 = md[:, 1] * d - md[:, 2] * m[:, 1] / H",
        "i1 = md[:, 1] * d + md[:, 2] * m[:, 1] / H",
        "^Seed 004",
    ),
    Mutation(
        "Ex 3.x halved attitude feedback",
        "book ch. 3",
        "Examples 3.1–3.3 feed back half the estimated attitude error",
        "ins_hil.reproduce.book_ch3_examples:run",
        "quat_from_rotvec(-x[0:3])",
        "quat_from_rotvec(-0.5 * x[0:3])",
        "^Book Ex 3.1",
    ),
    Mutation(
        "001 gravity height term sign",
        "seed 001",
        "eq. 16: the free-air term −(3.0877e-6 − 4.4e-9 sin²φ) h enters with + (normal_gravity)",
        "ins_hil.nav.earth:normal_gravity",
        "return g0 - (3.0877e-6 - 4.4e-9 * s2) * h",
        "return g0 + (3.0877e-6 - 4.4e-9 * s2) * h",
        "^Seed 001: (Schuler|WGS84|error-model|i-, e-frame and NED)",  # not the 1-h mechanization runs (minutes)
    ),
    Mutation(
        "001 transport rate sign",
        "seed 001",
        "the strapdown's east transport rate −v_N/(M + h) with + (Schuler loop)",
        "ins_hil.nav.mechanization:StrapdownNED.step",
        "enE = -wN / rmh",
        "enE = wN / rmh",
        "^Seed 001: Schuler",
    ),
    Mutation(
        "001 e-frame Coriolis",
        "seed 001",
        "eq. 51: the e-frame mechanization's Coriolis term −2Ω_ie v^e becomes −Ω_ie v^e",
        "ins_hil.nav.mechanization_ie:StrapdownECEF.step",
        "v1 = s.v + dvf + (g - 2.0 * _cross(_WZ, v_mid)) * dt",
        "v1 = s.v + dvf + (g - 1.0 * _cross(_WZ, v_mid)) * dt",
        "^Seed 001: i-, e-frame and NED mechanizations, order",
    ),
    Mutation(
        "001 i-frame gravity for gravitation",
        "seed 001",
        "eq. 44 read literally: the i-frame mechanization integrates gravity (eq. 11) instead of gravitation",
        "ins_hil.nav.mechanization_ie:StrapdownECI._gravitation",
        "earth.gravitation_ecef(",
        "earth.gravity_ecef(",
        "^Seed 001: i-, e-frame and NED mechanizations, order",
    ),
    Mutation(
        "001 NED rates at the step start",
        "seed 001",
        "the NED mechanization takes ω_ie, gravity and the radii at the step's start latitude (first order)",
        "ins_hil.nav.mechanization:StrapdownNED.step",
        "latm = lat + 0.5 * vN / (rm0 + h) * dt",
        "latm = lat",
        "^Seed 001: i-, e-frame and NED mechanizations, order",
    ),
    Mutation(
        "002 ExpRvrs1h coefficient",
        "seed 002",
        "ExpRvrs1h's c = 1/12 (eq. 7) becomes 1/12.5",
        "ins_hil.nav.onestep:FAMILY_C",
        repr(1.0 / 12.0),
        repr(1.0 / 12.5),
        "^Seed 002",
        key="exprvrs1h",
    ),
    Mutation(
        "003 SLERP rotation order",
        "seed 003",
        "quat_slerp applies the body-frame relative rotation on the left: exp(t·log(q0*⊗q1)) ⊗ q0",
        "ins_hil.nav.rotation:quat_slerp",
        "quat_mul(a, quat_from_rotvec(float(t) * rotvec_from_quat(d)))",
        "quat_mul(quat_from_rotvec(float(t) * rotvec_from_quat(d)), a)",
        "^Seed 003",
    ),
    Mutation(
        "003 J2 polar term",
        "seed 003",
        "the J2 gravity's z factor (3 − 5z²/r²) becomes (1 − 5z²/r²)",
        "ins_hil.nav.earth:j2_gravity_nd",
        "gz = -gm_r3 * z * (1.0 + k * (3.0 - u))",
        "gz = -gm_r3 * z * (1.0 + k * (1.0 - u))",
        "^Seed 003",
    ),
    Mutation(
        "003 continuous–discrete Ṗ",
        "seed 003",
        "Ṗ = AP + PAᵀ + Q loses the PAᵀ term between the measurements",
        "ins_hil.fusion.continuous_discrete:ContinuousDiscreteKF._advance",
        "return AP + AP.T + Q",
        "return AP + Q",
        "^Seed 003",
    ),
    Mutation(
        "003 orthodromic torsion sign",
        "seed 003",
        "eq. 1.5: the geodesic-torsion term of ω⁰_ξ, −τ v_ξ, enters with +",
        "ins_hil.nav.orthodromic:transport_rate",
        "-v_eta * k_eta - tau * v_xi",
        "-v_eta * k_eta + tau * v_xi",
        "^Seed 003",
    ),
    Mutation(
        "book ch. 2 δλ_q sign",
        "book ch. 2",
        "eq. 2.28: δλ_q = [1 + q‖∇θ‖², ½∇θ]",
        "ins_hil.nav.attitude:dlq",
        "out[..., 0] = 1.0 - q * _sq(th)",
        "out[..., 0] = 1.0 + q * _sq(th)",
        "^Book ch. 2",
    ),
    Mutation(
        "book ch. 5 decision rule",
        "book ch. 5",
        "eq. 5.23: the failed sensor taken as r* instead of n − r*",
        "ins_hil.fdi.recursive:cyclic_decision",
        "return len(mu) - int(np.argmax(mu)) - 1",
        "return int(np.argmax(mu))",
        "^Book ch. 3–5",
    ),
    Mutation(
        "book ch. 2 eq. 2.45 factor",
        "book ch. 2",
        "eq. 2.45: ω_i² = (…)/L instead of (…)/(2L) (12 accelerometers)",
        "ins_hil.nav.gyrofree:twelve_accel_squares",
        "k = 1.0 / (2.0 * L)",
        "k = 1.0 / L",
        "^Book §2.4",
    ),
    Mutation(
        "book ch. 4 eq. 4.9 tilt (strapdown rotation term)",
        "book ch. 4",
        "the strapdown's ½ Δθ × Δv rotation term with the opposite sign",
        "ins_hil.nav.mechanization:StrapdownNED.step",
        "dx = ux + 0.5 * (ay * uz - az * uy)",
        "dx = ux - 0.5 * (ay * uz - az * uy)",
        "^Book eq. 4.9",
    ),
    Mutation(
        "book ch. 4 calibration split",
        "book ch. 4",
        "eq. 4.19: εB_sym = (εB − εBᵀ)/2",
        "ins_hil.nav.calibration:decompose",
        "sym = 0.5 * (eb + eb.T)",
        "sym = 0.5 * (eb - eb.T)",
        "^Book ch. 3–5",
    ),
)


def _resolve(target: str) -> tuple[Any, Any, str]:
    """(module, owner of the attribute, attribute name) of "module:qualname"."""
    modname, _, qual = target.partition(":")
    mod = importlib.import_module(modname)
    owner: Any = mod
    *path, name = qual.split(".")
    for p in path:
        owner = getattr(owner, p)
    return mod, owner, name


def _mutated_function(m: Mutation, mod: Any, orig: Any) -> Any:
    src = textwrap.dedent(inspect.getsource(orig))
    n = src.count(m.old)
    if n != 1:
        raise ValueError(f"mutation {m.id!r}: {m.old!r} occurs {n} times in {m.target} (expected once)")
    flags = __future__.annotations.compiler_flag
    code = compile(src.replace(m.old, m.new), f"<mutation {m.id}>", "exec", flags=flags, dont_inherit=True)
    ns: dict[str, Any] = {}
    exec(code, mod.__dict__, ns)  # the function's own source with one snippet replaced
    return ns[orig.__name__]


@contextmanager
def applied(m: Mutation) -> Iterator[None]:
    """Apply ``m`` in this process (every module attribute bound to the original is patched); undone on exit."""
    mod, owner, name = _resolve(m.target)
    orig = getattr(owner, name)
    undo: list[tuple[Any, str, Any]] = []
    if m.key is not None:
        if repr(orig[m.key]) != m.old:
            raise ValueError(f"mutation {m.id!r}: {m.target}[{m.key!r}] is {orig[m.key]!r}, not {m.old}")
        before = orig[m.key]
        orig[m.key] = float(m.new)
        try:
            yield
        finally:
            orig[m.key] = before
        return
    new = _mutated_function(m, mod, orig)
    if inspect.isclass(owner):
        undo.append((owner, name, orig))
        setattr(owner, name, new)
    else:
        for other in list(sys.modules.values()):
            for attr, val in list(getattr(other, "__dict__", {}).items()):
                if val is orig:
                    undo.append((other, attr, orig))
                    setattr(other, attr, new)
    try:
        yield
    finally:
        for obj, attr, val in undo:
            setattr(obj, attr, val)


@dataclass(frozen=True)
class Outcome:
    """What a mutation did to the rows of its sections: the failed rows, or the crash."""

    id: str
    rows: int
    failed: tuple[str, ...]
    crash: str = ""

    @property
    def caught(self) -> bool:
        return bool(self.failed) and not self.crash


def check(m: Mutation) -> Outcome:
    """Apply ``m`` in this process and recompute its sections' rows (call in a fresh interpreter: rows are cached)."""
    from . import groups

    secs = [(title, fn) for title, fn in groups() if re.search(m.sections, title)]
    if not secs:
        raise ValueError(f"mutation {m.id!r}: no report section matches {m.sections!r}")
    n, failed = 0, []
    with applied(m):
        try:
            for _, fn in secs:
                rows = fn()
                n += len(rows)
                failed += [f"{r.group}: {r.case}" for r in rows if r.status == "fail"]
        except Exception as e:  # a crash is reported, and is not a catch
            tb = traceback.extract_tb(e.__traceback__)[-1]
            return Outcome(m.id, n, tuple(failed), f"{type(e).__name__}: {e} ({tb.name}, line {tb.lineno})")
    return Outcome(m.id, n, tuple(failed))


def run(mutations: tuple[Mutation, ...] = MUTATIONS, progress: bool = False) -> list[Outcome]:
    """Each mutation checked in a fresh interpreter (``python -m ins_hil.reproduce.mutations ID``)."""
    out = []
    for m in mutations:
        if progress:
            print(f"mutation: {m.id} ...", end="", flush=True)
        p = subprocess.run(
            [sys.executable, "-m", "ins_hil.reproduce.mutations", m.id], capture_output=True, text=True, check=False
        )
        lines = p.stdout.strip().splitlines()
        if p.returncode != 0 or not lines:
            o = Outcome(m.id, 0, (), f"exit status {p.returncode}: {(p.stderr.strip().splitlines() or [''])[-1]}")
        else:
            d = json.loads(lines[-1])
            o = Outcome(d["id"], d["rows"], tuple(d["failed"]), d["crash"])
        if progress:
            print(" caught" if o.caught else " NOT CAUGHT", f"({len(o.failed)} of {o.rows} rows fail)", o.crash)
        out.append(o)
    return out


def markdown(outcomes: list[Outcome]) -> str:
    """The mutation list with what caught each."""
    by_id = {m.id: m for m in MUTATIONS}
    lines = ["| mutation | seed / book | change | caught by (rows failing) |", "|---|---|---|---|"]
    for o in outcomes:
        m = by_id[o.id]
        how = (
            f"**crash** {o.crash}"
            if o.crash
            else (f"{len(o.failed)} rows, e.g. {o.failed[0]}" if o.failed else "**NOT CAUGHT**")
        )
        lines.append(f"| {m.id} | {m.source} | {m.what} | {how.replace('|', chr(92) + '|')} |")
    return "\n".join(lines)


def list_markdown() -> str:
    """The report's section on the mutation check: the list (the outcomes need `ins-hil reproduce --mutations`)."""
    lines = [
        "## Mutation check",
        "",
        "`ins-hil reproduce --mutations` applies each of these small formula changes in a fresh interpreter "
        "(ins_hil/reproduce/mutations.py) and recomputes the rows of the sections named; each must make at least "
        "one row fail (a crash does not count). A discrepancy row is held at its documented value, so it fails "
        "too when a change moves it.",
        "",
        "| mutation | seed / book | change | in | sections that must catch it |",
        "|---|---|---|---|---|",
    ]
    for m in MUTATIONS:
        where = m.target.replace("ins_hil.", "")
        lines.append(f"| {m.id} | {m.source} | {m.what} | `{where}` | `{m.sections}` |")
    return "\n".join([*lines, ""])


def _main(argv: list[str]) -> int:
    (mid,) = argv
    m = next((x for x in MUTATIONS if x.id == mid), None)
    if m is None:
        print(f"unknown mutation {mid!r}", file=sys.stderr)
        return 2
    o = check(m)
    print(json.dumps({"id": o.id, "rows": o.rows, "failed": list(o.failed), "crash": o.crash}))
    return 0


if __name__ == "__main__":
    raise SystemExit(_main(sys.argv[1:]))
