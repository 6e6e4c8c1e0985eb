"""The published σ covers the error on the simulated default flight (configs/default.toml's [sim]: UAV at
20 m/s, MEMS IMU, GNSS 5 Hz 50 ms late, baro 25 Hz), flown offline through the default pipeline over a
few seeds: position and velocity NEES (all three axes, horizontal and vertical) inside the χ² 95 % band,
the horizontal error inside 3σ_h in ≥ 99 % of the epochs, no lag bias; and ``ins-hil replay`` of a
recording of such a run reports them against the simulator's truth regenerated from the header."""

from __future__ import annotations

import json
import re
from pathlib import Path

import pytest
from ins_hil.drivers.serial_frame import decode, encode
from runtime_helpers import sim_config_dict

from ins_hil.cli import main
from ins_hil.config import from_dict
from ins_hil.evaluation.sim_flight import monte_carlo_sim, sim_truth
from ins_hil.runtime.recorder import Recorder
from ins_hil.runtime.replay import check_imu
from ins_hil.sim.devices import send_order
from ins_hil.types import ImuSample

SEEDS = [200, 201, 202]


@pytest.fixture(scope="module")
def mc() -> dict:
    return monte_carlo_sim(sim_config_dict(), SEEDS, duration=32.0, t_from=16.0)


@pytest.mark.slow
def test_sigma_is_consistent_with_the_error(mc: dict) -> None:
    for name in ("pos", "vel", "pos_ne", "vel_ne", "pos_d", "vel_d"):
        lo, hi = mc[f"nees_{name}_band_95"]
        assert lo <= mc[f"nees_{name}"] <= hi, (name, mc[f"nees_{name}"], lo, hi)
    assert mc["cover_3sigma_min"] >= 0.99, mc["runs"]
    assert abs(mc["along_bias_m"]) < 0.1


def _record(path: Path, seconds: float, tamper_t: float) -> None:
    """A recording of the default simulated run as the gateway writes it: the config in the header, the
    IMU samples through the serial frame (float32 increments, µs stamps), every input in send order; the
    IMU sample at ``tamper_t`` altered by 1 µrad (it must be reported as not matching the truth)."""
    cfg = from_dict(sim_config_dict(), "test")
    rec = Recorder(path, header={"config": cfg.to_dict(), "pipeline": cfg.to_dict()["pipeline"]})
    for s in send_order(cfg.sim, seconds):
        if isinstance(s, ImuSample):
            s = decode(encode(s))
            if abs(s.t - tamper_t) < 1e-4:
                s.dtheta = s.dtheta + 1e-6
        rec.write(s)
    rec.close()


@pytest.mark.slow
def test_replay_of_a_simulated_recording_reports_the_error_against_truth(tmp_path: Path, capsys) -> None:
    log = tmp_path / "sim.ihlog"
    _record(log, 30.0, tamper_t=29.5)
    assert main(["replay", str(log), "--quiet"]) == 0
    out = capsys.readouterr().out
    m = re.search(r"(\d+)/(\d+) matched, 1 differ", out)
    assert m and m.group(1) == m.group(2) and int(m.group(1)) > 29000, out
    m = re.search(r"along-track bias ([-+.\d]+) m, horizontal RMS ([.\d]+) m.*NEES position ([.\d]+) velocity "
                  r"([.\d]+).*inside 3σ_h ([.\d]+) %", out)  # fmt: skip
    assert m, out
    bias, rms, _, _, cover = (float(x) for x in m.groups())
    assert abs(bias) < 0.1 and 0.0 < rms < 0.5 and cover >= 99.0, out


def test_check_imu_matches_the_regenerated_samples_bit_for_bit() -> None:
    cfg = from_dict(sim_config_dict(), "test")
    truth = sim_truth(cfg.sim, 2.0)
    imu = [decode(encode(s)) for s in send_order(cfg.sim, 2.0) if isinstance(s, ImuSample)]
    assert check_imu(truth, imu) == {"samples": len(imu), "matched": len(imu), "equal": len(imu), "max_abs_diff": 0.0}
    imu[5].dvel = imu[5].dvel * (1 + 1e-6)
    assert check_imu(truth, imu)["equal"] == len(imu) - 1


def test_replay_sim_command_prints_the_figures(tmp_path: Path, capsys) -> None:
    assert main(["replay", "sim", "--runs", "1", "--seed", "203", "--duration", "20", "--out", str(tmp_path)]) == 0
    cap = capsys.readouterr()
    out = cap.out
    assert "along-track bias" in out and "mean NEES over the runs" in out and "3σ_h" in out
    # progress on stderr, a line a run (each flies its whole duration)
    assert [x for x in cap.err.splitlines() if x.startswith("  [1/1] seed 203: horizontal RMS ")], cap.err
    r = json.loads((tmp_path / "metrics.json").read_text())["sim"]
    assert r["seeds"] == [203] and len(r["runs"]) == 1
    # the figures of one short run, not just their ranges: the error inside 3σ_h (measured 100 % of 100 epochs),
    # position and velocity NEES (measured 2.6, 2.9) inside the 3-dof 95 % band
    assert r["runs"][0]["epochs"] == 100 and r["cover_3sigma"] >= 0.99, r
    for name in ("pos", "vel"):
        lo, hi = r[f"nees_{name}_band_95"]
        assert lo <= r[f"nees_{name}"] <= hi, (name, r)
    assert f"position (3 dof) {r['nees_pos']:.2f}" in out


def test_replay_sim_with_a_broken_config_is_one_line_on_stderr(tmp_path: Path, capsys) -> None:
    bad = tmp_path / "bad.toml"
    bad.write_text("[sim\n")
    assert main(["replay", "sim", "--config", str(bad), "--out", str(tmp_path / "o")]) == 2
    cap = capsys.readouterr()
    err = [x for x in cap.err.splitlines() if x.strip()]
    assert len(err) == 1 and str(bad) in err[0] and cap.out == "", (cap.out, cap.err)
