"""`ins-hil replay` on corrupted logs and configs (issue 39): under a 1 GiB address-space cap every run ends with
exit 0 and finite figures, or exit ≠ 0 and one line naming the file; a short valid log prints "not scored (why)",
never "nan"."""

from __future__ import annotations

import os
import random
import subprocess
import sys
from pathlib import Path

import pytest

from ins_hil.cli import main

sys.path.insert(0, str(Path(__file__).resolve().parent))
from test_datasets_replay import GOOD, _static_csv

CAP = 1 << 30  # bytes of address space
RUN = """
import resource, sys
resource.setrlimit(resource.RLIMIT_AS, ({cap}, {cap}))
from ins_hil.cli import main
sys.exit(main(sys.argv[1:]))
"""


def _replay(args: list[str], out: Path) -> tuple[int, str, str]:
    env = {**os.environ, "OPENBLAS_NUM_THREADS": "1", "OMP_NUM_THREADS": "1", "MPLBACKEND": "Agg"}
    env.pop("INS_HIL_DEBUG", None)
    p = subprocess.run([sys.executable, "-c", RUN.format(cap=CAP), "replay", *args, "--out", str(out), "--no-plots",
                        "--quiet"], capture_output=True, text=True, env=env, timeout=600)  # fmt: skip  # a hang guard
    return p.returncode, p.stdout, p.stderr


def _check(rc: int, out: str, err: str, name: str) -> None:
    if rc == 0:
        assert "nan" not in out.lower().replace("not scored", ""), out
    else:
        lines = [ln for ln in err.splitlines() if ln.strip()]
        assert rc in (1, 2) and len(lines) == 1 and name in lines[0], (rc, err)
        assert "Traceback" not in err and "internal error" not in err


def _mutations(good: bytes, rng: random.Random) -> list[bytes]:
    lines = good.split(b"\n")
    out = []
    flipped = bytearray(good)
    for _ in range(40):
        flipped[rng.randrange(30, len(flipped))] ^= 1 << rng.randrange(8)
    out.append(bytes(flipped))
    out.append(good[: len(good) // 3])  # truncated
    jump = list(lines)
    k = next(i for i, ln in enumerate(jump) if ln.startswith(b"imu,3.00"))
    jump[k] = jump[k].replace(b"imu,3.00,0.01", b"imu,3.00,3600")  # a dt of an hour
    out.append(b"\n".join(jump))
    back = [ln.replace(b"gnss,10.00", b"gnss,1e308") for ln in lines]  # aiding time far off
    out.append(b"\n".join(back))
    nan = [ln.replace(b"imu,20.00,0.01,", b"imu,20.00,0.01,nan,") for ln in lines]
    out.append(b"\n".join(nan) + b"\xff\xfe\n")  # and non-UTF-8 at the end
    return out


def test_corrupted_logs_end_cleanly_under_a_memory_cap(tmp_path: Path):
    good = tmp_path / "good.csv"
    _static_csv(good, seconds=30.0)
    cfg = tmp_path / "static.toml"
    cfg.write_text(GOOD)
    rng = random.Random(39)
    for i, data in enumerate(_mutations(good.read_bytes(), rng)):
        p = tmp_path / f"bad{i}.csv"
        p.write_bytes(data)
        rc, out, err = _replay([str(p), "--dataset", str(cfg)], tmp_path / f"out{i}")
        _check(rc, out, err, p.name)


@pytest.mark.parametrize("line", ["gnss_time_offset_s = -1e308", "gnss_time_offset_s = -9.2e18",
                                  "imu_time_offset_s = nan"])  # fmt: skip
def test_config_that_blew_13_gib_is_one_line(tmp_path: Path, line: str):
    good = tmp_path / "good.csv"
    _static_csv(good, seconds=10.0)
    cfg = tmp_path / "bad.toml"
    cfg.write_text(GOOD + f"[mounting]\n{line}\n")
    rc, out, err = _replay([str(good), "--dataset", str(cfg)], tmp_path / "out")
    assert rc == 2, (rc, out, err)
    _check(rc, out, err, "bad.toml")


def test_short_valid_log_prints_not_scored_instead_of_nan(tmp_path: Path, capsys: pytest.CaptureFixture[str]):
    data = tmp_path / "short.csv"
    _static_csv(data, seconds=3.0)  # too short to navigate: nothing to score
    cfg = tmp_path / "static.toml"
    cfg.write_text(GOOD)
    rc = main(["replay", str(data), "--dataset", str(cfg), "--out", str(tmp_path / "out"), "--no-plots", "--quiet"])
    text = capsys.readouterr().out
    assert rc == 0
    assert "nan" not in text.lower() and "not scored (the core never navigated)" in text, text


def test_non_finite_states_exit_1_naming_the_file_and_the_time(tmp_path: Path, capsys, monkeypatch):
    """A core whose state overflows (the pipeline's guard catches it; the gateway would restart the core): the
    replay gives no figures, exit 1 and one line naming the file and the time."""
    import numpy as np

    from ins_hil.core import NavCore

    data = tmp_path / "static.csv"
    _static_csv(data, seconds=20.0)
    cfg = tmp_path / "static.toml"
    cfg.write_text(GOOD)
    step = NavCore.step_begin

    def poisoned(self, imu):  # type: ignore[no-untyped-def]
        st = step(self, imu)
        if imu.t >= 10.0 and self.phase == "nav":  # the state overflows from here on
            self.ins.state.vel_ned = np.full(3, np.inf)
            return self.state()
        return st

    monkeypatch.setattr(NavCore, "step_begin", poisoned)
    rc = main(["replay", str(data), "--dataset", str(cfg), "--out", str(tmp_path / "out"), "--no-plots", "--quiet"])
    err = capsys.readouterr().err
    assert rc == 1 and "static.csv: non-finite navigation states from t = 10.0" in err and len(err.splitlines()) == 1
