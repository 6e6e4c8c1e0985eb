"""`ins-hil demo platform-ins`: seed 004's platform INS end to end, with the four PNGs and a printed summary."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from ins_hil.cli import main
from ins_hil.platform_ins import testbed as tb


def test_demo_platform_ins_writes_plots_and_summary(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    out = tmp_path / "pins"
    assert main(["demo", "platform-ins", "--duration", "900", "--out", str(out)]) == 0
    text = capsys.readouterr().out
    for key in ("cond(S) =", "eq. 5 residual RMS", "reduced adaptive", "classical", "noise scales: Q"):
        assert key in text
    for name in ("platform_angles", "level_flight", "reduced", "adaptive"):
        assert (out / f"{name}.png").read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"


def test_demo_platform_ins_refuses_a_run_shorter_than_the_settling(capsys: pytest.CaptureFixture[str]) -> None:
    assert main(["demo", "platform-ins", "--duration", "100"]) == 2  # a bad argument: exit status 2, one line
    assert "at least" in capsys.readouterr().err


def test_histories_are_recorded_without_changing_the_estimates() -> None:
    cfg = tb.TestbedConfig(duration=900.0)
    res = tb.simulate(cfg)
    m = len(res.t_k)
    hq, hr = res.scale_hist["reduced adaptive"]
    assert hq.shape == hr.shape == (m, 3)
    assert np.allclose(hq[len(res.reduced) - 1], res.scales["reduced adaptive"][0])
    assert res.reduced.shape == (m - 2, 3) and res.z_phi.shape == res.z_acc.shape == res.gated.shape == (m,)
    # the reduced measurement of epoch k is S⁻¹(z_k, z_k+1, z_k+2) (eq. 21)
    k = 5
    assert np.allclose(res.reduced[k], res.s_inv @ res.z_phi[k : k + 3])
