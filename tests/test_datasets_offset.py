"""IMU–GNSS time offset from the data (ins_hil.datasets.offset) on a simulated flight with a known offset."""

from __future__ import annotations

import dataclasses
import math
from pathlib import Path

import numpy as np
import pytest

from ins_hil.datasets import config as dcfg
from ins_hil.datasets.dataset import Dataset
from ins_hil.datasets.offset import estimate_imu_offset
from ins_hil.sim import sensors as se
from ins_hil.sim import trajectory as tr


def _flight(offset: float, seed: int, seconds: float = 150.0) -> Dataset:
    """The simulated UAV mission (MEMS IMU 100 Hz, RTK-grade GNSS 5 Hz) with its IMU stamped ``offset`` s
    early: the offset to find is +offset."""
    rng = np.random.default_rng(seed)
    truth = tr.generate(tr.mission_profile(), seconds, 0.01, math.radians(45.0), math.radians(7.0), 100.0)
    imu = se.corrupt_imu(truth, se.mems_gyro(rng), se.mems_accel(rng), seed=rng).samples()
    fixes = se.gnss_fixes(truth, se.GnssModel(rate=5.0, std_ne=0.02, std_d=0.04, std_vel=0.02), seed=rng)
    return Dataset([dataclasses.replace(s, t=s.t - offset) for s in imu], list(fixes))


def _cfg() -> dcfg.DatasetConfig:
    c = dcfg.from_dict({"dataset": {"name": "sim"}})
    c.use_mag = c.use_baro = False
    return c


@pytest.mark.slow  # 11 replays of a 150-s flight each (~20 s on an idle 2-core machine)
@pytest.mark.parametrize(("offset", "seed"), [(0.06, 3), (-0.04, 5)])
def test_offset_found_within_its_uncertainty(offset: float, seed: int) -> None:
    steps: list[int] = []
    est = estimate_imu_offset(_flight(offset, seed), _cfg(), span_s=0.15, step_s=0.03, settle_s=20.0,
                              progress=lambda k, n: steps.append(k))  # fmt: skip
    assert steps == list(range(1, len(est.grid_s) + 1))
    # measured: +60 ms → +51.3 ± 7.6 ms, −40 ms → −45.4 ± 6.6 ms; returning the config's 0 would fail
    assert math.isfinite(est.offset_s) and 0.0 < est.std_s < 0.02
    assert abs(est.offset_s - offset) < 3.0 * est.std_s + 0.005
    assert "ms ±" in est.summary()


def test_offset_outside_the_search_is_said() -> None:
    est = estimate_imu_offset(_flight(0.2, 3, 100.0), _cfg(), span_s=0.06, step_s=0.03, settle_s=20.0)
    assert math.isnan(est.offset_s) and "above" in est.reason and "widen" in est.summary()


def test_offset_needs_gnss_and_outages() -> None:
    ds = _flight(0.0, 3, 60.0)
    with pytest.raises(ValueError, match="no GNSS"):
        estimate_imu_offset(dataclasses.replace(ds, gnss=[]), _cfg())
    with pytest.raises(ValueError, match="at least 3"):
        estimate_imu_offset(ds, _cfg(), window=(0.0, 40.0))


def test_write_offset_keeps_the_rest_of_the_config(tmp_path: Path) -> None:
    from ins_hil.datasets.offset import write_offset

    p = tmp_path / "a.toml"
    p.write_text('[dataset]\nname = "a"  # x\n\n[mounting]\n# the antenna\ngnss_lever_arm_m = [0, 0, -0.1]\n'
                 "imu_time_offset_s = 0.01\n\n[outages]\non_s = 5.0\n")  # fmt: skip
    write_offset(p, -0.0371)
    text = p.read_text()
    assert "imu_time_offset_s = -0.0371" in text and "0.01" not in text
    assert "# x" in text and "# the antenna" in text and "on_s = 5.0" in text
    assert dcfg.load(p).imu_time_offset == pytest.approx(-0.0371)
    q = tmp_path / "b.toml"
    q.write_text('[dataset]\nname = "b"\n')
    write_offset(q, 0.02)
    assert dcfg.load(q).imu_time_offset == pytest.approx(0.02)
    r = tmp_path / "c.toml"
    r.write_text('[dataset]\nname = "c"\n[mounting]\ngnss_lever_arm_m = [0, 0, 0]\n')
    write_offset(r, 0.03)
    assert dcfg.load(r).imu_time_offset == pytest.approx(0.03)


@pytest.mark.slow  # 7 replays of a 110-s flight
def test_estimate_offset_command(tmp_path: Path, capsys) -> None:
    from ins_hil.cli import main
    from ins_hil.datasets import generic_csv

    data = tmp_path / "flight.csv"
    generic_csv.write_generic_csv(data, _flight(0.06, 3, 110.0))
    cfg = tmp_path / "flight.toml"
    cfg.write_text('[dataset]\nname = "flight"\n[aiding]\nbaro = false\nmag = false\n')
    rc = main(["replay", str(data), "--dataset", str(cfg), "--estimate-offset", "--offset-span", "0.12",
               "--offset-step", "0.04", "--write-offset", "--quiet"])  # fmt: skip
    text = capsys.readouterr().out
    assert rc == 0 and "IMU time offset:" in text and text.count(" m²") == 7
    assert 0.0 < dcfg.load(cfg).imu_time_offset < 0.12  # written: the +60 ms offset, not the config's 0
