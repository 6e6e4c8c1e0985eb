"""The gateway's own recordings (``.ihlog``) in the dataset registry: a simulated run's log is replayed like any
data set, with the simulator's truth (regenerated from the header) as its reference."""

from __future__ import annotations

import json
from pathlib import Path

import pytest
from ins_hil.drivers.serial_frame import decode, encode
from runtime_helpers import sim_config_dict

from ins_hil.cli import main
from ins_hil.config import from_dict
from ins_hil.datasets import report
from ins_hil.datasets.config import from_dict as dataset_config
from ins_hil.datasets.dataset import DatasetError, detect_format, read_dataset
from ins_hil.runtime.recorder import Recorder
from ins_hil.sim.devices import send_order
from ins_hil.types import GnssFix, ImuSample


def _record(path: Path, seconds: float, sim: bool = True) -> None:
    """A recording of the default simulated run as the gateway writes it (config in the header, IMU through the
    serial frame, every input in send order); ``sim`` False: the header does not say the run was simulated."""
    cfg = from_dict(sim_config_dict(), "test")
    conf = cfg.to_dict()
    if not sim:
        conf["sim_enabled"] = False
    rec = Recorder(path, header={"config": conf, "pipeline": conf["pipeline"]})
    for s in send_order(cfg.sim, seconds):
        rec.write(decode(encode(s)) if isinstance(s, ImuSample) else s)
    rec.close()


@pytest.mark.slow
def test_ihlog_of_a_simulated_run_is_scored_against_the_truth(tmp_path: Path, capsys):
    from ins_hil.datasets import ihlog
    from ins_hil.evaluation.sim_flight import sim_truth

    ihlog.set_truth_source(sim_truth)  # what `ins-hil replay` installs (a library caller installs it itself)
    log = tmp_path / "sim.ihlog"
    _record(log, 20.0)
    assert detect_format(log) == "ihlog"
    ds = read_dataset(log)
    assert len(ds.imu) == 20000 and ds.meta["rates_hz"]["gnss"] == pytest.approx(5.0, rel=0.05)
    assert all(isinstance(f, GnssFix) for f in ds.gnss) and len(ds.baro) > 400
    assert ds.reference is not None and ds.reference.name == "simulator truth"
    m, _ = report.replay(ds, dataset_config({"dataset": {"name": "sim"}}))
    ref = m["reference"]
    assert isinstance(ref, dict) and ref["against"] == "simulator truth"
    # MEMS IMU, GNSS 1 m / 0.1 m/s at 5 Hz, 6 s of navigation: measured 0.45 m / 0.064 m/s over 30 s
    assert ref["position_m"]["horizontal"]["rms"] < 1.5
    assert ref["velocity_mps"]["horizontal"]["rms"] < 0.3
    # through the command: --dataset routes the log to the dataset replay (without it: the exact pipeline replay)
    toml = tmp_path / "sim.toml"
    toml.write_text('[dataset]\nname = "sim-log"\nformat = "ihlog"\n[score]\nagainst = ["gnss", "reference"]\n')
    out = tmp_path / "out"
    assert main(["replay", str(log), "--dataset", str(toml), "--out", str(out), "--no-plots", "--quiet"]) == 0
    text = capsys.readouterr().out
    assert "vs simulator truth: position horizontal" in text
    assert json.loads((out / "metrics.json").read_text())["format"] == "ihlog"


def test_ihlog_without_sim_has_no_reference_and_bad_logs_are_one_line(tmp_path: Path):
    log = tmp_path / "real.ihlog"
    _record(log, 1.0, sim=False)
    ds = read_dataset(log)
    assert ds.reference is None and len(ds.imu) >= 1000  # the simulator emits whole 10-s chunks
    bad = tmp_path / "bad.ihlog"
    bad.write_bytes(log.read_bytes()[:7] + b"\xff" * 40)
    with pytest.raises(DatasetError) as e:
        read_dataset(bad)
    assert "not a readable gateway log" in str(e.value) and "\n" not in str(e.value)
