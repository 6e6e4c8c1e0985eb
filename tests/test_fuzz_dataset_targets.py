"""The dataset readers and the dataset config are targets of the project's fuzz campaign (issue 39): each runs,
seeded from the shipped logs, without an escaped exception or a sample outside the physical ranges."""

from __future__ import annotations

import random

import pytest

from ins_hil.fuzz import bad_sample
from ins_hil.fuzz.targets import TARGETS, Wrong, by_name

NAMES = ["reader_csv", "reader_px4_ulog", "reader_px4_csv", "reader_ardupilot_bin", "reader_ardupilot_log",
         "reader_rtklib", "reader_ihlog", "dataset_config", "replay_dataset"]  # fmt: skip


def test_targets_registered():
    assert set(NAMES) <= {t.name for t in TARGETS}


@pytest.mark.parametrize("name", NAMES)
def test_target_runs_clean(name: str, shared_dir):
    (t,) = by_name([name])
    step = t.setup(random.Random(39))
    for _ in range(30):
        n, out = step()  # an escaped exception fails the test
        assert n == 1
        assert not [s for s in out if isinstance(s, Wrong) or bad_sample(s)], out[:3]


def test_seeds_cut_from_the_shipped_logs_are_small_valid_logs(shared_dir, tmp_path):
    from ins_hil.datasets.dataset import read_dataset
    from ins_hil.fuzz.targets import SEED_RECORDS, dataflash_seed, ulog_seed

    uav = shared_dir / "data/uav"
    u, u_spans = ulog_seed((uav / "px4_hover_92s/hover.ulg").read_bytes())
    b, b_spans = dataflash_seed((uav / "ardupilot_copter_150s/flight.bin").read_bytes())
    for name, data, spans in (("s.ulg", u, u_spans), ("s.bin", b, b_spans)):
        assert len(data) < 60_000
        assert spans[-1][0] + spans[-1][1] == len(data)  # the spans tile the messages, header aside
        (tmp_path / name).write_bytes(data)
        ds = read_dataset(tmp_path / name)
        assert SEED_RECORDS - 2 <= len(ds.imu) <= SEED_RECORDS
        assert len(ds.gnss) >= 5  # the hover log had no fix: the ULog seed's GNSS records carry one
        assert all(s.dt > 0 for s in ds.imu)


def test_replay_oracle_is_the_guarantee(tmp_path):
    from ins_hil.fuzz.targets import replay_oracle

    p = tmp_path / "d.ulg"
    assert replay_oracle(0, "pos rms 1.2 m\nroll not scored (never navigated)\n", "", p) == []
    assert replay_oracle(0, "roll rms nan °", "", p)  # a NaN printed as a figure
    assert replay_oracle(0, "h error -inf m", "", p)
    assert replay_oracle(0, "info: nanoseconds, inference", "", p) == []  # words, not numbers
    assert replay_oracle(2, "", f"ins-hil replay: {p}: not a PX4 ULog file\n", p) == []
    assert replay_oracle(2, "", f"ins-hil replay: {p}: x\nsecond line\n", p)  # not one line
    assert replay_oracle(2, "", "ins-hil replay: damaged\n", p)  # does not name the file
    assert replay_oracle(1, "", f"ins-hil replay: {p}: the replay failed (KeyError: 'x')\n", p)
    assert replay_oracle(1, "", f"ins-hil replay: IndexError: {p} (run with --debug for the traceback)\n", p)


def test_replay_targets_measure_the_guarantee(shared_dir):
    from ins_hil.fuzz import run_target

    (t,) = by_name(["replay_process"])
    r = run_target(t, None, seed=39, inputs=2)
    assert r.inputs == 2 and r.accepted_bad == 0 and r.escaped == 0
    assert 0 < r.maxima["replay wall s"] and 0 < r.maxima["replay peak RSS MiB"] < 1024
