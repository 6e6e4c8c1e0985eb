"""Which digest cases `ins-hil reproduce` covers, and why the others are not rows (DIGEST_000 §8, DIGEST_001_004 §6)."""

from __future__ import annotations

# (case, what, where it is a row / why it is not)
ROW = "row"
NOT = "not a row"

SEED_CASES: tuple[tuple[str, str, str, str], ...] = (
    ("001-A", "WGS84 derived constants", ROW, "Seed 001: WGS84, gravity, Earth rate (the core's nav.earth)"),
    ("001-B", "Somigliana normal gravity", ROW, "Seed 001: WGS84, gravity, Earth rate (the core's nav.earth)"),
    ("001-C", "series vs Somigliana gravity", ROW, "Seed 001: gravity series (printed β₁ = f²/4 shown as a typo)"),
    ("001-D", "height-dependent gravity", ROW, "Seed 001: WGS84, gravity, Earth rate (the core's nav.earth)"),
    ("001-E", "Earth rate 15.041 °/h", ROW, "Seed 001: WGS84, gravity, Earth rate (the core's nav.earth)"),
    ("001-F", "Schuler period", ROW, "Seed 001 Schuler oscillation"),
    ("001-G", "Schuler response", ROW, "Seed 001 Schuler oscillation"),
    ("001-H", "Euler/DCM/quaternion (ENU, y-x-z)", ROW, "Seed 001: converters `ins_hil.nav.enu` (the core stays NED)"),
    ("001-I", "attitude update", ROW, "Seed 001: eq. 61/63 with the core's quaternion functions"),
    (
        "001-J",
        "static coarse alignment eqs. 64–69",
        ROW,
        "Seed 001: `alignment.coarse_alignment_enu` (not a NavCore option)",
    ),
    (
        "001-K",
        "error-model Jacobian F",
        ROW,
        "Seed 001: F vs finite differences (ENU, in `reproduce`; not the core's F)",
    ),
    ("001-L", "Kalman update forms", ROW, "Seed 001: information vs covariance form"),
    ("002-A", "code ≡ formula", NOT, "identity, not a row"),
    ("002-B…002-I", "coning drift laws and ratios", ROW, "Seed 002 coning drift"),
    ("002-J", "phase dependence", ROW, "Seed 002 phase dependence"),
    ("002-K", "normalisation", ROW, "Seed 002 normalisation (norm growth per step)"),
    ("003-A…003-D", "derived guards against seed 003's typos", ROW, "Seed 003 (the thesis prints no results)"),
    ("004-A", "reduced measurements eqs. 19–21", ROW, "Seed 004"),
    ("004-B", "platform-angle reconstruction eqs. 3–5", ROW, "Seed 004"),
    ("004-C", "level-flight accelerometer measurement eqs. 6–8", ROW, "Seed 004"),
    ("004-D", "Ts-060K improvements 44/65/11 %", ROW, "discrepancy: no data, parameters or metric; simulated analogue"),
)

BOOK_CASES: tuple[tuple[str, str, str, str], ...] = (
    ("1–11", "chapter 2 tables 2.1–2.4, Ex 2.1–2.3", ROW, "Book ch. 2"),
    ("12–13", "Ex 2.4 / 2.5 constants; Ex 2.5/2.6 runs", ROW, "Book §2.4 (Ex 2.6 with λ = 7: discrepancy)"),
    ("14–15", "chapter 3 scenario constants, WMM example", NOT, "not yet a reproduction row"),
    ("16", "operation counts 516 / 29 154 (3.24)/(3.25)", ROW, "Book §3.1 (MATLAB flops figures not reproducible)"),
    ("17–19", "Ex 4.1, Tables 4.1–4.2", NOT, "not yet a reproduction row"),
    ("20", "accelerometer calibration results", NOT, "not reproducible: no raw data"),
    ("21–25", "Ex 5.1–5.3 isolation tables", NOT, "not yet reproduction rows (Ex 5.3 closed loop: case 27)"),
    ("26", "observability", NOT, "not yet a reproduction row"),
    (
        "27",
        "Ex 3.1–3.3 / 5.3 closed loops",
        ROW,
        "Book Ex 3.1–3.3 closed loops (Ex 3.2, 3.3: discrepancies) and Ex 5.3",
    ),
    ("28", "chapter 6 results", ROW, "§6.1 lab test: simulated analogue; 6.2–6.5: no data"),
    ("29–31", "chapter 2 identities", NOT, "identities, not rows"),
    ("32–33", "gyro-free identities", ROW, "Book §2.4"),
    ("34–35", "QR-form and Φ identities", NOT, "identities, not rows"),
    ("36", "QR / singular-r / Joseph / conventional agree", ROW, "Book §3.1 (singular-r variant)"),
    ("37–39", "magnetometer, calibration, FDI identities", NOT, "identities, not rows"),
)


def markdown() -> str:
    """The coverage list as a Markdown section."""
    lines = ["## Digest cases: covered and not covered", ""]
    for title, cases in (
        ("DIGEST_001_004 §6 (seeds 001–004)", SEED_CASES),
        ("DIGEST_000 §8 (the book)", BOOK_CASES),
    ):
        lines += [f"### {title}", "", "| case | what | in `reproduce` | where / why not |", "|---|---|---|---|"]
        for case, what, kind, why in cases:
            lines.append(f"| {case} | {what} | {'yes' if kind == ROW else 'no'} | {why} |")
        lines.append("")
    return "\n".join(lines)
