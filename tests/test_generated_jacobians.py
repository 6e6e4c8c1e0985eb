"""The Jacobians generated from one SymPy derivation (firmware_ref/tools/derive_jacobians.py).

* change indication (as PX4's EKF2 derivation): regenerating gives the checked-in C header and Python module
  byte for byte, so an edit of the derivation without regenerating (or of a generated file by hand) fails;
* the generated F and H are the derivatives of the nonlinear error models (central differences on random states);
* the Python filter takes its F (``ErrorStateEKF.build_F``) and H (``ins_hil.fusion.measurements``) from the
  generated module, placed in its state layout; the C core uses the generated header (its parity with NavCore:
  tests/test_cref_parity.py).
"""

from __future__ import annotations

import importlib.util
import math
import sys
from pathlib import Path

import numpy as np
import pytest

from ins_hil.fusion import generated_jacobians as gj
from ins_hil.fusion import measurements as mm
from ins_hil.fusion.ekf import ErrorStateEKF, FilterConfig
from ins_hil.nav.rotation import dcm_from_quat, quat_normalize

REPO = Path(__file__).resolve().parent.parent
TOOL = REPO / "firmware_ref" / "tools" / "derive_jacobians.py"


def _tool():  # type: ignore[no-untyped-def]
    spec = importlib.util.spec_from_file_location("derive_jacobians", TOOL)
    assert spec is not None and spec.loader is not None
    mod = importlib.util.module_from_spec(spec)
    sys.modules["derive_jacobians"] = mod
    spec.loader.exec_module(mod)
    return mod


def test_regenerating_gives_the_checked_in_files() -> None:
    tool = _tool()
    c_src, py_src = tool.generate()
    assert tool.C_OUT.read_text() == c_src, "firmware_ref/src/generated/ins_jacobians.h is stale: regenerate"
    assert tool.PY_OUT.read_text() == py_src, "ins_hil/fusion/generated_jacobians.py is stale: regenerate"
    assert tool.main(["--check"]) == 0


def test_the_check_fails_on_an_edited_file(tmp_path: Path) -> None:
    tool = _tool()
    c_src, _ = tool.generate()
    edited = tmp_path / "ins_jacobians.h"
    edited.write_text(c_src.replace("b->vr_dd = g2r;", "b->vr_dd = -g2r;"))
    tool.C_OUT, was = edited, tool.C_OUT
    try:
        assert tool.main(["--check"]) == 1
    finally:
        tool.C_OUT = was


def _random_state(rng: np.random.Generator) -> dict[str, np.ndarray]:
    q = quat_normalize(rng.normal(size=4))
    m = rng.normal(size=3)
    m /= np.linalg.norm(m)
    if m[0] < -0.9:
        m[0] = -m[0]
    return {
        "C": dcm_from_quat(q),
        "f": rng.normal(0.0, 5.0, 3) + np.array((0.0, 0.0, -9.8)),
        "wie": np.array((7.29e-5 * math.cos(0.8), 0.0, -7.29e-5 * math.sin(0.8))),
        "wen": rng.normal(0.0, 3e-6, 3),
        "w": rng.normal(0.0, 0.5, 3),
        "l": rng.normal(0.0, 1.0, 3),
        "v": rng.normal(0.0, 10.0, 3),
        "m": m,
    }


def _sk(a: np.ndarray) -> np.ndarray:
    return np.array(((0.0, -a[2], a[1]), (a[2], 0.0, -a[0]), (-a[1], a[0], 0.0)))


def _numjac(fn, n_out: int, eps: float = 1e-6) -> np.ndarray:  # type: ignore[no-untyped-def]
    """Central differences of ``fn`` (15 error states → n_out) at the zero error state."""
    J = np.zeros((n_out, gj.NX))
    for k in range(gj.NX):
        d = np.zeros(gj.NX)
        d[k] = eps
        J[:, k] = (np.asarray(fn(d)) - np.asarray(fn(-d))) / (2 * eps)
    return J


def _parts(x: np.ndarray) -> tuple[np.ndarray, ...]:
    return x[0:3], x[3:6], x[6:9], x[9:12], x[12:15]


@pytest.mark.parametrize("seed", range(20))
def test_generated_jacobians_are_the_derivatives_of_the_nonlinear_models(seed: int) -> None:
    """The generated F and H against central differences of the nonlinear error models (δ = true − computed,
    Ĉ = (I + [μ×]) C): the error dynamics of the strapdown equations and each measurement's prediction."""
    rng = np.random.default_rng(seed)
    s = _random_state(rng)
    C, f, wie, wen, w, lev, v, m = s["C"], s["f"], s["wie"], s["wen"], s["w"], s["l"], s["v"], s["m"]
    itg, ita, g2r = 1.0 / 300.0, 1.0 / 200.0, 3.08e-6
    I3 = np.eye(3)

    def dyn(x: np.ndarray) -> np.ndarray:
        dr, dv, psi, dbg, dba = _parts(x)
        ddv = (I3 - _sk(psi)) @ (f - C @ dba) - f - np.cross(2 * wie + wen, dv) + np.array((0.0, 0.0, g2r * dr[2]))
        dpsi = -np.cross(wie + wen, psi) + C @ dbg
        return np.concatenate((dv, ddv, dpsi, -itg * dbg, -ita * dba))

    tol = {"rtol": 1e-6, "atol": 1e-8}
    np.testing.assert_allclose(gj.F(C, f, wie, wen, itg, ita, g2r), _numjac(dyn, 15), **tol)
    Ct = lambda psi: (I3 - _sk(psi)) @ C
    np.testing.assert_allclose(gj.H_gnss_pos(C, lev), _numjac(lambda x: x[0:3] + Ct(x[6:9]) @ lev - C @ lev, 3), **tol)
    np.testing.assert_allclose(
        gj.H_gnss_vel(C, w, lev),
        _numjac(lambda x: x[3:6] + Ct(x[6:9]) @ np.cross(w - x[9:12], lev) - C @ np.cross(w, lev), 3),
        **tol,
    )
    np.testing.assert_allclose(gj.H_baro(), _numjac(lambda x: -x[2:3], 1), **tol)
    np.testing.assert_allclose(gj.H_zupt(), _numjac(lambda x: x[3:6], 3), **tol)
    np.testing.assert_allclose(gj.H_zaru(), _numjac(lambda x: -x[9:12], 3), **tol)
    np.testing.assert_allclose(
        gj.H_nhc(C, v), _numjac(lambda x: (C.T @ (I3 + _sk(x[6:9])) @ (v + x[3:6]) - C.T @ v)[1:3], 2), **tol
    )
    tau = mm.tau_matrix(m)
    np.testing.assert_allclose(
        gj.H_mag(m), _numjac(lambda x: (tau @ np.cross(m, (I3 + _sk(x[6:9])) @ m))[1:3], 2), **tol
    )
    # the sensor-error columns: scale factors (f̃ = (1 + s) f + b) and the gyro g-sensitivity (ω̃ = ω + b + G f)
    fb, its = C.T @ f, 1.0 / 3600.0

    def dyn_s(xs: np.ndarray) -> np.ndarray:
        dsg, dsa, dG = xs[0:3], xs[3:6], xs[6:15].reshape(3, 3)
        out = np.zeros(gj.NXS)
        out[3:6] = -C @ (fb * dsa)
        out[6:9] = C @ (w * dsg + dG @ fb)
        out[15:21] = -its * xs[0:6]
        return out

    J = np.zeros((gj.NXS, 15))
    for k in range(15):
        d = np.zeros(15)
        d[k] = 1e-6
        J[:, k] = (dyn_s(d) - dyn_s(-d)) / 2e-6
    FS = gj.F_sensor(C, fb, w, its)
    np.testing.assert_allclose(FS[:, 15:], J, **tol)
    assert not np.any(FS[:, :15])


def _numjac_n(fn, n_in: int, n_out: int, eps: float = 1e-6) -> np.ndarray:  # type: ignore[no-untyped-def]
    J = np.zeros((n_out, n_in))
    for k in range(n_in):
        d = np.zeros(n_in)
        d[k] = eps
        J[:, k] = (np.asarray(fn(d)) - np.asarray(fn(-d))) / (2 * eps)
    return J


@pytest.mark.parametrize("seed", range(10))
def test_generated_aid_rows_are_the_derivatives_of_their_models(seed: int) -> None:
    """The aid rows (airspeed, odometer, drag, the mounted NHC, the longitudinal-acceleration prior, the magnetometer
    hard iron): central differences of each nonlinear model by [15 base states, the aid's states]."""
    rng = np.random.default_rng(100 + seed)
    s = _random_state(rng)
    C, w, lev, v = s["C"], s["w"], s["l"], s["v"]
    I3 = np.eye(3)
    tol = {"rtol": 1e-6, "atol": 1e-8}
    Ct_T = lambda psi: C.T @ (I3 + _sk(psi))  # C_true^T
    wind = rng.normal(0.0, 5.0, 2)
    u = v - np.array((wind[0], wind[1], 0.0))

    def ut(x: np.ndarray) -> np.ndarray:
        return u + x[3:6] - np.array((x[15], x[16], 0.0))

    np.testing.assert_allclose(gj.H_airspeed(u), _numjac_n(lambda x: [np.linalg.norm(ut(x))], 17, 1), **tol)
    k = 0.03
    np.testing.assert_allclose(
        gj.H_odometer(C, v, k), _numjac_n(lambda x: [(1 + k + x[15]) * (Ct_T(x[6:9]) @ (v + x[3:6]))[0]], 16, 1), **tol
    )
    mu = 0.3
    np.testing.assert_allclose(
        gj.H_drag(C, u, mu), _numjac_n(lambda x: -mu * (Ct_T(x[6:9]) @ ut(x))[0:2] + x[12:14], 17, 2), **tol
    )
    R = dcm_from_quat(quat_normalize(rng.normal(size=4)))
    np.testing.assert_allclose(
        gj.H_nhc_mounted(C, v, R, w, lev),
        _numjac_n(
            lambda x: ((I3 - _sk(x[15:18])) @ R @ (Ct_T(x[6:9]) @ (v + x[3:6]) + np.cross(w - x[9:12], lev)))[1:3],
            18,
            2,
        ),
        **tol,
    )
    g = 9.81
    np.testing.assert_allclose(  # the longitudinal-acceleration prior: (R (f_b − δb_a + C_true^T g))_x
        gj.H_long_accel(C, R, g),
        _numjac_n(lambda x: (R @ (w - x[12:15] + Ct_T(x[6:9]) @ np.array((0.0, 0.0, g))))[0:1], 15, 1),
        **tol,
    )
    m = s["m"]
    uu = rng.normal(size=3)
    tau = mm.tau_matrix(m)

    def mag(db: np.ndarray) -> np.ndarray:
        ub = uu + db
        nb = float(np.linalg.norm(ub))
        return np.concatenate(((tau @ np.cross(m, C @ (ub / nb)))[1:3], [-nb]))

    un = float(np.linalg.norm(uu))
    np.testing.assert_allclose(gj.H_mag_bias(m, C, uu / un, un), _numjac_n(mag, 3, 3), **tol)


def test_the_aid_modules_take_their_rows_from_the_generated_code() -> None:
    """mm / the aid modules place the generated rows: the base columns, then the aid's own states."""
    from ins_hil.aids.airspeed import true_airspeed
    from ins_hil.aids.odometer import odometer_speed
    from ins_hil.fusion.ekf import StateIndex

    rng = np.random.default_rng(3)
    s = _random_state(rng)
    C, v, w, lev = s["C"], s["v"], s["w"], s["l"]
    idx = StateIndex.build(FilterConfig(wind_states=True, mount_states=True), (("odo_sf", 1, 0.02, 0.0),))
    wind = np.array((2.0, -1.0))
    u = v - np.array((wind[0], wind[1], 0.0))
    _, H = true_airspeed(idx, v, wind, 10.0)
    g = gj.H_airspeed(u)
    np.testing.assert_array_equal(H[:, 3:6], g[:, 3:6])
    np.testing.assert_array_equal(H[:, idx.wind : idx.wind + 2], g[:, 15:17])
    _, H = mm.multirotor_drag(idx, C, v, wind, np.zeros(3), 0.3)
    g = gj.H_drag(C, u, 0.3)
    np.testing.assert_array_equal(H[:, 0:9], g[:, 0:9])
    np.testing.assert_array_equal(H[:, idx.ba : idx.ba + 3], g[:, 12:15])
    np.testing.assert_array_equal(H[:, idx.wind : idx.wind + 2], g[:, 15:17])
    R = dcm_from_quat(quat_normalize(rng.normal(size=4)))
    _, H, _ = mm.nonholonomic_mounted(idx, C, v, R, w, lev)
    g = gj.H_nhc_mounted(C, v, R, w, lev)
    np.testing.assert_array_equal(H[:, 0:9], g[:, 0:9])
    np.testing.assert_array_equal(H[:, idx.bg : idx.bg + 3], g[:, 9:12])
    np.testing.assert_array_equal(H[:, idx.mnt : idx.mnt + 3], g[:, 15:18])
    _, H = mm.longitudinal_accel(idx, C, R, 0.2, 9.81)
    g = gj.H_long_accel(C, R, 9.81)
    np.testing.assert_array_equal(H[:, 0:9], g[:, 0:9])
    np.testing.assert_array_equal(H[:, idx.ba : idx.ba + 3], g[:, 12:15])
    _, H = odometer_speed(idx, C, v, 0.01, 5.0)
    g = gj.H_odometer(C, v, 0.01)
    np.testing.assert_array_equal(H[:, 0:9], g[:, 0:9])
    assert H[0, idx.extra["odo_sf"]] == g[0, 15] and H.shape == (1, idx.n)
    idx_m = StateIndex.build(FilterConfig(mag_bias=True))
    _, H = mm.magnetometer(idx_m, C, C.T @ s["m"] * 40.0, s["m"] * 40.0, np.array((0.01, 0.0, -0.02)))
    assert idx_m.mb is not None and np.all(H[:, idx_m.mb : idx_m.mb + 3] != 0.0)


@pytest.mark.parametrize("states", [{}, {"accel_bias": False}, {"gyro_bias": False, "accel_bias": False},
                                    {"scale_factors": True}, {"gyro_gsens": True},
                                    {"scale_factors": True, "gyro_gsens": True}])  # fmt: skip
def test_the_filter_takes_its_F_and_H_from_the_generated_code(states: dict[str, bool]) -> None:
    """ErrorStateEKF.build_F and the measurement builders are the generated Jacobians placed in the filter's
    layout (bias columns moved or dropped; the states the derivation does not cover filled besides)."""
    rng = np.random.default_rng(7)
    s = _random_state(rng)
    C = s["C"]
    kf = ErrorStateEKF(FilterConfig(omega_rv_terms=False, **states))  # (those terms are not derived)
    idx = kf.idx
    itg, ita = 1.0 / kf.cfg.gyro_bias_tau, 1.0 / kf.cfg.accel_bias_tau
    F_gen = gj.F(C, s["f"], s["wie"], s["wen"], itg, ita, kf._g2r)
    rows = [r for r in range(15) if r < 9 or (idx.bg is not None and r < 12) or (idx.ba is not None and r >= 12)]
    to = [r if r < 9 else (idx.bg + r - 9 if r < 12 else idx.ba + r - 12) for r in rows]  # type: ignore[operator]
    F_hand = kf.build_F(C, s["f"], s["wie"], s["wen"], C.T @ s["f"], s["w"], 0.8, 100.0)
    np.testing.assert_array_equal(F_hand[np.ix_(to, to)], F_gen[np.ix_(rows, rows)])
    assert np.any(F_hand[6:9, 6:9] != 0.0) and np.any(F_hand[3:6, 6:9] != 0.0)
    # the sensor-error columns from the generated F_sensor, placed (full layout 15-17 s_g, 18-20 s_a, 21-29 G)
    FS = gj.F_sensor(C, C.T @ s["f"], s["w"], 1.0 / kf.cfg.sf_tau)
    for start, lo, hi in ((idx.sg, 15, 18), (idx.sa, 18, 21), (idx.gs, 21, 30)):
        if start is not None:
            cols = list(range(start, start + hi - lo))
            np.testing.assert_array_equal(F_hand[np.ix_(range(9), cols)], FS[0:9, lo:hi])
            assert np.any(FS[0:9, lo:hi] != 0.0)

    lat, lon, h = 0.8, 0.5, 100.0
    _, H = mm.gnss_position(idx, C, lat, lon, h, lat, lon, h, s["l"])
    np.testing.assert_array_equal(H, mm.placed(gj.H_gnss_pos(C, s["l"]), idx))
    _, H = mm.gnss_velocity(idx, C, s["v"], s["w"], s["v"], s["l"])
    np.testing.assert_array_equal(H, mm.placed(gj.H_gnss_vel(C, s["w"], s["l"]), idx))
    assert H.shape == (3, idx.n) and (idx.bg is None or np.any(H[:, idx.bg : idx.bg + 3] != 0.0))
    _, H = mm.nonholonomic(idx, C, s["v"])
    np.testing.assert_array_equal(H, mm.placed(gj.H_nhc(C, s["v"]), idx))
    _, H = mm.magnetometer(idx, C, C.T @ s["m"], s["m"])
    np.testing.assert_allclose(H, mm.placed(gj.H_mag(s["m"]), idx), rtol=1e-12, atol=1e-15)  # m renormalised
    z, H = mm.zero_rate(idx, s["w"])
    np.testing.assert_array_equal(H, mm.placed(gj.H_zaru(), idx))
    np.testing.assert_array_equal(z, -s["w"])
    _, H = mm.baro_height(idx, h, h)
    assert H.shape == (1, idx.n) and H[0, 2] == -1.0 and np.count_nonzero(H) == 1
