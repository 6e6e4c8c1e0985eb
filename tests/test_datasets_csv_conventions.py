"""The generic CSV's conventions (issue 40): its IMU and magnetometer columns are in the IMU's axes and the dataset
config's ``[mounting] imu_to_body_deg`` takes them to body FRD (identity by default), in the documented direction;
an optional take-off / landing ``event`` record; the replay without a dataset config says so in a note."""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest

from ins_hil.datasets import generic_csv, report
from ins_hil.datasets.config import DatasetConfig, load
from ins_hil.datasets.dataset import Dataset, DatasetError, read_dataset
from ins_hil.datasets.run import prepare
from ins_hil.types import BaroSample, FixType, GnssFix, ImuSample, MagSample

MAGIC = "# ins-hil dataset csv 1"


def _at_rest(seconds: float = 3.0) -> Dataset:
    n = int(seconds * 100)
    f = np.array((0.3, 0.0, -9.8))  # a small x specific force: where it goes shows the rotation
    imu = [ImuSample(0.01 * k, 0.01, np.array((1e-5, 0.0, 0.0)), f * 0.01) for k in range(1, n + 1)]
    gnss = [GnssFix(0.2 * k, 0.8, 0.2, 300.0, np.zeros(3), 1.0, 2.0, 0.2, FixType.FIX_3D, 9)
            for k in range(int(seconds * 5))]  # fmt: skip
    baro = [BaroSample(0.1 * k, math.nan, 300.0) for k in range(int(seconds * 10))]
    mag = [MagSample(0.1 * k, np.array((2e-5, 0.0, 4e-5))) for k in range(int(seconds * 10))]
    return Dataset(imu, gnss, baro, mag, events=[(1.0, "takeoff"), (2.5, "landing")])


def _config(tmp_path: Path, mounting: str) -> DatasetConfig:
    p = tmp_path / "c.toml"
    p.write_text(
        f'[dataset]\nname = "t"\n[mounting]\nimu_to_body_deg = {mounting}\n[aiding]\nmag_reference = [20, 0, 40]\n'
    )
    return load(p)


def test_events_round_trip_and_bad_events_are_one_line(tmp_path: Path):
    p = tmp_path / "d.csv"
    generic_csv.write_generic_csv(p, _at_rest())
    ds = read_dataset(p)
    assert ds.event("takeoff") == pytest.approx(1.0) and ds.event("landing") == pytest.approx(2.5)
    bad = tmp_path / "bad.csv"
    for line in ("event,1.0,liftoff", "event,nan,takeoff", "event,1.0", "event,x,takeoff", "event,1,takeoff,2"):
        bad.write_text(f"{MAGIC}\nimu,0.01,0.01,0,0,0,0,0,-9.8\n{line}\n")
        with pytest.raises(DatasetError, match=rf"{bad}:3: event: expected t .* takeoff, landing") as e:
            read_dataset(bad)
        assert "\n" not in str(e.value)


def test_the_outage_protocol_counts_from_the_csv_take_off(tmp_path: Path):
    p = tmp_path / "d.csv"
    generic_csv.write_generic_csv(p, _at_rest())
    assert read_dataset(p).event("takeoff") == pytest.approx(1.0)  # what OutageProtocol(relative_to="takeoff") uses


def test_csv_imu_is_in_the_imu_axes_and_the_mounting_takes_it_to_body(tmp_path: Path):
    p = tmp_path / "d.csv"
    generic_csv.write_generic_csv(p, _at_rest())
    ds = read_dataset(p)
    f_imu = ds.imu[10].dvel / ds.imu[10].dt
    plain = prepare(ds, DatasetConfig(name="t"))  # no mounting: the IMU's axes are body FRD
    assert np.allclose(plain.imu[10].dvel / plain.imu[10].dt, f_imu)
    # yaw = +90°: the IMU's x axis points to the body's right, so its x reading is body +y
    yawed = prepare(ds, _config(tmp_path, "[0, 0, 90]"))
    assert np.allclose(yawed.imu[10].dvel / yawed.imu[10].dt, (0.0, 0.3, -9.8), atol=1e-9)
    # roll = 180°: the IMU upside down, its z up: a level IMU would read +9.8 on z, the body −9.8
    flipped = prepare(ds, _config(tmp_path, "[180, 0, 0]"))
    assert np.allclose(flipped.imu[10].dvel / flipped.imu[10].dt, (0.3, 0.0, 9.8), atol=1e-9)
    mag = [a for a in yawed.aux if isinstance(a, MagSample)]
    assert np.allclose(mag[0].field_b, (0.0, 2e-5, 4e-5), atol=1e-12)  # the magnetometer too
    # a list: the first rotation to the IMU's axes first (C = R2 R1): yaw 90 then roll 180
    both = prepare(ds, _config(tmp_path, "[[0, 0, 90], [180, 0, 0]]"))
    assert np.allclose(both.imu[10].dvel / both.imu[10].dt, (0.0, -0.3, 9.8), atol=1e-9)


def test_a_replay_without_a_dataset_config_says_so(tmp_path: Path):
    p = tmp_path / "d.csv"
    generic_csv.write_generic_csv(p, _at_rest())
    m, text = report.replay_to_dir(p, None, tmp_path / "out", plots=False)
    assert f"note: {report.NO_CONFIG_NOTE}" in text.splitlines() and m["notes"][0] == report.NO_CONFIG_NOTE
    c = tmp_path / "c.toml"
    c.write_text('[dataset]\nname = "t"\n')
    _, text = report.replay_to_dir(p, c, tmp_path / "out2", plots=False)
    assert "no dataset config" not in text
