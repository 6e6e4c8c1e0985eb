"""The fast paths of a replay (``ins-hil replay … --core c``, whole process): they give what the slow paths gave.

The C core's batched epochs (``Pipeline.imu_run`` → ``CNavCore.run_states``: one C call for the IMU samples up
to the next hand-over) against one ``Pipeline.imu`` per sample; the χ² thresholds without scipy; a dataset
config's check without the gateway's drivers; the DataFlash reader stepping over the messages it does not want;
the track's NED in one call."""

from __future__ import annotations

import dataclasses
import json
import math
import struct
import subprocess
import sys
from pathlib import Path
from typing import Any

import numpy as np
import pytest

import ins_hil.runtime.pipeline as pipeline_mod
from ins_hil.cref import CNavCore
from ins_hil.datasets import config, dataflash
from ins_hil.datasets.run import GnssScore, Track, offline_config
from ins_hil.fdi.thresholds import chi2_sf, chi2_threshold
from ins_hil.nav import earth
from ins_hil.nav.mechanization import StrapdownState
from ins_hil.runtime.pipeline import Pipeline
from ins_hil.types import FaultMode, GnssFix, ImuSample, NavState

ORIGIN = (0.8, 0.5, 100.0)


def _nav() -> Any:
    return config.from_dict({"dataset": {"name": "t"}, "nav": {"alignment": {"mode": "given"}}}).nav_config()


def _imu(n: int = 400, seed: int = 3) -> list[ImuSample]:
    """A jittering 100-Hz IMU with 0.3 s of lost data before sample 150, a sample whose time goes back (200)
    and one with an impossible interval (260): the validation boundary refuses those two."""
    rng = np.random.default_rng(seed)
    out, t = [], 0.0
    for k in range(n):
        dt = 0.01 * (1.0 + 0.02 * rng.standard_normal())
        t += dt + (0.3 if k == 150 else 0.0)
        dth = 1e-3 * rng.standard_normal(3)
        dv = np.array([0.02, -0.01, -9.80665 * dt]) + 1e-3 * rng.standard_normal(3)
        out.append(ImuSample(t, dt, dth, dv))
    out[200] = dataclasses.replace(out[200], t=out[199].t - 0.005)
    out[260] = dataclasses.replace(out[260], dt=5.0)
    return out


def _fixes(imu: list[ImuSample]) -> list[GnssFix]:
    lat, lon, h = ORIGIN
    return [GnssFix(s.t, lat, lon, h, np.zeros(3), 1.0, 2.0, 0.3) for s in imu[10::20]]


def _replay(batched: bool, extra: tuple[Any, ...] = ()) -> tuple[Pipeline, Track, GnssScore]:
    """The offline loop's feed (every fix after the IMU sample that reaches its time, then flushed), through
    ``Pipeline.imu_run`` (batched) or one ``Pipeline.imu`` per sample."""
    imu = _imu()
    fixes = _fixes(imu)
    withheld = fixes[5:7]
    fused = [f for f in fixes if f not in withheld]
    track, score = Track(ORIGIN), GnssScore(np.zeros(3), ORIGIN, withheld)
    init = StrapdownState(np.array([1.0, 0.0, 0.0, 0.0]), np.zeros(3), *ORIGIN, 0.0)
    pipe = Pipeline(offline_config(True, "c"), [track, score, *extra], nav=_nav(), initial=init)
    # the core of an offline replay: per-sample step lengths (make_core's with no initial state, after the
    # alignment's hand-over)
    core = pipe.core = CNavCore(init.copy(), _nav(), fixed_step=False)
    core.batched = 0  # type: ignore[attr-defined]
    run_states = core.run_states

    def counted(*a: Any) -> list[NavState]:
        core.batched += 1  # type: ignore[attr-defined]
        return run_states(*a)

    core.run_states = counted  # type: ignore[method-assign]
    j, k = 0, 0
    while k < len(imu):
        k_end = k + 1
        if batched:
            while k_end < len(imu) and not (j < len(fused) and fused[j].t <= imu[k_end - 1].t):
                k_end += 1
            pipe.imu_run(imu[k:k_end])
        else:
            pipe.imu(imu[k])
        t = imu[k_end - 1].t
        while j < len(fused) and fused[j].t <= t:
            pipe.aid(fused[j])
            j += 1
        pipe.flush()
        k = k_end
    return pipe, track, score


def _same_state(a: NavState, b: NavState) -> None:
    for f in dataclasses.fields(NavState):
        u, v = getattr(a, f.name), getattr(b, f.name)
        if isinstance(u, np.ndarray):
            assert np.array_equal(u, v), f.name
        else:
            assert u == v, f.name


def test_the_batched_c_epochs_are_the_per_sample_ones() -> None:
    one, t1, s1 = _replay(batched=False)
    run, t2, s2 = _replay(batched=True)
    assert isinstance(run.core, CNavCore) and len(t1.states) > 300
    assert len(t1.states) == len(t2.states)
    for a, b in zip(t1.states, t2.states, strict=True):
        _same_state(a, b)  # the same C steps: bit for bit
    assert one.counts == run.counts and one.counts.get("reject_imu_time") == 1 and one.counts.get("reject_imu_dt") == 1
    assert [(e.t, e.sensor, e.mode, e.detail) for e in one.drain_events()] == [
        (e.t, e.sensor, e.mode, e.detail) for e in run.drain_events()
    ]
    # the 0.3 s lost, and the interval of each refused sample
    assert one.core.imu_lost == run.core.imu_lost and run.core.imu_lost[0] == 3  # type: ignore[union-attr]
    assert run.core.batched > 5 and one.core.batched == 0  # type: ignore[union-attr]
    assert [(r.fix.t, r.inside, r.prior.tolist()) for r in s1.sorted_rows()] == [
        (r.fix.t, r.inside, r.prior.tolist()) for r in s2.sorted_rows()
    ]


@pytest.mark.parametrize("precision", ["double", "float"])
def test_run_states_gives_the_states_and_the_lost_data_of_step(precision: Any) -> None:
    """run_states gives step_begin's states (after the mechanization, before the time update); state() after it
    is step()'s (after the time update)."""
    imu = [s for k, s in enumerate(_imu()) if k not in (200, 260)]
    init = StrapdownState(np.array([1.0, 0.0, 0.0, 0.0]), np.zeros(3), *ORIGIN, 0.0)
    a, b = (CNavCore(init.copy(), _nav(), fixed_step=False, precision=precision) for _ in range(2))
    a.step(imu[0])
    b.step(imu[0])
    one = [a.step_begin(s) for s in imu[1:]]
    assert not np.array_equal(one[-1].std_pos, a.state().std_pos)  # the time update grew σ after the publication
    inc = np.array([np.concatenate([s.dtheta, s.dvel]) for s in imu[1:]])
    assert b.can_run()
    run = b.run_states(inc, np.array([s.t for s in imu[1:]]), np.array([s.dt for s in imu[1:]]))
    for u, v in zip(one, run, strict=True):
        _same_state(u, v)
    _same_state(a.state(), b.state())
    assert b.run_gap_rows == [149, 199, 258] and a.imu_lost == b.imu_lost  # the 0.3 s; samples 200, 260 left out
    ea, eb = a.drain_events(), b.drain_events()
    assert [(e.t, e.magnitude, e.detail) for e in ea] == [(e.t, e.magnitude, e.detail) for e in eb]
    assert len(eb) == 3 and all(e.mode == FaultMode.DROPOUT for e in eb)
    with pytest.raises(ValueError, match="fixed_step=False"):
        CNavCore(init.copy(), _nav()).run_states(inc[:2], np.ones(2), np.ones(2))


def test_the_c_state_follows_every_change_of_the_core() -> None:
    """CNavCore.state() is built once per change: a step, an update (with a velocity-delay roll-back) each give
    a new state, and asking twice between them gives the same one."""
    nav = dataclasses.replace(_nav(), gnss=dataclasses.replace(_nav().gnss, vel_delay=0.05))
    init = StrapdownState(np.array([1.0, 0.0, 0.0, 0.0]), np.zeros(3), *ORIGIN, 0.0)
    c = CNavCore(init, nav, fixed_step=False)
    imu = [s for k, s in enumerate(_imu()) if k < 100]
    for s in imu:
        c.step(s)
    st = c.state()
    assert c.state() is st
    lat, lon, h = ORIGIN
    c.fuse(GnssFix(imu[-1].t, lat + 1e-6, lon, h + 1.0, np.array([0.5, 0.0, 0.0]), 1.0, 2.0, 0.3))
    st2 = c.state()
    assert st2 is not st and st2.lat != st.lat and not np.array_equal(st2.vel_ned, st.vel_ned)
    assert int(c._hist.rollbacks) == 1  # the velocity, 0.05 s older, by roll-back
    c.step(ImuSample(imu[-1].t + 0.01, 0.01, np.zeros(3), np.array([0.0, 0.0, -0.0980665])))
    assert c.state() is not st2 and c.state().t == pytest.approx(imu[-1].t + 0.01)


@pytest.mark.parametrize("dof", [1, 2, 3, 4, 5, 6, 9])
def test_chi2_threshold_is_scipys_isf(dof: int) -> None:
    from scipy.special import gammainccinv

    for p in (1e-12, 1e-9, 1e-6, 1e-3, 0.05, 0.5):
        x = chi2_threshold(p, dof)
        assert x == pytest.approx(2.0 * gammainccinv(0.5 * dof, p), rel=1e-12)
        assert chi2_sf(x, dof) == pytest.approx(p, rel=1e-12)
    with pytest.raises(ValueError, match="integer"):
        chi2_threshold(0.01, 0)


def test_a_dataset_replay_starts_without_scipy_cantools_or_pymavlink() -> None:
    """What ``ins-hil replay --dataset`` loads before reading: the command, the dataset config (its [nav] tables
    checked against the core's schema), the pipeline with its drift monitor. Not the gateway's drivers (cantools,
    pymavlink), nor scipy for the monitor's χ² thresholds."""
    code = (
        "import sys\n"
        "from pathlib import Path\n"
        "import ins_hil.commands.replay\n"
        "from ins_hil.datasets import config\n"
        "from ins_hil.datasets.run import offline_config\n"
        "from ins_hil.runtime.pipeline import Pipeline\n"
        "c = config.load(Path('configs/datasets/px4_quad.toml'))\n"
        "Pipeline(offline_config(True, 'c'), nav=c.nav_config())\n"
        "print(sorted(m for m in ('scipy', 'cantools', 'pymavlink', 'can') if m in sys.modules))\n"
    )
    root = __import__("pathlib").Path(__file__).resolve().parent.parent
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, cwd=root, check=True)
    assert out.stdout.strip() == "[]", out.stdout + out.stderr


def test_the_core_nav_schema_alone_is_the_full_schemas() -> None:
    from ins_hil import config_schema

    full = {s.name: s for s in config_schema.sections()}
    for s in config_schema._nav_sections():
        assert s == full[s.name]


def _fmt(mid: int, name: str, length: int, form: str, cols: str) -> bytes:
    return b"\xa3\x95\x80" + struct.pack("<BB4s16s64s", mid, length, name.encode(), form.encode(), cols.encode())


def test_dataflash_messages_not_wanted_are_stepped_over_as_if_unpacked() -> None:
    """A message type the reader does not want is stepped over without unpacking it: by its length when its
    body unpacks, by its header when its FMT length does not fit its format (as an unpacked one would be), and a
    log cut inside one ends there."""
    imu = _fmt(0x81, "IMU", 11, "Q", "TimeUS")
    good = _fmt(0x82, "GOOD", 7, "I", "A")
    bad = _fmt(0x83, "BAD", 9, "I", "A")  # 6 bytes of body for a 4-byte format: skipped after its header

    def m(mid: int, body: bytes) -> bytes:
        return b"\xa3\x95" + bytes([mid]) + body

    body = b"".join(
        m(0x81, struct.pack("<Q", k)) + m(0x82, struct.pack("<I", k)) + m(0x83, struct.pack("<I", k) + b"\0\0")
        for k in range(20)
    )
    log = imu + good + bad + body
    for tail in (b"", m(0x82, b"\x01\x02")):  # complete, or cut inside a GOOD message
        data = log + tail
        want_all = dataflash.binary_rows(data, {"IMU", "GOOD", "BAD"})
        want_imu = dataflash.binary_rows(data, {"IMU"})
        assert want_imu["IMU"] == want_all["IMU"] and [d["TimeUS"] for d in want_imu["IMU"]] == list(range(20))
        assert len(want_all["GOOD"]) == 20 and want_all["BAD"] == []
    cut = log[: -len(m(0x83, b"\0" * 6)) - 9]  # the last IMU message cut: the log ends before it
    assert [d["TimeUS"] for d in dataflash.binary_rows(cut, {"IMU"})["IMU"]] == list(range(19))


def test_ned_from_geodetic_many_is_the_one_point_routine() -> None:
    rng = np.random.default_rng(1)
    llh = np.column_stack([0.6 + 1e-4 * rng.standard_normal(200), 0.1 + 1e-4 * rng.standard_normal(200),
                           100.0 + 10.0 * rng.standard_normal(200)])  # fmt: skip
    one = np.array([earth.ned_from_geodetic(*r, 0.6, 0.1, 90.0) for r in llh])
    assert np.allclose(earth.ned_from_geodetic_many(llh, 0.6, 0.1, 90.0), one, rtol=0.0, atol=1e-9)
    assert earth.ned_from_geodetic_many(np.zeros((0, 3)), 0.6, 0.1, 90.0).shape == (0, 3)
    assert math.isfinite(float(one[0, 0]))


def test_ned_from_geodetic_with_its_reference_held_is_the_same_routine() -> None:
    """A caller holding the origin's ``ned_ref`` (the replay's scores: many points, one origin) gets the numbers
    of the plain call, bit for bit (the same operations), and so does ``antenna_ned`` given it and C_b^n."""
    from ins_hil.datasets.run import antenna_ned
    from ins_hil.nav.rotation import dcm_from_quat

    rng = np.random.default_rng(2)
    ref = earth.ned_ref(0.6, 0.1, 90.0)
    for lat, lon, h in zip(0.6 + 1e-3 * rng.standard_normal(50), 0.1 + 1e-3 * rng.standard_normal(50),
                           100.0 + 10.0 * rng.standard_normal(50), strict=True):  # fmt: skip
        assert np.array_equal(earth.ned_from_geodetic(lat, lon, h, 0.6, 0.1, 90.0, ref=ref),
                              earth.ned_from_geodetic(lat, lon, h, 0.6, 0.1, 90.0))  # fmt: skip
        q = rng.standard_normal(4)
        st = NavState(t=1.0, q_nb=q / np.linalg.norm(q), vel_ned=rng.standard_normal(3), lat=lat, lon=lon, h=h)
        lever = rng.standard_normal(3)
        plain = antenna_ned(st, lever, 1.004, (0.6, 0.1, 90.0))
        assert np.array_equal(antenna_ned(st, lever, 1.004, (0.6, 0.1, 90.0), ref, dcm_from_quat(st.q_nb)), plain)
        assert np.linalg.norm(plain - earth.ned_from_geodetic(lat, lon, h, 0.6, 0.1, 90.0)) > 0.0


def test_states_at_takes_each_point_to_the_first_state_at_or_after_it() -> None:
    """The observers' matching of points to one call's states (``GnssScore`` and ``ReferenceScore.epochs``):
    a point at a state's time is that state's, one between two states the later's; points after the last
    state wait for the next call."""
    from ins_hil.datasets.run import states_at

    def at(t: float) -> NavState:
        return NavState(t, np.array([1.0, 0.0, 0.0, 0.0]), np.zeros(3), 0.6, 0.1, 90.0)

    states = [at(t) for t in (1.0, 2.0, 3.0)]
    points = [0.5, 1.0, 1.5, 2.0, 3.0, 3.5]
    assert states_at(points, 0, states) == ([0, 0, 1, 1, 2], 5)
    assert states_at(points, 2, states) == ([1, 1, 2], 5)
    assert states_at(points, 5, states) == ([], 5)  # 3.5 s: after the last state
    assert states_at(points, 5, [at(3.5)]) == ([0], 6)
    assert states_at(points, 6, states) == ([], 6) and states_at(points, 0, []) == ([], 0)


def test_bench_core_reads_the_batch_ratio_off_the_replay_command(monkeypatch: pytest.MonkeyPatch) -> None:
    """bench-core's Dask section takes serial / parallel wall times and the ratio from the line `ins-hil replay
    --batch … --compare-serial` prints (ins_hil/commands/replay.py), and leaves out what the C core refuses."""
    from ins_hil.bench import core_replay

    seen: list[list[str]] = []

    class Done:
        returncode = 0
        stdout = ("| job | ... |\nserial 62.8 s, parallel 91.0 s (LocalCluster of 2 workers): 0.69x; every job the "
                  "same results\n")  # fmt: skip
        stderr = ""

    def fake_run(cmd: list[str], **kw: Any) -> Done:
        seen.append(cmd)
        return Done()

    monkeypatch.setattr(subprocess, "run", fake_run)
    row = core_replay.batch_row(seeds=4, workers=2)
    assert (row["serial_s"], row["parallel_s"]) == (62.8, 91.0) and row["ratio"] == pytest.approx(62.8 / 91.0)
    assert row["same"] == "every job the same results" and len(row["runs"]) == core_replay.BATCH_REPEAT
    # every shipped config with its recording on disk is either run or named as refused (with the reason)
    have = {p.stem for p in core_replay.CONFIGS.glob("*.toml") if (c := config.load(p)).path and c.path.exists()}
    assert set(row["configs"]) | {r.split(" ")[0] for r in row["refused"]} == have
    assert all("(" in r for r in row["refused"])
    warm, cmd = seen[0], seen[1]  # an unmeasured small batch first (the bytecode cache), then the measured runs
    assert warm[warm.index("--seeds") + 1] == "2" and len(seen) == 1 + core_replay.BATCH_REPEAT
    assert cmd[cmd.index("--core") + 1] == "c" and "--compare-serial" in cmd and cmd[cmd.index("--seeds") + 1] == "4"
    md = core_replay.batch_md(row)
    assert "| 62.8 | 91.0 | 0.69× |" in md and "NOT met" in md


def test_bench_core_batch_counts_the_least_wall_time_of_each_side_over_its_runs(monkeypatch: Any) -> None:
    """The batch comparison runs the command BATCH_REPEAT times and takes each side's least wall time (other tenants
    only slow a run down): a slow serial run does not flatter the ratio, nor a slow Dask run spoil it; every run's
    figures are printed, and a run whose jobs differ is reported."""
    import subprocess

    from ins_hil.bench import core_replay

    same = "every job the same results"
    outs = iter([(1.0, 1.0, "warm-up"), (9.0, 5.0, same), (12.4, 5.1, same), (8.0, 4.9, "results differ: a#1")])

    class Done:
        returncode = 0
        stderr = ""

        def __init__(self) -> None:
            a, b, same = next(outs)
            self.stdout = f"serial {a} s, parallel {b} s (LocalCluster of 2 workers): {a / b:.2f}x; {same}\n"

    monkeypatch.setattr(subprocess, "run", lambda cmd, **kw: Done())
    row = core_replay.batch_row(seeds=4, workers=2, repeat=3)
    assert (row["serial_s"], row["parallel_s"]) == (8.0, 4.9) and row["ratio"] == pytest.approx(8.0 / 4.9)
    assert row["same"] == "results differ: a#1"
    md = core_replay.batch_md(row)
    assert "9.0 / 5.0 s, 1.80×; 12.4 / 5.1 s, 2.43×; 8.0 / 4.9 s, 1.63×" in md and "median ratio 1.80×" in md
    assert "| 8.0 | 4.9 | 1.63× |" in md and "NOT met" in md


def test_bench_core_splits_the_batch_cpu_into_parsing_and_running_two_at_once(tmp_path: Path) -> None:
    """batch_cpu sums the jobs' CPU of both runs and compares the replay times of the jobs whose log came from the
    cache in both (the same work): their ratio is the cost of two jobs at once, and 2 over it the ceiling of 2
    workers that batch_md prints beside the batch's own ratio."""
    from ins_hil.bench import core_replay

    def job(name: str, cached: bool, cpu: float, replay: float) -> dict[str, Any]:
        return {"job": name, "cached": cached, "cpu_s": cpu, "replay_s": replay}

    ser = [job("a#0", False, 1.2, 1.0), job("a#1", True, 1.0, 1.0), job("b#0", False, 0.5, 0.4),
           job("b#1", True, 0.4, 0.4)]  # fmt: skip
    par = [job("a#0", False, 1.5, 1.2), job("a#1", True, 1.25, 1.25), job("b#0", False, 0.6, 0.5),
           job("b#1", False, 0.6, 0.5)]  # fmt: skip  # b#1 parsed again on the other worker: not compared
    (tmp_path / "batch.json").write_text(json.dumps({"rows": par, "compare_serial": {"serial_rows": ser}}))
    got = core_replay.batch_cpu(tmp_path / "batch.json")
    assert got["cpu_serial_s"] == pytest.approx(3.1) and got["cpu_parallel_s"] == pytest.approx(3.95)
    assert (got["replay_serial_s"], got["replay_parallel_s"], got["replay_jobs"]) == (1.0, 1.25, 1.0)
    assert core_replay.batch_cpu(tmp_path / "missing.json") == {}
    row = {"configs": ["a", "b"], "refused": [], "seeds": 2, "workers": 2, "serial_s": 3.2, "parallel_s": 2.0,
           "ratio": 1.6, "same": "every job the same results", "load_before": (0.3,), "load_after": (0.9,),
           **got}  # fmt: skip
    md = core_replay.batch_md(row)
    assert "×1.25 per job when both workers run" in md and "2 / 1.25 = 1.60×" in md and "(100% of that)" in md
    assert "NOT met" in md


def test_the_c_guard_of_a_run_is_state_ok_row_by_row() -> None:
    from ins_hil.runtime.pipeline import QNORM_TOL, STATE_H_MAX, STATE_H_MIN, STATE_SPEED_MAX, state_ok

    rng = np.random.default_rng(5)
    rows = np.zeros((64, 32))
    q = rng.standard_normal((64, 4))
    rows[:, 1:5] = q / np.linalg.norm(q, axis=1, keepdims=True)
    rows[:, 5:8] = rng.standard_normal((64, 3))
    rows[:, 8], rows[:, 9], rows[:, 10] = 0.8, 0.5, 100.0
    rows[:, 17:26] = np.abs(rng.standard_normal((64, 9)))
    bad = [(1, 1, 1.1), (2, 5, 2e4), (3, 8, 1.6), (4, 9, 2e3), (5, 10, -2e5), (6, 10, 2e6), (7, 17, -0.1),
           (8, 22, math.inf), (9, 25, math.nan), (10, 6, math.nan), (11, 2, math.inf), (12, 8, math.nan),
           (20, 9, -2e3), (30, 7, -2e4), (40, 10, math.nan), (50, 19, math.inf), (60, 23, -0.0)]  # fmt: skip
    for r, c, x in bad:
        rows[r, c] = x
    want = [state_ok(NavState(t=o[0], q_nb=o[1:5], vel_ned=o[5:8], lat=o[8], lon=o[9], h=o[10], std_pos=o[17:20],
                              std_vel=o[20:23], std_att=o[23:26])) for o in rows]  # fmt: skip
    assert want.count(False) == len(bad) - 1  # σ = -0.0 passes (0.0 <= -0.0)
    core = CNavCore(StrapdownState(np.array([1.0, 0.0, 0.0, 0.0]), np.zeros(3), *ORIGIN, 0.0), _nav(), dt=0.01)
    lims = (QNORM_TOL, STATE_SPEED_MAX, STATE_H_MIN, STATE_H_MAX)
    for k in range(65):  # the first state that fails, from each row on (len: none), and of the 26 columns only
        first = next((i for i, ok in enumerate(want[k:]) if not ok), 64 - k)
        assert core.first_bad(rows[k:], *lims) == first, k
        assert core.first_bad(rows[k:, :26], *lims) == first, k
    assert core.first_bad(rows[13:20], *lims) == 7 and core.first_bad(rows[12:13], *lims) == 0


def test_a_bad_state_inside_a_batched_run_is_the_per_sample_core_fault() -> None:
    """A run whose state leaves the plausible range (here 15 g forward for 75 s: over 10 km/s) faults the core at
    the same sample on both paths: the same counts (core_bad_state, core_restart), events and published states."""

    def feed(batched: bool) -> tuple[Pipeline, Track]:
        init = StrapdownState(np.array([1.0, 0.0, 0.0, 0.0]), np.zeros(3), *ORIGIN, 0.0)
        track = Track(ORIGIN)
        pipe = Pipeline(offline_config(False, "c"), [track], nav=_nav(), initial=init)
        pipe.core = CNavCore(init.copy(), _nav(), fixed_step=False)
        dv = np.array([15.0 * 9.80665 * 0.01, 0.0, -9.80665 * 0.01])
        imu = [ImuSample(0.01 * (k + 1), 0.01, np.zeros(3), dv) for k in range(7500)]
        if batched:
            pipe.imu_run(imu)
        else:
            for s in imu:
                pipe.imu(s)
        return pipe, track

    (one, t1), (run, t2) = feed(False), feed(True)
    assert one.counts.get("core_bad_state", 0) >= 1 and one.counts.get("core_restart") == 1 and one.counts == run.counts
    assert [(e.t, e.detail) for e in one.drain_events()] == [(e.t, e.detail) for e in run.drain_events()]
    assert len(t1.states) == len(t2.states)
    for a, b in zip(t1.states, t2.states, strict=True):
        _same_state(a, b)


def test_the_batched_c_runs_reach_the_track_as_rows_with_the_same_arrays() -> None:
    """On the batched C path the track keeps each run's state-record rows (``RunStates``: a ``NavState`` built
    only for the run's last state and for the withheld fixes scored in it), and its arrays are the per-sample
    path's, bit for bit."""
    from ins_hil.cref import RunStates

    built = [0]
    getitem = RunStates.__getitem__

    def counting(self: RunStates, i: Any) -> Any:
        built[0] += 1
        return getitem(self, i)

    RunStates.__getitem__ = counting  # type: ignore[method-assign,assignment]
    try:
        p1, t1, s1 = _replay(batched=False)
        p2, t2, s2 = _replay(batched=True)
        runs = [c for c in t2._chunks if isinstance(c, RunStates)]
        assert runs and sum(len(c) for c in runs) > 250
        # the 2 withheld fixes (and a slack of 2): the pipeline's last state of a run is built only when read
        assert built[0] <= 2 + 2, built
        assert p1.last_state is not None and p2.last_state is not None
        _same_state(p1.last_state, p2.last_state)
        assert p2.last_state is p2.last_state and p2._good is p2.last_state and built[0] <= 2 + 2 + 1
    finally:
        RunStates.__getitem__ = getitem  # type: ignore[method-assign]
    a1, a2 = t1.arrays(), t2.arrays()
    assert a1.keys() == a2.keys()
    for k in a1:
        assert np.array_equal(a1[k], a2[k]), k
    assert [(r.fix.t, r.prior.tolist(), r.state.t) for r in s1.sorted_rows() if r.inside] == [
        (r.fix.t, r.prior.tolist(), r.state.t) for r in s2.sorted_rows() if r.inside
    ]


def test_the_reference_score_takes_a_batched_run_as_it_takes_each_epoch() -> None:
    """``ReferenceScore.epochs`` scores each reference point inside a window at the first state at or after its
    time, as its per-epoch path does: the same rows (time, error, σ) on the batched C path."""
    from ins_hil.datasets.dataset import Trajectory
    from ins_hil.datasets.reference import ReferenceScore

    imu = _imu()
    t_ref = np.arange(0.05, imu[-1].t, 0.037)  # not on the IMU times; some between a run's samples
    pos = np.column_stack((0.1 * t_ref, -0.05 * t_ref, np.zeros_like(t_ref)))
    tr = Trajectory("ref", t_pos=t_ref, pos_ned=pos, origin=ORIGIN)
    windows = [(0.5, 1.2), (2.0, 2.6), (3.1, 3.9)]
    one, two = (ReferenceScore(tr, ORIGIN, np.array([0.1, 0.0, -0.05]), windows) for _ in range(2))
    _replay(False, (one,))
    _replay(True, (two,))
    assert len(one.rows) > 40
    rows = [[(t, e.tolist(), s.tolist()) for t, e, s in sc.rows] for sc in (one, two)]
    assert rows[0] == rows[1]


def test_a_screened_replay_checks_each_imu_sample_once() -> None:
    """``replay(screened=True)`` (a ``Prepared``'s samples, which passed ``screen``): the pipeline's validator does
    not check them a second time once it knows the period (only its learning samples), and the states, counts
    and events are those of the checked replay; an unscreened stream is still checked sample by sample (the
    pipeline refuses its two bad samples)."""
    from ins_hil.datasets.run import replay, screen
    from ins_hil.validation import LEARN_SAMPLES

    raw = _imu()
    sc = screen(raw, [], [], "t")
    assert len(sc.imu) == len(raw) - 2 and "2 of 400 IMU samples dropped" in sc.notes[0]  # the one boundary
    fixes = _fixes(sc.imu)
    init = StrapdownState(np.array([1.0, 0.0, 0.0, 0.0]), np.zeros(3), *ORIGIN, 0.0)

    aid_calls = [0]

    def run(imu: list[ImuSample], screened: bool) -> tuple[Pipeline, Track, int]:
        calls = [0]
        track = Track(ORIGIN)
        aid_calls[0] = 0

        def setup(pipe: Pipeline) -> None:
            pipe.core = CNavCore(init.copy(), _nav(), fixed_step=False)
            val, check = pipe._val_imu, pipe.validator.check

            def counted(s: ImuSample) -> str | None:
                calls[0] += 1
                return val(s)

            def counted_aid(s: Any) -> str | None:
                aid_calls[0] += 1
                return check(s)

            pipe._val_imu = counted  # type: ignore[method-assign]
            pipe.validator.check = counted_aid  # type: ignore[method-assign]

        pipe, _ = replay(imu, fixes, _nav(), [track], initial=init, pipeline=offline_config(False, "c"), setup=setup,
                         screened=screened)  # fmt: skip
        return pipe, track, calls[0]

    once, t1, n1 = run(sc.imu, True)
    assert aid_calls[0] == 0  # the screened fixes: not checked again
    twice, t2, n2 = run(sc.imu, False)
    assert aid_calls[0] == len(fixes)
    assert n2 == len(sc.imu) and n1 <= LEARN_SAMPLES + 25, (n1, n2)  # the period learnt, then none
    assert once.counts == twice.counts and once.counts.get("fused_GnssFix", 0) > 10
    assert len(t1.states) == len(t2.states) == len(sc.imu)
    for a, b in zip(t1.states, t2.states, strict=True):
        _same_state(a, b)
    raw_pipe, _, n3 = run(raw, False)
    assert n3 >= len(raw) and raw_pipe.counts.get("reject_imu_time") == 1 and raw_pipe.counts.get("reject_imu_dt") == 1


def test_the_c_state_guard_is_state_ok_of_the_state_and_builds_no_state() -> None:
    """``CNavCore.state_guard`` (the pipeline's check after an aiding segment and at a flush) is ``state_ok`` of
    ``state()`` on good and bad states; a batched replay's segments and flushes build no ``NavState`` for it."""
    from ins_hil.runtime.pipeline import QNORM_TOL, STATE_H_MAX, STATE_H_MIN, STATE_SPEED_MAX, state_ok

    lims = (QNORM_TOL, STATE_SPEED_MAX, STATE_H_MIN, STATE_H_MAX)
    init = StrapdownState(np.array([1.0, 0.0, 0.0, 0.0]), np.zeros(3), *ORIGIN, 0.0)
    for field, i, x in (("", 0, 0.0), ("P", 0, math.nan), ("P", 4, -1.0), ("v", 1, 2e4), ("q", 0, 1.1),
                        ("h", 0, -2e5), ("lat", 0, math.nan)):  # fmt: skip
        core = CNavCore(init.copy(), _nav(), fixed_step=False)
        for s in _imu()[:20]:
            core.step(s)
        c = core._core
        if field == "P":
            c.ekf.P[i][i] = x
        elif field in ("v", "q"):
            getattr(c.mech, field)[i] = x
        elif field:
            setattr(c.mech, field, x)
        core._st = None  # (written behind the core's back)
        assert core.state_guard(*lims) is state_ok(core.state()) is (field == ""), field
    # a batched replay on C: no state_ok of a built state after its segments and at its flushes
    calls = [0]

    def counting(st: NavState) -> bool:
        calls[0] += sys._getframe(1).f_code.co_name in ("_segment", "flush")
        return state_ok(st)

    old = pipeline_mod.state_ok
    pipeline_mod.state_ok = counting
    try:
        pipe, _, score = _replay(batched=True)
    finally:
        pipeline_mod.state_ok = old
    assert sum(r.fused for r in score.rows) > 10 and pipe.counts.get("core_bad_state", 0) == 0
    assert calls[0] == 0, calls
