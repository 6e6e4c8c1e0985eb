"""Batch replays (ins_hil.datasets.batch): entries, seeds, a failing log among good ones, and the same rows
serially and on a real Dask LocalCluster of 2 worker processes."""

from __future__ import annotations

import json
from pathlib import Path

import pytest
from test_datasets_replay import GOOD, _static_csv, _toml

from ins_hil.datasets import config as dcfg
from ins_hil.datasets.dataset import DatasetError
from ins_hil.evaluation import batch


def _logs(tmp_path: Path) -> tuple[Path, Path]:
    d = tmp_path / "logs"
    d.mkdir()
    _static_csv(d / "a.csv", yaw_deg=30.0, seconds=40.0)
    _static_csv(d / "b.csv", yaw_deg=-60.0, seconds=40.0)
    return d, _toml(tmp_path / "static.toml", GOOD)


def test_entries_expand_to_logs_and_configs(tmp_path: Path) -> None:
    d, cfg = _logs(tmp_path)
    (d / "notes.txt").write_text("not a log")
    assert batch.expand([str(d)], str(cfg)) == [(str(d / "a.csv"), str(cfg)), (str(d / "b.csv"), str(cfg))]
    assert batch.expand([str(d / "*.csv")]) == [(str(d / "a.csv"), None), (str(d / "b.csv"), None)]
    assert batch.expand([str(cfg)]) == [(None, str(cfg))]
    with pytest.raises(DatasetError, match="matches no file"):
        batch.expand([str(d / "*.ulg")])
    with pytest.raises(DatasetError, match="no such file"):
        batch.expand([str(tmp_path / "missing.csv")])


def test_seeds_shift_the_outage_protocol(tmp_path: Path) -> None:
    cfg = dcfg.load(_toml(tmp_path / "c.toml", GOOD))
    assert batch.seeded(cfg, 0) is cfg
    starts = [batch.seeded(cfg, s).outages.start_s for s in (1, 2, 3)]
    assert all(20.0 <= s < 40.0 for s in starts) and len(set(starts)) == 3
    assert batch.seeded(cfg, 2).outages.start_s == starts[1]  # reproducible
    js = batch.jobs([("x.csv", None)], 3, tmp_path)
    assert [j.seed for j in js] == [0, 1, 2] and len({j.out for j in js}) == 3


@pytest.mark.slow  # a Dask LocalCluster of 2 worker processes (~30 s with its start-up)
def test_a_failing_log_does_not_stop_the_batch_and_dask_gives_the_serial_rows(tmp_path: Path) -> None:
    d, cfg = _logs(tmp_path)
    bad = tmp_path / "bad.csv"
    bad.write_text("# ins-hil dataset csv 1\nimu,1,2\n")
    pairs = [(str(d / "a.csv"), str(cfg)), (str(bad), str(cfg)), (str(d / "b.csv"), str(cfg))]
    done: list[int] = []
    serial, _ = batch.run_batch(batch.jobs(pairs, 2, tmp_path / "s"), workers=0, on_done=lambda r, k, n: done.append(k))
    assert done == list(range(1, 7))
    assert [("error" in r) for r in serial] == [False, False, True, True, False, False]
    assert "bad.csv:2: imu" in serial[2]["error"]
    for r in (serial[0], serial[4]):
        assert r["gnss_h_rms_m"] < 0.2 and r["outage_h_rms_m"] < 1.0
    m = json.loads((Path(batch.jobs(pairs, 2, tmp_path / "s")[1].out) / "metrics.json").read_text())
    assert m["seed"] == 1 and m["outages"]["protocol"]["start_s"] != 20.0
    dask_rows, _ = batch.run_batch(batch.jobs(pairs, 2, tmp_path / "d"), workers=2)
    keys = ("job", "gnss_h_rms_m", "outage_h_rms_m", "outage_h_max_m", "error")
    same = repr([{k: r.get(k) for k in keys} for r in dask_rows]) == repr([{k: r.get(k) for k in keys} for r in serial])
    assert same  # repr: a seed whose outages fall past the end scores NaN on both
    text = batch.table(serial)
    assert text.count("\n") == 7 and "bad.csv#0" in text and "bad.csv:2" in text


def test_batch_command_writes_the_summary_and_fails_on_a_bad_log(tmp_path: Path, capsys) -> None:
    from ins_hil.cli import main

    d, cfg = _logs(tmp_path)
    (d / "bad.csv").write_text("# ins-hil dataset csv 1\nimu,1,2\n")
    out = tmp_path / "out"
    rc = main(["replay", "--batch", str(d), "--dataset", str(cfg), "--workers", "0", "--out", str(out), "--quiet"])
    text = capsys.readouterr().out
    assert rc == 1  # one log failed; the two others were replayed
    rows = json.loads((out / "batch.json").read_text())["rows"]
    assert [("error" in r) for r in rows] == [False, False, True]
    assert "3 replays" in text and "1 failed" in (out / "batch.md").read_text()
    assert all((Path(r) / "metrics.json").is_file() for r in sorted(str(p) for p in out.iterdir() if p.is_dir())[:2])
