"""The dataset config validated in full at load (issue 39): finite numbers, ranges, shapes and types in every
table, one line naming the file and the key; a value that blew the replay's memory (gnss_time_offset_s = -1e308)
refused."""

from __future__ import annotations

from pathlib import Path

import pytest

from ins_hil.datasets import config as dcfg

HEAD = "[dataset]\nname = 'x'\n"
BAD = {
    "[mounting]\ngnss_time_offset_s = -1e308\n": r"mounting\.gnss_time_offset_s = -1e\+308: expected a number in",
    "[mounting]\ngnss_time_offset_s = -9.2e18\n": r"mounting\.gnss_time_offset_s = -9\.2e\+18",
    "[mounting]\nimu_time_offset_s = nan\n": r"mounting\.imu_time_offset_s = nan: expected a finite number",
    "[mounting]\nimu_to_body_deg = [0, inf, 0]\n": r"mounting\.imu_to_body_deg\[1\] = inf: expected a finite",
    "[mounting]\nimu_to_body_deg = [1e300, 0, 0]\n": r"imu_to_body_deg = \[1e\+300, 0, 0\]: expected 3",
    "[mounting]\ngnss_lever_arm_m = [0, 1e9, 0]\n": r"mounting\.gnss_lever_arm_m .*within ±100",
    "[aiding]\ndeclination_deg = 1e300\n": r"aiding\.declination_deg = 1e\+300",
    "[aiding]\nhold_rate_hz = 1e-300\n": r"aiding\.hold_rate_hz = 1e-300",
    "[aiding]\nmag_reference = [0, 0, -inf]\n": r"aiding\.mag_reference\[2\] = -inf",
    "[outages]\non_s = 1e-300\n": r"outages\.on_s = 1e-300",
    "[outages]\nstart_s = -1e308\n": r"outages\.start_s = -1e\+308",
    "[score]\nmin_fix_type = 99\n": r"score\.min_fix_type = 99: expected an integer in \[0, 6\]",
    "[score]\nagainst = [[1]]\n": r"score\.against = \[\[1\]\]: expected names",
    "[score]\nsettle_s = -5\n": r"score\.settle_s = -5",
    "[rtklib]\nmax_q = 0\n": r"rtklib\.max_q = 0",
    "[rtklib]\ntime_calib_s = 0\n": r"rtklib\.time_calib_s = 0",
    "[rtklib]\npos = ''\n": r"rtklib\.pos = '': expected a non-empty text",
    "[sensor]\ngyro_arw = -1.0\n": r"sensor\.gyro_arw = -1\.0: expected",
    "[sensor]\ngyro_bias_tau = 'slow'\n": r"sensor\.gyro_bias_tau = 'slow': expected",
    "[nav.gnss]\ngate = -3\n": r"nav\.gnss\.gate = -3: expected",
    "[nav.filter]\ninit_pos = [1, 2]\n": r"nav\.filter\.init_pos",
    "[nav.alignment]\ntime = inf\n": r"nav\.alignment\.time = inf: expected a finite number",
    "[dataset]\nposition_deg = [95, 0, 0]\n": r"dataset\.position_deg = \[95, 0, 0\]",
}


@pytest.mark.parametrize("body", list(BAD))
def test_bad_value_is_one_line_naming_file_and_key(tmp_path: Path, body: str):
    text = HEAD + body if not body.startswith("[dataset]") else body.replace("[dataset]\n", HEAD)
    p = tmp_path / "bad.toml"
    p.write_text(text)
    with pytest.raises(dcfg.DatasetConfigError, match=BAD[body]) as e:
        dcfg.load(p)
    assert "\n" not in str(e.value) and str(e.value).startswith(str(p)), str(e.value)


def test_shipped_dataset_configs_still_load():
    root = Path(__file__).resolve().parents[1] / "configs" / "datasets"
    for p in sorted(root.glob("*.toml")):
        assert dcfg.load(p).name
