"""Golden replays: the change indication of the navigation numbers.

Three short, deterministic runs are reduced to one row per second of sensor time (state, σ and biases, every
value in full precision) and checked in under ``tests/golden/``:

- ``drive0708_120s.csv``: the real car drive's first 120 s after its first GNSS epoch, with the drive
  settings (ZUPT + NHC) and the outage protocol's windows inside that span (40–55 s, 85–100 s);
- ``sim_uav_python_60s.csv`` / ``sim_uav_c_60s.csv``: the simulated UAV scenario (seed 0, 60 s) through
  the Python core and through the C reference core (GNSS + baro: the settings both support).

A replay matches its file when every value is within its column's tolerance (``tests/golden/tolerances.toml``):
a few hundred times the spread measured between emulated hosts (other numpy SIMD paths, other OpenBLAS
kernels), so a last-bit difference of libm or BLAS passes and a real change of the numbers fails
(docs/testing.md). A change that is meant to move the numbers regenerates the files::

    scripts/golden            # rewrite tests/golden/*.csv
    scripts/golden --check    # compare only (what the test does)
    scripts/golden --spread   # measure the spread between emulated hosts against the tolerances
"""

from __future__ import annotations

import argparse
import dataclasses
import hashlib
import math
import os
import subprocess
import sys
import tempfile
import tomllib
from collections.abc import Callable, Iterable, Sequence
from functools import partial
from pathlib import Path
from typing import Any

import blas_pin  # noqa: F401  (before numpy: one OpenBLAS kernel where it can be had: a smaller spread)
import numpy as np

REPO = Path(__file__).resolve().parent.parent
GOLDEN = Path(__file__).resolve().parent / "golden"
TOLERANCES = GOLDEN / "tolerances.toml"
SHARED = REPO.parent / "shared"
DRIVE_SECONDS = 120.0
SIM_SECONDS = 60.0

COLUMNS = (
    "t_s", "n_m", "e_m", "d_m", "vn_mps", "ve_mps", "vd_mps", "roll_deg", "pitch_deg", "yaw_deg",
    "sn_m", "se_m", "sd_m", "svn_mps", "sve_mps", "svd_mps", "sroll_deg", "spitch_deg", "syaw_deg",
    "bgx_dps", "bgy_dps", "bgz_dps", "bax_mps2", "bay_mps2", "baz_mps2",
)  # fmt: skip
#: columns compared modulo 360° (a heading or a roll near ±180° may come out on the other side)
WRAPPED = frozenset({"roll_deg", "yaw_deg"})

#: edits the NavConfig of a run (the sensitivity test changes one filter constant)
Tweak = Callable[[Any], Any]


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


def drive_rows(shared: Path = SHARED, tweak: Tweak | None = None) -> list[list[float]]:
    """The drive's first ``DRIVE_SECONDS`` s through its dataset config (``configs/datasets/drive0708.toml``),
    replayed like ``ins_hil.datasets.run.run_dataset``; ``tweak`` edits its NavConfig (the sensitivity test)."""
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
    core = NavCore(None, tweak(p.nav) if tweak else p.nav)
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


def sim_rows(kind: str, tweak: Tweak | None = None) -> list[list[float]]:
    """The simulated UAV scenario (seed 0, ``SIM_SECONDS`` s) through the ``python`` or ``c`` core; ``tweak``
    edits its NavConfig (the sensitivity test)."""
    from ins_hil.runtime.pipeline import nav_config
    from ins_hil.sim import scenarios
    from ins_hil.types import MagSample

    sc = scenarios.build("uav", seed=0, duration=SIM_SECONDS)
    # the settings both cores support (the C core has no magnetometer update): GNSS + baro
    cfg = nav_config(sc.nav)
    cfg = dataclasses.replace(cfg, mag=dataclasses.replace(cfg.mag, ref_ned=None))
    if tweak:
        cfg = tweak(cfg)
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


RUNS: dict[str, Callable[..., list[list[float]]]] = {
    "drive0708_120s": drive_rows,
    "sim_uav_python_60s": partial(sim_rows, "python"),
    "sim_uav_c_60s": partial(sim_rows, "c"),
}


def digest(rows: Iterable[Sequence[float]]) -> str:
    """SHA-256 of the rows in full precision (``repr`` of each float, one line per row): equal only when
    every value is equal to the last bit (two replays in one process)."""
    h = hashlib.sha256()
    for r in rows:
        h.update((",".join(repr(float(v)) for v in r) + "\n").encode())
    return h.hexdigest()


def render(name: str, rows: Sequence[Sequence[float]]) -> str:
    """The checked-in text: a header, then the rows with every value in full precision (``repr``)."""
    lines = [
        f"# golden replay {name}: one row per second of sensor time, full precision (tests/golden_replay.py);"
        " compared per column within tests/golden/tolerances.toml",
        ",".join(COLUMNS),
    ]
    lines += [",".join(repr(float(v)) for v in r) for r in rows]
    return "\n".join(lines) + "\n"


def parse(text: str, source: str = "golden") -> np.ndarray:
    """The rows of a checked-in file (rows × ``COLUMNS``, float64, bit for bit what ``render`` wrote)."""
    lines = [ln for ln in text.splitlines() if ln and not ln.startswith("#")]
    if not lines or tuple(lines[0].split(",")) != COLUMNS:
        raise ValueError(f"{source}: expected the header {','.join(COLUMNS)}")
    rows = [[float(v) for v in ln.split(",")] for ln in lines[1:]]
    if any(len(r) != len(COLUMNS) for r in rows):
        raise ValueError(f"{source}: every row needs {len(COLUMNS)} values")
    return np.array(rows, dtype=float).reshape(-1, len(COLUMNS))


def load(name: str) -> np.ndarray:
    """The checked-in rows of run ``name``."""
    path = GOLDEN / f"{name}.csv"
    return parse(path.read_text(), str(path))


@dataclasses.dataclass(frozen=True)
class Tolerance:
    """A column's tolerance: ``|now − golden| ≤ abs`` (the column's unit); ``spread``: the largest difference
    measured between emulated hosts (``scripts/golden --spread``) when it was chosen; ``reason``: why."""

    abs: float
    spread: float
    reason: str


def tolerances(path: Path = TOLERANCES) -> dict[str, Tolerance]:
    """The per-column tolerances (every column of ``COLUMNS``, from ``tests/golden/tolerances.toml``)."""
    doc = tomllib.loads(path.read_text())
    missing = [c for c in COLUMNS if c not in doc]
    if missing:
        raise ValueError(f"{path}: no tolerance for {', '.join(missing)}")
    return {c: Tolerance(float(doc[c]["abs"]), float(doc[c]["spread"]), str(doc[c]["reason"])) for c in COLUMNS}


def deviation(want: np.ndarray, got: np.ndarray) -> np.ndarray:
    """``|got − want|`` per value (rows × columns; angles of ``WRAPPED`` modulo 360°, NaN = NaN, a NaN
    against a number: inf). The shapes must be equal."""
    d = np.abs(got - want)
    for j, c in enumerate(COLUMNS):
        if c in WRAPPED:
            d[:, j] = np.abs((got[:, j] - want[:, j] + 180.0) % 360.0 - 180.0)
    both = np.isnan(want) & np.isnan(got)
    return np.where(both, 0.0, np.where(np.isnan(d), np.inf, d))


def compare(want: np.ndarray, got: np.ndarray, tol: dict[str, Tolerance]) -> list[str]:
    """One line per column whose largest deviation exceeds its tolerance (empty: the replay matches)."""
    if want.shape != got.shape:
        return [f"{got.shape[0]} rows instead of {want.shape[0]}"]
    d = deviation(want, got)
    bad = []
    for j, c in enumerate(COLUMNS):
        k = int(np.argmax(d[:, j])) if len(d) else 0
        if len(d) and d[k, j] > tol[c].abs:
            bad.append(
                f"{c}: |Δ| = {d[k, j]:.3g} > {tol[c].abs:g} at t = {want[k, 0]:.3f} s "
                f"(golden {want[k, j]!r}, now {got[k, j]!r})"
            )
    return bad


def check(names: Iterable[str] = RUNS) -> dict[str, list[str]]:
    """The runs whose replay no longer matches its checked-in file, with what moved."""
    tol = tolerances()
    bad = {}
    for name in names:
        path = GOLDEN / f"{name}.csv"
        if not path.is_file():
            bad[name] = [f"{path} is missing (scripts/golden writes it)"]
            continue
        msgs = compare(load(name), np.array(RUNS[name](), dtype=float).reshape(-1, len(COLUMNS)), tol)
        if msgs:
            bad[name] = msgs
    return bad


def host_variants() -> dict[str, dict[str, str | None]]:
    """Emulated hosts for ``--spread``: environment changes (None: unset) that move the last bits the way
    another machine does: numpy's SIMD dispatch (without AVX-512 numpy computes exp, log, atan2, tan,
    arcsin, power with libm instead of its own AVX-512 kernels), OpenBLAS's kernel, and no ``blas_pin``.
    Only the numpy features this CPU has are disabled."""
    from numpy._core._multiarray_umath import __cpu_features__ as have

    v: dict[str, dict[str, str | None]] = {"no blas_pin (OpenBLAS picks its kernel)": {"OPENBLAS_CORETYPE": None}}
    for core in ("SkylakeX", "Zen", "Sandybridge", "Nehalem", "Prescott"):
        v[f"OpenBLAS {core} kernel"] = {"OPENBLAS_CORETYPE": core}
    v["OpenBLAS on 1 thread"] = {"OPENBLAS_NUM_THREADS": "1"}
    feats = [f for f in ("AVX512_SPR", "AVX512_ICL", "X86_V4") if have.get(f)]
    if feats:
        v["numpy without AVX-512 (x86-64-v3)"] = {"NPY_DISABLE_CPU_FEATURES": " ".join(feats)}
    if have.get("X86_V3"):
        v3 = " ".join([*feats, "X86_V3"])
        v["numpy on x86-64-v2 (SSE4.2)"] = {"NPY_DISABLE_CPU_FEATURES": v3}
        old = {"NPY_DISABLE_CPU_FEATURES": v3, "OPENBLAS_CORETYPE": "Nehalem"}
        v["an old host: numpy x86-64-v2, OpenBLAS Nehalem"] = old
    return v


def _dump(names: Sequence[str], out: Path, env: dict[str, str | None]) -> None:
    """Run the replays in a child process with ``env`` applied and write them to ``out`` (.npz)."""
    e = dict(os.environ)
    for k, val in env.items():
        if val is None:
            e.pop(k, None)
        else:
            e[k] = val
    # the child skips blas_pin when OPENBLAS_CORETYPE is to be unset (the pin would set it again)
    unpinned = "OPENBLAS_CORETYPE" in env and env["OPENBLAS_CORETYPE"] is None
    stub = "import types; sys.modules['blas_pin'] = types.ModuleType('blas_pin'); " if unpinned else ""
    code = (
        f"import sys; {stub}sys.path[:0] = [{str(Path(__file__).parent)!r}, {str(REPO)!r}]; "
        "import golden_replay as g; raise SystemExit(g.main(sys.argv[1:]))"
    )
    subprocess.run([sys.executable, "-c", code, "--dump", str(out), *names], env=e, check=True)


def spread(names: Sequence[str]) -> int:
    """Print, per column, the largest deviation from the checked-in rows over ``host_variants`` and ``names``,
    against the tolerance; exit status 1 if any variant exceeds a tolerance."""
    tol = tolerances()
    want = {n: load(n) for n in names}
    worst = {c: (0.0, 0.0, "-") for c in COLUMNS}  # |Δ|, |Δ|/|golden|, where
    over = []
    with tempfile.TemporaryDirectory() as tmp:
        for i, (label, env) in enumerate(host_variants().items()):
            out = Path(tmp) / f"{i}.npz"
            _dump(names, out, env)
            got = np.load(out)
            for n in names:
                if got[n].shape != want[n].shape:
                    over.append(f"{label}, {n}: {got[n].shape[0]} rows instead of {want[n].shape[0]}")
                    continue
                d = deviation(want[n], got[n])
                rel = d / np.maximum(np.abs(want[n]), np.finfo(float).tiny)
                for j, c in enumerate(COLUMNS):
                    if d[:, j].max() > worst[c][0]:
                        worst[c] = (float(d[:, j].max()), float(rel[:, j][d[:, j] > 0].max()), f"{n}, {label}")
                over += [f"{label}, {n}: {m}" for m in compare(want[n], got[n], tol)]
            print(f"{label}: {', '.join(f'{k}={v}' for k, v in env.items())}", file=sys.stderr)
    print(f"{'column':<11} {'max |Δ|':>9} {'its |Δ|/|v|':>11} {'tolerance':>9} {'tol/|Δ|':>8}  where")
    for c in COLUMNS:
        d, r, where = worst[c]
        ratio = f"{tol[c].abs / d:8.0f}" if d > 0 else f"{'-':>8}"
        print(f"{c:<11} {d:9.2g} {r:11.2g} {tol[c].abs:9.2g} {ratio}  {where}")
    for m in over:
        print(f"OVER: {m}")
    return 1 if over else 0


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description="Regenerate (default) or check the golden replays in tests/golden/.")
    ap.add_argument("--check", action="store_true", help="compare with the checked-in files; exit 1 on a change")
    ap.add_argument(
        "--spread", action="store_true", help="measure the deviation on emulated hosts against the tolerances"
    )
    ap.add_argument("--dump", metavar="NPZ", type=Path, help=argparse.SUPPRESS)
    ap.add_argument("names", nargs="*", default=list(RUNS), help=f"runs (default: all of {', '.join(RUNS)})")
    a = ap.parse_args(argv)
    unknown = [n for n in a.names if n not in RUNS]
    if unknown:
        print(f"golden: unknown run(s) {', '.join(unknown)} (known: {', '.join(RUNS)})", file=sys.stderr)
        return 2
    if a.dump:
        np.savez(a.dump, **{n: np.array(RUNS[n](), dtype=float).reshape(-1, len(COLUMNS)) for n in a.names})
        return 0
    if a.spread:
        return spread(a.names)
    if a.check:
        bad = check(a.names)
        for n in a.names:
            print(f"{n}: {'CHANGED' if n in bad else 'within tolerance'}")
            for m in bad.get(n, []):
                print(f"  {m}")
        return 1 if bad else 0
    GOLDEN.mkdir(exist_ok=True)
    for n in a.names:
        text = render(n, RUNS[n]())
        (GOLDEN / f"{n}.csv").write_text(text)
        print(f"{n}: {text.count(chr(10)) - 2} rows written to {GOLDEN / (n + '.csv')}")
    return 0


if __name__ == "__main__":
    sys.path.insert(0, str(REPO))
    raise SystemExit(main())
