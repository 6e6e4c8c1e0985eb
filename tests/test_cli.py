"""The `ins-hil` entry point."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import pytest


def test_help_lists_commands() -> None:
    out = subprocess.run([sys.executable, "-m", "ins_hil", "--help"], capture_output=True, text=True, check=True)
    assert "demo" in out.stdout and "run" in out.stdout


def test_demo_short_run_prints_errors() -> None:
    out = subprocess.run(
        [sys.executable, "-m", "ins_hil", "demo", "--duration", "20", "--rate", "100"],
        capture_output=True,
        text=True,
        check=True,
    )
    assert "worst: attitude" in out.stdout
    worst = out.stdout.strip().splitlines()[-1]
    pos = float(worst.split("position")[1].split("m")[0])
    assert pos < 0.01


def test_bad_argument_is_a_clear_error() -> None:
    out = subprocess.run([sys.executable, "-m", "ins_hil", "demo", "--duration", "-1"], capture_output=True, text=True)
    assert out.returncode != 0 and "positive" in out.stderr


@pytest.mark.slow  # two 1 s bench runs, ~20 s with the start-up
def test_runtime_bench_writes_nothing_unless_asked(tmp_path: Path) -> None:
    """`python -m ins_hil.bench.latency` prints the figures; only --out (or --docs) writes a report."""
    docs = Path(__file__).resolve().parent.parent / "docs"
    tracked = {p: (p.read_bytes(), p.stat().st_mtime_ns) for p in (docs / "runtime.md", docs / "runtime_latency.png")}
    cmd = [sys.executable, "-m", "ins_hil.bench.latency", "--duration", "1", "--no-c"]
    r = subprocess.run(cmd, capture_output=True, text=True, cwd=tmp_path, timeout=120)
    assert r.returncode == 0, r.stderr
    assert "| arrival → state ready |" in r.stdout
    assert {p: (p.read_bytes(), p.stat().st_mtime_ns) for p in tracked} == tracked
    assert list(tmp_path.iterdir()) == []
    out = tmp_path / "report" / "runtime.md"
    r = subprocess.run([*cmd, "--out", str(out)], capture_output=True, text=True, cwd=tmp_path, timeout=120)
    assert r.returncode == 0, r.stderr
    assert out.read_text().startswith("# Runtime") and (out.parent / "runtime_latency.png").stat().st_size > 0
    assert {p: (p.read_bytes(), p.stat().st_mtime_ns) for p in tracked} == tracked
