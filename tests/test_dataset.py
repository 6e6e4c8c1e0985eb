"""The RTKLIB reader on the real drive with its dataset config: robust csv parsing, time tags and .pos, mounting,
the outage protocol and the study's held-out windows."""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest

from ins_hil.datasets import config as dataset_config
from ins_hil.datasets import rtklib as dd
from ins_hil.datasets import study
from ins_hil.datasets.dataset import DatasetError, detect_format, read_dataset
from ins_hil.datasets.evaluate import run_drive
from ins_hil.datasets.report import protocol_windows
from ins_hil.datasets.run import prepare

REPO = Path(__file__).resolve().parent.parent
DRIVE_TOML = REPO / "configs" / "datasets" / "drive0708.toml"


@pytest.fixture(scope="module")
def drive_dir(shared_dir: Path) -> Path:
    d = shared_dir / "data" / "gnss_imu_drive_0708"
    assert (d / "imu_1934.csv").is_file(), f"{d} lacks imu_1934.csv"
    return d


@pytest.fixture(scope="module")
def cfg() -> dataset_config.DatasetConfig:
    return dataset_config.load(DRIVE_TOML)


def _load(d: Path, c: dataset_config.DatasetConfig, **rtk: object) -> dd.Recording:
    """The drive with ``c``, ``rtk`` overriding [rtklib] keys."""
    import dataclasses

    return dd.load(d, dataclasses.replace(c, rtklib={**c.rtklib, **rtk}))


def test_imu_csv_skips_partial_first_and_last_lines(tmp_path: Path, drive_dir: Path):
    lines = (drive_dir / "imu_1934.csv").read_text().splitlines()[:50]
    text = "13,1.013,-0.671\n" + "\n".join(lines) + "\n0.100,0.022,1.0"  # partial first and last line
    p = tmp_path / "imu.csv"
    p.write_text(text + "\ngarbage,line,x,1,2,3,4\n")
    acc, gyro, tick, bad = dd.read_imu_csv(p)
    assert len(acc) == 50 and bad == 3
    assert tick[0] == 261906 and np.all(np.diff(tick) > 0)
    np.testing.assert_allclose(acc[0], (0.119, 0.027, 1.013))
    np.testing.assert_allclose(gyro[0], (-0.671, 3.082, 0.198))
    with pytest.raises(ValueError, match="no valid IMU line"):
        (tmp_path / "empty.csv").write_text("x\n")
        dd.read_imu_csv(tmp_path / "empty.csv")


def test_timetag_and_pos(drive_dir: Path):
    tag = dd.read_timetag(drive_dir / "imu_1934.csv.tag")
    assert tag.start == 1752003261  # 2025-07-08 19:34:21 GPST
    assert 0.0 <= tag.frac < 1.0
    assert np.all(np.diff(tag.ticks) >= 0) and 548.0 < tag.duration < 549.0
    pos = dd.read_pos(drive_dir / "gnss_1934_sf.pos")
    assert len(pos.t) == 2197
    assert int(np.sum(pos.q == 1)) == 2189 and int(np.sum(pos.q == 2)) == 8
    np.testing.assert_allclose(np.diff(pos.t), 0.25, atol=1e-3)
    assert math.degrees(pos.lat[0]) == pytest.approx(40.0966268, abs=1e-7)
    assert math.degrees(pos.lon[0]) == pytest.approx(-105.1474483, abs=1e-7)
    # the file's vu is up: NED down velocity is its negative (first epoch vu = 0.009 m/s)
    assert pos.vel_ned[0, 2] == pytest.approx(-0.009)
    with pytest.raises(ValueError, match=r"time-tag"):
        dd.read_timetag(drive_dir / "README.md")


def test_load_drive_mounting_time_and_outages(drive_dir: Path, cfg: dataset_config.DatasetConfig):
    rec = dd.load(drive_dir, cfg)
    dr = rec.dataset
    assert len(dr.imu) == 54859
    dts = np.array([s.dt for s in dr.imu])
    assert abs(np.median(dts) - 0.01) < 5e-4
    # the IMU covers the GNSS span (IMU time = GPST + offset −0.125 s)
    assert dr.imu[0].t < dr.gnss[0].t + 5 and dr.imu[-1].t > dr.gnss[-1].t
    # at rest (first 30 s) gravity is along body down after the mounting rotation: |horizontal| < 0.5 m/s²
    f = np.array([s.dvel / s.dt for s in dr.imu[:2000]]).mean(axis=0)
    assert f[2] < -9.7 and math.hypot(f[0], f[1]) < 0.5
    # without the residual misalignment, x would carry the −6.79° pitch (≈ 1.15 m/s²)
    import dataclasses

    R = dataclasses.replace(cfg, imu_to_body=cfg.imu_to_body[:1]).mounting_dcm()
    raw = rec.imu_log.acc[:2000].mean(axis=0) @ cfg.mounting_dcm().T.T  # back to sensor axes
    assert abs((R @ raw)[0]) > 1.0
    np.testing.assert_allclose(cfg.nav_config().gnss.lever_arm_b, (0.0, -0.05, 0.0))
    outs = protocol_windows(dr, prepare(dr, cfg), cfg)
    assert outs is not None and len(outs) == 11  # README: 11 outages
    assert outs[0][0] - rec.pos.t[0] == pytest.approx(40.0)
    assert all(b - a == pytest.approx(15.0) for a, b in outs)
    assert outs[-1][1] <= rec.pos.t[-1] - 30.0


def test_rtklib_reader_in_the_registry(drive_dir: Path, tmp_path: Path, cfg: dataset_config.DatasetConfig):
    """Detected from the folder; with no config: identity mounting and a note; names from the config."""
    assert detect_format(drive_dir) == "rtklib"
    ds = read_dataset(drive_dir)
    assert ds.meta["format"] == "rtklib" and any("no dataset config" in n for n in ds.meta["notes"])
    ds_cfg = read_dataset(drive_dir, "rtklib", cfg)
    assert ds_cfg.imu[100].t == pytest.approx(ds.imu[100].t - 0.24)  # the config's IMU time offset
    # prepare() applies only a config's difference from what the reader applied (e.g. a trial time offset)
    import dataclasses

    assert prepare(ds_cfg, cfg).imu[100] is ds_cfg.imu[100]
    shifted = prepare(ds_cfg, dataclasses.replace(cfg, imu_time_offset=-0.20)).imu[100]
    assert shifted.t == pytest.approx(ds_cfg.imu[100].t + 0.04) and np.array_equal(shifted.dvel, ds_cfg.imu[100].dvel)
    mount_only = dataclasses.replace(cfg, imu_to_body=cfg.imu_to_body[:1])  # without the residual misalignment
    turned = prepare(ds_cfg, mount_only).imu[100]
    v_sensor = cfg.mounting_dcm().T @ ds_cfg.imu[100].dvel
    np.testing.assert_allclose(turned.dvel, mount_only.mounting_dcm() @ v_sensor, atol=1e-12)
    # renamed files: found as the folder's only candidates, or named in the config; a wrong name is one line
    d = tmp_path / "renamed"
    d.mkdir()
    lines = (drive_dir / "imu_1934.csv").read_bytes().splitlines(keepends=True)
    (d / "imu.csv").write_bytes(b"".join(lines[:3000]))
    tag = (drive_dir / "imu_1934.csv.tag").read_bytes()
    (d / "imu.csv.tag").write_bytes(tag)
    (d / "sol.pos").write_bytes((drive_dir / "gnss_1934_sf.pos").read_bytes())
    with pytest.raises(ValueError, match="last byte offset"):  # the tags of the whole file
        read_dataset(d)
    with pytest.raises(DatasetError, match=r"imu_1934\.csv missing"):
        read_dataset(d, "rtklib", cfg)
    with pytest.raises(dataset_config.DatasetConfigError, match=r"rtklib\.time_map"):
        dataset_config.from_dict({"dataset": {"name": "x"}, "rtklib": {"time_map": "spline"}})
    with pytest.raises(dataset_config.DatasetConfigError, match=r"rtklib\.imu_columns"):
        dataset_config.from_dict({"dataset": {"name": "x"}, "rtklib": {"imu_columns": ["ax", "ay"]}})
    with pytest.raises(dataset_config.DatasetConfigError, match=r"unknown key rtklib\.imu"):
        dataset_config.from_dict({"dataset": {"name": "x"}, "rtklib": {"imu": "a.csv"}})


def test_rtklib_conventions_from_the_config(drive_dir: Path, tmp_path: Path):
    """Column layout and the up-velocity sign come from [rtklib]."""
    pos_up = dd.read_pos(drive_dir / "gnss_1934_sf.pos")
    pos_down = dd.read_pos(drive_dir / "gnss_1934_sf.pos", velocity_up=False)
    np.testing.assert_array_equal(pos_up.vel_ned[:, 2], -pos_down.vel_ned[:, 2])
    rows = [r.split(",") for r in (drive_dir / "imu_1934.csv").read_text().splitlines()[1:50]]
    p = tmp_path / "imu.csv"
    p.write_text("".join(",".join(r) + "\n" for r in rows))
    acc, gyro, tick, _ = dd.read_imu_csv(p)
    q = tmp_path / "swapped.csv"
    q.write_text("".join(",".join([r[6], *r[3:6], "0", *r[0:3]]) + "\n" for r in rows))
    a2, g2, k2, bad = dd.read_imu_csv(q, None, ["tick", "gx", "gy", "gz", "-", "ax", "ay", "az"])
    assert bad == 0 and len(a2) == len(rows)
    np.testing.assert_array_equal(a2, acc)
    np.testing.assert_array_equal(g2, gyro)
    np.testing.assert_array_equal(k2, tick)


def test_validation_windows_never_overlap_the_protocol(drive_dir: Path, cfg: dataset_config.DatasetConfig):
    _, p, proto = study.load(cfg, drive_dir)
    for shift in (15.0, 17.5, 22.5, 27.5, 30.0):
        val = study.shifted_windows(cfg, p, shift)
        assert len(val) >= 10
        assert not any(a < d and c < b for a, b in val for c, d in proto)
    with pytest.raises(ValueError, match="shift"):
        study.shifted_windows(cfg, p, 10.0)


def test_tag_arrival_counts_crlf_bytes(tmp_path: Path):
    """The tag offsets count the logged stream's bytes (CRLF line ends); the csv here has LF ends."""
    lines = [b"0.1,0.0,1.0,0.0,0.0,0.0,1000", b"0.1,0.0,1.0,0.0,0.0,0.0,1010", b"0.1,0.0,1.0,0.0,0.0,0.0,1020"]
    p = tmp_path / "imu.csv"
    p.write_bytes(b"\n".join(lines) + b"\n")
    ends: list[int] = []
    _, _, tick, _ = dd.read_imu_csv(p, ends)
    e = np.array(ends, dtype=float).reshape(-1, 2)
    n = len(lines[0]) + 2  # CRLF line length
    # records: (tick ms, file position reached): the second line completes at 2n bytes, received at 25 ms
    tag = dd.TimeTag(0, 0, 0.0, np.array((5.0, 25.0, 40.0)), np.array((n - 5.0, 2.0 * n, 3.0 * n)))
    arr = dd.tag_arrival_ms(tag, e[:, 0], e[:, 1], p.stat().st_size)
    np.testing.assert_allclose(arr, (25.0, 25.0, 40.0))
    t, c = dd.tag_time_map(tag, tick, arr)
    assert c == pytest.approx(-985.0)  # lower envelope: the third line arrived 20 ms after its tick
    np.testing.assert_allclose(t, (0.015, 0.025, 0.035))
    with pytest.raises(ValueError, match="CRLF"):
        dd.tag_arrival_ms(tag, e[:, 0], e[:, 1], p.stat().st_size - 40)


@pytest.mark.slow
def test_tag_time_map_is_consistent_with_the_rtk_course(drive_dir: Path, cfg: dataset_config.DatasetConfig):
    """Bug fixed in session 2: the upstream linear tick map assumes the first csv line arrived at the tag
    start (it arrived 115 ms later), so its time error drifts by ~130 ms over the drive. With the tag map
    (every line through its arrival tag) the gyro yaw rate matches the course of the RTK positions at one
    constant latency, the config's imu_time_offset_s, in both halves of the drive."""
    import dataclasses

    from ins_hil.nav import earth

    lags = {}
    for tm in ("tags", "linear"):
        c = dataclasses.replace(cfg, imu_time_offset=-0.24 if tm == "tags" else -0.125)  # README: −0.125 s, linear
        dr = _load(drive_dir, c, time_map=tm)
        pos, t_imu, wz = dr.pos, dr.imu_log.t, dr.imu_log.gyro[:, 2]
        ned = np.array([earth.ned_from_geodetic(a, b, c, pos.lat[0], pos.lon[0], pos.h[0])
                        for a, b, c in zip(pos.lat, pos.lon, pos.h)])  # fmt: skip
        ch = ned[2:] - ned[:-2]  # chord course at the middle epoch
        tc = pos.t[1:-1]
        dcrs = np.diff(np.unwrap(np.arctan2(ch[:, 1], ch[:, 0])))
        fast = np.hypot(ch[:, 0], ch[:, 1]) > 1.5
        ok = fast[1:] & fast[:-1]
        psi = np.concatenate([[0.0], np.cumsum(0.5 * (wz[1:] + wz[:-1]) * np.diff(t_imu))])
        grid = np.arange(-0.2, 0.2, 0.005)
        for half, sel in (("first", tc[1:] < tc[len(tc) // 2]), ("second", tc[1:] >= tc[len(tc) // 2])):
            err = [np.mean((np.diff(np.interp(tc + L, t_imu, psi))[ok & sel] - dcrs[ok & sel]) ** 2) for L in grid]
            lags[tm, half] = float(grid[int(np.argmin(err))])
    # residual lag after the shipped offsets: ~0 for the tag map in both halves, drifting for the linear map
    assert abs(lags["tags", "first"]) <= 0.02 and abs(lags["tags", "second"]) <= 0.02, lags
    assert abs(lags["linear", "first"] - lags["linear", "second"]) >= 0.05, lags


def test_startup_validation_is_a_fresh_alignment_outside_the_protocol(
    drive_dir: Path, cfg: dataset_config.DatasetConfig
):
    """The held-out start-up outage: a restart during the 200.8–209.5 s stop, the outage from 0.25 s after the
    first fix at ≥ 1 m/s, ending where the protocol's next outage begins (its epochs are never scored)."""
    _, p, proto = study.load(cfg, drive_dir)
    st = cfg.study
    imu, gnss, outs = study.startup_validation(p.imu, p.gnss, st["startup_restart_s"], st["startup_score_until_s"],
                                               p.nav.alignment.gnss_yaw_speed)  # fmt: skip
    t0 = p.gnss[0].t
    assert imu[0].t >= t0 + 201.0 and gnss[0].t >= t0 + 201.0
    ((a, b),) = outs
    assert 209.5 < a - t0 < 213.0 and b - t0 == pytest.approx(220.0)
    first_moving = next(f for f in gnss if math.hypot(f.vel_ned[0], f.vel_ned[1]) >= 1.0)
    assert a == pytest.approx(first_moving.t + 0.25)
    assert not any(a < d and c < b for c, d in proto)
    with pytest.raises(ValueError, match="departure"):
        study.startup_validation(
            p.imu, p.gnss, 531.0, 545.0, p.nav.alignment.gnss_yaw_speed
        )  # final stop: no departure


def test_synthetic_baro_is_the_rtk_height_plus_seeded_noise(drive_dir: Path, cfg: dataset_config.DatasetConfig):
    """The what-if barometer: RTK-fixed epochs only, RTK height − datum + white noise σ + random walk, per seed."""
    rec = dd.load(drive_dir, cfg)
    g, pos = rec.dataset.gnss, rec.pos
    ok = pos.q == 1
    truth = pos.h[ok] - 1601.0

    def baro(white: float, drift: float, seed: int) -> np.ndarray:
        return np.array([b.altitude for b in study.synthetic_baro(g, white, drift, seed, datum=1601.0)])

    b0 = study.synthetic_baro(g, 0.0, 0.0, 0, datum=1601.0)
    assert len(b0) == int(ok.sum())
    assert np.allclose([b.altitude for b in b0], truth)
    assert [b.t for b in b0] == list(pos.t[ok])
    w = baro(0.5, 0.0, 3) - truth
    assert 0.45 < w.std() < 0.55 and abs(w.mean()) < 0.05
    d = baro(0.0, 0.05, 3) - truth
    span = pos.t[ok][-1] - pos.t[ok][0]
    assert np.std(np.diff(d)) == pytest.approx(0.05 * math.sqrt(span / (len(d) - 1)), rel=0.1)  # m per epoch
    again = baro(0.5, 0.05, 3)
    assert np.array_equal(again, baro(0.5, 0.05, 3))
    assert not np.array_equal(again, baro(0.5, 0.05, 4))
    with pytest.raises(ValueError, match="must be ≥ 0"):
        study.synthetic_baro(g, -0.1, 0.0, 0, datum=1601.0)


@pytest.mark.slow
def test_replay_of_the_drive_folder_with_its_config_gives_the_protocol_figures(drive_dir: Path, tmp_path: Path):
    """``ins-hil replay DIR --dataset configs/datasets/drive0708.toml``: the protocol's figures of
    docs/accuracy/metrics.json (the drive's study, ZUPT + NHC) through the generic dataset replay."""
    import json

    from ins_hil.cli import main

    doc = json.loads((REPO / "docs" / "accuracy" / "metrics.json").read_text())["drive"]["outages_aids"]
    out = tmp_path / "out"
    assert main(["replay", str(drive_dir), "--dataset", str(DRIVE_TOML), "--out", str(out), "--no-plots",
                 "--quiet"]) == 0  # fmt: skip
    m = json.loads((out / "metrics.json").read_text())
    assert m["outages"]["outages_scored"] == 11
    # the study's run of the same protocol (one replay loop: the same figures to the last digit)
    cfg = dataset_config.load(DRIVE_TOML)
    _, p, outages = study.load(cfg, drive_dir)
    ref, _, _ = run_drive(p.imu, p.gnss, [f.fix_type >= cfg.min_fix_type for f in p.gnss], p.nav, outages,
                          aiding_fdi=cfg.aiding_fdi)  # fmt: skip
    assert m["outages"]["outage_h_rms_m"] == pytest.approx(ref["outage_h_rms_m"], rel=1e-12)  # 1.325789 m
    assert m["outages"]["outage_h_max_m"] == pytest.approx(ref["outage_h_max_m"], rel=1e-12)  # 9.188699 m
    # docs/accuracy/metrics.json (1.326941 m: scored at the state after each step's fusion, before the replay
    # ran through the pipeline; now at the state the pipeline publishes)
    assert m["outages"]["outage_h_rms_m"] == pytest.approx(doc["outage_h_rms_m"], rel=2e-3)
    assert m["outages"]["outage_h_max_m"] == pytest.approx(doc["outage_h_max_m"], rel=2e-3)
    assert m["outages"]["beats_both_in_every_outage"]


def test_study_and_protocol_keys_are_checked():
    """[study] and the new [outages]/[score] keys: bad values are one-line errors; first_gnss windows end tail_s
    before the last fix."""
    for bad, what in (({"study": {"whatif_baro": [["x", -1, 0]]}}, "whatif_baro"),
                      ({"study": {"startup_restart_s": 1.0}}, "go together"),
                      ({"study": {"validation_shifts_s": ["a"]}}, "validation_shifts_s"),
                      ({"outages": {"relative_to": "landing"}}, "relative_to"),
                      ({"outages": {"tail_s": -1.0}}, "tail_s"),
                      ({"score": {"min_fix_type": "rtk"}}, "min_fix_type")):  # fmt: skip
        with pytest.raises(dataset_config.DatasetConfigError, match=what) as e:
            dataset_config.from_dict({"dataset": {"name": "x"}, **bad})
        assert "\n" not in str(e.value)
    o = dataset_config.OutageProtocol("first_gnss", 40.0, 15.0, 30.0, None, 30.0)
    assert o.windows(0.0, 200.0) == [(40.0, 55.0), (85.0, 100.0), (130.0, 145.0)]


def test_flight_log_without_magnetometer_takes_its_yaw_from_the_gnss_velocity_bank(
    drive_dir: Path, cfg: dataset_config.DatasetConfig
):
    """A flight controller's log (PX4, ArduPilot) without a magnetometer aligns its yaw with the GNSS-velocity
    yaw bank, as EKF2 does; a car's RTKLIB set keeps the course; the config's own choice wins."""
    import dataclasses

    ds = read_dataset(drive_dir, "rtklib", cfg)
    ds.mag = []
    assert not prepare(ds, cfg).nav.alignment.yaw_gsf  # rtklib (the car): the course
    ds.meta = {**ds.meta, "format": "px4-csv"}
    p = prepare(ds, cfg)
    assert p.nav.alignment.yaw_gsf and any("yaw bank" in n for n in p.notes)
    off = dataclasses.replace(cfg, nav={**cfg.nav, "alignment": {**cfg.nav.get("alignment", {}), "yaw_gsf": False}})
    assert not prepare(ds, off).nav.alignment.yaw_gsf
