"""The dataset readers and the dataset config are targets of the project's fuzz campaign (issue 39): each runs,
seeded from the shipped logs, without an escaped exception or a sample outside the physical ranges."""

from __future__ import annotations

import random

import pytest

from ins_hil.fuzz import Checked, Measure, Replayed, bad_sample
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
        samples = [s for s in out if not isinstance(s, Checked | Measure | Replayed)]  # the engine's own counters
        assert not [s for s in samples if isinstance(s, Wrong) or bad_sample(s)], out[:3]


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


def test_suspects_covers_every_sample_the_oracle_flags() -> None:
    """The reader targets check every screened sample at once (numpy) and pass on only the doubtful ones: that set
    must hold every sample bad_sample flags, plausible ones left out."""
    import math

    import numpy as np

    from ins_hil.fuzz import DT_RANGE, MAX_ACCEL, MAX_RATE, suspects
    from ins_hil.types import FixType, GnssFix, ImuSample, MagSample

    rng = random.Random(39)
    special = [0.0, -0.0, 1e-300, 1e308, -1e308, math.inf, -math.inf, math.nan, DT_RANGE[0], DT_RANGE[1]]
    samples: list = []
    for k in range(3000):
        dt = 0.005 if rng.random() < 0.6 else rng.choice([*special, DT_RANGE[0] * (1 - 1e-12), DT_RANGE[1] * 1.0001])
        th, dv = [1e-4, -2e-4, 3e-5], [0.01, 0.0, -0.049]
        r = rng.random()
        if r < 0.1:  # every component at the bound: the norm is the limit, within rounding
            th = [MAX_RATE * dt * rng.choice((1.0, 1.0 + 1e-15, 1.0 - 1e-15))] * 3
        elif r < 0.2:
            dv = [MAX_ACCEL * dt * rng.choice((1.0, 1.0 + 1e-15, 1.0 - 1e-15))] * 3
        elif r < 0.35:
            (th if rng.random() < 0.5 else dv)[rng.randrange(3)] = rng.choice(special)
        samples.append(ImuSample(0.01 * k, dt, np.array(th), np.array(dv)))
    samples += [GnssFix(1.0, 0.8, 0.2, 100.0, None, 1.0, 2.0, 0.3, FixType.FIX_3D),
                GnssFix(1.0, 0.8, 0.2, math.nan, None), MagSample(1.0, np.array((1.0, 0, 0))),
                MagSample(1.0, np.array((2e-5, 0, 4e-5)))]  # fmt: skip
    got = {id(s) for s in suspects(samples)}
    bad = [s for s in samples if bad_sample(s)]
    assert len(bad) > 500 and all(id(s) in got for s in bad)
    assert len(got) < len(samples) - 500  # the plausible ones are not passed on
    ok = ImuSample(1.0, 0.005, np.array((1e-4, 0, 0)), np.array((0, 0, -0.049)))
    assert suspects([ok, samples[-1]]) == []


def test_engine_counts_checked_samples_and_checks_the_suspects() -> None:
    import numpy as np

    from ins_hil.fuzz import Checked, Target, run_target
    from ins_hil.types import ImuSample

    def setup(rng: random.Random):
        def step():
            return 1, [ImuSample(1.0, 0.0, np.zeros(3), np.zeros(3)), Checked(7)]

        return step

    r = run_target(Target("toy", "a toy", setup, nav=False), None, inputs=5)
    assert r.inputs == 5 and r.accepted == 5 * 8 and r.decoded_bad == 5


@pytest.mark.parametrize("fmt", ["csv", "px4-ulog", "px4-csv", "ardupilot-bin", "ardupilot-log", "rtklib", "ihlog"])
def test_short_seeds_are_valid_logs_of_every_kind_of_record(fmt: str, shared_dir, tmp_path) -> None:
    """Most reader inputs are cut from the short seeds: they still read as valid logs with IMU and GNSS samples, and
    the long seeds the replays are cut from are the longer cuts."""
    from ins_hil.datasets.dataset import read_dataset
    from ins_hil.fuzz.targets import FOLDERS, SHORT_RECORDS, _reader_seeds

    def read(seed: dict[str, bytes], name: str):
        d = tmp_path / name
        d.mkdir()
        for k, b in seed.items():
            (d / k).write_bytes(b)
        return read_dataset(d if fmt in FOLDERS else d / next(iter(seed)), fmt)

    shorts, longs = _reader_seeds(fmt, tmp_path, short=True), _reader_seeds(fmt, tmp_path)
    assert len(shorts) == len(longs) >= 1
    for i, (s, lg) in enumerate(zip(shorts, longs, strict=True)):
        a, b = read(s, f"s{i}"), read(lg, f"l{i}")
        assert SHORT_RECORDS * 0.6 <= len(a.imu) <= SHORT_RECORDS < len(b.imu)
        assert a.gnss and set(s) == set(lg)
        assert sum(map(len, s.values())) < sum(map(len, lg.values()))


def test_reader_target_still_replays_and_catches_a_nan_figure(shared_dir, monkeypatch) -> None:
    """An accepted input of a reader target is replayed while the replays are within their share (here all of the
    time): a NaN figure in its summary is returned as a finding."""
    from ins_hil.datasets import report
    from ins_hil.fuzz import targets

    monkeypatch.setattr(report, "format_table", lambda rows: "roll error rms nan deg")
    monkeypatch.setattr(targets, "REPLAY_SHARE", 1.0)
    for name in ("reader_csv", "reader_ardupilot_bin"):
        (t,) = by_name([name])
        step = t.setup(random.Random(1))
        found: list = []
        for _ in range(20):  # until an input is accepted (a mutated seed may be refused)
            found = [s for s in step()[1] if isinstance(s, Wrong)]
            if found:
                break
        assert found and "NaN" in found[0].what


#: the reader formats whose long (replayed) seeds get the core navigating under the replay config (every one: the
#: RTKLIB seed is the drive's drive-off, whose yaw comes from the GNSS course)
NAV_FORMATS = ["csv", "px4-ulog", "px4-csv", "ardupilot-bin", "ardupilot-log", "rtklib", "ihlog"]


def _long_seeds(fmt: str, tmp_path):
    from ins_hil.datasets.dataset import read_dataset
    from ins_hil.fuzz.targets import _mutated, reader_seeds

    seeds = reader_seeds(fmt)
    assert seeds
    return [read_dataset(_mutated(random.Random(0), {}, fmt, tmp_path / f"in{i}", s), fmt) for i, s in
            enumerate(seeds)]  # fmt: skip


@pytest.mark.parametrize("fmt", NAV_FORMATS)
def test_replayed_seeds_navigate_and_a_nan_after_alignment_is_caught(fmt: str, shared_dir, tmp_path, monkeypatch):
    """The unmutated long seed of each reader target, replayed as the target replays an accepted input, gets the
    core navigating (the NaN-state oracle sees a navigating filter); a NaN put into the navigating filter's state
    (here by the mechanization, late in the seed) is a finding, not a clean refusal."""
    from ins_hil.fuzz import Replayed
    from ins_hil.fuzz.targets import _replay_check, replay_config
    from ins_hil.nav.mechanization import StrapdownNED

    for ds in _long_seeds(fmt, tmp_path):
        out = _replay_check(ds, replay_config())
        assert [type(s) for s in out] == [Replayed] and out[0].navigating, out
        t_nan = ds.imu[0].t + 0.9 * (ds.imu[-1].t - ds.imu[0].t)
        step = StrapdownNED.step

        def poisoned(self, *a, _step=step, _t=t_nan, **k):
            _step(self, *a, **k)
            if self.state.t >= _t:
                self.state.vel_ned = self.state.vel_ned * float("nan")

        monkeypatch.setattr(StrapdownNED, "step", poisoned)
        out = _replay_check(ds, replay_config())
        monkeypatch.setattr(StrapdownNED, "step", step)
        wrong = [s for s in out if isinstance(s, Wrong)]
        assert wrong and "non-finite" in wrong[0].what, out


def test_dataset_config_replays_navigate(shared_dir) -> None:
    """The synthetic data set an accepted dataset config replays is long enough for the shipped flight configs'
    alignment: their cores navigate."""
    from ins_hil.datasets.config import load
    from ins_hil.fuzz.targets import CONFIG_SECONDS, ROOT, _replay_check, _synthetic_dataset

    for name in ("ardupilot_copter", "px4_quad"):
        out = _replay_check(_synthetic_dataset(CONFIG_SECONDS), load(ROOT / "configs/datasets" / f"{name}.toml"))
        assert len(out) == 1 and out[0].navigating, (name, out)


def test_campaign_counts_the_replays_that_navigated(shared_dir, monkeypatch) -> None:
    """The counts (and the state file) carry how many replayed inputs reached "navigating" per target."""
    from ins_hil.fuzz import TargetResult, run_target
    from ins_hil.fuzz import targets as T

    assert T.REPLAY_SHARE < 1.0
    monkeypatch.setattr(T, "REPLAY_SHARE", 1e9)  # every accepted input replayed: the count does not hang on timing
    (t,) = by_name(["reader_ihlog"])
    r = run_target(t, None, seed=5, inputs=40)
    assert 0 < r.replays_nav <= r.replays <= r.inputs
    back = TargetResult.from_dict(r.to_dict())
    assert (back.replays, back.replays_nav) == (r.replays, r.replays_nav)
    old = {k: v for k, v in r.to_dict().items() if k not in ("replays", "replays_nav")}  # a state written before
    assert TargetResult.from_dict(old).replays == 0
