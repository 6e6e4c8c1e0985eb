"""The dataset readers and the dataset config are targets of the project's fuzz campaign (issue 39): each runs,
seeded from the shipped logs, without an escaped exception or a sample outside the physical ranges."""

from __future__ import annotations

import random

import pytest

from ins_hil.fuzz import bad_sample
from ins_hil.fuzz.targets import TARGETS, Wrong, by_name

NAMES = ["reader_csv", "reader_px4_ulog", "reader_px4_csv", "reader_ardupilot_bin", "reader_ardupilot_log",
         "reader_rtklib", "reader_ihlog", "dataset_config"]  # fmt: skip


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
