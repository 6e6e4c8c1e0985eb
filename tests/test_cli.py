"""The `ins-hil` entry point."""

from __future__ import annotations

import subprocess
import sys


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
