"""Dump the navigation states of the first T s of the real drive replay (outage protocol, with and without
aids) to an .npz, or compare two dumps exactly: the bit-identity check for changes in the core.

    python scripts/diagnostics/drive_states.py dump before.npz [--seconds 120]
    python scripts/diagnostics/drive_states.py compare before.npz after.npz
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np

from ins_hil.core import NavCore
from ins_hil.datasets import config as dataset_config
from ins_hil.datasets import study

DRIVE_CONFIG = Path(__file__).resolve().parents[2] / "configs" / "datasets" / "drive0708.toml"


def dump(path: Path, seconds: float) -> None:
    cfg_ds = dataset_config.load(DRIVE_CONFIG)
    _, dr, outs_p = study.load(cfg_ds)  # the prepared drive (imu, gnss, nav) and its protocol
    outages = outs_p
    t_end = dr.imu[0].t + seconds
    imu = [s for s in dr.imu if s.t <= t_end]
    gnss = [f for f in dr.gnss if f.t <= t_end]
    out: dict[str, np.ndarray] = {}
    for aids in (False, True):
        core = NavCore(None, dr.nav if aids else study.without_aids(dr.nav))
        rows = []
        j = 0
        for s in imu:  # the fuse order of ins_hil.datasets.evaluate.run_drive
            core.step(s)
            while j < len(gnss) and gnss[j].t <= s.t:
                f = gnss[j]
                j += 1
                if not any(a <= f.t < b for a, b in outages):
                    core.fuse(f)
            st = core.state()
            rows.append(
                np.concatenate(
                    (
                        [st.t, st.lat, st.lon, st.h],
                        st.q_nb,
                        st.vel_ned,
                        st.gyro_bias,
                        st.accel_bias,
                        st.std_pos,
                        st.std_vel,
                        st.std_att,
                    )
                )
            )
        out[f"aids_{int(aids)}"] = np.array(rows)
        print(f"aids={aids}: {len(rows)} states, final t {rows[-1][0]:.3f}")
    np.savez(path, **out)


def compare(a: Path, b: Path) -> int:
    da, db = np.load(a), np.load(b)
    bad = 0
    for k in da.files:
        x, y = da[k], db[k]
        same = x.shape == y.shape and np.array_equal(x, y)
        print(f"{k}: {x.shape} {'BIT-IDENTICAL' if same else 'DIFFERENT'}")
        if not same and x.shape == y.shape:
            d = np.argwhere(x != y)
            k = d[0][0]
            print(f"  first difference at state {k} (t {x[k, 0]:.3f}), max |diff| {np.max(np.abs(x - y)):.3e}")
        bad += not same
    return 1 if bad else 0


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("cmd", choices=("dump", "compare"))
    ap.add_argument("files", nargs="+", type=Path, help="dump: the .npz to write; compare: the two .npz to compare")
    ap.add_argument("--seconds", type=float, default=120.0, help="dump: the first S s of the drive (default 120)")
    a = ap.parse_args(argv)
    want = 1 if a.cmd == "dump" else 2
    if len(a.files) != want:
        ap.error(f"{a.cmd} takes {want} file(s), got {len(a.files)}")
    if a.cmd == "dump":
        if not 0 < a.seconds < float("inf"):
            ap.error(f"--seconds {a.seconds:g}: must be a positive number of seconds")
        from ins_hil.commands._outputs import OutputPathError, out_file

        try:
            out_file(a.files[0], "dump")  # before the replay, not after it
        except OutputPathError as e:
            ap.error(str(e))
        dump(a.files[0], a.seconds)
        return 0
    for f in a.files:
        if not f.is_file():
            ap.error(f"{f}: no such file")
    return compare(a.files[0], a.files[1])


if __name__ == "__main__":
    sys.exit(main())
