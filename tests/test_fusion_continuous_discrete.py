"""Seed 003's continuous–discrete Kalman filter (ins_hil.fusion.continuous_discrete) against independent forms:
a closed-form scalar case, Van Loan's exact discretisation, and a hand-written discrete filter in the
small-step limit; asynchronous sensors each at its own time."""

from __future__ import annotations

import math

import numpy as np
import pytest

from ins_hil.fusion.continuous_discrete import ContinuousDiscreteKF, DiscreteKF, make_linear_filter


def _scalar_closed_form(a, b, q, r, x0, p0, u, meas):
    """ṗ = 2ap + q: p(t) = (p0 + q/2a) e^{2at} − q/2a; x(t) = x0 e^{at} + bu (e^{at} − 1)/a; update c = 1."""
    t, x, p = 0.0, x0, p0
    for tn, y in meas:
        d = tn - t
        e = math.exp(a * d)
        x = x * e + b * u * (e - 1.0) / a
        p = (p + q / (2 * a)) * e * e - q / (2 * a)
        k = p / (p + r)
        x, p, t = x + k * (y - x), (1 - k) * p, tn
    return x, p


def test_scalar_matches_closed_form_at_irregular_times():
    a, b, q, r, u = -0.4, 2.0, 0.3, 0.5, 0.7
    rng = np.random.default_rng(3)
    times = np.cumsum(rng.uniform(0.01, 0.9, 25))
    meas = [(float(t), float(y)) for t, y in zip(times, rng.normal(2.0, 1.0, 25), strict=True)]
    f = make_linear_filter("continuous_discrete", [[a]], [[q]], [1.0], [[4.0]], {"s": ([[1.0]], [[r]])}, B=[[b]],
                           max_step=0.005)  # fmt: skip
    f.run([(t, "s", [y]) for t, y in meas], u=[u])
    x, p = _scalar_closed_form(a, b, q, r, 1.0, 4.0, u, meas)
    assert f.x[0] == pytest.approx(x, rel=1e-10)
    assert f.P[0, 0] == pytest.approx(p, rel=1e-10)


def _model():
    # position–velocity–accelerometer-bias model, two sensors at their own (interleaved, irregular) times
    A = np.array([[0.0, 1.0, 0.0], [0.0, 0.0, -1.0], [0.0, 0.0, -1.0 / 50.0]])
    Q = np.diag([0.0, 0.04, 2 * 0.01**2 / 50.0])
    sensors = {"pos": (np.array([[1.0, 0.0, 0.0]]), np.array([[4.0]])),
               "vel": (np.array([[0.0, 1.0, 0.0]]), np.array([[0.01]]))}  # fmt: skip
    rng = np.random.default_rng(7)
    tp = np.cumsum(rng.uniform(0.8, 1.2, 30))
    tv = np.cumsum(rng.uniform(0.15, 0.45, 90))
    meas = [(float(t), "pos", rng.normal(size=1)) for t in tp] + [(float(t), "vel", rng.normal(size=1)) for t in tv]
    return A, Q, sensors, meas


def test_matches_van_loan_discrete_filter_with_asynchronous_sensors():
    A, Q, sensors, meas = _model()
    P0 = np.diag([25.0, 1.0, 0.01])
    cd = make_linear_filter("continuous_discrete", A, Q, np.zeros(3), P0, sensors, max_step=0.01)
    dk = make_linear_filter("discrete", A, Q, np.zeros(3), P0, sensors)
    out_cd, out_dk = cd.run(meas), dk.run(meas)
    assert cd.n_updates == len(meas) == 120
    for (t1, x1, p1), (t2, x2, p2) in zip(out_cd, out_dk, strict=True):
        assert t1 == t2
        assert np.max(np.abs(p1 - p2)) <= 1e-9 * np.max(np.abs(p2))
        assert np.max(np.abs(x1 - x2)) <= 1e-9 * (1.0 + np.max(np.abs(x2)))


def test_small_step_limit_of_the_first_order_discrete_filter():
    """Φ = I + AΔt, Q_d = QΔt in N steps between measurements converges to the continuous–discrete P as O(Δt)."""
    A, Q, sensors, meas = _model()
    meas = sorted(meas, key=lambda m: m[0])[:40]
    P0 = np.diag([25.0, 1.0, 0.01])
    cd = ContinuousDiscreteKF(A=A, Q=Q, x=np.zeros(3), P=P0, max_step=0.01)
    for k, (c, r) in sensors.items():
        cd.add_sensor(k, c, r)
    cd.run(meas)

    def euler_filter(n_sub):
        x, P, t = np.zeros(3), P0.copy(), 0.0
        for tn, name, y in meas:
            h = (tn - t) / n_sub
            for _ in range(n_sub):
                Phi = np.eye(3) + A * h
                x, P = Phi @ x, Phi @ P @ Phi.T + Q * h
            C, R = sensors[name]
            K = P @ C.T @ np.linalg.inv(C @ P @ C.T + R)
            x, P, t = x + K @ (y - C @ x), (np.eye(3) - K @ C) @ P, tn
        return x, P

    errs = [np.max(np.abs(euler_filter(n)[1] - cd.P)) / np.max(np.abs(cd.P)) for n in (50, 100, 200)]
    assert errs[0] < 5e-3
    assert 1.8 < errs[0] / errs[1] < 2.2 and 1.8 < errs[1] / errs[2] < 2.2  # first order: the limit is cd.P


def test_rk4_step_converges_to_fourth_order():
    A, Q, _, _ = _model()
    P0 = np.diag([25.0, 1.0, 0.01])
    ref = DiscreteKF(A=A, Q=Q, x=np.zeros(3), P=P0)
    ref.predict_to(3.0)
    err = []
    for h in (0.5, 0.25):
        f = ContinuousDiscreteKF(A=A, Q=Q, x=np.zeros(3), P=P0, max_step=h)
        f.predict_to(3.0)
        err.append(np.max(np.abs(f.P - ref.P)))
    assert 12.0 < err[0] / err[1] < 20.0


def test_bad_input_is_refused_in_one_line():
    f = make_linear_filter("continuous_discrete", [[0.0]], [[1.0]], [0.0], [[1.0]], {"s": ([[1.0]], [[1.0]])})
    f.update("s", [1.0], t=2.0)
    with pytest.raises(ValueError, match="before the filter's time"):
        f.update("s", [1.0], t=1.0)
    with pytest.raises(ValueError, match="unknown sensor"):
        f.update("gnss", [1.0], t=3.0)
    with pytest.raises(ValueError, match="expected one of"):
        make_linear_filter("ukf", [[0.0]], [[1.0]], [0.0], [[1.0]])
    with pytest.raises(ValueError, match="do not fit"):
        f.add_sensor("bad", [[1.0, 0.0]], [[1.0]])
