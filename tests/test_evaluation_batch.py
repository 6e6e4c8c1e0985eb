"""Batch replays (ins_hil.datasets.batch): entries, seeds, the longest-first order, the parsed-log cache, a
failing log among good ones, the same rows serially and on a real Dask LocalCluster of 2 worker processes,
and ``--compare-serial``."""

from __future__ import annotations

import dataclasses
import json
import os
import re
import sys
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
    batch.clear_cache()  # as the command does: forked workers would start with this process's parsed logs
    dask_rows, _ = batch.run_batch(batch.jobs(pairs, 2, tmp_path / "d"), workers=2)
    keys = ("job", "gnss_h_rms_m", "outage_h_rms_m", "outage_h_max_m", "error")
    same = repr([{k: r.get(k) for k in keys} for r in dask_rows]) == repr([{k: r.get(k) for k in keys} for r in serial])
    assert same  # repr: a seed whose outages fall past the end scores NaN on both
    # each good log parsed once on the cluster (its seeds on the worker that parsed it), not once per worker
    assert sum(r.get("cached") is False for r in dask_rows) == 2
    assert len({r["pid"] for r in dask_rows if "pid" in r}) == 2
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


def test_order_is_longest_first_with_the_seeds_of_a_log_together(tmp_path: Path) -> None:
    d = tmp_path / "logs"
    d.mkdir()
    _static_csv(d / "short.csv", seconds=20.0)
    _static_csv(d / "long.csv", seconds=60.0)
    cfg = _toml(tmp_path / "static.toml", GOOD)  # an outage protocol: twice the cost of the same log without
    plain = _toml(tmp_path / "plain.toml", GOOD.split("[outages]")[0])
    pairs = [(str(d / "short.csv"), str(plain)), (str(tmp_path / "gone.csv"), str(cfg)),
             (str(d / "long.csv"), str(plain)), (str(d / "short.csv"), str(cfg))]  # fmt: skip
    js = batch.jobs(pairs, 2, tmp_path / "out")
    short, long = ((d / n).stat().st_size for n in ("short.csv", "long.csv"))
    assert [batch.cost(js[k]) for k in (0, 2, 4, 6)] == [short, 0.0, long, 2 * short]
    assert batch.cost(js[1]) == batch.cost(js[0])  # the seed does not change the cost
    assert long > 2 * short  # 60 s of samples against 20 s: the long log first, even without its protocol
    seq = batch.order(js)
    assert sorted(seq) == list(range(len(js)))
    assert [pairs.index((js[i].source, js[i].config)) for i in seq] == [2, 2, 3, 3, 0, 0, 1, 1]  # unreadable: last
    assert [js[i].seed for i in seq] == [0, 1] * 4
    # an earlier run's replay times (batch.json's rows): short.csv with the protocol measured longest of all
    rows = [{"source": js[k].source, "config": js[k].config, "replay_s": s, "plot_s": 0.5}
            for k, s in ((0, 1.0), (1, 2.0), (2, 9.0), (4, 3.0), (6, 6.0), (7, 6.0))]  # fmt: skip
    rows.append({"source": js[3].source, "config": js[3].config, "error": "gone"})
    known = batch.measured(rows)
    assert known[(js[0].source, js[0].config)] == 2.0 and known[(js[6].source, js[6].config)] == 6.5
    seq = batch.order(js, known)
    assert [pairs.index((js[i].source, js[i].config)) for i in seq] == [1, 1, 3, 3, 2, 2, 0, 0]
    del known[(js[2].source, js[2].config)]  # a log it did not measure: sizes for all (seconds and bytes differ)
    assert batch.order(js, known) == batch.order(js)


def test_a_freed_worker_takes_a_log_it_parsed_else_one_nobody_started_else_the_longest() -> None:
    left = ["long", "long", "mid", "mid", "short"]  # the jobs left, in order(): their logs
    assert batch.pick(left, [], set()) == 0  # the first worker: the longest
    assert batch.pick(left[1:], [], {"long"}) == 1  # the second: not the log the first is parsing
    assert batch.pick(left[1:], ["mid"], {"long", "mid"}) == 1  # its own log's next seed before a longer one
    assert batch.pick(["long", "short"], ["mid"], {"long", "mid"}) == 1  # short: nobody parsed it yet
    assert batch.pick(["long", "short"], ["mid"], {"long", "mid", "short"}) == 0  # else the longest left


def test_the_parsed_log_cache_hits_for_seeds_and_misses_on_a_changed_file(tmp_path: Path) -> None:
    d, toml = _logs(tmp_path)
    a, b = d / "a.csv", d / "b.csv"
    cfg = dcfg.load(toml)
    batch.clear_cache()
    ds, hit = batch.load_cached(a, cfg)
    assert not hit and len(ds.imu) > 1000
    again, hit = batch.load_cached(a, batch.seeded(cfg, 3))  # another seed: the same parse
    assert hit and again is ds
    st = a.stat()
    os.utime(a, ns=(st.st_atime_ns, st.st_mtime_ns + 1_000_000_000))  # touched: read again
    fresh, hit = batch.load_cached(a, cfg)
    assert not hit and fresh is not ds and len(fresh.imu) == len(ds.imu)
    assert batch.load_cached(a, cfg)[1]
    _, hit = batch.load_cached(a, dataclasses.replace(cfg, imu_time_offset=0.01))  # a parse-relevant part
    assert not hit
    _, hit = batch.load_cached(b, cfg)
    assert not hit
    others = [tmp_path / f"c{k}.csv" for k in range(batch.CACHE_SIZE)]
    for q in others:
        q.write_bytes(a.read_bytes())
        assert not batch.load_cached(q, cfg)[1]
    assert not batch.load_cached(a, cfg)[1]  # pushed out by the CACHE_SIZE newer ones
    assert batch.load_cached(others[-1], cfg)[1]
    batch.clear_cache()


def test_serial_rows_carry_timings_and_a_failing_log_is_still_reported(tmp_path: Path) -> None:
    d, cfg = _logs(tmp_path)
    bad = tmp_path / "bad.csv"
    bad.write_text("# ins-hil dataset csv 1\nimu,1,2\n")
    pairs = [(str(bad), str(cfg)), (str(d / "a.csv"), str(cfg))]
    batch.clear_cache()
    started: list[str] = []
    rows, wall = batch.run_batch(batch.jobs(pairs, 2, tmp_path / "s", plots=False), workers=0,
                                 on_done=lambda r, k, n: started.append(r["job"]))  # fmt: skip
    assert started == ["a.csv#0", "a.csv#1", "bad.csv#0", "bad.csv#1"]  # longest first ...
    assert [r["job"] for r in rows] == ["bad.csv#0", "bad.csv#1", "a.csv#0", "a.csv#1"]  # ... rows in job order
    assert "bad.csv:2: imu" in rows[0]["error"] and "bad.csv:2: imu" in rows[1]["error"]
    assert [r.get("cached") for r in rows[2:]] == [False, True]
    for r in rows[2:]:
        assert r["load_s"] > 0 and r["replay_s"] > 0 and r["plot_s"] >= 0 and r["cpu_s"] > 0
        assert r["load_s"] + r["replay_s"] + r["plot_s"] <= r["elapsed_s"] + 1e-6
    job_out = Path(batch.jobs(pairs, 2, tmp_path / "s")[2].out)
    assert json.loads((job_out / "metrics.json").read_text())["plots"] == [] and not list(job_out.glob("*.png"))
    line = batch.breakdown(rows, wall, 1)
    assert "(1 parsed, 1 from the cache)" in line and "over 4 jobs" in line
    loaded = sum(r.get("load_s", 0.0) for r in rows)
    assert f"load {loaded:.1f} s" in line
    assert batch.differences(rows, rows) == []
    other = [dict(r) for r in rows]
    other[3]["elapsed_s"] += 5.0  # a timing is not a result
    assert batch.differences(rows, other) == []
    other[3]["gnss_h_rms_m"] += 0.001
    assert batch.differences(rows, other) == ["a.csv#1"]
    batch.clear_cache()


@pytest.mark.slow  # the batch serially, then on two LocalClusters of 1 worker process (~35 s)
def test_compare_serial_prints_both_wall_times_and_their_ratio(tmp_path: Path, capsys) -> None:
    from ins_hil.cli import main

    d, cfg = _logs(tmp_path)
    out = tmp_path / "out"
    argv = ["replay", "--batch", str(d / "a.csv"), "--dataset", str(cfg), "--seeds", "2", "--out", str(out), "--quiet"]
    assert main([*argv, "--workers", "0", "--compare-serial"]) == 2  # nothing to compare with
    assert "needs --workers > 0" in capsys.readouterr().err
    assert main([*argv, "--scheduler", "tcp://127.0.0.1:1", "--compare-dask-defaults"]) == 2
    assert "needs our LocalCluster" in capsys.readouterr().err
    rc = main([*argv, "--workers", "1", "--compare-serial", "--compare-dask-defaults", "--no-plots"])
    text = capsys.readouterr().out
    assert rc == 0
    summary = json.loads((out / "batch.json").read_text())
    s, dd = summary["compare_serial"], summary["compare_dask_defaults"]
    m = re.search(r"Dask's worker settings ([\d.]+) s \(([\d.]+)x serial\), ours \(batch.WORKER_CONFIG\) ([\d.]+) s "
                  r"\(([\d.]+)x serial\): ([\d.]+)x; the same results", text)  # fmt: skip
    assert m is not None, text
    assert float(m[1]) == round(dd["defaults_wall_s"], 1) and float(m[3]) == round(dd["ours_wall_s"], 1)
    assert float(m[2]) == round(s["serial_wall_s"] / dd["defaults_wall_s"], 2)
    assert float(m[5]) == round(dd["defaults_wall_s"] / dd["ours_wall_s"], 2) and dd["differences"] == []
    assert (out / "dask_defaults").is_dir() and "Dask's worker settings: load" in text
    m = re.search(r"serial ([\d.]+) s, parallel ([\d.]+) s \(LocalCluster of 1 workers\): ([\d.]+)x; (.*)", text)
    assert m is not None, text
    assert float(m[1]) == round(s["serial_wall_s"], 1) and float(m[2]) == round(s["parallel_wall_s"], 1)
    assert float(m[3]) == round(s["serial_wall_s"] / s["parallel_wall_s"], 2)
    assert m[4] == "every job the same results" and s["differences"] == []
    assert "serial: load" in text and "(1 parsed, 1 from the cache)" in text
    assert all((out / "serial" / Path(j.out).name / "metrics.json").is_file()
               for j in batch.jobs([(str(d / "a.csv"), str(cfg))], 2, out))  # fmt: skip
    assert [r["job"] for r in s["serial_rows"]] == ["a.csv#0", "a.csv#1"]


def test_a_workers_warm_up_leaves_the_simulator_to_the_job_that_needs_it() -> None:
    """The warm-up imports the readers, the core and the plots' module, not the simulator (0.12 CPU s per
    worker, before its first job): a flight log's job never loads it."""
    import subprocess

    mods = "'ins_hil.datasets.report' in sys.modules, 'ins_hil.evaluation.sim_flight' in sys.modules"
    code = f"import sys; from ins_hil.evaluation import batch; batch.warm_up(); print({mods})"
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True).stdout.split()
    assert out == ["True", "False"]


@pytest.mark.slow  # a LocalCluster of 1 worker process (~3 s)
def test_our_local_cluster_runs_its_workers_without_the_profiler_and_with_a_slow_event_loop_tick() -> None:
    import dask
    from dask.distributed import Client

    keys = list(batch.WORKER_CONFIG)
    before = {k: dask.config.get(k) for k in keys}
    assert before["distributed.worker.profile.enabled"] is True  # dask's defaults, left as they were
    assert before["distributed.admin.tick.interval"] == "20ms"
    cluster = batch.local_cluster(1)
    try:
        with Client(cluster) as client:
            # forked on Linux: the worker already holds this process's imports (spawned, it would not)
            forked = client.run(lambda: "ins_hil.evaluation.batch" in __import__("sys").modules)
            seen = client.run(lambda: {k: dask.config.get(k) for k in keys})
            # the worker's own event loop watchdog runs at the setting's interval (ms)
            ticks = client.run(lambda dask_worker: dask_worker.periodic_callbacks["tick"].callback_time)
    finally:
        cluster.close()
    assert list(seen.values()) == [batch.WORKER_CONFIG]
    assert list(forked.values()) == [sys.platform.startswith("linux")]
    assert list(ticks.values()) == [1000]
    cluster = batch.local_cluster(1, {})  # Dask's own settings (--compare-dask-defaults)
    try:
        with Client(cluster) as client:
            ticks = client.run(lambda dask_worker: dask_worker.periodic_callbacks["tick"].callback_time)
            profile = client.run(lambda: dask.config.get("distributed.worker.profile.enabled"))
    finally:
        cluster.close()
    assert list(ticks.values()) == [20] and list(profile.values()) == [True]
    assert {k: dask.config.get(k) for k in keys} == before  # only the workers' settings


VARIANTS = """
# two variants of the static test config
[short]
outages = { on_s = 5.0 }

["vib-0.2"]
sensor = { gyro_vib_gain = 0.2 }
"""


def test_variants_file_errors_are_one_line(tmp_path: Path) -> None:
    cases = {
        "": "no variants",
        "x = 1\n": "x = 1: a variant is a table [x]",
        "[a.b]\nsensor = { gyro_vib_gain = 0.2 }\n": 'quote the name, ["a-0.5"]',
        "[a]\ndataset = { name = 'y' }\n": "[a] dataset: a variant sets sensor, mounting",
        "[config]\n": "not 'config'",
        "[a]\nnav = [1]\n": None,  # a table of the wrong type is caught against the log's config (below)
    }
    for body, want in cases.items():
        p = _toml(tmp_path / "v.toml", body)
        if want is None:
            continue
        with pytest.raises(dcfg.DatasetConfigError, match=re.escape(want)) as e:
            batch.load_variants(p)
        assert "\n" not in str(e.value) and str(p) in str(e.value)
    with pytest.raises(dcfg.DatasetConfigError, match="no such variants file"):
        batch.load_variants(tmp_path / "missing.toml")
    cfg = _toml(tmp_path / "c.toml", GOOD)
    typo = batch.load_variants(_toml(tmp_path / "t.toml", "[typo]\nnav.aids = { dragg = true }\n"))
    with pytest.raises(dcfg.DatasetConfigError, match=r"c\.toml with variant \[typo\].*dragg"):
        batch.jobs([("x.csv", str(cfg))], 1, tmp_path, variants=typo)


def test_variants_and_shifts_make_the_jobs_and_reach_their_configs(tmp_path: Path) -> None:
    cfg = _toml(tmp_path / "c.toml", GOOD)
    plain = _toml(tmp_path / "plain.toml", GOOD.split("[outages]")[0])
    vs = batch.load_variants(_toml(tmp_path / "v.toml", VARIANTS))
    assert [n for n, _ in vs] == ["short", "vib-0.2"]
    js = batch.jobs([("a.csv", str(cfg)), ("b.csv", str(plain))], 2, tmp_path / "o", variants=vs, shifts=[-5.0, 10])
    a = [j for j in js if j.source == "a.csv"]
    b = [j for j in js if j.source == "b.csv"]
    assert len(a) == 3 * 2 * 2 and len(b) == 2 + 2 * 2 + 2  # no outage protocol: unshifted, but [short] adds one
    assert [(j.variant, j.shift_s) for j in b[::2]] == [(None, 0.0), ("short", -5.0), ("short", 10.0), ("vib-0.2", 0.0)]
    assert len({j.out for j in js}) == len(js)
    assert [j.name for j in a[:4]] == ["a.csv-5s#0", "a.csv-5s#1", "a.csv+10s#0", "a.csv+10s#1"]
    assert a[4].name == "a.csv[short]-5s#0" and Path(a[4].out).name == "00-a.csv-short-shift-5s-seed0"
    base = dcfg.load(cfg)
    c = batch._config(a[4])  # [short], shift -5 s, seed 0
    assert (c.outages.start_s, c.outages.on_s, c.outages.off_s) == (base.outages.start_s - 5.0, 5.0, 10.0)
    c = batch._config(a[10])  # [vib-0.2], shift +10 s, seed 0
    assert c.nav_config().filter.gyro_vib_gain == 0.2 and c.outages.start_s == base.outages.start_s + 10.0
    assert base.nav_config().filter.gyro_vib_gain != 0.2
    seeded = batch._config(a[11])  # seed 1 on top of the shift
    assert seeded.outages.start_s == batch.seeded(batch.shifted(base, 10.0), 1).outages.start_s
    assert repr(batch._config(a[0]).nav_config()) == repr(base.nav_config())  # the config as it is


def test_variant_table_pools_the_seeds_of_each_shift(tmp_path: Path) -> None:
    def row(v: str, sh: float, rms: float, mx: float, beats: bool) -> dict:
        return {"job": f"x[{v}]", "log": "x.csv", "variant": v, "shift_s": sh, "outage_h_rms_m": rms,
                "outage_h_max_m": mx, "beats_both_in_every_outage": beats, "gnss_h_rms_m": 0.1}  # fmt: skip

    rows = [
        row("config", -5, 3.0, 5.0, True),
        row("config", -5, 4.0, 9.0, False),
        row("config", 10, 1.0, 2.0, True),
        row("b", -5, 1.0, 1.5, True),
        {"job": "x[b]", "log": "x.csv", "variant": "b", "shift_s": 10, "error": "E"},
    ]
    text = batch.variant_table(rows)
    lines = text.splitlines()
    assert lines[0] == "**x.csv**: outage h error RMS / worst (m)"
    head = "| variant | outage shift -5 s | outage shift +10 s | pooled | beats both | GNSS h RMS m | failed |"
    assert lines[2] == head
    pooled = (3.0**2 + 4.0**2 + 1.0**2) / 3
    assert lines[4] == f"| config | 3.54 / 9.00 | 1.00 / 2.00 | {pooled**0.5:.2f} / 9.00 | 2 of 3 | 0.10 | 0 |"
    assert lines[5] == "| b | 1.00 / 1.50 | — | 1.00 / 1.50 | 1 of 2 | 0.10 | 1 |"
    assert batch.variant_table([{"job": "x#0", "variant": "config", "shift_s": 0.0}]) == ""
    lag = [{"job": "y", "log": "y", "variant": v, "shift_s": 0.0, "gnss_h_rms_m": 0.2, "vel_innov_lag1": l}
           for v, l in (("config", [-0.4, -0.2]), ("s2", [-0.1, 0.05]))]  # fmt: skip
    lines = batch.variant_table(lag).splitlines()
    assert lines[0] == "**y**" and lines[2] == "| variant | GNSS h RMS m | vel innov lag-1 N / E | failed |"
    assert lines[4:] == ["| config | 0.20 | -0.40 / -0.20 | 0 |", "| s2 | 0.20 | -0.10 / +0.05 | 0 |"]


def test_variant_table_shows_each_outage_for_one_protocol() -> None:
    """One protocol (one shift, one seed each): a column with each outage's h RMS and one line with the trivial
    predictors' (the same for every variant: they use the GNSS only); seeds or shifts move the outages, so
    then there is no such column."""

    def row(v: str, seed: int, each: list[float]) -> dict:
        return {"job": f"x[{v}]#{seed}", "log": "x.csv", "variant": v, "shift_s": 0.0, "outage_h_rms_m": 1.0,
                "outage_h_max_m": 2.0, "beats_both_in_every_outage": False, "each_h_rms_m": each,
                "each_hold_h_rms_m": [0.5, 2.0], "each_cv_h_rms_m": [3.0, 4.0]}  # fmt: skip

    rows = [row("config", 0, [1.0, 3.0]), row("b", 0, [0.25, 1.5]),
            {"job": "x[c]", "log": "x.csv", "variant": "c", "shift_s": 0.0, "error": "E"}]  # fmt: skip
    lines = batch.variant_table(rows).splitlines()
    assert lines[2] == "| variant | outage | beats both | each outage h RMS m | failed |"
    assert lines[4] == "| config | 1.00 / 2.00 | 0 of 1 | 1.00 / 3.00 | 0 |"
    assert lines[5] == "| b | 1.00 / 2.00 | 0 of 1 | 0.25 / 1.50 | 0 |"
    assert lines[6] == "| c | — | 0 of 1 | — | 1 |"
    assert lines[8] == ("Each outage, hold the last fix: 0.50 / 2.00 m; constant-velocity extrapolation: "
                        "3.00 / 4.00 m (h RMS).")  # fmt: skip
    seeds = [*rows, row("config", 1, [3.0, 3.0])]
    two = [dict(r, shift_s=sh) for r in rows for sh in (0.0, 10.0)]
    for t in (batch.variant_table(seeds), batch.variant_table(two)):
        assert "each outage" not in t and "Each outage" not in t


@pytest.mark.slow  # 6 s on a busy 2-core machine
def test_variants_command_puts_them_side_by_side(tmp_path: Path, capsys) -> None:
    from ins_hil.cli import main

    d, cfg = _logs(tmp_path)
    vs = _toml(tmp_path / "v.toml", VARIANTS)
    out = tmp_path / "out"
    rc = main(["replay", str(d / "a.csv"), "--dataset", str(cfg), "--variants", str(vs), "--shifts", "-5", "0",
               "--workers", "0", "--out", str(out), "--quiet", "--no-plots"])  # fmt: skip
    text = capsys.readouterr().out
    assert rc == 0
    summary = json.loads((out / "batch.json").read_text())
    assert summary["variants"] == ["config", "short", "vib-0.2"] and summary["shifts_s"] == [-5.0, 0.0]
    rows = summary["rows"]
    assert [(r["variant"], r["shift_s"]) for r in rows] == [(v, s) for v in ("config", "short", "vib-0.2")
                                                            for s in (-5.0, 0.0)]  # fmt: skip
    js = batch.jobs(batch.expand([str(d / "a.csv")], str(cfg)), 1, out, False, batch.load_variants(vs), [-5, 0])
    for r, job in zip(rows, js, strict=True):
        assert r["job"] == job.name
        p = json.loads((Path(job.out) / "metrics.json").read_text())["outages"]["protocol"]
        assert p["start_s"] == 20.0 + r["shift_s"] and p["on_s"] == (5.0 if r["variant"] == "short" else 10.0)
    assert "| config |" in text and "| short |" in text and "| vib-0.2 |" in text
    assert "outage shift -5 s" in (out / "batch.md").read_text()


def test_shipped_variants_fit_every_shipped_dataset_config(tmp_path: Path) -> None:
    repo = Path(__file__).resolve().parents[1]
    pairs = batch.expand([str(repo / "configs" / "datasets")])
    files = sorted((repo / "configs" / "variants").glob("*.toml"))
    assert {f.stem for f in files} >= {"gnss_noise", "noise", "accel_bias", "gap", "drag"}
    for f in files:
        vs = batch.load_variants(f)
        js = batch.jobs(pairs, 1, tmp_path, False, vs, [-10.0, 15.0])  # every variant checked against every config
        for name, _ in vs:  # each changes the NavConfig of some shipped config (std-scale-1 that of px4_quad)
            mine = [j for j in js if j.variant == name and j.seed == 0 and j.shift_s in (0.0, -10.0)]
            plain = [batch._config(dataclasses.replace(j, variant=None, overrides=None)) for j in mine]
            assert any(repr(batch._config(j).nav_config()) != repr(c.nav_config())
                       for j, c in zip(mine, plain, strict=True)), (f.name, name)  # fmt: skip


def test_the_last_run_in_the_folder_gives_the_order_its_replay_times(tmp_path: Path) -> None:
    """``ins-hil replay --batch … --out DIR`` orders its jobs by DIR/batch.json's measured times when it has them
    (an unreadable or missing summary: by the logs' sizes)."""
    from ins_hil.commands.replay import _last_costs

    path = tmp_path / "batch.json"
    assert _last_costs(path) is None
    path.write_text("{not json")
    assert _last_costs(path) is None
    path.write_text(json.dumps({"rows": [{"source": "a.csv", "config": None, "replay_s": 2.0, "plot_s": 1.0}]}))
    assert _last_costs(path) == {("a.csv", None): 3.0}
    path.write_text(json.dumps([1, 2]))
    assert _last_costs(path) is None
