"""IMU–GNSS time offset from the data (ins_hil.datasets.offset) on a simulated flight with a known offset."""

from __future__ import annotations

import dataclasses
import functools
import math
from pathlib import Path

import numpy as np
import pytest

from ins_hil.datasets import config as dcfg
from ins_hil.datasets.dataset import Dataset
from ins_hil.datasets.offset import GridEstimate, estimate_imu_offset
from ins_hil.sim import sensors as se
from ins_hil.sim import trajectory as tr


@functools.cache  # one flight per (offset, seed, seconds) in this process: the estimates do not change it
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


@functools.cache  # the +60 ms search is also the coarse-to-fine one of the test below: run once
def _found(offset: float, seed: int) -> tuple[GridEstimate, list[int]]:
    """The coarse-to-fine search (±150 ms in 30-ms steps) on ``_flight(offset, seed)``: (estimate, progress calls)."""
    steps: list[int] = []
    est = estimate_imu_offset(_flight(offset, seed), _cfg(), span_s=0.15, step_s=0.03, settle_s=20.0,
                              progress=lambda k, n: steps.append(k))  # fmt: skip
    return est, steps


@pytest.mark.slow  # 11 replays of a 150-s flight each (~20 s on an idle 2-core machine)
@pytest.mark.parametrize(("offset", "seed"), [(0.06, 3), (-0.04, 5)])
def test_offset_found_within_its_uncertainty(offset: float, seed: int) -> None:
    est, steps = _found(offset, seed)
    assert steps == list(range(1, len(est.grid) + len(est.coarse_grid) + 1))  # one call per replay, coarse and fine
    # measured: +60 ms → +51.3 ± 7.6 ms, −40 ms → −45.4 ± 6.6 ms; returning the config's 0 would fail
    assert math.isfinite(est.value) and 0.0 < est.std < 0.02
    assert abs(est.value - offset) < 3.0 * est.std + 0.005
    assert "ms ±" in est.summary()


@pytest.mark.slow  # 11 full replays of a 150-s flight, then 6 decimated and 5-7 full
def test_coarse_to_fine_search_finds_the_exhaustive_offset_with_fewer_full_replays() -> None:
    """The coarse stage (every other candidate, IMU decimated, baro thinned) puts the fine full replays around the
    minimum: the same vertex, from the same replays, as replaying every candidate in full."""
    from ins_hil.datasets.offset import decimate

    ds = _flight(0.06, 3)
    full = estimate_imu_offset(ds, _cfg(), span_s=0.15, step_s=0.03, settle_s=20.0, exhaustive=True)
    fast, _ = _found(0.06, 3)  # the same search on the same flight as test_offset_found_within_its_uncertainty
    assert len(full.grid) == 11 and not len(full.coarse_grid)
    assert len(fast.coarse_grid) == 6 and 5 <= len(fast.grid) <= 7
    assert math.isfinite(fast.value) and fast.value == full.value
    i = np.searchsorted(full.grid, fast.grid[0] - 1e-12)
    assert np.array_equal(fast.cost_m2, full.cost_m2[i : i + len(fast.grid)])  # the same full replays
    assert "coarse (decimated replays)" in "\n".join(fast.table())
    d = decimate(ds, 50.0)
    assert len(d.imu) == len(ds.imu) // 2 and d.imu[0].dt == pytest.approx(0.02)


@pytest.mark.slow  # 12 s on a busy 2-core machine
def test_offset_outside_the_search_is_said() -> None:
    est = estimate_imu_offset(_flight(0.2, 3, 100.0), _cfg(), span_s=0.06, step_s=0.03, settle_s=20.0)
    assert math.isnan(est.value) and "above" in est.reason and "widen" in est.summary()


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


def _car(mount_yaw_deg: float, seed: int, seconds: float = 120.0) -> Dataset:
    """The simulated weaving car (MEMS IMU 100 Hz, RTK-grade GNSS 5 Hz) with its IMU mounted yawed by
    ``mount_yaw_deg`` about the body z axis (C_s^b = R_z(yaw)): the mounting yaw to find."""
    from ins_hil.nav.rotation import dcm_from_euler

    rng = np.random.default_rng(seed)
    truth = tr.generate(tr.car_profile(t_start=2.0, t_stop=seconds - 10.0), seconds, 0.01, math.radians(45.0),
                        math.radians(7.0), 100.0)  # fmt: skip
    imu = se.corrupt_imu(truth, se.mems_gyro(rng), se.mems_accel(rng), seed=rng).samples()
    C_bs = dcm_from_euler(0.0, 0.0, math.radians(mount_yaw_deg)).T  # body → IMU axes
    imu = [dataclasses.replace(s, dtheta=C_bs @ s.dtheta, dvel=C_bs @ s.dvel) for s in imu]
    fixes = se.gnss_fixes(truth, se.GnssModel(rate=5.0, std_ne=0.02, std_d=0.04, std_vel=0.02), seed=rng)
    return Dataset(imu, list(fixes))


@pytest.mark.slow  # 9 replays of a 120-s drive
def test_mounting_yaw_found_on_a_car_with_the_nhc() -> None:
    """A 3° mounting yaw: the NHC turns it into a lateral velocity, so the outages find it; the config's 0 is
    outside the estimate's uncertainty."""
    from ins_hil.datasets.offset import estimate_mounting_yaw

    c = dcfg.from_dict({"dataset": {"name": "car"}, "nav": {"aids": {"nhc": True}}})
    c.use_mag = c.use_baro = False
    est = estimate_mounting_yaw(_car(3.0, 4), c, span=math.radians(4.0), step=math.radians(1.0), settle_s=20.0)
    assert math.isfinite(est.value) and 0.0 < est.std < math.radians(1.0), est.summary()
    assert abs(math.degrees(est.value) - 3.0) < 3.0 * math.degrees(est.std) + 0.5, est.summary()
    assert abs(est.value) > 3.0 * est.std and "°" in est.summary()


@pytest.mark.slow  # 5 replays of a 100-s flight
def test_mounting_yaw_of_a_flight_without_the_nhc_is_said_to_be_unobservable(tmp_path: Path, capsys) -> None:
    """Nothing ties a multirotor's body axes to its motion: the cost is flat, the command says so, writes
    nothing and exits 2 when asked to write."""
    from ins_hil.cli import main
    from ins_hil.datasets import generic_csv

    data = tmp_path / "flight.csv"
    generic_csv.write_generic_csv(data, _flight(0.0, 3, 100.0))
    cfg = tmp_path / "flight.toml"
    cfg.write_text('[dataset]\nname = "flight"\n[aiding]\nbaro = false\nmag = false\n')
    before = cfg.read_text()
    rc = main(["replay", str(data), "--dataset", str(cfg), "--estimate-mounting", "--mounting-span", "2",
               "--mounting-step", "1", "--write-mounting", "--quiet"])  # fmt: skip
    out, err = capsys.readouterr()
    assert rc == 2 and "mounting yaw: not found (not observable on this log" in out
    assert "--write-mounting needs --dataset and an estimate" in err and cfg.read_text() == before


def test_write_mounting_yaw_sets_the_last_rotation_and_keeps_the_rest(tmp_path: Path) -> None:
    from ins_hil.datasets.offset import write_mounting_yaw

    p = tmp_path / "a.toml"
    p.write_text('[dataset]\nname = "a"\n\n[mounting]\n'
                 "imu_to_body_deg = [[180.0, 0.0, 180.0], [0.0, -6.79, 5.35]]  # mount, then the misalignment\n"
                 "gnss_lever_arm_m = [0, 0, -0.1]\n\n[outages]\non_s = 5.0\n")  # fmt: skip
    write_mounting_yaw(p, dcfg.load(p), math.radians(4.47))
    text = p.read_text()
    assert "imu_to_body_deg = [[180.00, 0.00, 180.00], [0.00, -6.79, 4.47]]  # mount, then the misalignment" in text
    assert "gnss_lever_arm_m = [0, 0, -0.1]" in text and "on_s = 5.0" in text
    np.testing.assert_allclose(np.degrees(dcfg.load(p).imu_to_body[-1]), [0.0, -6.79, 4.47], atol=1e-9)
    q = tmp_path / "b.toml"
    q.write_text('[dataset]\nname = "b"\n')
    write_mounting_yaw(q, dcfg.load(q), math.radians(-2.0))
    np.testing.assert_allclose(np.degrees(dcfg.load(q).imu_to_body[-1]), [0.0, 0.0, -2.0], atol=1e-9)
