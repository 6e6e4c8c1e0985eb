"""Golden replays: the change indication of the navigation numbers.

Three short, deterministic runs are reduced to one row per second of sensor time (state and σ,
six significant digits) and checked in under ``tests/golden/``:

- ``drive0708_120s.csv``: the real car drive's first 120 s after its first GNSS epoch, with the drive
  settings (ZUPT + NHC) and the outage protocol's windows inside that span (40–55 s, 85–100 s);
- ``sim_uav_python_60s.csv`` / ``sim_uav_c_60s.csv``: the simulated UAV scenario (seed 0, 60 s) through
  the Python core and through the C reference core (GNSS + baro: the settings both support).

Each file also holds the SHA-256 of the same rows in full precision (``repr`` of every float), so a change
that moves any number by one bit fails ``tests/test_golden.py``, and the six-digit rows show in the diff
how far it moved. A change that is meant to move the numbers regenerates the files::

    scripts/golden            # rewrite tests/golden/*.csv
    scripts/golden --check    # compare only (what the test does)
"""

from __future__ import annotations

import argparse
import dataclasses
import hashlib
import math
import re
import sys
from collections.abc import Callable, Iterable, Sequence
from pathlib import Path
from typing import Any

import blas_pin  # noqa: F401  (before numpy: one OpenBLAS kernel, bit-reproducible digests)
import numpy as np

REPO = Path(__file__).resolve().parent.parent
GOLDEN = Path(__file__).resolve().parent / "golden"
SHARED = REPO.parent / "shared"
DRIVE_SECONDS = 120.0
SIM_SECONDS = 60.0

COLUMNS = (
    "t_s", "n_m", "e_m", "d_m", "vn_mps", "ve_mps", "vd_mps", "roll_deg", "pitch_deg", "yaw_deg",
    "sn_m", "se_m", "sd_m", "svn_mps", "sve_mps", "svd_mps", "sroll_deg", "spitch_deg", "syaw_deg",
    "bgx_dps", "bgy_dps", "bgz_dps", "bax_mps2", "bay_mps2", "baz_mps2",
)  # fmt: skip


def _row(st: Any, origin: tuple[float, float, float]) -> list[float]:
    """One golden row of a NavState: NED position from ``origin`` (m), velocity, Euler angles, σ, biases."""
    from ins_hil.nav import earth
    from ins_hil.nav.rotation import euler_from_quat

    p = earth.ned_from_geodetic(st.lat, st.lon, st.h, *origin)
    eul = np.degrees(euler_from_quat(st.q_nb))
    vals: list[float] = [st.t, *p, *st.vel_ned, *eul, *st.std_pos, *st.std_vel, *np.degrees(st.std_att)]
    vals += [*np.degrees(st.gyro_bias), *st.accel_bias]
    return [float(v) for v in vals]


class _Sampler:
    """Keeps the state at the first step at or after every whole second of sensor time (from ``t0``)."""

    def __init__(self, t0: float, state: Callable[[], Any]) -> None:
        self.t0, self.state, self.next = t0, state, 0.0
        self.rows: list[list[float]] = []
        self.origin: tuple[float, float, float] | None = None

    def __call__(self, t: float, ready: bool) -> None:
        if not ready or t - self.t0 < self.next - 1e-9:
            return
        st = self.state()
        if self.origin is None:
            self.origin = (st.lat, st.lon, st.h)
        row = _row(st, self.origin)
        row[0] = t - self.t0
        self.rows.append(row)
        self.next = math.floor(t - self.t0 + 1e-9) + 1.0


def drive_rows(shared: Path = SHARED) -> list[list[float]]:
    """The drive's first ``DRIVE_SECONDS`` s through its dataset config (``configs/datasets/drive0708.toml``),
    replayed like ``ins_hil.datasets.run.run_dataset``."""
    from ins_hil.core import NavCore
    from ins_hil.datasets import config, rtklib
    from ins_hil.datasets.report import protocol_windows
    from ins_hil.datasets.run import prepare

    cfg = config.load(REPO / "configs" / "datasets" / "drive0708.toml")
    ds = rtklib.load(shared / "data" / "gnss_imu_drive_0708", cfg).dataset
    p = prepare(ds, cfg)
    t0 = float(p.gnss[0].t)
    end = t0 + DRIVE_SECONDS
    outs = [w for w in protocol_windows(ds, p, cfg) or [] if w[0] < end]
    gnss = [f for f in p.gnss if f.t < end and not any(a <= f.t < b for a, b in outs)]
    core = NavCore(None, p.nav)
    samp = _Sampler(t0, core.state)
    j = 0
    for s in p.imu:
        if s.t >= end:
            break
        core.step(s)
        while j < len(gnss) and gnss[j].t <= s.t:
            core.fuse(gnss[j])
            j += 1
        samp(s.t, core.phase == "nav")
    return samp.rows


def sim_rows(kind: str) -> list[list[float]]:
    """The simulated UAV scenario (seed 0, ``SIM_SECONDS`` s) through the ``python`` or ``c`` core."""
    from ins_hil.runtime.pipeline import nav_config
    from ins_hil.sim import scenarios
    from ins_hil.types import MagSample

    sc = scenarios.build("uav", seed=0, duration=SIM_SECONDS)
    # the settings both cores support (the C core has no magnetometer update): GNSS + baro
    cfg = nav_config(sc.nav)
    cfg = dataclasses.replace(cfg, mag=dataclasses.replace(cfg.mag, ref_ned=None))
    meas = [m for m in sc.meas if not isinstance(m, MagSample)]
    if kind == "python":
        from ins_hil.core import NavCore

        core: Any = NavCore(sc.initial, cfg)
    else:
        from ins_hil.cref import CNavCore

        core = CNavCore(sc.initial, cfg)
    order = sorted(meas, key=lambda m: getattr(m, "t_arrival_ns", 0) * 1e-9 or m.t)
    samp = _Sampler(float(sc.imu[0].t) - float(sc.imu[0].dt), core.state)
    j = 0
    for s in sc.imu:
        core.step(s)
        while j < len(order) and (getattr(order[j], "t_arrival_ns", 0) * 1e-9 or order[j].t) <= s.t + 1e-9:
            core.fuse(order[j])
            j += 1
        samp(s.t, True)
    return samp.rows


RUNS: dict[str, Callable[[], list[list[float]]]] = {
    "drive0708_120s": drive_rows,
    "sim_uav_python_60s": lambda: sim_rows("python"),
    "sim_uav_c_60s": lambda: sim_rows("c"),
}


def digest(rows: Iterable[Sequence[float]]) -> str:
    """SHA-256 of the rows in full precision (``repr`` of each float, one line per row)."""
    h = hashlib.sha256()
    for r in rows:
        h.update((",".join(repr(float(v)) for v in r) + "\n").encode())
    return h.hexdigest()


def libraries() -> str:
    """The numerical libraries the digest depends on: another numpy/scipy release may move the last bit."""
    import numpy
    import scipy

    return f"numpy {numpy.__version__}, scipy {scipy.__version__}"


def differs(want: str, got: str) -> bool:
    """True when ``got`` does not match the checked-in ``want``: the six-digit rows always, the full-precision
    digest when both were computed with the same numpy/scipy releases (the bit-for-bit change indication)."""
    w, g = want.splitlines(), got.splitlines()
    if w[2:] != g[2:] or w[0] != g[0]:
        return True
    lib = re.compile(r"\((numpy [^)]*)\)")
    wl, gl = lib.search(w[1]), lib.search(g[1])
    same_libs = wl is not None and gl is not None and wl.group(1) == gl.group(1)
    return same_libs and w[1] != g[1]


def render(name: str, rows: list[list[float]]) -> str:
    """The checked-in text: a header with the full-precision digest, then the six-digit rows."""
    lines = [
        f"# golden replay {name}: one row per second of sensor time (tests/golden_replay.py)",
        f"# sha256 of the full-precision rows ({libraries()}): {digest(rows)}",
        ",".join(COLUMNS),
    ]
    lines += [",".join(f"{v:.6g}" for v in r) for r in rows]
    return "\n".join(lines) + "\n"


def check(names: Iterable[str] = RUNS) -> list[str]:
    """Names whose replay no longer matches its checked-in file (bit for bit)."""
    bad = []
    for name in names:
        path = GOLDEN / f"{name}.csv"
        if not path.is_file() or differs(path.read_text(), render(name, RUNS[name]())):
            bad.append(name)
    return bad


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description="Regenerate (default) or check the golden replays in tests/golden/.")
    ap.add_argument("--check", action="store_true", help="compare with the checked-in files; exit 1 on a change")
    ap.add_argument("names", nargs="*", default=list(RUNS), help=f"runs (default: all of {', '.join(RUNS)})")
    a = ap.parse_args(argv)
    unknown = [n for n in a.names if n not in RUNS]
    if unknown:
        print(f"golden: unknown run(s) {', '.join(unknown)} (known: {', '.join(RUNS)})", file=sys.stderr)
        return 2
    if a.check:
        bad = check(a.names)
        for n in a.names:
            print(f"{n}: {'CHANGED' if n in bad else 'identical'}")
        return 1 if bad else 0
    GOLDEN.mkdir(exist_ok=True)
    for n in a.names:
        text = render(n, RUNS[n]())
        (GOLDEN / f"{n}.csv").write_text(text)
        print(f"{n}: {text.count(chr(10)) - 3} rows written to {GOLDEN / (n + '.csv')}")
    return 0


if __name__ == "__main__":
    sys.path.insert(0, str(REPO))
    raise SystemExit(main())
