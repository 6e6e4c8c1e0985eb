"""Every reproducible case of the digests (DIGEST_001_004 §6, DIGEST_000 §8) with its status in `ins-hil reproduce`.

Each case names the rows that reproduce it by two regular expressions (on :attr:`Row.group` and
:attr:`Row.case`); its status is computed from those rows (all pass / with discrepancies / with
failures). A case with no selector is not a row, with the reason why.
"""

from __future__ import annotations

import re
from dataclasses import dataclass

from . import Row


@dataclass(frozen=True)
class Case:
    """A digest case: id, what it is, the rows that reproduce it (group regex, case regex) or why none does."""

    id: str
    what: str
    group: str | None = None  # regex on Row.group; None: not a row
    case: str = ""  # regex on Row.case
    why: str = ""  # where / why not

    def rows(self, rows: list[Row]) -> list[Row]:
        if self.group is None:
            return []
        g, c = re.compile(self.group), re.compile(self.case)
        return [r for r in rows if g.search(r.group) and c.search(r.case)]


F = "001-A/B/D/E"
CONING = "^Seed 002 coning drift"
SEED_CASES: tuple[Case, ...] = (
    Case("001-A", "WGS84 derived constants", F, r"^b = |^e²"),
    Case("001-B", "Somigliana normal gravity, 7 latitudes", F, r"^γ₀\("),
    Case("001-C", "series vs Somigliana gravity (printed β₁ = f²/4 a typo)", "^001-C"),
    Case("001-D", "height-dependent gravity", F, r"^γ\(45°, h"),
    Case("001-E", "Earth rate 15.041 °/h", F, "^Earth rate"),
    Case("001-F", "Schuler period", "Schuler oscillation", "^period"),
    Case("001-G", "Schuler response", "Schuler oscillation", "^peak"),
    Case("001-H", "Euler/DCM/quaternion (ENU, y-x-z) and the NED/FRD converters", "^001-H"),
    Case("001-I", "attitude update eqs. 61, 63", "^001-I / 001-L", r"^max \|\(61\)"),
    Case("001-J", "static coarse alignment eqs. 64–69", "^001-J"),
    Case("001-K", "error-model Jacobian F (seed's and the core's)", "^001-K"),
    Case("001-L", "Kalman update forms eqs. 143–144", "001-L", "143|information|Kalman|P"),
    Case("001-M", "i-frame and e-frame mechanizations (eqs. 45, 51) vs the NED one (no printed numbers)", "^001-M"),
    Case("002-A", "code ≡ formula", why="an identity of the seed's code, tested in tests/test_seed002.py"),
    Case("002-B", "Revers1h drift 0.042 μ²", CONING, "^Revers1h δ"),
    Case("002-C", "RK21 drift 0.083 μ², opposite sign", CONING, "^RK21 |^sign of RK21"),
    Case("002-D", "RK21 / Revers1h ≈ 2", CONING, "^RK21/Revers1h"),
    Case("002-E", "Picard drift 0.0021 μ² (literal eq. 6)", CONING, "^Picard|^Revers1h/Picard"),
    Case("002-F", "ExpRvrs1h 7.3e-3 μ⁴", CONING, "^ExpRvrs1h δ/μ⁴"),
    Case("002-G", "ExpRvrs1h ≈ Picard at μ = 1", CONING, "^ExpRvrs1h/Picard"),
    Case("002-H", "2600 times", CONING, "^Revers1h/ExpRvrs1h|^largest μ"),
    Case("002-I", "small-μ law 1.6e-7 μ² (not reproduced: the 4th-order law persists)", CONING, r"^ExpRvrs1h δ/μ² "),
    Case("002-J", "phase dependence", "^Seed 002 phase"),
    Case("002-K", "normalisation", "^Seed 002 normalisation"),
    Case("003-A", "DCM orthogonality (printed C a typo)", "^003-A", "DCM"),
    Case("003-B", "quaternion product i∘j = k", "^003-A", "^003-B"),
    Case("003-C", "J2 gravity with the corrected μ", "^003-A", "^003-C"),
    Case("003-D", "Table 1.1 corrected", "^003-A", "^003-D"),
    Case("003-E", "SLERP (shortest path, small-angle safe; the thesis prints no numbers)", "^003-E"),
    Case("003-F", "continuous–discrete Kalman filter, asynchronous sensors (no printed numbers)", "^003-F"),
    Case(
        "003-G",
        "orthodromic frame: transport rate and curvature (eqs. 1.5–1.6; printed coefficient and sign: typos)",
        "^003-G",
    ),
    Case("004-A", "reduced measurements eqs. 19–21, cond(S)", "^004-A"),
    Case("004-B", "platform-angle reconstruction eqs. 3–5", "^004-B"),
    Case("004-C", "level-flight accelerometer measurement eqs. 6–8", "^004-C"),
    Case("004-D", "Ts-060K improvements 44/65/11 % (no data: simulated analogue)", "^004-D"),
)

BOOK_CASES: tuple[Case, ...] = (
    Case("1", "Table 2.1, single-axis revolution", "^Table 2.1$"),
    Case("2", "Ex 2.1 angle-error series", "^Ex 2.1$"),
    Case("3", "Table 2.2, δλ¹, δλ², δλ²_m", "^Table 2.2$", "^δλ[¹²]"),
    Case("4", "Table 2.2, δλ³ (start-up ∇θ₀ = 0)", "^Table 2.2$", "^δλ³"),
    Case("5", "optimal q for Ex 2.3", "^Optimal q", "0.0939|numerically"),
    Case("6", "q* formula (2.31), both forms", "^Optimal q", r"^q\*"),
    Case("7", "Table 2.3 formula rows (2.32)", r"^Table 2.3 \(formula"),
    Case("8", "Table 2.4 formula rows (2.33)", r"^Table 2.4 \(formula"),
    Case("9", "Table 2.3 II / Table 2.4 γ = 0 simulated drift", r"^Table 2.[34] \(simulation", "II|γ ?= ?0°?[,)]"),
    Case("10", "Table 2.3 I simulated drift", r"^Table 2.3 \(simulation", "case I,"),
    Case("11", "Table 2.4 lower rows γ = 30…90°", r"^Table 2.4 \(simulation", "γ ?= ?(30|45|60|90)"),
    Case("12", "Ex 2.4 constants", "^Ex 2.4 constants"),
    Case("13", "Ex 2.5 constants and outcomes (Ex 2.6 λ: discrepancy)", "^Ex 2.5/2.6"),
    Case("2.7", "Ex 2.7: Ex 2.4 with 12 accelerometers, μ = 7, ode45 (not in §8's list; figure only)", "^Ex 2.7 "),
    Case("14", "ch. 3 scenario constants", "^Ch. 3 scenario constants"),
    Case("15", "WMM example (3.31)–(3.33)", "^WMM example"),
    Case("16", "operation counts 516 / 29 154 (flops figures: no MATLAB 5)", "^§3.1.4"),
    Case("17", "Ex 4.1 refined alignment (a)–(c); the draw (d) is not given", "^Ex 4.1"),
    Case("18", "Table 4.1 reference rates", "^Tables 4.1, 4.2", "Table 4.1"),
    Case("19", "Table 4.2 decomposition", "^Tables 4.1, 4.2", "sym|skew"),
    Case(
        "20",
        "accelerometer calibration: the printed A's decomposition (eqs. 4.18–4.21)",
        "^§4.2.1 accelerometer",
        why="the estimate of A itself needs the raw data (not in the book); its printed decomposition is checked",
    ),
    Case("4.9", "error-growth formula (4.9) against a strapdown simulation (not in §8's list)", "^Book eq. 4.9"),
    Case("21", "Ex 5.1 / Table 5.1 SVD isolation", "^Ex 5.1–5.4", "^Table 5.1"),
    Case("22", "Ex 5.3 Z matrix", "^Ex 5.1–5.4", "^Ex 5.3: max"),
    Case("23", "Ex 5.3 isolation logic and run (a₁ unit: discrepancy)", r"^Ex 5.1–5.4|^Ex 5.3 \(", "â₁|isolating"),
    Case("24", "Table 5.3 determinant isolation", "^Ex 5.1–5.4", "^Table 5.3"),
    Case(
        "25",
        "Table 5.2: decisions, and our recursive-LS isolation rate (Monte Carlo; magnitudes: unknown draw)",
        "^Ex 5.1–5.4",
        "^Table 5.2",
    ),
    Case("26", "observability ranks", "observability ranks"),
    Case("27", "Ex 3.1–3.3 / 5.3 closed loops", r"^Ex 3\.[123] |^Ex 5.3 \("),
    Case(
        "28a",
        "§6.1 static lab test",
        "^Book §6.1",
        why="simulated analogue (white noise of the book's sensor grades, no Earth rate, the GPS's 0.3 m mean error): "
        "its rows are discrepancies held at our values, not passes",
    ),
    Case(
        "28b",
        "§6.2 rotating-table statistics vs GrafNav (mean/std/max N/E/D)",
        why="not reproduced: the errors are of a real receiver (1.1 m mean bias) against a ±12 cm post-processed "
        "reference; no data, and our simulator has no receiver bias model to compare",
    ),
    Case(
        "28c",
        "§6.3 walking, §6.4 car test",
        why="figures only, no numbers; our real drive (docs/accuracy.md) is the analogue, not a row",
    ),
    Case("28d", "§6.5 flight Exp. 1: 20-s outage maxima", "^Book §6.5", why="simulated analogue (discrepancies)"),
    Case(
        "28e",
        "§6.5 flight RMS (static/dynamic); Exp. 2 and the IG-500N specification",
        why="not reproduced: RMS relative to the flight's own GNSS, no data; the analogues are the shipped PX4 / "
        "ArduPilot logs (docs/design/flight_log_findings.md; other vehicles and sensors, not rows); the IG-500N "
        "figures are a vendor specification, not a result",
    ),
    Case("29–31", "chapter 2 identities", why="identities, tested in tests/test_book_ch2.py, not rows"),
    Case("32–33", "gyro-free identities", "^Ex 2.4 constants", "rank|det"),
    Case("34–35", "QR-form and Φ identities", why="identities, tested in tests/test_fusion_sqrt.py, not rows"),
    Case("36", "QR / singular-r / Joseph / conventional agree", "^§3.1.2"),
    Case(
        "37–39",
        "magnetometer, calibration, FDI identities",
        why="identities, tested in tests/test_fusion.py, test_calibration.py, test_fdi_book.py",
    ),
)


def status(case: Case, rows: list[Row]) -> str:
    """ "n pass", "n pass, m discrepancies", "… k FAIL" or "not a row"."""
    rs = case.rows(rows)
    if case.group is None:
        return "not a row"
    if not rs:
        return "**no rows matched**"
    p = sum(r.status == "pass" for r in rs)
    d = sum(r.status == "discrepancy" for r in rs)
    f = len(rs) - p - d
    parts = [f"{p} pass"] + ([f"{d} discrepancy" if d == 1 else f"{d} discrepancies"] if d else [])
    return ", ".join(parts + ([f"**{f} FAIL**"] if f else []))


def counts(rows: list[Row]) -> dict[str, int]:
    """How many cases are rows (all passing / with a discrepancy) and how many are not rows."""
    out = {"cases": 0, "all pass": 0, "with discrepancies": 0, "not rows": 0}
    for c in SEED_CASES + BOOK_CASES:
        out["cases"] += 1
        rs = c.rows(rows)
        if c.group is None:
            out["not rows"] += 1
        elif all(r.status == "pass" for r in rs):
            out["all pass"] += 1
        else:
            out["with discrepancies"] += 1
    return out


def markdown(rows: list[Row]) -> str:
    """The coverage table as a Markdown section (status computed from ``rows``)."""
    n = counts(rows)
    lines = [
        "## Digest cases: covered and not covered",
        "",
        f"{n['cases']} entries of the digests' case lists: {n['all pass']} reproduced with every row passing, "
        f"{n['with discrepancies']} with rows reported as discrepancies, {n['not rows']} not rows (reason given).",
        "",
    ]
    for title, cases in (("DIGEST_001_004 §6 (seeds 001–004)", SEED_CASES), ("DIGEST_000 §8 (the book)", BOOK_CASES)):
        lines += [f"### {title}", "", "| case | what | status | rows in | note / why not |", "|---|---|---|---|---|"]
        for c in cases:
            rs = c.rows(rows)
            where = "; ".join(dict.fromkeys(r.group for r in rs)).replace("|", "\\|") if rs else "—"
            lines.append(f"| {c.id} | {c.what} | {status(c, rows)} | {where} | {c.why} |")
        lines.append("")
    return "\n".join(lines)
