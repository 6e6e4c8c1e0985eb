"""``CNavCore.run_gnss`` (``cref_run_gnss``): a stretch of GNSS fixes and the IMU samples between them in one C call
gives what one ``run_states`` per run of samples and one ``fuse`` per fix give (the same C calls in the same order):
the states, the covariance, the ratios, the gate events, the fixes held for a reset and the roll-backs, also when a
fix is rejected (the call stops there) and with fixes it does not take (a velocity that is not finite), on a
simulated flight with a 0.1-s velocity delay (``ins_hil.bench.core_replay.synthetic_log``)."""

from __future__ import annotations

import dataclasses
import math
from typing import Any, cast

import numpy as np
import pytest

from ins_hil.bench import core_replay as cr
from ins_hil.cref import CNavCore, RunStates
from ins_hil.types import GnssFix


@pytest.fixture(scope="module")
def log() -> Any:
    """The synthetic log (30 s) with hostile fixes: a 60-m position jump at 20 s (rejected), a velocity-only fix, a
    fix without velocity and one whose velocity is NaN (fused one by one)."""
    p = cr.synthetic_log(30.0)
    g = list(p.gnss)
    k = {round(f.t, 2): i for i, f in enumerate(g)}
    i20, i22, i24, i26 = k[20.0], k[22.0], k[24.0], k[26.0]
    g[i20] = dataclasses.replace(g[i20], lat=g[i20].lat + 60.0 / 6.4e6)
    g[i22] = dataclasses.replace(g[i22], lat=math.nan)
    g[i24] = dataclasses.replace(g[i24], vel_ned=None)
    g[i26] = dataclasses.replace(g[i26], vel_ned=np.array([0.0, math.nan, 0.0]))
    return dataclasses.replace(p, gnss=g)


def _core(p: Any) -> CNavCore:
    _, c, why = cr._cores(p.nav)
    assert c is not None, why
    return c


def _outcome(c: CNavCore) -> dict[str, Any]:
    st = c.state()
    state = np.concatenate(([st.t], st.q_nb, st.vel_ned, [st.lat, st.lon, st.h], st.gyro_bias, st.accel_bias,
                            st.std_pos, st.std_vel, st.std_att))  # fmt: skip
    return {"state": state, "P": c.covariance(), "ratios": dict(c._ratios),
            "events": [(e.t, e.detail) for e in c.drain_events()], "rejected": [(f.t, q) for f, q in c._rejected],
            "rollbacks": int(c._hist.rollbacks), "consecutive": [int(x) for x in c._e_cons[0:4]]}  # fmt: skip


def test_a_log_fed_with_run_gnss_ends_as_one_fuse_per_fix(log: Any) -> None:
    one, runs = _core(log), _core(log)
    cr.feed(log, one, gnss_runs=False)
    cr.feed(log, runs, gnss_runs=True)
    a, b = _outcome(one), _outcome(runs)
    assert a["rollbacks"] > 300 and len(a["events"]) >= 2  # the jump rejected, then accepted again
    assert any("gnss_pos innovation test ratio" in d for _, d in a["events"])
    # the same C calls in the same order on this host: equal, not close
    np.testing.assert_array_equal(a["state"], b["state"])
    np.testing.assert_array_equal(a["P"], b["P"])
    assert a["ratios"] == b["ratios"] and a["events"] == b["events"] and a["rejected"] == b["rejected"]
    assert (a["rollbacks"], a["consecutive"]) == (b["rollbacks"], b["consecutive"])


def _until_nav(p: Any) -> tuple[CNavCore, int, int]:
    """A C core fed up to its first navigating IMU sample (k) with the fixes before it (j)."""
    c = _core(p)
    inc, t, dts = p.imu_arrays()
    k = j = 0
    while c.phase != "nav":
        e = int(np.searchsorted(t, p.gnss[j].t, side="left")) + 1
        k += len(c.run_states(inc[k:e], t[k:e], dts[k:e]))
        while j < len(p.gnss) and p.gnss[j].t <= t[k - 1]:
            c.fuse(p.gnss[j])
            j += 1
    return c, k, j


def test_run_gnss_records_are_the_states_of_run_states_and_stop_at_the_rejected_fix(log: Any) -> None:
    inc, t, dts = log.imu_arrays()
    (a, k0, j0), (b, _, _) = _until_nav(log), _until_nav(log)
    fixes = [f for f in log.gnss[j0:] if f.t < 21.0 and f.vel_ned is not None]  # the jump at 20 s among them
    reach = np.searchsorted(t, [f.t for f in fixes], side="left") + 1
    ends, first = np.unique(np.maximum(reach, k0 + 1), return_index=True)
    ab = np.append(first, len(fixes)).astype(np.int64)
    r = b.run_gnss(inc, t, dts, k0, ends.astype(np.int64), ab, fixes, None)
    # the same, a run_states per group and a fuse per fix, up to the fix the call stopped at
    rows, ratios, k = [], [], k0
    for g in range(r.groups):
        rs = a.run_states(inc[k : ends[g]], t[k : ends[g]], dts[k : ends[g]])
        rows.append(cast(RunStates, rs).rows.copy())
        ratios += [rs[i].test_ratios for i in range(len(rs))]
        k = int(ends[g])
        for f in fixes[ab[g] : min(ab[g + 1], r.updates)]:
            a.fuse(f)
    assert r.why == 2 and fixes[r.updates - 1].t == pytest.approx(20.0)  # stopped at the rejected jump
    np.testing.assert_array_equal(np.vstack(rows), r.states.rows)
    assert [r.states[i].test_ratios for i in range(len(r.states))] == ratios
    assert r.t_pre == pytest.approx([float(t[int(ends[g]) - 1]) for g in range(r.groups) for _ in
                                     range(int(ab[g]), min(int(ab[g + 1]), r.updates))], abs=0)  # fmt: skip
    x, y = _outcome(a), _outcome(b)
    np.testing.assert_array_equal(x["state"], y["state"])
    assert x["ratios"] == y["ratios"] and x["events"] == y["events"] and x["rejected"] == y["rejected"]
    assert len(y["rejected"]) == 1
    with pytest.raises(ValueError, match="no rejected fix held"):  # fuse takes the fixes after a rejection
        b.run_gnss(inc, t, dts, int(ends[r.groups - 1]), ends[r.groups :].astype(np.int64),
                   ab[r.groups :] - ab[r.groups], fixes[int(ab[r.groups]) :], None)  # fmt: skip


def test_run_gnss_refuses_what_fuse_takes_one_by_one(log: Any) -> None:
    inc, t, dts = log.imu_arrays()
    c, k0, j0 = _until_nav(log)
    f = log.gnss[j0]
    e = np.array([k0 + 5], dtype=np.int64)
    ab = np.array([0, 1], dtype=np.int64)
    t0 = c.state().t
    bad_vel = dataclasses.replace(f, vel_ned=np.array([0.0, math.inf, 0.0]))
    with pytest.raises(ValueError, match="velocity must be None or finite"):
        c.run_gnss(inc, t, dts, k0, e, ab, [bad_vel], None)
    with pytest.raises(ValueError, match=r"GnssFix\.std_d must be >= 0"):
        c.run_gnss(inc, t, dts, k0, e, ab, [dataclasses.replace(f, std_d=-1.0)], None)
    with pytest.raises(ValueError, match="int64 end rising"):
        c.run_gnss(inc, t, dts, k0, np.array([k0], dtype=np.int64), ab, [f], None)
    assert c.state().t == t0  # nothing ran
    r = c.run_gnss(inc, t, dts, k0, e, ab, [f], records=False)
    assert (r.groups, r.updates, r.why, len(r.states), r.t_pre) == (1, 1, 0, 0, [])
    assert c.state().t == t[k0 + 4] and isinstance(f, GnssFix)
